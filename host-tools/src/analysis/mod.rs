//! Analyses of a program and its run that move nothing: the pre-flight check against
//! the machine ([`preflight`]), the joint forces of a cutting load ([`statics`]),
//! plots of a run ([`plot`]) and the tool's direction from A and B ([`direction`]).

pub mod deviation;
pub mod direction;
pub mod plot;
pub mod preflight;
pub mod statics;
