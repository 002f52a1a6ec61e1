//! # pkmc host tools
//!
//! `nc-send`, `pkmc-sim` and `contour-study`, in rooms that follow the data path
//! (`docs/architecture.md`):
//!
//! - [`gcode`]: the front end — G-code text to canonical commands ([`gcode::canon`])
//!   to protocol blocks ([`gcode::blocks`]).
//! - [`machine_file`]: the TOML description of a machine, checked and converted to the
//!   core's `MachineConfig`.
//! - [`link`]: the client end of the serial link — transports, the protocol client and
//!   the streaming of a job. It knows nothing of the simulator: a board, a simulator
//!   behind a pseudo-terminal or one in this process are all a [`link::Transport`].
//! - [`sim`]: the simulated controller (the core's `Controller` against simulated
//!   drives, plants and injected faults) and its board loop, served over a
//!   pseudo-terminal or in process.
//! - [`analysis`]: pre-flight checks and plots.
//! - [`calibrate`]: kinematic calibration of the parallel machines' geometry from
//!   measured tool poses, and the plan of the poses to measure (`nc-send calibrate`).
//! - [`contour_study`]: the contour-error study of the seeds' controller schemes on a
//!   machine file's servo axes and plants.
//! - [`job`]: the application layer shared by the binaries and the tests — compile,
//!   check, start a simulator when asked, stream, report.
//! - [`cli`]: the operator's terminal (progress, keys, Ctrl-C) and board discovery.
//! - [`input`]: bounded reading of input files.

pub mod analysis;
pub mod calibrate;
pub mod cli;
pub mod contour_study;
pub mod control;
pub mod gcode;
pub mod grbl;
pub mod input;
pub mod job;
pub mod link;
pub mod machine_file;
pub mod scope;
pub mod sim;
pub mod station;
