//! The single commands (`home`, `jog`, `mdi`, `reset`, `status`) and what a job
//! does before it starts (homing or unlocking).

use super::{exit, open_port, open_target, Failure, RunOptions};
use crate::link::{JobEnd, JobHooks, Link, LinkOptions, PortTransport, Transport};
use pkmc::config::{MachineConfig, AXES, AXIS_NAMES};
use pkmc::kinematics::MachineKinematics;
use pkmc::motion::block::{Block, Motion};
use pkmc::wire::{Control, State, Status};

/// What `home` sends: the homing cycle on a machine with home switches; on one
/// without, the rapid move to its home pose, planned here from where the controller
/// stands (the controller plans nothing itself).
pub fn home_command<T: Transport>(link: &mut Link<T>) -> Result<Control, Failure> {
    let machine = link.machine().clone();
    if machine.joints.iter().any(|j| j.homing.enabled()) {
        return Ok(Control::Home);
    }
    let from = link.request_status()?.pose;
    let block = Block {
        line: 0,
        motion: Motion::Rapid,
        target: machine.home,
        feed: 0,
        tolerance_nm: 0,
    };
    let kin = MachineKinematics::new(&machine);
    let planned = pkmc::motion::planner::plan_move(&block, from, &machine, &kin).map_err(|e| {
        Failure::new(
            exit::PREFLIGHT,
            format!("home: the move home cannot be planned: {e}"),
        )
    })?;
    Ok(Control::Jog(planned))
}

/// A jog in axis units: the pose axis, the distance and the feed per second.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct JogRequest {
    /// Pose axis, 0 to 5 (X Y Z A B C).
    pub axis: usize,
    /// Distance, nm or n°; never 0.
    pub distance: i64,
    /// Feed, nm/s or n°/s; positive.
    pub feed: i64,
}

/// The one check of a jog as an operator asks for it (`nc-send jog`, the station's
/// jog buttons): `axis` one of X Y Z A B C (either case), `distance` in mm or
/// degrees, a number and not 0 (a jog of 0 is a slip of the hand), `feed` in mm/min
/// or degrees/min, a positive number. `feed_field` names the feed as the operator
/// gave it (`--feed`, `feed`). A refusal names the field and exits 2.
pub fn jog_request(
    axis: &str,
    distance: f64,
    feed: f64,
    feed_field: &str,
) -> Result<JogRequest, Failure> {
    let bad = |m: String| Failure::new(exit::BAD_INPUT, m);
    let i = AXIS_NAMES
        .iter()
        .position(|n| axis.len() == 1 && axis.starts_with(|c: char| c.eq_ignore_ascii_case(n)))
        .ok_or_else(|| bad(format!("jog: unknown axis {axis:?} (X Y Z A B C)")))?;
    if !distance.is_finite() || distance == 0.0 {
        return Err(bad(format!(
            "jog: distance {distance}: must be a number other than 0 (a jog of 0 moves nothing)"
        )));
    }
    if !feed.is_finite() || feed <= 0.0 {
        return Err(bad(format!(
            "jog: {feed_field} {feed}: must be a positive number"
        )));
    }
    let scale = pkmc::units::units_per_user(pkmc::config::axis_is_rotary(i)) as f64;
    Ok(JogRequest {
        axis: i,
        distance: (distance * scale).round() as i64,
        feed: (feed / 60.0 * scale).round() as i64,
    })
}

/// What `jog` sends: `distance` (axis units) along pose axis `axis` at `feed`
/// (units/s), clipped to the joint travel and planned here from where the controller
/// stands. An axis the machine does not have is refused (exit 2).
pub fn jog_command<T: Transport>(
    link: &mut Link<T>,
    axis: usize,
    distance: i64,
    feed: i64,
) -> Result<Control, Failure> {
    let machine = link.machine().clone();
    if machine.axes[axis].max_velocity <= 0 {
        let have: Vec<String> = (0..AXES)
            .filter(|&i| machine.axes[i].max_velocity > 0)
            .map(|i| AXIS_NAMES[i].to_string())
            .collect();
        return Err(Failure::new(
            exit::BAD_INPUT,
            format!(
                "jog: the machine has no {} axis (its axes: {})",
                AXIS_NAMES[axis],
                have.join(" ")
            ),
        ));
    }
    let from = link.request_status()?.pose;
    let kin = MachineKinematics::new(&machine);
    let planned = pkmc::motion::planner::plan_jog(&machine, &kin, &from, axis, distance, feed)
        .map_err(|e| Failure::new(exit::PREFLIGHT, format!("jog: cannot be planned: {e}")))?;
    Ok(Control::Jog(planned))
}

/// Before a job or a move: with `home`, homes the machine and waits until it is
/// there; otherwise a controller locked after a reset (alarm `Unhomed`) is unlocked
/// where it stands on the simulator (`sim`), and is an error naming the fix on a
/// board. Returns how the job ended if homing ended it (an alarm).
pub fn prepare<T: Transport>(
    link: &mut Link<T>,
    home: bool,
    sim: bool,
    hooks: &mut dyn JobHooks,
) -> Result<Option<JobEnd>, Failure> {
    let s = link.request_status()?;
    let locked = s.alarm.map(|a| a.cause) == Some(pkmc::wire::AlarmCause::Unhomed);
    if home {
        if !locked && s.state != State::Idle {
            return Err(Failure::new(
                exit::ALARM,
                format!(
                    "{}: cannot home: the controller is {}",
                    link.transport().name(),
                    state_text(&s)
                ),
            ));
        }
        let cmd = home_command(link)?;
        link.control(cmd)?;
        return match link.wait_idle(hooks)? {
            JobEnd::Done => Ok(None),
            end => Ok(Some(end)),
        };
    }
    if locked {
        if !sim {
            return Err(Failure::new(
                exit::ALARM,
                format!(
                    "{}: the controller is locked after a reset (it does not know where the \
                     machine is): home it (--home, or `nc-send home`) or unlock it where it \
                     stands (`nc-send reset`)",
                    link.transport().name()
                ),
            ));
        }
        link.control(Control::AlarmReset)?;
    }
    Ok(None)
}

/// A single command (`status`, `home`, `jog`, `reset`) on a live link.
pub fn connect(
    machine: &MachineConfig,
    path: &str,
    opts: LinkOptions,
) -> Result<Link<PortTransport>, Failure> {
    Ok(Link::connect(PortTransport::open(path)?, machine, opts)?)
}

/// Runs `f` on a link to `target` (starting the simulator if asked), then stops the
/// simulator.
pub fn with_link<R>(
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
    f: impl FnOnce(&mut Link<PortTransport>) -> Result<R, Failure>,
) -> Result<R, Failure> {
    let (server, path) = open_target(machine, opts)?;
    let result = open_port(&path, server.as_ref())
        .and_then(|io| Ok(Link::connect(io, machine, opts.link)?))
        .and_then(|mut link| f(&mut link));
    if let Some(s) = server {
        s.finish()?;
    }
    result
}

/// Compiles one MDI line from the controller's current pose and runs it on `link`.
pub fn mdi<T: Transport>(
    link: &mut Link<T>,
    machine: &MachineConfig,
    line: &str,
    tools: &crate::gcode::ToolTable,
    hooks: &mut dyn JobHooks,
) -> Result<(Vec<Block>, JobEnd), Failure> {
    let status = link.request_status()?;
    let blocks = super::compile::compile_text_with(line, "MDI", machine, status.pose, tools)?;
    let end = link.run_job(&blocks, hooks)?;
    Ok((blocks, end))
}

/// Sends `cmd` (home or jog) and waits until the motion it starts is over.
pub fn move_and_wait<T: Transport>(
    link: &mut Link<T>,
    cmd: Control,
    hooks: &mut dyn JobHooks,
) -> Result<JobEnd, Failure> {
    link.refuse_if_held()?;
    let before = link.request_status()?;
    let locked = before.alarm.map(|a| a.cause) == Some(pkmc::wire::AlarmCause::Unhomed);
    if before.state != State::Idle && !(cmd == Control::Home && locked) {
        return Err(Failure::new(
            exit::ALARM,
            format!(
                "{}: the controller is {}; it moves only when idle",
                link.transport().name(),
                state_text(&before)
            ),
        ));
    }
    link.control(cmd)?;
    let end = link.wait_idle(hooks)?;
    if let (JobEnd::Done, Control::Jog(planned)) = (&end, cmd) {
        // The controller acts on a planned move only if it starts where it stands:
        // a refusal leaves it where it was, which must not pass for success.
        let after = link.request_status()?;
        if after.pose != planned.block.target {
            return Err(Failure::new(
                exit::ALARM,
                format!(
                    "{}: the controller did not make the move (it refuses a move that does \
                     not start where it stands, or comes while it is busy)",
                    link.transport().name()
                ),
            ));
        }
    }
    Ok(end)
}

/// A controller's state in words, with its alarm when it has one: `alarm (not
/// homed)`.
pub fn state_text(s: &Status) -> String {
    crate::link::view::StatusView::new(s).state_text()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_jog_is_checked_once_and_a_jog_of_zero_is_refused_naming_its_field() {
        let r = jog_request("y", -2.5, 1200.0, "--feed").unwrap();
        assert_eq!(
            r,
            JogRequest {
                axis: 1,
                distance: -2_500_000,
                feed: 20_000_000
            }
        );
        assert_eq!(jog_request("B", 90.0, 60.0, "feed").unwrap().axis, 4);
        let refused = |axis, distance, feed, field| {
            let f = jog_request(axis, distance, feed, field).unwrap_err();
            assert_eq!(f.code, exit::BAD_INPUT);
            f.message
        };
        assert!(refused("X", 0.0, 600.0, "feed").contains("distance 0"));
        assert!(refused("X", f64::NAN, 600.0, "feed").contains("distance NaN"));
        assert!(refused("Q", 1.0, 600.0, "feed").contains("unknown axis \"Q\""));
        assert!(refused("XY", 1.0, 600.0, "feed").contains("unknown axis"));
        assert!(refused("X", 1.0, 0.0, "--feed").contains("--feed 0"));
        assert!(refused("X", 1.0, f64::INFINITY, "feed").contains("feed inf"));
    }
}
