//! Commands on the board's standard input: the machine's inputs (e-stop, limit
//! switches, amplifier faults, a jammed axis), the USB cable, the reset button, a held
//! core, and the report. One per line; `at SECONDS COMMAND` runs it at that virtual
//! time instead of at once.
//!
//! | command | effect |
//! |---|---|
//! | `estop on` / `estop off` | the e-stop input (PA10 high = e-stop) |
//! | `limit K on` / `limit K off` | limit/home input K open (high) or closed |
//! | `fault G on` / `fault G off` | amplifier fault line of group G pulled low |
//! | `jam C` | servo channel C's axis stops where it is (its plant is frozen) |
//! | `unplug` / `plug` | the USB cable |
//! | `reset` | a pulse on NRST (the reset button) |
//! | `hold MS` | the core executes nothing for MS ms (its instruction fetch stalled); the peripherals run on |
//! | `mark` | start the figures afresh: busy periods, servo latencies, the worst of each |
//! | `report` | print the JSON report now |
//! | `quit` | stop, as Ctrl-C does |

use crate::cpu::Core;
use crate::periph::clocks::ResetCause;
use crate::time;
use crate::usbhost::Host;

/// What the caller does next.
pub enum Outcome {
    /// Nothing more.
    Done,
    /// Print the report.
    Report,
    /// Stop.
    Quit,
    /// The figures start afresh.
    Mark,
}

/// The board commands that make the simulator's fault injection `i` (`--inject
/// KIND[:JOINT]@SECONDS`, the same syntax as `nc-send --inject`) happen at its pins,
/// at `SECONDS` of virtual time since power-on: the e-stop input; joint J's limit
/// switch (input J); the fault line of joint J's amplifier group; joint J's servo axis
/// jammed; the USB cable pulled for [`pkmc_host::sim::LINK_CUT`].
pub fn injection(
    i: &pkmc_host::sim::Injection,
    core: &Core,
) -> Result<Vec<(u64, String)>, anyhow::Error> {
    use pkmc::config::Drive;
    use pkmc_host::sim::FaultKind;
    let at = (i.at_s * time::UNITS_PER_S as f64) as u64;
    let b = core.uc.get_data();
    let joint = |what: &str| -> Result<(usize, Drive), anyhow::Error> {
        let j = i
            .joint
            .ok_or_else(|| anyhow::anyhow!("--inject {what} needs :JOINT"))?;
        let jc =
            b.machine.machine.joints.get(j).ok_or_else(|| {
                anyhow::anyhow!("--inject {what}:{j}: the machine has no joint {j}")
            })?;
        Ok((j, jc.drive))
    };
    let servo_channel = |what: &str| -> Result<usize, anyhow::Error> {
        match joint(what)? {
            (_, Drive::Servo { channel }) => Ok(channel as usize),
            (j, Drive::Stepper { .. }) => Err(anyhow::anyhow!(
                "--inject {what}:{j}: joint {j} is a stepper, and the board has no stepper \
                 fault line (docs/wiring.md)"
            )),
        }
    };
    Ok(match i.kind {
        FaultKind::EStop => vec![(at, "estop on".into())],
        FaultKind::Limit => vec![(at, format!("limit {} on", joint("limit")?.0))],
        FaultKind::DriveFault => {
            let c = servo_channel("drive-fault")?;
            vec![(at, format!("fault {} on", b.wiring.servo_group[c]))]
        }
        FaultKind::FollowingError => {
            vec![(at, format!("jam {}", servo_channel("following-error")?))]
        }
        FaultKind::LinkLoss => {
            let cut = time::from_ms(pkmc_host::sim::LINK_CUT.as_millis() as u64);
            vec![(at, "unplug".into()), (at + cut, "plug".into())]
        }
    })
}

/// Parses a line: `Some((time, command))`, `None` for a blank line or a comment.
pub fn parse(line: &str) -> Result<Option<(Option<u64>, String)>, String> {
    let line = line.trim();
    if line.is_empty() || line.starts_with('#') {
        return Ok(None);
    }
    let mut words = line.split_whitespace();
    if line.starts_with("at ") {
        words.next();
        let t: f64 = words
            .next()
            .and_then(|w| w.parse().ok())
            .ok_or_else(|| format!("\"{line}\": \"at\" wants a time in seconds"))?;
        let rest: Vec<&str> = words.collect();
        return Ok(Some((
            Some((t * time::UNITS_PER_S as f64) as u64),
            rest.join(" "),
        )));
    }
    Ok(Some((None, line.to_string())))
}

fn on_off(w: Option<&str>, cmd: &str) -> Result<bool, String> {
    match w {
        Some("on") => Ok(true),
        Some("off") => Ok(false),
        _ => Err(format!("\"{cmd}\": expected on or off")),
    }
}

fn index(w: Option<&str>, cmd: &str, below: usize) -> Result<usize, String> {
    w.and_then(|w| w.parse().ok())
        .filter(|&k: &usize| k < below)
        .ok_or_else(|| format!("\"{cmd}\": expected a number below {below}"))
}

/// Runs `cmd` on the board.
pub fn apply(cmd: &str, core: &mut Core, host: &mut Host) -> Result<Outcome, String> {
    let mut w = cmd.split_whitespace();
    let verb = w.next().unwrap_or("");
    let now = core.uc.get_data().now;
    let b = core.uc.get_data_mut();
    match verb {
        "estop" => b.machine.estop = on_off(w.next(), cmd)?,
        "limit" => {
            let k = index(w.next(), cmd, b.wiring.limits.len())?;
            if on_off(w.next(), cmd)? {
                b.machine.limits |= 1 << k;
            } else {
                b.machine.limits &= !(1 << k);
            }
        }
        "fault" => {
            let g = index(w.next(), cmd, b.machine.amp_fault.len())?;
            b.machine.amp_fault[g] = on_off(w.next(), cmd)?;
        }
        "probe" => {
            let touching = on_off(w.next(), cmd)?;
            let at = match w.next() {
                None => now,
                Some(us) => {
                    let us: f64 = us
                        .parse()
                        .ok()
                        .filter(|u: &f64| (0.0..1e6).contains(u))
                        .ok_or_else(|| {
                            format!(
                                "\"{cmd}\": expected µs after the next tick edge, 0 to 1 000 000"
                            )
                        })?;
                    let edge = b
                        .next_tick_edge(now)
                        .ok_or_else(|| format!("\"{cmd}\": no tick has run yet"))?;
                    edge + (us * time::UNITS_PER_S as f64 / 1e6).round() as u64
                }
            };
            b.machine.probe_plan.push((at, touching));
        }
        "jam" => {
            let c = index(w.next(), cmd, b.machine.servos.len())?;
            b.machine.servos[c]
                .as_mut()
                .ok_or_else(|| format!("\"{cmd}\": servo channel {c} drives no joint"))?
                .jam();
        }
        "unplug" => host.plug(false, now),
        "plug" => host.plug(true, now),
        "reset" => b.reset_due = Some(ResetCause::Pin),
        // A debugger's reset request (as `probe-rs reset` makes it): AIRCR written
        // with VECTKEY and SYSRESETREQ through the debug port, on the same bus.
        "sysreset" => b.write(0xE000_ED0C, 4, 0x05FA_0004),
        "hold" => {
            let ms = index(w.next(), cmd, 100_000)?;
            core.held_until = now + time::from_ms(ms as u64);
        }
        "mark" => {
            let st = &mut b.stats;
            st.busy.clear();
            st.worst_busy.clear();
            st.servo_latency.clear();
            st.worst_servo.clear();
            b.worst_profile = None;
            return Ok(Outcome::Mark);
        }
        "report" => return Ok(Outcome::Report),
        "quit" => return Ok(Outcome::Quit),
        _ => return Err(format!("unknown command \"{cmd}\" (see docs/vboard.md)")),
    }
    core.uc.get_data_mut().drive_inputs();
    Ok(Outcome::Done)
}
