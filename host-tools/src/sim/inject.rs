//! Injected faults (`--inject KIND[:JOINT]@SECONDS`): what can be injected, how it is
//! parsed, and how the simulator forces the controller's inputs at its time.

use super::Simulator;
use super::{Result, SimError};
use pkmc::config::Drive;

/// A fault injected into the simulator (`nc-send --inject KIND[:JOINT]@SECONDS`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Injection {
    /// What.
    pub kind: FaultKind,
    /// Joint concerned (limit switch, drive fault, following error), 0-based.
    pub joint: Option<usize>,
    /// Simulated time, s.
    pub at_s: f64,
}

/// Kinds of injectable faults.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultKind {
    /// The e-stop input becomes active and stays so.
    EStop,
    /// A joint's limit switch trips and stays tripped.
    Limit,
    /// A joint's drive (or servo amplifier) reports a fault and goes on reporting it.
    DriveFault,
    /// A servo joint jams: it stops moving, so its following error grows.
    FollowingError,
    /// The line goes dead both ways for [`LINK_CUT`] (wall time).
    LinkLoss,
}

/// How long an injected link loss lasts: longer than the controller's limit
/// ([`pkmc::controller::LINK_LOSS_TICKS`], 1 s), shorter than the time after which
/// nc-send gives the link up (3 s), so the host hears the alarm afterwards.
pub const LINK_CUT: std::time::Duration = std::time::Duration::from_millis(1500);

impl std::str::FromStr for Injection {
    type Err = String;
    fn from_str(text: &str) -> Result<Self, String> {
        let bad = |why: &str| {
            format!("--inject {text:?}: {why} (KIND[:JOINT]@SECONDS, KIND one of estop, limit, drive-fault, following-error, link-loss)")
        };
        let (what, at) = text.split_once('@').ok_or_else(|| bad("no @SECONDS"))?;
        let at_s: f64 = at
            .parse()
            .ok()
            .filter(|t: &f64| t.is_finite() && *t >= 0.0)
            .ok_or_else(|| bad("SECONDS must be a non-negative number"))?;
        let (kind, joint) = match what.split_once(':') {
            Some((k, j)) => (
                k,
                Some(
                    j.parse::<usize>()
                        .map_err(|_| bad("JOINT must be a joint index (0-based)"))?,
                ),
            ),
            None => (what, None),
        };
        let kind = match kind {
            "estop" | "e-stop" => FaultKind::EStop,
            "limit" => FaultKind::Limit,
            "drive-fault" => FaultKind::DriveFault,
            "following-error" => FaultKind::FollowingError,
            "link-loss" => FaultKind::LinkLoss,
            other => return Err(bad(&format!("unknown fault {other:?}"))),
        };
        if joint.is_some() && matches!(kind, FaultKind::EStop | FaultKind::LinkLoss) {
            return Err(bad("this fault names no joint"));
        }
        Ok(Injection { kind, joint, at_s })
    }
}

impl Simulator {
    /// Injects faults at their times; refuses one that cannot happen on this machine.
    pub fn inject(&mut self, injections: &[Injection]) -> Result<()> {
        let m = self.ctrl.machine();
        for i in injections {
            let joint = i.joint.unwrap_or_else(|| match i.kind {
                FaultKind::FollowingError => m
                    .joints
                    .iter()
                    .position(|j| matches!(j.drive, Drive::Servo { .. }))
                    .unwrap_or(0),
                _ => 0,
            });
            let Some(jc) = m.joints.get(joint) else {
                return Err(SimError::NoSuchJoint {
                    joint,
                    machine: m.name.to_string(),
                    joints: m.joints.len(),
                });
            };
            if i.kind == FaultKind::FollowingError && !matches!(jc.drive, Drive::Servo { .. }) {
                return Err(SimError::NotAServo {
                    joint,
                    machine: m.name.to_string(),
                });
            }
            self.injections.push(Injection {
                joint: Some(joint),
                ..*i
            });
        }
        Ok(())
    }

    /// Is an injected link cut due (its start time reached)? True once per injection:
    /// the server then cuts the line for [`LINK_CUT`].
    pub fn take_link_cut(&mut self) -> bool {
        let now = self.time_s();
        if let Some(k) = self
            .injections
            .iter()
            .position(|i| i.kind == FaultKind::LinkLoss && i.at_s <= now)
        {
            self.injections.remove(k);
            return true;
        }
        false
    }

    pub(super) fn apply_injections(&mut self) {
        let now = self.time_s();
        let mut k = 0;
        while k < self.injections.len() {
            let i = self.injections[k];
            if i.kind == FaultKind::LinkLoss || i.at_s > now {
                k += 1;
                continue;
            }
            self.injections.remove(k);
            let j = i.joint.unwrap_or(0);
            match i.kind {
                FaultKind::EStop => self.forced.estop = true,
                FaultKind::Limit => self.forced.limit |= 1 << j,
                FaultKind::DriveFault => self.forced.drive_fault |= 1 << j,
                FaultKind::FollowingError => {
                    if let Drive::Servo { channel } = self.ctrl.machine().joints[j].drive {
                        if let Some(s) = self.servos[channel as usize].as_mut() {
                            s.jam();
                        }
                    }
                }
                FaultKind::LinkLoss => {}
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pkmc::config::MachineConfig;

    #[test]
    fn injections_parse_and_bad_ones_say_why() {
        let i: Injection = "limit:2@1.5".parse().unwrap();
        assert_eq!(
            i,
            Injection {
                kind: FaultKind::Limit,
                joint: Some(2),
                at_s: 1.5
            }
        );
        assert_eq!(
            "estop@0".parse::<Injection>().unwrap().kind,
            FaultKind::EStop
        );
        let e = "smoke@1".parse::<Injection>().unwrap_err();
        assert!(e.contains("unknown fault \"smoke\""), "{e}");
        assert!("estop:1@1".parse::<Injection>().is_err());
        assert!("limit@-1".parse::<Injection>().is_err());
        assert!("limit"
            .parse::<Injection>()
            .unwrap_err()
            .contains("no @SECONDS"));
    }

    #[test]
    fn a_following_error_cannot_be_injected_into_a_stepper() {
        let mut sim = Simulator::new(MachineConfig::cartesian_xyz()).unwrap();
        let e = sim
            .inject(&["following-error:1@1".parse().unwrap()])
            .unwrap_err();
        assert!(
            format!("{e}").contains("joint 1 of cartesian-xyz is a stepper"),
            "{e}"
        );
    }
}
