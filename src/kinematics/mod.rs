//! Kinematics: poses (X Y Z A B C) to joint positions and back.
//!
//! Pure integer math with no hardware or planner dependencies (the LinuxCNC habit):
//! inverse kinematics returns the joints or a typed reason why the pose cannot be
//! reached. Every machine kind runs the shared test suite (`suite.rs`: the inverse
//! against an `f64` reference, forward convergence and round trip, unreachable poses,
//! the analytic [`Kinematics::jacobian`] against central differences); adding a kind
//! adds one entry to its table. Units are those of [`crate::units`].
//!
//! Machines: [`Cartesian`], the H-4 with rolling table ([`h4::H4Table`]), the
//! hexapod ([`hexapod::Hexapod`]) and the hexapod under an X-Y table's tool
//! ([`hexapod_xy::HexapodXy`]); their geometry comes from
//! [`crate::config::KinematicsConfig`], nothing is hard-coded here. The parallel
//! machines' inverse kinematics is fixed point ([`fixed`]: Q31 sin/cos, positions in
//! half nanometres, exact 64-bit sums of squares, integer square roots to ±0.51) with
//! an error budget stated in each module and checked against an `f64` reference by the
//! suite (≤ 5 nm per joint required; ≤ 1.4 nm measured). Their
//! forward kinematics is Newton's method: the residual from the same inverse evaluated
//! in 1/16 nm, the step from the analytic Jacobian solved in `f32` with partial
//! pivoting ([`solve`]); 2 iterations from the previous period's pose, at most
//! [`MAX_ITERATIONS`], ≤ 0.63 nm from the exact solution. Cortex-M4 instruction counts and how they
//! are measured: `docs/performance.md` (`python3 .ci/m4count.py`).
//!
//! Invariants: no allocation, no panics, no unbounded loops, no `f64` (the MCU's FPU is
//! single precision); results are bit-identical on the MCU and the host.

pub mod contour_map;
pub mod fixed;
pub mod h4;
pub mod hexapod;
pub mod hexapod_xy;
pub mod hexapod_xy_map;
pub mod solve;

pub use contour_map::{ContourMap, PoseVec, POSE_AXES};

#[cfg(test)]
mod reference;
#[cfg(test)]
mod suite;

use crate::config::{JointConfig, KinematicsConfig, MachineConfig, AXES, MAX_JOINTS};

/// A pose: X Y Z in nm, A B C in n°.
pub type Pose = [i64; AXES];
/// Joint positions q1..qN in axis units; entries past the machine's joints are 0.
pub type Joints = [i64; MAX_JOINTS];
/// ∂q/∂p at a pose: row i = joint i, column k = pose axis k, in joint units per pose
/// unit (nm/nm, nm/n°, n°/n°); rows past the machine's joints and columns of the axes
/// it does not use are 0.
pub type Jacobian = [[f32; AXES]; MAX_JOINTS];

/// Most Newton iterations of a forward kinematics call (2 suffice from the pose of the
/// previous interpolation period).
pub const MAX_ITERATIONS: u8 = 8;

/// Forward kinematics stops after a Newton step no larger than this on every axis, nm
/// (angles: arc length at the machine's lever arm). Newton's error after a step s is
/// at most c·s² with c ≤ 2.5e-8 /nm for these machines (the curvature of the leg
/// equations near the 25° forearm limit), so a 1 µm step leaves ≤ 0.025 nm; what
/// remains is the pose's rounding to whole nm and the residual's ~0.1 nm error seen
/// through the Jacobian: ≤ 0.63 nm from the exact solution, measured. Stopping on the
/// step size rather than on the joint residual also avoids limit cycles between
/// neighbouring integer poses.
pub const FINAL_STEP: f32 = 1_000.0;

/// Why a pose has no joint solution (or forward kinematics found no pose).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Unreachable {
    /// Geometrically out of reach.
    OutOfReach,
    /// Reachable, but joint `joint` (0-based) would leave its travel.
    JointLimit {
        /// Joint index.
        joint: u8,
    },
    /// Too near a singularity (H-4: a forearm flatter than its minimum elevation;
    /// forward kinematics: a Jacobian pivot below [`solve::PIVOT_MIN`]).
    Singular,
    /// Forward kinematics did not converge within [`MAX_ITERATIONS`] from the guess.
    NoConvergence,
}

/// Maps poses to joints and back.
pub trait Kinematics {
    /// Joints of `pose`, without travel checks.
    fn inverse(&self, pose: &Pose, joints: &mut Joints) -> Result<(), Unreachable>;
    /// Pose of `joints`, starting from the nearby pose `guess`.
    fn forward(&self, joints: &Joints, guess: &Pose, pose: &mut Pose) -> Result<(), Unreachable>;
    /// The analytic Jacobian ∂q/∂p of the inverse at `pose` (see [`Jacobian`]), in `f32`
    /// (relative error ~1e-6), without travel checks: a joint's rate along a path with
    /// tangent t (pose units per unit of path) is Σₖ J[i][k]·t[k]. Fails where
    /// [`Kinematics::inverse`] fails (near the reach limits both test the same bound,
    /// on values computed with different roundings).
    fn jacobian(&self, pose: &Pose, jac: &mut Jacobian) -> Result<(), Unreachable>;
}

/// Each joint follows one pose axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Cartesian {
    axis_of_joint: [u8; MAX_JOINTS],
    joints: usize,
}

impl Cartesian {
    /// The pose axis joint `j` follows.
    pub fn axis_of(&self, j: usize) -> usize {
        self.axis_of_joint[j] as usize
    }
}

impl Kinematics for Cartesian {
    fn inverse(&self, pose: &Pose, joints: &mut Joints) -> Result<(), Unreachable> {
        for (q, &a) in joints.iter_mut().zip(&self.axis_of_joint).take(self.joints) {
            *q = pose[a as usize];
        }
        Ok(())
    }

    fn forward(&self, joints: &Joints, guess: &Pose, pose: &mut Pose) -> Result<(), Unreachable> {
        *pose = *guess;
        for (q, &a) in joints.iter().zip(&self.axis_of_joint).take(self.joints) {
            pose[a as usize] = *q;
        }
        Ok(())
    }

    fn jacobian(&self, _pose: &Pose, jac: &mut Jacobian) -> Result<(), Unreachable> {
        *jac = [[0.0; AXES]; MAX_JOINTS];
        for (row, &a) in jac.iter_mut().zip(&self.axis_of_joint).take(self.joints) {
            row[a as usize] = 1.0;
        }
        Ok(())
    }
}

/// The kinematics a machine configuration selects.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MachineKinematics {
    /// See [`Cartesian`].
    Cartesian(Cartesian),
    /// See [`h4::H4Table`].
    H4Table(h4::H4Table),
    /// See [`hexapod::Hexapod`].
    Hexapod(hexapod::Hexapod),
    /// See [`hexapod_xy::HexapodXy`].
    HexapodXy(hexapod_xy::HexapodXy),
}

impl MachineKinematics {
    /// Builds the kinematics of `config`.
    pub fn new(config: &MachineConfig) -> Self {
        match config.kinematics {
            KinematicsConfig::Cartesian { axis_of_joint } => Self::Cartesian(Cartesian {
                axis_of_joint,
                joints: config.joints.len(),
            }),
            KinematicsConfig::H4Table(g) => Self::H4Table(h4::H4Table::new(&g)),
            KinematicsConfig::Hexapod(g) => Self::Hexapod(hexapod::Hexapod::new(&g)),
            KinematicsConfig::HexapodXy(g) => {
                Self::HexapodXy(hexapod_xy::HexapodXy::new(&g, &config.joints))
            }
        }
    }

    /// Forward kinematics, returning the Newton iterations used (0 for Cartesian).
    pub fn forward_counted(
        &self,
        joints: &Joints,
        guess: &Pose,
        pose: &mut Pose,
    ) -> Result<u8, Unreachable> {
        match self {
            Self::Cartesian(k) => k.forward(joints, guess, pose).map(|_| 0),
            Self::H4Table(k) => k.forward(joints, guess, pose),
            Self::Hexapod(k) => k.forward(joints, guess, pose),
            Self::HexapodXy(k) => k.forward(joints, guess, pose),
        }
    }

    /// Inverse kinematics followed by the travel check of every joint.
    pub fn inverse_checked(
        &self,
        pose: &Pose,
        joints_cfg: &[JointConfig],
        joints: &mut Joints,
    ) -> Result<(), Unreachable> {
        self.inverse(pose, joints)?;
        for (j, (q, c)) in joints.iter().zip(joints_cfg).enumerate() {
            if *q < c.min || *q > c.max {
                return Err(Unreachable::JointLimit { joint: j as u8 });
            }
        }
        Ok(())
    }
}

impl Kinematics for MachineKinematics {
    fn inverse(&self, pose: &Pose, joints: &mut Joints) -> Result<(), Unreachable> {
        match self {
            Self::Cartesian(k) => k.inverse(pose, joints),
            Self::H4Table(k) => k.inverse(pose, joints),
            Self::Hexapod(k) => k.inverse(pose, joints),
            Self::HexapodXy(k) => k.inverse(pose, joints),
        }
    }
    fn forward(&self, joints: &Joints, guess: &Pose, pose: &mut Pose) -> Result<(), Unreachable> {
        self.forward_counted(joints, guess, pose).map(|_| ())
    }
    fn jacobian(&self, pose: &Pose, jac: &mut Jacobian) -> Result<(), Unreachable> {
        match self {
            Self::Cartesian(k) => k.jacobian(pose, jac),
            Self::H4Table(k) => k.jacobian(pose, jac),
            Self::Hexapod(k) => k.jacobian(pose, jac),
            Self::HexapodXy(k) => k.jacobian(pose, jac),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cartesian_joints_follow_their_axes() {
        let k = MachineKinematics::new(&MachineConfig::cartesian_xyz());
        let mut q = [0; MAX_JOINTS];
        k.inverse(&[1, 2, 3, 0, 0, 0], &mut q).unwrap();
        assert_eq!(&q[..3], &[1, 2, 3]);
    }
}
