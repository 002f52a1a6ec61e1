//! A block's motion: its vocabulary ([`block`]: what the host asks for and the plan
//! it streams with it), its path in exact integers ([`geometry`]), speed profiles
//! ([`profile`]), the look-ahead on the host and the controller's queue
//! ([`planner`]), and the executor that advances the path each 1 ms tick
//! ([`interp`]).

pub mod block;
pub mod geometry;
pub mod interp;
pub mod planner;
pub mod profile;
