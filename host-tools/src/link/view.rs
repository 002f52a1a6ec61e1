//! The controller's status as every face shows it: `nc-send`'s status line and JSON,
//! the progress line, the job's report, the Grbl bridge's status report and the
//! station's page all read a [`StatusView`]. Lengths in millimetres and angles in
//! degrees, the feed in mm/min, the state and the alarm in the core's words
//! (`pkmc::wording`), and beside them the stable names a script or a page compares
//! (`Idle`, `LimitSwitch`: the names the wire serialises them by).

use pkmc::config::{axis_is_rotary, MachineConfig, AXES, AXIS_NAMES};
use pkmc::units::to_user;
use pkmc::wire::{Alarm, State, Status, NO_JOINT};

/// A path speed in nm/s (or n°/s) in mm/min (or degrees/min): the one conversion.
pub fn feed_mm_min(nm_per_s: i64) -> f64 {
    nm_per_s as f64 * 60.0 / 1e6
}

/// The stable name of a state, cause or other unit variant: the name the wire
/// serialises it by (`Idle`, `EStop`, `FollowingError`).
pub fn name_of<T: serde::Serialize>(v: &T) -> String {
    match serde_json::to_value(v) {
        Ok(serde_json::Value::String(s)) => s,
        _ => String::new(),
    }
}

/// An alarm as it is shown.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AlarmView {
    /// The cause's stable name (`LimitSwitch`).
    pub cause: String,
    /// The cause in the core's words (`limit switch`).
    pub cause_words: String,
    /// The whole alarm in the core's words: `following error on joint 2 at line 40`.
    pub words: String,
    /// The joint it names, 1-based.
    pub joint: Option<u8>,
    /// The NC line it was raised at (0: none).
    pub line: u32,
}

impl AlarmView {
    /// The view of `a`.
    pub fn new(a: &Alarm) -> Self {
        Self {
            cause: name_of(&a.cause),
            cause_words: a.cause.to_string(),
            words: a.to_string(),
            joint: (a.joint != NO_JOINT).then(|| a.joint + 1),
            line: a.line,
        }
    }
}

/// A status as it is shown.
#[derive(Clone, Debug, PartialEq)]
pub struct StatusView {
    /// The state's stable name (`Idle`, `Running`, `Hold`, `Homing`, `Alarm`,
    /// `EStop`, `Starved`).
    pub state: String,
    /// The state in the core's words (`idle`, `e-stop`).
    pub state_words: String,
    /// NC line executing.
    pub line: u32,
    /// Commanded pose: X Y Z mm, A B C degrees.
    pub pose: [f64; AXES],
    /// Commanded joints, mm or degrees (empty without the machine).
    pub joints: Vec<f64>,
    /// Measured joints, mm or degrees (empty without the machine).
    pub measured: Vec<f64>,
    /// Path speed, mm/min.
    pub feed_mm_min: f64,
    /// Feed override, %.
    pub feed_override: u16,
    /// The alarm, if any.
    pub alarm: Option<AlarmView>,
}

impl StatusView {
    /// The view of `s` without the joints.
    pub fn new(s: &Status) -> Self {
        Self {
            state: name_of(&s.state),
            state_words: s.state.to_string(),
            line: s.line,
            pose: std::array::from_fn(|i| to_user(s.pose[i], axis_is_rotary(i))),
            joints: Vec::new(),
            measured: Vec::new(),
            feed_mm_min: feed_mm_min(s.speed),
            feed_override: s.feed_override,
            alarm: s.alarm.as_ref().map(AlarmView::new),
        }
    }

    /// The view of `s` with `machine`'s joints, commanded and measured.
    pub fn with_joints(s: &Status, machine: &MachineConfig) -> Self {
        let joints = &machine.joints;
        Self {
            joints: joints
                .iter()
                .enumerate()
                .map(|(j, jc)| to_user(s.joints[j], jc.rotary))
                .collect(),
            measured: joints
                .iter()
                .enumerate()
                .map(|(j, jc)| to_user(jc.scale.position_of(s.measured[j]), jc.rotary))
                .collect(),
            ..Self::new(s)
        }
    }

    /// The pose in words: `X 1.0000 Y … C 0.0000`.
    pub fn pose_text(&self) -> String {
        (0..AXES)
            .map(|i| format!("{} {:.4}", AXIS_NAMES[i], self.pose[i]))
            .collect::<Vec<_>>()
            .join(" ")
    }

    /// The state in words, with the alarm when there is one: `alarm (not homed)`.
    pub fn state_text(&self) -> String {
        match &self.alarm {
            Some(a) => format!("{} ({})", self.state_words, a.words),
            None => self.state_words.clone(),
        }
    }
}

/// The stable name of state `s` (a held job's state, where no status comes with it).
pub fn state_name(s: State) -> String {
    name_of(&s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use pkmc::wire::AlarmCause;

    #[test]
    fn a_status_is_shown_in_user_units_and_the_cores_words() {
        let mut s = Status {
            state: State::Alarm,
            line: 40,
            blocks_done: 0,
            motion_ticks: 0,
            pose: [0; AXES],
            joints: [0; pkmc::config::MAX_JOINTS],
            measured: [0; pkmc::config::MAX_JOINTS],
            speed: 20_000_000,
            buffered_ms: 0,
            free_slots: 0,
            free_bends: 0,
            feed_override: 100,
            alarm: None,
            homed: false,
            orphan: false,
            probe_input: false,
            probes: 0,
        };
        s.pose[0] = 1_500_000;
        s.pose[3] = -90_000_000_000;
        s.alarm = Some(Alarm {
            cause: AlarmCause::FollowingError,
            joint: 2,
            line: 40,
        });
        let v = StatusView::new(&s);
        assert_eq!(
            (v.state.as_str(), v.state_words.as_str()),
            ("Alarm", "alarm")
        );
        assert_eq!(v.feed_mm_min, 1200.0);
        assert_eq!(v.pose[0], 1.5);
        assert_eq!(v.pose[3], -90.0);
        let a = v.alarm.as_ref().unwrap();
        assert_eq!(a.cause, "FollowingError");
        assert_eq!(a.cause_words, "following error");
        assert_eq!(a.words, "following error on joint 3 at line 40");
        assert_eq!(a.joint, Some(3));
        assert_eq!(
            v.state_text(),
            "alarm (following error on joint 3 at line 40)"
        );
        assert!(v.pose_text().starts_with("X 1.5000 Y 0.0000"));
        assert_eq!(state_name(State::EStop), "EStop");
    }
}
