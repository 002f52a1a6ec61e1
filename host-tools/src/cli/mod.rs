//! The operator's terminal: progress, single keys and Ctrl-C while a job runs
//! ([`progress`]), and finding the board on USB when no port is named ([`discover`]).

pub mod discover;
pub mod progress;
