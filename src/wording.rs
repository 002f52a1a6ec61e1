//! Operator-facing wording of the core's error and state enums: `Display` for each,
//! and `defmt::Format` on the MCU (the firmware's log), both from one text.
//!
//! The phrases are short and lower-case, those the host tools print (the machine
//! file's refusals, the pre-flight findings), so that a message reads the same from
//! the simulator, the pre-flight check, the link and the firmware's log. Joints are
//! named q1, q2, ... as in the pre-flight findings, except in an [`Alarm`] (`joint 2`,
//! 1-based, as the job report writes it) and in [`ConfigError`], whose texts name the
//! machine file's fields (`joints[0]`, 0-based; [`ConfigError::with_joint_names`] adds
//! the file's joint names).
//!
//! Only formatting: nothing here runs on the tick or receive paths. Each text is
//! written once, against [`Out`], which either formatter implements.

use core::fmt;

use crate::config::{
    ConfigError, GeometryField, AXIS_NAMES, BOARD_STEPS_PER_TICK, GEOMETRY_MAX, MAX_STEPPERS,
    MAX_WINDOW,
};
use crate::drive::homing::{HomeEvent, Phase};
use crate::drive::servo::Trip;
use crate::kinematics::Unreachable;
use crate::motion::geometry::GeometryError;
use crate::motion::planner::PushError;
use crate::units::{NM_PER_MM, TICK_NS};
use crate::wire::store::StoreError;
use crate::wire::{Alarm, AlarmCause, FrameError, NakReason, State, NO_JOINT};

/// Where a text goes: a `core::fmt` formatter, or a defmt one on the MCU.
trait Out {
    /// Writes `s`.
    fn str(&mut self, s: &str) -> fmt::Result;
    /// Writes `n` in decimal.
    fn num(&mut self, n: i64) -> fmt::Result;
}

impl Out for fmt::Formatter<'_> {
    fn str(&mut self, s: &str) -> fmt::Result {
        self.write_str(s)
    }
    fn num(&mut self, n: i64) -> fmt::Result {
        write!(self, "{n}")
    }
}

/// A defmt formatter as an [`Out`].
#[cfg(target_os = "none")]
struct Defmt<'a>(defmt::Formatter<'a>);

#[cfg(target_os = "none")]
impl Out for Defmt<'_> {
    fn str(&mut self, s: &str) -> fmt::Result {
        defmt::write!(self.0, "{=str}", s);
        Ok(())
    }
    fn num(&mut self, n: i64) -> fmt::Result {
        defmt::write!(self.0, "{=i64}", n);
        Ok(())
    }
}

/// A type's text, written once for both formatters.
trait Words {
    /// Writes the text to `o`.
    fn words(&self, o: &mut dyn Out) -> fmt::Result;
}

/// `Display` (and, on the MCU, `defmt::Format`) from [`Words`].
macro_rules! worded {
    ($($t:ty),* $(,)?) => {$(
        impl fmt::Display for $t {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                self.words(f)
            }
        }
        #[cfg(target_os = "none")]
        impl defmt::Format for $t {
            fn format(&self, f: defmt::Formatter<'_>) {
                let _ = self.words(&mut Defmt(f));
            }
        }
    )*};
}

worded!(
    State,
    AlarmCause,
    Alarm,
    NakReason,
    FrameError,
    Unreachable,
    GeometryError,
    PushError,
    StoreError,
    ConfigError,
    GeometryField,
    Trip,
    Phase,
    HomeEvent,
);

/// `q` and the 1-based number of joint `joint` (0-based).
fn joint_q(o: &mut dyn Out, joint: i64) -> fmt::Result {
    o.str("q")?;
    o.num(joint + 1)
}

impl Words for State {
    fn words(&self, o: &mut dyn Out) -> fmt::Result {
        o.str(match self {
            State::Idle => "idle",
            State::Running => "running",
            State::Hold => "hold",
            State::Homing => "homing",
            State::Alarm => "alarm",
            State::EStop => "e-stop",
            State::Starved => "starved",
        })
    }
}

impl Words for AlarmCause {
    fn words(&self, o: &mut dyn Out) -> fmt::Result {
        o.str(match self {
            AlarmCause::Unreachable => "out of the machine's reach",
            AlarmCause::JointLimit => "travel limit",
            AlarmCause::Singularity => "too near a singularity",
            AlarmCause::Aborted => "aborted",
            AlarmCause::EStop => "emergency stop",
            AlarmCause::LimitSwitch => "limit switch",
            AlarmCause::DriveFault => "drive fault",
            AlarmCause::FollowingError => "following error",
            AlarmCause::LinkLoss => "link lost",
            AlarmCause::Watchdog => "watchdog",
            AlarmCause::MachineMismatch => "machine mismatch",
            AlarmCause::Unhomed => "not homed",
            AlarmCause::HomingFailed => "homing failed",
            AlarmCause::JointSpeed => "joint speed guard",
            AlarmCause::HostTimeout => "host silent too long, job held",
            AlarmCause::ProbeAtStart => "probe already in the state the probing move seeks",
        })
    }
}

/// Cause, joint (1-based) and NC line: `following error on joint 2 at line 40`.
impl Words for Alarm {
    fn words(&self, o: &mut dyn Out) -> fmt::Result {
        self.cause.words(o)?;
        if self.joint != NO_JOINT {
            o.str(" on joint ")?;
            o.num(self.joint as i64 + 1)?;
        }
        if self.line != 0 {
            o.str(" at line ")?;
            o.num(self.line as i64)?;
        }
        Ok(())
    }
}

impl Words for NakReason {
    fn words(&self, o: &mut dyn Out) -> fmt::Result {
        o.str(match self {
            NakReason::Corrupt => "corrupt frame",
            NakReason::Gap => "sequence gap",
            NakReason::QueueFull => "queue full",
            NakReason::Version => "protocol version mismatch",
            NakReason::NoSession => "no session",
            NakReason::BadBlock => "malformed block",
            NakReason::MachineMismatch => "machine mismatch",
            NakReason::JobHeld => "an unfinished job of another host is held",
        })
    }
}

impl Words for FrameError {
    fn words(&self, o: &mut dyn Out) -> fmt::Result {
        o.str(match self {
            FrameError::TooLong => "message too long for a frame",
            FrameError::Cobs => "bad COBS encoding",
            FrameError::Short => "frame too short",
            FrameError::Crc => "CRC mismatch",
            FrameError::Message => "undecodable message",
        })
    }
}

impl Words for Unreachable {
    fn words(&self, o: &mut dyn Out) -> fmt::Result {
        match self {
            Unreachable::OutOfReach => o.str("out of the machine's reach"),
            Unreachable::JointLimit { joint } => {
                o.str("joint ")?;
                joint_q(o, *joint as i64)?;
                o.str(" would leave its travel")
            }
            Unreachable::Singular => o.str("too near a singularity"),
            Unreachable::NoConvergence => o.str("the forward kinematics did not converge"),
        }
    }
}

impl Words for GeometryError {
    fn words(&self, o: &mut dyn Out) -> fmt::Result {
        o.str(match self {
            GeometryError::ArcEndOffCircle => "arc end is off its circle",
            GeometryError::ArcWithoutRadius => "arc without a radius",
            GeometryError::PlanMismatch => "the path sent does not describe its block",
            GeometryError::SplineOutOfRange => {
                "spline out of range (no X Y Z motion, or control points too far apart)"
            }
        })
    }
}

impl Words for PushError {
    fn words(&self, o: &mut dyn Out) -> fmt::Result {
        match self {
            PushError::Full => o.str("queue full"),
            PushError::Geometry(e) => e.words(o),
        }
    }
}

impl Words for StoreError {
    fn words(&self, o: &mut dyn Out) -> fmt::Result {
        match self {
            StoreError::NoRecord => o.str("no stored machine"),
            StoreError::Damaged => o.str("damaged record (length or CRC mismatch)"),
            StoreError::Undecodable => o.str("not a machine configuration"),
            StoreError::Invalid(e) => e.words(o),
            StoreError::Busy => o.str("the controller is moving"),
        }
    }
}

impl Words for Trip {
    fn words(&self, o: &mut dyn Out) -> fmt::Result {
        match self {
            Trip::FollowingError { error, limit } => {
                o.str("following error ")?;
                o.num(*error as i64)?;
                o.str(" counts beyond its limit of ")?;
                o.num(*limit as i64)?;
                o.str(" counts")
            }
            Trip::AmplifierFault => o.str("amplifier fault"),
        }
    }
}

impl Words for Phase {
    fn words(&self, o: &mut dyn Out) -> fmt::Result {
        o.str(match self {
            Phase::Waiting => "waiting",
            Phase::Search => "searching the home switch",
            Phase::StopOnSwitch => "stopping on the switch",
            Phase::Latch => "backing off the switch",
            Phase::Index => "waiting for the index pulse",
            Phase::Latched => "latched",
            Phase::Return => "going to the home pose",
            Phase::Done => "at the home pose",
        })
    }
}

impl Words for HomeEvent {
    fn words(&self, o: &mut dyn Out) -> fmt::Result {
        match self {
            HomeEvent::Latched { joint, index } => {
                o.str("joint ")?;
                joint_q(o, *joint as i64)?;
                o.str(" latched")?;
                if let Some(count) = index {
                    o.str(" on the index pulse at count ")?;
                    o.num(*count)?;
                }
                Ok(())
            }
            HomeEvent::Failed { joint } => {
                o.str("joint ")?;
                joint_q(o, *joint as i64)?;
                o.str(": no home switch (or index pulse) within its travel")
            }
            HomeEvent::Finished => o.str("homing finished"),
        }
    }
}

// The board-channel text below names channels 3–6 and a 1 ms tick.
const _: () = {
    let compact = BOARD_STEPS_PER_TICK[3];
    let mut c = 0;
    while c < MAX_STEPPERS {
        assert!((c >= 3) == (BOARD_STEPS_PER_TICK[c] == compact));
        c += 1;
    }
    assert!(TICK_NS == 1_000_000);
};

/// What is wrong with a geometry field.
enum Wrong {
    /// A coordinate beyond ±[`GEOMETRY_MAX`].
    Coordinate,
    /// A length not in 0..[`GEOMETRY_MAX`].
    Length,
    /// In words.
    Text(&'static str),
}

impl Words for GeometryField {
    fn words(&self, o: &mut dyn Out) -> fmt::Result {
        let (name, wrong) = match self {
            GeometryField::Joints => (
                "joints",
                Wrong::Text(
                    "the h4-table needs q1..q4 linear and q5 rotary (5 joints), the hexapod \
                     six linear legs, the hexapod-xy six linear legs and a linear table X, Y",
                ),
            ),
            GeometryField::Rails => ("h4_table.rails", Wrong::Coordinate),
            GeometryField::Forearm => ("h4_table.forearm", Wrong::Length),
            GeometryField::BarHalf => ("h4_table.bar_half", Wrong::Length),
            GeometryField::Sides => ("h4_table.sides", Wrong::Text("each must be -1 or +1")),
            GeometryField::Attach => ("h4_table.attach", Wrong::Coordinate),
            GeometryField::ToolLength => ("h4_table.tool_length", Wrong::Coordinate),
            GeometryField::TablePivot => ("h4_table.table_pivot", Wrong::Coordinate),
            GeometryField::MinElevation => (
                "h4_table.min_elevation",
                Wrong::Text("must lie between 0 and 90 degrees"),
            ),
            GeometryField::Base => ("hexapod.base", Wrong::Text("out of range (±537 mm)")),
            GeometryField::Platform => (
                "hexapod.platform",
                Wrong::Text("a joint farther than 268 mm from the platform origin, or all at it"),
            ),
            GeometryField::PlatformHome => (
                "hexapod_xy.platform_home",
                Wrong::Text("out of range (±537 mm)"),
            ),
            GeometryField::ToolZ => ("hexapod_xy.tool_z", Wrong::Coordinate),
        };
        o.str(name)?;
        o.str(": ")?;
        let from = match wrong {
            Wrong::Text(what) => return o.str(what),
            Wrong::Coordinate => "out of range (±",
            Wrong::Length => "out of range (0..",
        };
        o.str(from)?;
        o.num(GEOMETRY_MAX / NM_PER_MM)?;
        o.str(" mm)")
    }
}

impl Words for ConfigError {
    fn words(&self, o: &mut dyn Out) -> fmt::Result {
        config_words(self, o, None)
    }
}

impl ConfigError {
    /// This error's text with each joint also named as in the machine file, `names`
    /// in joint order: `joints[2] (z).channel: ...` where `Display` writes
    /// `joints[2].channel: ...` (`?` for a joint beyond `names`).
    pub fn with_joint_names<'a>(&'a self, names: &'a [&'a str]) -> impl fmt::Display + 'a {
        NamedConfigError { error: self, names }
    }
}

/// [`ConfigError::with_joint_names`].
struct NamedConfigError<'a> {
    error: &'a ConfigError,
    names: &'a [&'a str],
}

impl fmt::Display for NamedConfigError<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        config_words(self.error, f, Some(self.names))
    }
}

/// The text of `e`, joints named from `names` if given (the machine file's wording,
/// `host-tools/src/machine_file`).
fn config_words(e: &ConfigError, o: &mut dyn Out, names: Option<&[&str]>) -> fmt::Result {
    let name = |o: &mut dyn Out, j: u8| -> fmt::Result {
        o.str("joints[")?;
        o.num(j as i64)?;
        o.str("]")?;
        if let Some(names) = names {
            o.str(" (")?;
            o.str(names.get(j as usize).copied().unwrap_or("?"))?;
            o.str(")")?;
        }
        Ok(())
    };
    // `joints[j]` and the rest of the text.
    let about = |o: &mut dyn Out, j: &u8, rest: &str| -> fmt::Result {
        name(o, *j)?;
        o.str(rest)
    };
    match e {
        ConfigError::NoJoints => o.str("joints: the machine has no joints"),
        ConfigError::BoardChannel { joint } => {
            about(
                o,
                joint,
                ".channel: the board's timer on this channel cannot emit the steps its \
                 max_velocity needs (channels 3–6 take at most ",
            )?;
            o.num(BOARD_STEPS_PER_TICK[3] as i64)?;
            o.str(" steps per ms)")
        }
        ConfigError::Smoothing => {
            o.str("motion: the smoothing window must be a power of two up to ")?;
            o.num(MAX_WINDOW as i64)?;
            o.str(" ticks")
        }
        ConfigError::JointLimits { joint } => {
            about(o, joint, ": speed and acceleration must be positive")
        }
        ConfigError::JointTravel { joint } => about(o, joint, ".min must be below max"),
        ConfigError::JointScale { joint } => about(o, joint, ".steps_per_unit rounds to zero"),
        ConfigError::JointChannel { joint } => {
            about(o, joint, ".channel: beyond the board or used twice")
        }
        ConfigError::StepRate { joint } => about(
            o,
            joint,
            ".max_velocity: needs more steps per second than the drive timing allows",
        ),
        ConfigError::JointAxis { joint } => {
            about(o, joint, ".axis: names no axis with limits in [axes]")
        }
        ConfigError::AxisLimits { axis } => {
            let mut buf = [0u8; 4];
            let axis = match AXIS_NAMES.get(*axis as usize) {
                Some(c) => &*c.encode_utf8(&mut buf),
                None => "?",
            };
            o.str("axes.")?;
            o.str(axis)?;
            o.str(": bad limits")
        }
        ConfigError::HomeOutsideTravel { joint } => {
            o.str("home: outside the travel of ")?;
            name(o, *joint)
        }
        ConfigError::Geometry { field } => field.words(o),
        ConfigError::ServoGains { channel } => {
            o.str("servo channel ")?;
            o.num(*channel as i64)?;
            o.str(
                ": gains must be finite, limits non-negative, dac_per_unit non-zero and \
                 min_ferror <= ferror",
            )
        }
        ConfigError::Contour => o.str(
            "contour: gains must be finite, clamps non-negative, and coupling needs a \
             Cartesian machine",
        ),
        ConfigError::Homing { joint } => about(
            o,
            joint,
            ".homing: switch_at must lie in the travel, speeds within max_velocity, \
             latch_velocity > 0, and use_index only on a servo joint",
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;
    use std::string::ToString;

    /// Every text is non-empty and no two are alike.
    fn distinct<T: fmt::Display>(values: &[T]) {
        let texts: Vec<String> = values.iter().map(ToString::to_string).collect();
        assert!(texts.iter().all(|t| !t.is_empty()), "{texts:?}");
        let unique: HashSet<&String> = texts.iter().collect();
        assert_eq!(unique.len(), texts.len(), "{texts:?}");
    }

    #[test]
    fn every_state_reads_differently() {
        use State::*;
        distinct(&[Idle, Running, Hold, Homing, Alarm, EStop]);
        assert_eq!(Idle.to_string(), "idle");
    }

    #[test]
    fn every_alarm_cause_reads_differently() {
        use AlarmCause::*;
        let causes = [
            Unreachable,
            JointLimit,
            Singularity,
            Aborted,
            EStop,
            LimitSwitch,
            DriveFault,
            FollowingError,
            LinkLoss,
            Watchdog,
            MachineMismatch,
            Unhomed,
            HomingFailed,
            JointSpeed,
        ];
        distinct(&causes);
        let alarm = |joint, line| Alarm {
            cause: FollowingError,
            joint,
            line,
        };
        distinct(&[
            alarm(NO_JOINT, 0),
            alarm(1, 0),
            alarm(NO_JOINT, 40),
            alarm(1, 40),
        ]);
        assert_eq!(
            alarm(1, 40).to_string(),
            "following error on joint 2 at line 40"
        );
    }

    #[test]
    fn every_link_refusal_reads_differently() {
        use NakReason::*;
        distinct(&[
            Corrupt,
            Gap,
            QueueFull,
            Version,
            NoSession,
            BadBlock,
            MachineMismatch,
            JobHeld,
        ]);
        use FrameError::*;
        distinct(&[TooLong, Cobs, Short, Crc, Message]);
    }

    #[test]
    fn every_motion_refusal_reads_differently() {
        use crate::kinematics::Unreachable::*;
        distinct(&[OutOfReach, JointLimit { joint: 2 }, Singular, NoConvergence]);
        assert_eq!(
            JointLimit { joint: 2 }.to_string(),
            "joint q3 would leave its travel"
        );
        use GeometryError::*;
        distinct(&[ArcEndOffCircle, ArcWithoutRadius, PlanMismatch]);
        distinct(&[
            PushError::Full,
            PushError::Geometry(ArcEndOffCircle),
            PushError::Geometry(ArcWithoutRadius),
            PushError::Geometry(PlanMismatch),
        ]);
    }

    #[test]
    fn every_servo_and_homing_text_reads_differently() {
        distinct(&[
            Trip::FollowingError {
                error: 2100,
                limit: 2000,
            },
            Trip::AmplifierFault,
        ]);
        use Phase::*;
        distinct(&[
            Waiting,
            Search,
            StopOnSwitch,
            Latch,
            Index,
            Latched,
            Return,
            Done,
        ]);
        distinct(&[
            HomeEvent::Latched {
                joint: 0,
                index: None,
            },
            HomeEvent::Latched {
                joint: 0,
                index: Some(-7),
            },
            HomeEvent::Failed { joint: 0 },
            HomeEvent::Finished,
        ]);
    }

    fn every_config_error() -> Vec<ConfigError> {
        use GeometryField::*;
        let joint = 2;
        let mut all = vec![
            ConfigError::NoJoints,
            ConfigError::Smoothing,
            ConfigError::BoardChannel { joint },
            ConfigError::JointLimits { joint },
            ConfigError::JointTravel { joint },
            ConfigError::JointScale { joint },
            ConfigError::JointChannel { joint },
            ConfigError::StepRate { joint },
            ConfigError::JointAxis { joint },
            ConfigError::AxisLimits { axis: 4 },
            ConfigError::HomeOutsideTravel { joint },
            ConfigError::ServoGains { channel: 1 },
            ConfigError::Contour,
            ConfigError::Homing { joint },
        ];
        for field in [
            Joints,
            Rails,
            Forearm,
            BarHalf,
            Sides,
            Attach,
            ToolLength,
            TablePivot,
            MinElevation,
            Base,
            Platform,
        ] {
            all.push(ConfigError::Geometry { field });
        }
        all
    }

    #[test]
    fn every_configuration_and_store_error_reads_differently() {
        let all = every_config_error();
        distinct(&all);
        let mut stored: Vec<StoreError> = all.iter().map(|e| StoreError::Invalid(*e)).collect();
        stored.extend([
            StoreError::NoRecord,
            StoreError::Damaged,
            StoreError::Undecodable,
            StoreError::Busy,
        ]);
        distinct(&stored);
        let names = ["x", "y", "z"];
        let named: Vec<String> = all
            .iter()
            .map(|e| e.with_joint_names(&names).to_string())
            .collect();
        distinct(&named);
    }

    #[test]
    fn configuration_errors_read_as_the_machine_file_reports_them() {
        let e = ConfigError::BoardChannel { joint: 2 };
        assert_eq!(
            e.with_joint_names(&["x", "y", "z"]).to_string(),
            "joints[2] (z).channel: the board's timer on this channel cannot emit the steps \
             its max_velocity needs (channels 3–6 take at most 256 steps per ms)"
        );
        assert_eq!(
            ConfigError::HomeOutsideTravel { joint: 5 }
                .with_joint_names(&["x"])
                .to_string(),
            "home: outside the travel of joints[5] (?)"
        );
        assert_eq!(
            ConfigError::JointTravel { joint: 0 }.to_string(),
            "joints[0].min must be below max"
        );
        assert_eq!(
            ConfigError::Smoothing.to_string(),
            "motion: the smoothing window must be a power of two up to 32 ticks"
        );
        assert_eq!(
            ConfigError::AxisLimits { axis: 4 }.to_string(),
            "axes.B: bad limits"
        );
        let field = GeometryField::Rails;
        assert_eq!(
            ConfigError::Geometry { field }.to_string(),
            "h4_table.rails: out of range (±1073 mm)"
        );
        assert_eq!(
            GeometryField::Forearm.to_string(),
            "h4_table.forearm: out of range (0..1073 mm)"
        );
    }
}

#[path = "wording/recorder.rs"]
mod recorder;
