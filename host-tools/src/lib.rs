//! # pkmc host tools
//!
//! `nc-send` and the simulator: the G-code front end ([`gcode`]), machine files
//! ([`machine_file`]), the simulated controller ([`sim`]), both ends of the serial link
//! ([`link`]) and the job runner shared by `nc-send` and the tests ([`job`]).

pub mod blocks;
pub mod canon;
pub mod contour_study;
pub mod discover;
pub mod faults;
pub mod gcode;
pub mod input;
pub mod job;
pub mod link;
pub mod machine_file;
pub mod plant;
pub mod plot;
pub mod preflight;
pub mod progress;
pub mod sim;
