//! The linearised map between the servo channels and the pose near the setpoint
//! ([`ContourMap`]), which the contour controller works in.

use crate::config::{Drive, MachineConfig, MAX_SERVOS};

/// Pose coordinates the contour controller works in: X Y Z (mm) and the tool
/// direction's A B (degrees).
pub const POSE_AXES: usize = 5;

/// A vector over [`POSE_AXES`]: X Y Z in mm, A B in degrees.
pub type PoseVec = [f32; POSE_AXES];

/// How the servo channels map to the pose near the setpoint: the linearised forward
/// kinematics `to_pose` = ∂pose/∂q (pose units per channel unit: mm or degrees per mm
/// or degree of the joint) and the inverse's Jacobian `to_joint` = ∂q/∂pose. A
/// Cartesian machine's map is constant (ones where a channel follows X, Y or Z); the
/// hexapod-xy's is recomputed every tick at the commanded pose
/// ([`crate::kinematics::hexapod_xy::HexapodXy::contour_map`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContourMap {
    /// ∂pose/∂q per channel.
    pub to_pose: [[f32; MAX_SERVOS]; POSE_AXES],
    /// ∂q/∂pose per channel.
    pub to_joint: [[f32; POSE_AXES]; MAX_SERVOS],
}

impl Default for ContourMap {
    fn default() -> Self {
        Self::NONE
    }
}

impl ContourMap {
    /// No channel coupled.
    pub const NONE: ContourMap = ContourMap {
        to_pose: [[0.0; MAX_SERVOS]; POSE_AXES],
        to_joint: [[0.0; POSE_AXES]; MAX_SERVOS],
    };

    /// The channel-indexed map of `machine`'s servo joints from a joint-indexed one
    /// (joint j in channel j, as
    /// [`crate::kinematics::hexapod_xy::HexapodXy::contour_map`] returns it).
    pub fn of_joints(machine: &MachineConfig, jm: &ContourMap) -> Self {
        let mut map = Self::NONE;
        for (j, jc) in machine.joints.iter().enumerate().take(MAX_SERVOS) {
            if let Drive::Servo { channel } = jc.drive {
                let c = channel as usize;
                if c < MAX_SERVOS {
                    for a in 0..POSE_AXES {
                        map.to_pose[a][c] = jm.to_pose[a][j];
                    }
                    map.to_joint[c] = jm.to_joint[j];
                }
            }
        }
        map
    }
}
