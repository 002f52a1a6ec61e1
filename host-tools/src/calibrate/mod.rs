//! Kinematic calibration of the parallel machines (`nc-send calibrate`, issue 36,
//! docs/calibration.md): the geometry of the machine file identified from measured
//! tool poses.
//!
//! - [`model`]: the parameterised `f64` kinematics of the H-4 with its rolling table,
//!   the hexapod and the hexapod-xy, written over [`dual::Scalar`] so the same
//!   equations give their exact derivatives.
//! - [`forward`]: forward kinematics (Newton) and the measurement's Jacobian with
//!   respect to the parameters (implicit function theorem).
//! - [`fit`]: identifiability (SVD of the scaled Jacobian, the parameters held),
//!   Levenberg–Marquardt, the covariance; the residual is pluggable ([`fit::Residual`])
//!   so a sphere-probing fit can be added beside the pose measurements.
//! - [`data`]: the pose-list and measurement CSV files.
//! - [`write`]: the corrected machine file.
//! - [`plan`]: measurement poses chosen for conditioning (greedy D-optimal).
//! - [`sphere`]: calibration from probing spheres (the residual, the probing file);
//!   [`sphere_plan`] the touches and the probing program; [`sphere_study`] the
//!   simulated-truth study of it.
//! - [`plot`]: maps of the tool position error over the workspace, before and after.
//! - [`truth`]: a simulated "true" machine for tests and worked examples.
//! - [`true_path`]: how far a simulated run's tool truly strays from its commanded
//!   path, by [`forward`] at the joints' true positions (`nc-send --sim --trace`).
//! - [`cli`]: the `nc-send calibrate` command.

pub mod cli;
pub mod data;
pub mod dual;
pub mod fit;
pub mod forward;
pub mod model;
pub mod plan;
pub mod plot;
pub mod sphere;
pub mod sphere_cli;
pub mod sphere_plan;
pub mod sphere_study;
pub mod study;
pub mod true_path;
pub mod truth;
pub mod write;
