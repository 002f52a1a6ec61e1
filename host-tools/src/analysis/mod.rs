//! Analyses of a program or a machine that move nothing: the pre-flight check against
//! the machine ([`preflight`]), plots of a run ([`plot`]) and the contour-error study of
//! the seeds' controller schemes ([`contour_study`]).

pub mod contour_study;
pub mod plot;
pub mod preflight;
