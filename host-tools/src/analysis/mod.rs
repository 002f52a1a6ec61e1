//! Analyses of a program and its run that move nothing: the pre-flight check against
//! the machine ([`preflight`]) and plots of a run ([`plot`]).

pub mod plot;
pub mod preflight;
