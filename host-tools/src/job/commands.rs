//! The single commands (`home`, `jog`, `mdi`, `reset`, `status`) and what a job
//! does before it starts (homing or unlocking).

use super::{describe_alarm, exit, open_port, open_target, Failure, RunOptions};
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

/// A controller's state in words, with its alarm when it has one: `alarm (Unhomed)`.
pub fn state_text(s: &Status) -> String {
    match s.alarm {
        Some(a) => format!("{} ({})", s.state, describe_alarm(&a)),
        None => s.state.to_string(),
    }
}
