//! Analyses of a program and its run that move nothing: the pre-flight check against
//! the machine ([`preflight`]), the joint forces of a cutting load ([`statics`]) and
//! plots of a run ([`plot`]).

pub mod deviation;
pub mod plot;
pub mod preflight;
pub mod statics;
