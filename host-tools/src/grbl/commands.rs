//! Grbl's `$` commands: those answered from the bridge's own state (`$`, `$$`, `$#`,
//! `$G`, `$I`, `$N`, `$Nx=`, settings), and those that act on the controller and run
//! only between jobs (`$H`, `$X`, `$C`, `$J=`). While a job moves or is held, these
//! get Grbl's answers at once: `$X` has no effect (`ok`), `$H` and `$C` are
//! `error:8` (not idle), and `$J=` is `error:8` unless a jog is under way, when it is
//! queued after it. Those answered from the bridge's state are refused in the states
//! where Grbl 1.1 refuses them ([`refused_in`]).

use super::bridge::{Bridge, Needs, Phase};
use super::words;
use crate::job::{home_command, Failure};
use crate::link::{JobEnd, Link, Transport};
use pkmc::config::{AXES, AXIS_NAMES};
use pkmc::kinematics::MachineKinematics;
use pkmc::motion::block::{Block, Motion};
use pkmc::wire::Control;

/// Where `line` may run.
pub(super) fn needs(line: &str) -> Needs {
    let t = line.trim().to_ascii_uppercase();
    if t == "$H" || t == "$X" || t == "$C" || t.starts_with("$J=") {
        Needs::Link
    } else {
        Needs::Nothing
    }
}

/// Grbl 1.1's refusal (`error:8`, not idle) of a `$` line in `phase`, as its
/// `system_execute_line` decides by the character after the `$`: `$` alone, `$G` and
/// `$X` run in every state; `$$` not in a cycle or a hold; `$C` and `$J=` have their
/// own rules (see [`run_link`]); every other one (`$#`, `$I`, `$N`, `$H`, settings)
/// only when idle or in an alarm, and storing a start-up line (`$Nx=`) only when idle.
/// `None`: the line may run.
fn refused_in(upper: &str, phase: Phase) -> Option<&'static str> {
    let when = match phase {
        Phase::Idle => return None,
        Phase::Alarm => "in an alarm",
        Phase::Check => "in check mode",
        Phase::Jog => "while jogging",
        Phase::Cycle => "while a cycle runs or is held",
    };
    match upper.as_bytes().get(1) {
        None | Some(b'G' | b'X' | b'C' | b'J') => None,
        Some(b'$') => (phase == Phase::Cycle).then_some(when),
        _ if upper.starts_with("$N0=") || upper.starts_with("$N1=") => Some(when),
        _ if phase == Phase::Alarm => None,
        _ => Some(when),
    }
}

/// Answers a `$` line that needs only the bridge's state, `phase` being Grbl's state
/// at that moment.
pub(super) fn answer_local(b: &mut Bridge<'_>, line: &str, phase: Phase) {
    let t = line.trim();
    let upper = t.to_ascii_uppercase();
    if let Some(when) = refused_in(&upper, phase) {
        b.refuse(
            8,
            &format!("{t} is refused {when}, as Grbl 1.1 refuses it (not idle)"),
        );
        return;
    }
    match upper.as_str() {
        "$" => {
            b.say(words::help());
            b.ok();
        }
        "$$" => {
            for (n, v) in words::settings(b.machine, &b.travel) {
                b.say(&format!("${n}={v}"));
            }
            b.ok();
        }
        "$#" => {
            let n = words::reported_axes(b.machine);
            let prb = b.last_probe.line(n);
            for l in words::offsets(&b.pipeline.interp().offsets(), n, prb) {
                b.say(&l);
            }
            b.ok();
        }
        "$G" => {
            let gc = b.pipeline.interp().modal_words();
            b.say(&format!("[GC:{gc}]"));
            b.ok();
        }
        "$I" => {
            for l in words::build_info(b.machine) {
                b.say(&l);
            }
            b.ok();
        }
        "$N" => {
            for i in 0..2 {
                let l = b.startup[i].clone();
                b.say(&format!("$N{i}={l}"));
            }
            b.ok();
        }
        _ if upper.starts_with("$N0=") || upper.starts_with("$N1=") => {
            let i = (upper.as_bytes()[2] - b'0') as usize;
            b.startup[i] = t[4..].to_string();
            b.ok();
        }
        _ if upper.starts_with('$') && upper[1..].split('=').next().is_some_and(is_number) => {
            let n = &upper[1..upper.find('=').unwrap_or(upper.len())];
            if upper.contains('=') {
                b.refuse(
                    3,
                    &format!(
                        "${n} is read-only here: the machine's limits come from its machine file"
                    ),
                );
            } else {
                match words::settings(b.machine, &b.travel)
                    .iter()
                    .find(|(k, _)| k.to_string() == n)
                {
                    Some((k, v)) => {
                        b.say(&format!("${k}={v}"));
                        b.ok();
                    }
                    None => b.refuse(3, &format!("no setting ${n}")),
                }
            }
        }
        // Outside an alarm, Grbl's $X has no effect.
        "$X" => b.ok(),
        _ if needs(t) == Needs::Link => {
            b.refuse(
                8,
                &format!("{t} runs only when the machine is idle (now it is moving or held)"),
            );
        }
        _ => b.refuse(3, &format!("unknown or unsupported command {t}")),
    }
}

fn is_number(s: &str) -> bool {
    !s.is_empty() && s.bytes().all(|c| c.is_ascii_digit())
}

/// Runs a `$` line that acts on the controller (the machine is not in a job). Grbl's
/// refusals: `$H`, `$J=` and turning `$C` on need an idle machine (`error:8`, also in
/// a feed hold at rest); `$X` outside an alarm has no effect.
pub(super) fn run_link<T: Transport>(
    b: &mut Bridge<'_>,
    link: &mut Link<T>,
    line: &str,
) -> Result<(), Failure> {
    let t = line.trim();
    let upper = t.to_ascii_uppercase();
    let held = b
        .status
        .as_ref()
        .is_some_and(|s| s.state == pkmc::wire::State::Hold);
    let not_idle = |b: &mut Bridge<'_>, why: &str| {
        b.refuse(8, &format!("{t} needs the machine idle: {why}"));
    };
    match upper.as_str() {
        "$X" => unlock(b, link)?,
        _ if b.locked() && upper != "$H" && upper != "$C" => {
            not_idle(b, "it is in alarm; '$X' unlocks, '$H' homes")
        }
        _ if held && !(upper == "$C" && b.mode.check) => {
            not_idle(b, "it is in a feed hold; '~' resumes, Ctrl-X clears it")
        }
        "$H" if b.mode.check => not_idle(b, "check mode is on; '$C' turns it off"),
        "$H" => home(b, link)?,
        "$C" if b.locked() && !b.mode.check => {
            not_idle(b, "it is in alarm; '$X' unlocks, '$H' homes")
        }
        "$C" => {
            b.mode.check = !b.mode.check;
            b.say(if b.mode.check {
                "[MSG:Enabled]"
            } else {
                "[MSG:Disabled]"
            });
            b.ok();
            if !b.mode.check {
                let pose = link.request_status()?.pose;
                b.pipeline.restart(pose);
            }
        }
        _ if b.mode.check => not_idle(b, "check mode is on; '$C' turns it off"),
        _ => jog(b, link, &t[3..])?,
    }
    Ok(())
}

/// `$X`: in an alarm, unlocks, unless the cause is still there (the e-stop held in,
/// a drive fault): then it says so, and `error:9` (G-code stays locked out).
fn unlock<T: Transport>(b: &mut Bridge<'_>, link: &mut Link<T>) -> Result<(), Failure> {
    if !b.locked() {
        b.ok();
        return Ok(());
    }
    // A failed probe's alarm is the bridge's own.
    b.mode.alarm = false;
    if b.locked() {
        link.control(Control::AlarmReset)?;
    }
    let s = link.request_status()?;
    b.status = Some(s.clone());
    if b.locked() {
        let why = match s.state {
            pkmc::wire::State::EStop => {
                "the e-stop is still latched: release it, then '$X'".to_string()
            }
            _ => format!("the controller is still {}", crate::job::state_text(&s)),
        };
        b.refuse(9, &format!("$X: not unlocked: {why}"));
    } else {
        b.say("[MSG:Caution: Unlocked]");
        b.ok();
    }
    Ok(())
}

/// `$H`: homes, reading the senders meanwhile; a reset during it is Grbl's ALARM:6.
fn home<T: Transport>(b: &mut Bridge<'_>, link: &mut Link<T>) -> Result<(), Failure> {
    let cmd = home_command(link)?;
    link.control(cmd)?;
    b.homing = true;
    let end = link.wait_idle(b);
    b.homing = false;
    let end = end?;
    if b.reset {
        // The line gets no answer: the reset drops it, as on Grbl.
        let s = link.request_status()?;
        b.pipeline.set_position(s.pose);
        b.alarm_told = s.alarm;
        b.status = Some(s);
        b.say("ALARM:6");
        b.say("[MSG:Homing was cancelled by a reset: '$H' homes again]");
        return Ok(());
    }
    after_move(b, link, end)?;
    // Homing ends a failed probe's alarm, as `$X` does.
    b.mode.alarm = false;
    // One answer for the line, as for every line: homing ended in an alarm
    // (reported above) is a refusal.
    if b.locked() {
        b.refuse(9, "$H: homing did not complete");
    } else {
        b.ok();
    }
    Ok(())
}

/// After homing or a jog: the interpreter moves to where the machine now is; an
/// alarm is reported.
fn after_move<T: Transport>(
    b: &mut Bridge<'_>,
    link: &mut Link<T>,
    end: JobEnd,
) -> Result<(), Failure> {
    let s = link.request_status()?;
    b.pipeline.set_position(s.pose);
    b.jog_end = s.pose;
    b.status = Some(s);
    if let JobEnd::Alarm(a) = end {
        super::report_alarm(b, &a);
    }
    Ok(())
}

/// `$J=…`: G20/G21, G90/G91, G53, axis words and F (required). The jog runs as a job
/// of its own, fed by the `$J=` lines that follow while it moves (queued, as Grbl
/// queues jogs); 0x85 or `!` cancels it and every queued jog.
fn jog<T: Transport>(b: &mut Bridge<'_>, link: &mut Link<T>, body: &str) -> Result<(), Failure> {
    let s = link.request_status()?;
    let block = match jog_block(b, body, &s.pose) {
        Ok(block) => block,
        Err((code, why)) => {
            b.refuse(code, &format!("$J={body}: {why}"));
            return Ok(());
        }
    };
    b.ok();
    // A jog runs at its own feed whatever the feed override (Grbl 1.1's jogging
    // interface): the controller is at 100 % for it and back to the sender's
    // override after it, including overrides set while it moved.
    if b.feed_override != 100 {
        link.control(Control::FeedOverride(100))?;
    }
    b.mode.jogging = true;
    b.jog_end = block.target;
    b.set_job(Some((1, 0)));
    let end = link.run_job(&[block], b);
    b.set_job(None);
    b.mode.jogging = false;
    if b.feed_override != 100 {
        link.control(Control::FeedOverride(b.feed_override))?;
    }
    after_move(b, link, end?)
}

/// One jog from `from` (where the jogs before it end): its block, or Grbl's error
/// number and why. The target is checked against the machine's reach (`error:15`
/// beyond it) and the move must be one the planner can plan (`error:16`).
pub(super) fn jog_block(
    b: &Bridge<'_>,
    body: &str,
    from: &[i64; pkmc::config::AXES],
) -> Result<Block, (u8, String)> {
    let (target, feed) = jog_target(b, body, from)?;
    let block = Block {
        line: b.line_no,
        motion: Motion::Linear,
        target,
        feed,
        tolerance_nm: JOG_BLEND_NM,
    };
    let report = crate::analysis::preflight::check(&[block], b.machine, *from);
    if let Some(f) = report.findings.first() {
        return Err((15, f.what.clone()));
    }
    let kin = MachineKinematics::new(b.machine);
    if let Err(e) = pkmc::motion::planner::plan_move(&block, *from, b.machine, &kin) {
        return Err((16, format!("cannot be planned: {e}")));
    }
    Ok(block)
}

/// A queued jog blends into the next within 10 µm of its end (Grbl's default
/// junction deviation, `$11=0.010`, is of the same size), so that a sender's run of
/// short jogs one way does not stop between them.
const JOG_BLEND_NM: u32 = 10_000;

type Jog = ([i64; AXES], i64);

/// The jog's target (machine frame) and feed (axis units/s) from its words.
fn jog_target(b: &Bridge<'_>, body: &str, pose: &[i64; AXES]) -> Result<Jog, (u8, String)> {
    let interp = b.pipeline.interp();
    let mut inch = interp.inch;
    let mut absolute = interp.absolute;
    let mut machine_frame = false;
    let mut axes: [Option<f64>; AXES] = [None; AXES];
    let mut feed = None;
    let text = body.to_ascii_uppercase();
    let mut rest = text.trim();
    while !rest.is_empty() {
        let letter = rest.as_bytes()[0] as char;
        let tail = rest[1..].trim_start();
        let end = tail
            .find(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == '+'))
            .unwrap_or(tail.len());
        let num: f64 = tail[..end]
            .parse()
            .map_err(|_| (2, format!("bad number after {letter}")))?;
        rest = tail[end..].trim_start();
        match letter {
            'G' => match (num * 10.0).round() as i64 {
                200 => inch = true,
                210 => inch = false,
                900 => absolute = true,
                910 => absolute = false,
                530 => machine_frame = true,
                _ => return Err((16, format!("G{num} is not allowed in a jog"))),
            },
            'F' => feed = Some(num),
            _ => match AXIS_NAMES.iter().position(|a| *a == letter) {
                Some(i) if b.machine.axes[i].max_velocity > 0 => axes[i] = Some(num),
                Some(_) => return Err((20, format!("the machine has no {letter} axis"))),
                None => return Err((16, format!("{letter} is not allowed in a jog"))),
            },
        }
    }
    let Some(f) = feed.filter(|f| *f > 0.0) else {
        return Err((22, "a jog needs a feed rate F".into()));
    };
    if axes.iter().all(Option::is_none) {
        return Err((26, "a jog needs an axis word".into()));
    }
    let unit = |i: usize| -> f64 {
        if i >= 3 {
            pkmc::units::NDEG_PER_DEG as f64
        } else if inch {
            25_400_000.0
        } else {
            pkmc::units::NM_PER_MM as f64
        }
    };
    let wco = interp.work_offset();
    let target: [i64; AXES] = std::array::from_fn(|i| match axes[i] {
        None => pose[i],
        Some(v) => {
            let v = (v * unit(i)).round() as i64;
            if !absolute {
                pose[i] + v
            } else if machine_frame {
                v
            } else {
                v + wco[i]
            }
        }
    });
    // F in units per minute along the XYZ path; degrees per minute (to µ°/s) when
    // only rotary axes move, as the front end reads it.
    let linear = (0..3).any(|i| target[i] != pose[i]);
    let feed = if linear {
        (f * unit(0) / 60.0).round() as i64
    } else {
        (f * 1e6 / 60.0).round() as i64
    };
    Ok((target, feed))
}

#[cfg(test)]
mod tests {
    use super::{refused_in, Phase};

    /// The table of Grbl 1.1's `system_execute_line`, state by state.
    #[test]
    fn dollar_lines_are_refused_where_grbl_refuses_them() {
        use Phase::*;
        let all = [Idle, Alarm, Check, Jog, Cycle];
        let allowed = |line: &str| -> Vec<Phase> {
            all.into_iter()
                .filter(|&p| refused_in(line, p).is_none())
                .collect()
        };
        for line in ["$", "$G", "$X"] {
            assert_eq!(allowed(line), all, "{line}");
        }
        assert_eq!(allowed("$$"), [Idle, Alarm, Check, Jog]);
        for line in ["$#", "$I", "$N", "$H", "$130", "$100=5", "$SLP"] {
            assert_eq!(allowed(line), [Idle, Alarm], "{line}");
        }
        assert_eq!(allowed("$N0=G54"), [Idle]);
    }
}
