//! What the bridge says, in Grbl 1.1's words: status reports, alarm and error codes,
//! settings (`$$`), offsets (`$#`), build information (`$I`) and help (`$`).
//! Lengths are in millimetres and angles in degrees, three decimals.

use crate::gcode::{ErrorKind, Offsets};
use crate::link::view::StatusView;
use pkmc::config::{axis_is_rotary, MachineConfig, AXES, AXIS_NAMES};
use pkmc::units::to_user;
use pkmc::wire::{AlarmCause, State, Status};

/// The version string of `$I` and of the banner.
pub const VERSION: &str = "1.1h";
/// Blocks the bridge holds ahead of the controller (the first number of `Bf:`).
pub const BLOCK_BUFFER: usize = 128;
/// Receive buffer the bridge offers a character-counting sender, bytes (the second
/// number of `Bf:` when empty).
pub const RX_BUFFER: usize = 1024;

/// The start-up banner.
pub fn banner() -> String {
    format!("Grbl {VERSION} ['$' for help]")
}

/// One axis value in the sender's units: mm for X Y Z, degrees for A B C.
pub fn value(axis: usize, v: i64) -> String {
    format!("{:.3}", to_user(v, axis_is_rotary(axis)))
}

/// Axes reported: X Y Z, and up to the last rotary axis the machine has (a machine
/// with B but not A reports A as 0, so that every value keeps its place).
pub fn reported_axes(machine: &MachineConfig) -> usize {
    (3..AXES)
        .filter(|&i| machine.axes[i].max_velocity > 0)
        .map(|i| i + 1)
        .max()
        .unwrap_or(3)
}

/// `x,y,z[,a,b,c]` of `pose`.
pub fn list(pose: &[i64; AXES], n: usize) -> String {
    (0..n)
        .map(|i| value(i, pose[i]))
        .collect::<Vec<_>>()
        .join(",")
}

/// What the bridge adds to a controller's state for a report.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Mode {
    /// A `$J=` jog is under way.
    pub jogging: bool,
    /// Check mode (`$C`): lines are compiled and checked, nothing moves.
    pub check: bool,
    /// Blocks accepted (`ok`) are not all executed yet: `Run` even while the
    /// controller has not started them.
    pub pending: bool,
    /// A G38.2 or G38.4 ended without the change (`ALARM:5`): the bridge is in an
    /// alarm until `$X` or `$H`, though the controller is not.
    pub alarm: bool,
}

/// The state word: `Idle`, `Run`, `Hold:0` (stopped) or `Hold:1` (stopping), `Jog`,
/// `Home`, `Alarm`, `Check`.
pub fn state_word(s: &Status, mode: Mode) -> &'static str {
    match s.state {
        _ if mode.alarm => "Alarm",
        _ if mode.check && matches!(s.state, State::Idle) => "Check",
        // A jog, its queued successors and its cancel's deceleration are all `Jog`.
        State::Idle | State::Running | State::Hold
            if mode.jogging && (mode.pending || s.state != State::Idle) =>
        {
            "Jog"
        }
        State::Idle if mode.pending => "Run",
        State::Idle => "Idle",
        // Starved (the host is late with blocks; it runs on when they come): `Run`, so
        // that a sender neither takes the job for over (`Idle`) nor waits for a cycle
        // start (`Hold`): it keeps streaming, which is what ends the starvation.
        State::Running | State::Starved => "Run",
        State::Hold if s.speed == 0 => "Hold:0",
        State::Hold => "Hold:1",
        State::Homing => "Home",
        State::Alarm | State::EStop => "Alarm",
    }
}

/// What a status report shows besides the controller's status.
pub struct Report<'a> {
    /// The machine.
    pub machine: &'a MachineConfig,
    /// Jogging, check mode.
    pub mode: Mode,
    /// Free blocks and free receive bytes.
    pub free: (usize, usize),
    /// Work offset in force, machine units.
    pub wco: [i64; AXES],
    /// The feed override the sender set, % (during a jog the controller runs at
    /// 100 %: Grbl's jogs ignore the feed override).
    pub feed_override: u16,
    /// Rapid and spindle overrides as the sender set them (they do not act; see
    /// `docs/senders.md`).
    pub rapid_spindle: (u8, u8),
}

/// `<State|MPos:…|FS:feed,speed|Bf:blocks,bytes|Ln:line|Ov:f,r,s|WCO:…|Pn:…>`.
pub fn status_report(s: &Status, r: &Report<'_>) -> String {
    let n = reported_axes(r.machine);
    let view = StatusView::new(s);
    let mpos: Vec<String> = view.pose[..n].iter().map(|v| format!("{v:.3}")).collect();
    let mut out = format!(
        "<{}|MPos:{}|FS:{:.0},0|Bf:{},{}|Ln:{}|Ov:{},{},{}|WCO:{}",
        state_word(s, r.mode),
        mpos.join(","),
        view.feed_mm_min,
        r.free.0,
        r.free.1,
        s.line,
        r.feed_override,
        r.rapid_spindle.0,
        r.rapid_spindle.1,
        list(&r.wco, n),
    );
    let mut pins = String::new();
    if s.state == State::EStop {
        pins.push('E');
    } else if s.alarm.is_some_and(|a| a.cause == AlarmCause::LimitSwitch) {
        let axis = s.alarm.map_or(0, |a| a.joint as usize);
        pins.push(
            ['X', 'Y', 'Z', 'A', 'B', 'C']
                .get(axis)
                .copied()
                .unwrap_or('X'),
        );
    }
    // The probe input triggered (Grbl's `P`).
    if s.probe_input {
        pins.push('P');
    }
    if !pins.is_empty() {
        out.push_str("|Pn:");
        out.push_str(&pins);
    }
    out.push('>');
    out
}

/// Grbl's alarm number for our cause (grblHAL's numbers beyond Grbl's own 1–9); the
/// `[MSG:…]` after it names our cause, joint and line.
pub fn alarm_code(cause: AlarmCause) -> u8 {
    match cause {
        AlarmCause::LimitSwitch => 1,
        AlarmCause::Unreachable | AlarmCause::JointLimit | AlarmCause::Singularity => 2,
        AlarmCause::Aborted | AlarmCause::LinkLoss | AlarmCause::Watchdog => 3,
        AlarmCause::ProbeAtStart => 4,
        AlarmCause::HomingFailed => 9,
        AlarmCause::EStop => 10,
        AlarmCause::Unhomed => 11,
        AlarmCause::DriveFault | AlarmCause::FollowingError | AlarmCause::JointSpeed => 17,
        _ => 3,
    }
}

/// Grbl 1.1's error number for a front-end error, by its kind (the numbers of
/// `doc/csv/error_codes_en_US.csv` of github.com/gnea/grbl); the `[MSG:…]` before it
/// gives file, line, column and our words. Kinds Grbl has no number of its own for
/// take the nearest: syntax around the words is 1 (not a word), a value that cannot
/// be read, computed or held is 2 (bad number).
pub fn error_code(kind: ErrorKind) -> u8 {
    use ErrorKind::*;
    match kind {
        ExpectedLetter | Syntax => 1,
        BadNumber | OutOfRange | Parameter => 2,
        Negative => 4,
        LineTooLong => 11,
        Unsupported | UnknownCode | NoSuchAxis | ModeConflict | Flow => 20,
        ModalGroup => 21,
        NoFeed => 22,
        NotInteger => 23,
        TwoAxisCommands => 24,
        RepeatedWord => 25,
        NoAxisWords => 26,
        MissingValue => 28,
        G53Motion => 30,
        UnusedAxisWords => 31,
        ArcNoPlaneAxis => 32,
        InvalidTarget => 33,
        ArcRadius => 34,
        ArcNoOffset => 35,
        UnusedWords => 36,
        ToolNumber => 38,
    }
}

/// `$$`: the machine's limits as settings. All are read-only here: they come from
/// the machine file. `$110`+i max rate (mm or °/min), `$120`+i acceleration (mm or
/// °/s²), `$130`–`$132` the travel of X, Y and Z (mm, from [`max_travel`]); and per
/// joint, `$200`+10·j … `$203`+10·j: travel min, max (mm or °), max speed (/min) and
/// acceleration (/s²).
pub fn settings(machine: &MachineConfig, travel: &[f64; 3]) -> Vec<(u32, String)> {
    let homing = machine.joints.iter().any(|j| j.homing.enabled());
    let mut out = vec![
        (10, "511".to_string()),
        (13, "0".to_string()),
        (20, "1".to_string()),
        (21, "0".to_string()),
        (22, (homing as u8).to_string()),
    ];
    let n = reported_axes(machine);
    for i in 0..n {
        let l = machine.axes[i];
        out.push((110 + i as u32, per_minute(i, l.max_velocity.max(0))));
        out.push((120 + i as u32, value(i, l.max_accel.max(0))));
    }
    for (i, t) in travel.iter().enumerate() {
        out.push((130 + i as u32, format!("{t:.3}")));
    }
    for (j, joint) in machine.joints.iter().enumerate() {
        let axis = if joint.rotary { 3 } else { 0 };
        let base = 200 + 10 * j as u32;
        out.push((base, value(axis, joint.min)));
        out.push((base + 1, value(axis, joint.max)));
        out.push((base + 2, per_minute(axis, joint.limits.max_velocity)));
        out.push((base + 3, value(axis, joint.limits.max_accel)));
    }
    out
}

/// How far X, Y and Z reach along a line through `pose` (the others held), mm to
/// 1 µm: the machine's travel per axis, for `$130`–`$132` (senders draw the
/// machine's limits from them). On a parallel machine the reach depends on the
/// pose; the bridge measures it through its start pose.
pub fn max_travel(machine: &MachineConfig, pose: &[i64; AXES]) -> [f64; 3] {
    let kin = pkmc::kinematics::MachineKinematics::new(machine);
    let mut q = [0i64; pkmc::config::MAX_JOINTS];
    let mut reach = |axis: usize, v: i64| {
        let mut p = *pose;
        p[axis] = v;
        kin.inverse_checked(&p, &machine.joints, &mut q).is_ok()
    };
    std::array::from_fn(|axis| {
        if machine.axes[axis].max_velocity <= 0 || !reach(axis, pose[axis]) {
            return 0.0;
        }
        let ends = [-1i64, 1].map(|dir| {
            // Out by 1 mm steps (up to 10 m), then halve the last step to 1 µm.
            let (mut inside, mut step) = (pose[axis], 1_000_000i64);
            let mut k = 0;
            while k < 10_000 && reach(axis, inside + dir * step) {
                inside += dir * step;
                k += 1;
            }
            while step > 1_000 {
                step /= 2;
                if reach(axis, inside + dir * step) {
                    inside += dir * step;
                }
            }
            inside
        });
        (ends[1] - ends[0]) as f64 / 1e6
    })
}

fn per_minute(axis: usize, v: i64) -> String {
    value(axis, v.saturating_mul(60))
}

/// `$#`: work systems, stored positions, G92, tool length offset, and `prb`, the last
/// probe's `[PRB:…]`.
pub fn offsets(o: &Offsets, n: usize, prb: String) -> Vec<String> {
    let mut out = Vec::new();
    for (k, s) in o.systems.iter().enumerate().take(6) {
        out.push(format!("[G{}:{}]", 54 + k, list(s, n)));
    }
    out.push(format!("[G28:{}]", list(&o.g28, n)));
    out.push(format!("[G30:{}]", list(&o.g30, n)));
    out.push(format!("[G92:{}]", list(&o.g92, n)));
    out.push(format!("[TLO:{}]", value(2, o.tool[2])));
    out.push(prb);
    out
}

/// `$I`: version and the buffer sizes.
pub fn build_info(machine: &MachineConfig) -> Vec<String> {
    vec![
        format!("[VER:{VERSION}.pkmc:{}]", machine.name),
        format!("[OPT:V,{BLOCK_BUFFER},{RX_BUFFER}]"),
        format!(
            "[MSG:pkmc bridge; axes {}]",
            AXIS_NAMES[..reported_axes(machine)]
                .iter()
                .collect::<String>()
        ),
    ]
}

/// `$`: the commands understood.
pub fn help() -> &'static str {
    "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $C $X $H ~ ! ? ctrl-x]"
}

#[cfg(test)]
mod tests {
    use super::{error_code, ErrorKind};

    /// The front end's error kinds that Grbl 1.1 answers with `error:20` ("unsupported
    /// or invalid g-code command"): what the dialect does not have (a feature not
    /// implemented, an unknown code or letter, an axis the machine lacks, O-word flow
    /// control line by line) or does not take in the mode in force. Every other kind has
    /// a number of its own ([`error_code`]).
    pub const UNSUPPORTED: &[ErrorKind] = &[
        ErrorKind::Unsupported,
        ErrorKind::UnknownCode,
        ErrorKind::NoSuchAxis,
        ErrorKind::ModeConflict,
        ErrorKind::Flow,
    ];

    /// Only the kinds listed as unsupported are `error:20`; every other kind has a
    /// number of its own among Grbl 1.1's G-code errors.
    #[test]
    fn no_error_kind_falls_back_to_20_unless_listed_as_unsupported() {
        assert!(ErrorKind::ALL.len() >= 20, "{:?}", ErrorKind::ALL);
        for &kind in ErrorKind::ALL {
            let code = error_code(kind);
            assert_eq!(
                code == 20,
                UNSUPPORTED.contains(&kind),
                "{kind:?} is error:{code}"
            );
            assert!(
                matches!(code, 1 | 2 | 4 | 11 | 20..=38),
                "{kind:?}: error:{code} is not one of Grbl 1.1's G-code errors"
            );
        }
    }
}
