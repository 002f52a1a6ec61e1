//! Control design, apart from the simulator that runs it: the plant models
//! ([`plant`]: a transfer function, its discrete state-space form, the mismatched
//! "true" plant of a robustness study), a servo joint's LQG design ([`lqg`]), the
//! identification of a plant from recorded closed-loop data ([`ident`]), PID and
//! feed-forward tuning on a model with its margins and predicted step
//! ([`tune`], plotted by the scope's `tune_plot`) and the crate's dense linear algebra
//! ([`linalg`], which calibration uses too). The machine
//! file designs its servo gains here, the simulator steps its plants from here, and the
//! contour study draws its plants from here. It imports nothing else of the crate.

pub mod ident;
pub mod linalg;
pub mod lqg;
pub mod plant;
pub mod tune;
