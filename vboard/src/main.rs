//! `pkmc-vboard`: the firmware's release ELF on a virtual NUCLEO-G474RE, its USB link
//! on a pseudo-terminal for `nc-send --port`, its machine the simulator's drives and
//! plants (docs/vboard.md).

mod board;
mod control;
mod cpu;
mod elf;
mod nvic;
mod periph;
mod replay;
mod rtt;
mod time;
mod unwind;
mod usbhost;
mod wiring;

use anyhow::{bail, Context, Result};
use board::{Board, MachineSide};
use cpu::{Core, Exit};
use std::io::{Read, Write};
use std::path::PathBuf;
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How often the USB host is serviced, virtual µs.
const SERVICE_US: u64 = 50;

struct Args {
    elf: Option<PathBuf>,
    machine: Option<PathBuf>,
    seconds: Option<f64>,
    link: Option<PathBuf>,
    by_id: Option<PathBuf>,
    flash: Option<PathBuf>,
    free_run: bool,
    quiet_log: bool,
    trace: Option<PathBuf>,
    servo8: bool,
    inject: Vec<pkmc_host::sim::Injection>,
    record: Option<PathBuf>,
    replay: Option<PathBuf>,
}

fn usage() -> ! {
    eprintln!(
        "usage: pkmc-vboard [--elf FIRMWARE.elf] [--machine FILE.toml] [--link PATH]\n\
         \x20                  [--by-id DIR] [--flash FILE] [--seconds S] [--free-run] [--quiet-log]\n\
         \x20                  [--trace FILE.csv] [--wiring default|servo8]\n\
         \x20                  [--inject KIND[:JOINT]@SECONDS]...\n\
         \x20                  [--record FILE | --replay FILE]\n\
         Runs the firmware ELF on a virtual STM32G474RE board and prints the\n\
         pseudo-terminal of its USB link (docs/vboard.md). Without --elf it builds\n\
         the release firmware for the wiring first (as cargo fw-build does)."
    );
    std::process::exit(2)
}

fn parse_args() -> Args {
    let mut a = Args {
        elf: None,
        machine: None,
        seconds: None,
        link: None,
        by_id: None,
        flash: None,
        free_run: false,
        quiet_log: false,
        trace: None,
        servo8: false,
        inject: Vec::new(),
        record: None,
        replay: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = || it.next().unwrap_or_else(|| usage());
        match arg.as_str() {
            "--elf" => a.elf = Some(value().into()),
            "--machine" => a.machine = Some(value().into()),
            "--seconds" => {
                a.seconds = Some(value().parse().unwrap_or_else(|_| usage()));
            }
            "--link" => a.link = Some(value().into()),
            "--by-id" => a.by_id = Some(value().into()),
            "--flash" => a.flash = Some(value().into()),
            "--free-run" => a.free_run = true,
            "--quiet-log" => a.quiet_log = true,
            "--trace" => a.trace = Some(value().into()),
            "--record" => a.record = Some(value().into()),
            "--replay" => a.replay = Some(value().into()),
            "--inject" => match value().parse() {
                Ok(i) => a.inject.push(i),
                Err(e) => {
                    eprintln!("pkmc-vboard: {e}");
                    std::process::exit(2);
                }
            },
            "--wiring" => match value().as_str() {
                "default" => a.servo8 = false,
                "servo8" => a.servo8 = true,
                _ => usage(),
            },
            _ => usage(),
        }
    }
    a
}

fn main() {
    if let Err(e) = run(parse_args()) {
        eprintln!("pkmc-vboard: {e:#}");
        std::process::exit(1);
    }
}

/// Builds the release firmware for the wiring, as `cargo fw-build` does (with
/// `--features board-servo8` for the eight-servo wiring), and returns its ELF.
fn build_firmware(servo8: bool) -> Result<PathBuf> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut cmd = std::process::Command::new("cargo");
    cmd.current_dir(&root)
        .args(["build", "-p", "pkmc", "--release", "--bin", "firmware"])
        .args(["--target", "thumbv7em-none-eabihf"]);
    if servo8 {
        cmd.args(["--features", "board-servo8"]);
    }
    // The firmware's own target directory and flags, not this program's.
    for var in [
        "CARGO_TARGET_DIR",
        "RUSTFLAGS",
        "CARGO_BUILD_TARGET",
        "CARGO_MANIFEST_DIR",
    ] {
        cmd.env_remove(var);
    }
    let status = cmd
        .status()
        .context("running cargo to build the firmware")?;
    if !status.success() {
        bail!("building the firmware failed ({status})");
    }
    Ok(root.join("target/thumbv7em-none-eabihf/release/firmware"))
}

fn run(args: Args) -> Result<()> {
    let elf = match &args.elf {
        Some(p) => p.clone(),
        None => build_firmware(args.servo8)?,
    };
    let raw =
        std::fs::read(&elf).with_context(|| format!("reading the firmware {}", elf.display()))?;
    let image = Rc::new(elf::Image::parse(raw.clone()).context("the firmware ELF")?);
    let mut machine_text = String::from("built-in cartesian-xyz");
    let (machine, plants) = match &args.machine {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            machine_text = text.clone();
            let file = pkmc_host::machine_file::read_file(&text, &p.display().to_string())
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            let m = file
                .to_config()
                .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
            let plants: Vec<_> = file.joints.iter().map(|j| j.plant.clone()).collect();
            (m, plants)
        }
        None => (pkmc::config::MachineConfig::cartesian_xyz(), Vec::new()),
    };
    // The drives stand where a fresh controller believes its joints are.
    let start = pkmc::controller::Controller::new(machine.clone())
        .map_err(|e| anyhow::anyhow!("the machine: {e:?}"))?
        .joints()
        .to_vec();
    // The firmware's wiring (its `board-servo8` feature) is the board's build: the
    // ELF does not say which it is, the board is told.
    let wiring = if args.servo8 {
        wiring::servo8()
    } else {
        wiring::mixed()
    };
    let groups = wiring.amp_lines.len();
    let side = MachineSide::new(machine, &start, &plants, groups)?;
    // A recording of this run's outside world, or one to replay instead of it.
    let setup = format!(
        "elf={:016x} machine={:016x} wiring={}",
        replay::fnv(&raw),
        replay::fnv(machine_text.as_bytes()),
        wiring.name
    );
    let mut replaying = match &args.replay {
        Some(p) => {
            if !args.inject.is_empty() || args.record.is_some() || args.flash.is_some() {
                bail!("--replay takes the recording's flash, injections and commands: no --flash, --inject or --record with it");
            }
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            let r = replay::Replay::new(replay::parse(&text, &p.display().to_string())?);
            if r.setup.as_deref() != Some(setup.as_str()) {
                bail!(
                    "{} was recorded with {}, this run is {setup}: the same ELF, machine file and wiring are needed",
                    p.display(),
                    r.setup.as_deref().unwrap_or("nothing named")
                );
            }
            Some(r)
        }
        None => None,
    };
    let config = match (&args.flash, replaying.as_mut().and_then(|r| r.flash.take())) {
        (_, Some(recorded)) => recorded,
        (Some(f), None) if f.exists() => std::fs::read(f)?,
        _ => vec![0xFF; periph::flash::CONFIG_SIZE as usize],
    };
    let mut recorder = match &args.record {
        Some(p) => {
            let mut r = replay::Recorder::create(p)?;
            r.event(0, &replay::Kind::Setup(setup.clone()))?;
            r.event(0, &replay::Kind::Flash(config.clone()))?;
            Some(r)
        }
        None => None,
    };
    if config.len() != periph::flash::CONFIG_SIZE as usize {
        bail!(
            "the flash file must hold {} bytes",
            periph::flash::CONFIG_SIZE
        );
    }
    eprintln!("vboard: wiring {}, firmware {}", wiring.name, elf.display());
    let board = Board::new(wiring, side, config);
    let mut core = Core::new(image.clone(), board)?;
    let mut log = rtt::Log::new(&image, &raw)?;
    let mut host = usbhost::Host::default();

    let mut node = Some(DeviceNode::open(args.link.as_deref())?);
    // The device's name in --by-id's directory, while it is enumerated (named at the
    // first enumeration, below).
    let mut by_id_name: Option<PathBuf> = None;
    let mut named = args.by_id.is_none();
    let mut old_port: Option<String> = None;
    println!(
        "{}",
        args.link.as_ref().map_or(
            node.as_ref().map(|n| n.port.clone()).unwrap_or_default(),
            |l| { l.display().to_string() }
        )
    );
    std::io::stdout().flush()?;

    let stop = Arc::new(AtomicBool::new(false));
    let s = stop.clone();
    ctrlc::set_handler(move || s.store(true, Ordering::SeqCst)).context("signal handler")?;

    // Commands on standard input, one per line, optionally "at SECONDS COMMAND"
    // (virtual time): see `control::apply`.
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    std::thread::spawn(move || {
        for line in std::io::stdin().lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let mut scheduled: Vec<(u64, String)> = Vec::new();
    // The device's bytes since the last look (recorded, or checked in a replay).
    let mut new_out: Vec<u8> = Vec::new();
    for i in &args.inject {
        for (at, cmd) in control::injection(i, &core)? {
            scheduled.push((at, cmd));
        }
    }

    let started = Instant::now();
    let service = time::from_us(SERVICE_US);
    let limit = args.seconds.map(|s| (s * time::UNITS_PER_S as f64) as u64);
    let mut next_ms = 0u64;
    let mut last_out: Option<u64> = None;
    // Frames the device accepted in each millisecond (for the link's rate).
    let mut frames_per_ms: Vec<u32> = Vec::new();
    let mut frames_seen = 0u64;
    let mut buf = [0u8; 4096];
    // One row per ten servo periods (a millisecond; the rows are the plants' steps at
    // the servo timer's update events): virtual time and each joint's drive position
    // (steps or encoder counts, from the joint's zero), as the machine's drives
    // report them.
    let mut trace = match &args.trace {
        Some(p) => {
            let mut f = std::io::BufWriter::new(
                std::fs::File::create(p).with_context(|| format!("creating {}", p.display()))?,
            );
            let n = core.uc.get_data().machine.machine.joints.len();
            let cols: Vec<String> = (1..=n).map(|j| format!("d{j}")).collect();
            writeln!(f, "t_s,{}", cols.join(","))?;
            core.uc.get_data_mut().trace_rows = Some(Vec::new());
            Some(f)
        }
        None => None,
    };
    let outcome = loop {
        let now = core.uc.get_data().now;
        let ended = replaying.as_ref().is_some_and(|r| now >= r.end);
        if stop.load(Ordering::SeqCst) || limit.is_some_and(|l| now >= l) || ended {
            if let Some(r) = recorder.as_mut() {
                r.event(now, &replay::Kind::End)?;
            }
            break Ok(());
        }
        match core.run(now + service)? {
            Exit::Time => {}
            Exit::Fault(f) => {
                let pc = f.pc.unwrap_or(0);
                break Err(anyhow::anyhow!(
                    "{} (pc {pc:#010x}, in {}) at {:.6} s",
                    f.what,
                    core.function_at(pc),
                    time::to_s(now)
                ));
            }
        }
        let now = core.uc.get_data().now;
        let sent = host.packets.1;
        let before = host.from_device.len();
        host.service(&mut core.uc.get_data_mut().usb, now);
        new_out.extend(host.from_device.range(before..));
        if host.packets.1 != sent {
            last_out = Some(now);
        }
        core.uc.get_data_mut().streaming = last_out.is_some_and(|t| now < t + time::from_ms(100));
        for line in host.log.drain(..) {
            eprintln!("vboard: usb: {line}");
        }
        // With --link or --by-id, the port is there only while the device is
        // enumerated, as a CDC-ACM device's /dev/ttyACM node is: a pulled cable removes
        // it (the host holding it open reads an error), enumeration after a replug makes
        // a new one (a new pseudo-terminal: without --link its name changes, as a
        // ttyACM number may). With --by-id, DIR names it by its USB identity as udev's
        // /dev/serial/by-id does.
        if let (false, Some(dir), Some(n)) = (named, args.by_id.as_deref(), node.as_ref()) {
            if host.phase == usbhost::Phase::Configured {
                by_id_name = Some(by_id(dir, &host, &n.port)?);
                named = true;
            }
        }
        if args.link.is_some() || args.by_id.is_some() {
            let link = args.link.as_deref();
            if node.is_some() && !host.plugged && host.phase == usbhost::Phase::Detached {
                let gone = node.take().map(|n| n.port).unwrap_or_default();
                old_port = Some(gone.clone());
                if let Some(link) = link {
                    let _ = std::fs::remove_file(link);
                }
                if let Some(name) = by_id_name.take() {
                    let _ = std::fs::remove_file(&name);
                }
                eprintln!(
                    "vboard: {} removed (device detached)",
                    link.map_or(gone, |l| l.display().to_string())
                );
            } else if node.is_none() && host.phase == usbhost::Phase::Configured {
                // Without --link the device comes back under a new name, as a program
                // that still holds /dev/ttyACM0 open makes the kernel name the returning
                // device /dev/ttyACM1 (pseudo-terminals whose name is the old one are
                // passed over).
                let mut passed = Vec::new();
                let n = loop {
                    let n = DeviceNode::open(link)?;
                    if link.is_some()
                        || old_port.as_deref() != Some(n.port.as_str())
                        || passed.len() > 8
                    {
                        break n;
                    }
                    passed.push(n);
                };
                drop(passed);
                if let Some(dir) = args.by_id.as_deref() {
                    by_id_name = Some(by_id(dir, &host, &n.port)?);
                }
                eprintln!(
                    "vboard: {} back (device enumerated)",
                    link.map_or(n.port.clone(), |l| l.display().to_string())
                );
                node = Some(n);
            }
        }
        if now >= next_ms {
            next_ms = now + time::from_ms(1);
            frames_per_ms.push((host.frames_out - frames_seen) as u32);
            frames_seen = host.frames_out;
            if let Some(f) = trace.as_mut() {
                let rows = core.uc.get_data_mut().trace_rows.replace(Vec::new());
                for (t, d) in rows.unwrap_or_default() {
                    let d: Vec<String> = d.iter().map(i64::to_string).collect();
                    writeln!(f, "{:.6},{}", time::to_s(t), d.join(","))?;
                }
            }
            while let Ok(line) = rx.try_recv() {
                if replaying.is_some() {
                    continue; // the recording's commands only
                }
                match control::parse(&line) {
                    Ok(Some((at, cmd))) => scheduled.push((at.unwrap_or(now), cmd)),
                    Ok(None) => {}
                    Err(e) => eprintln!("vboard: {e}"),
                }
            }
            let mut due: Vec<String> = {
                let (due, later): (Vec<_>, Vec<_>) =
                    scheduled.drain(..).partition(|(t, _)| *t <= now);
                scheduled = later;
                due.into_iter().map(|(_, c)| c).collect()
            };
            let mut replayed_in: Vec<u8> = Vec::new();
            if let Some(r) = replaying.as_mut() {
                for k in r.due(now)? {
                    match k {
                        replay::Kind::Cmd(c) => due.push(c),
                        replay::Kind::In(b) => replayed_in.extend(b),
                        _ => {}
                    }
                }
            }
            for cmd in due {
                if let Some(r) = recorder.as_mut() {
                    r.event(now, &replay::Kind::Cmd(cmd.clone()))?;
                }
                eprintln!("vboard: {cmd} at {:.4} s", time::to_s(now));
                match control::apply(&cmd, &mut core, &mut host) {
                    Ok(control::Outcome::Report) => report(
                        &core,
                        started.elapsed(),
                        (host.packets, host.bytes),
                        &frames_per_ms,
                    ),
                    Ok(control::Outcome::Quit) => stop.store(true, Ordering::SeqCst),
                    Ok(control::Outcome::Done) => {}
                    Ok(control::Outcome::Mark) => frames_per_ms.clear(),
                    Err(e) => eprintln!("vboard: {cmd}: {e}"),
                }
            }
            for line in log.poll(&mut core.uc)? {
                if !args.quiet_log {
                    eprintln!("{line}");
                }
            }
            // The pseudo-terminal, both ways (a replay's host bytes instead).
            if replaying.is_some() {
                host.to_device.extend(&replayed_in);
            } else if let Some(Ok(n)) = node.as_mut().map(|n| n.master.read(&mut buf)) {
                if n > 0 {
                    if let Some(r) = recorder.as_mut() {
                        r.event(now, &replay::Kind::In(buf[..n].to_vec()))?;
                    }
                }
                host.to_device.extend(&buf[..n]);
            }
            if let Some(r) = replaying.as_mut() {
                r.check_out(now, &new_out)?;
            } else if let Some(r) = recorder.as_mut() {
                if !new_out.is_empty() {
                    r.event(now, &replay::Kind::Out(new_out.clone()))?;
                }
            }
            new_out.clear();
            if !host.from_device.is_empty() {
                let out: Vec<u8> = host.from_device.iter().copied().collect();
                match node.as_mut().map(|n| n.master.write(&out)) {
                    Some(Ok(n)) => {
                        host.from_device.drain(..n);
                    }
                    // No port: what the device sends is lost, as it is when no
                    // program holds a real port open.
                    None => host.from_device.clear(),
                    Some(Err(_)) => {}
                }
            }
            // Never ahead of the wall clock (a replay has no host to wait for).
            if !args.free_run && replaying.is_none() {
                let ahead =
                    Duration::from_secs_f64(time::to_s(now)).saturating_sub(started.elapsed());
                if ahead > Duration::from_millis(2) {
                    std::thread::sleep(ahead);
                }
            }
        }
    };
    for line in log.poll(&mut core.uc).unwrap_or_default() {
        eprintln!("{line}");
    }
    report(
        &core,
        started.elapsed(),
        (host.packets, host.bytes),
        &frames_per_ms,
    );
    if let (Some(r), Ok(())) = (&replaying, &outcome) {
        if r.unseen() > 0 {
            bail!(
                "the replay diverged: {} bytes the device wrote in the recording were never written",
                r.unseen()
            );
        }
        eprintln!(
            "vboard: replay: {} host events given, {} device bytes as recorded",
            r.given, r.checked
        );
    }
    if let Some((busy, k, hist)) = &core.uc.get_data().worst_profile {
        eprintln!(
            "profile: the busiest period while streaming, {k} ms: {:.1} %",
            f64::from(*busy) / 10.0
        );
        let mut by_fn: std::collections::HashMap<String, u64> = Default::default();
        for (pc, n) in hist {
            let f = core.function_at(*pc);
            let f = f.rsplit_once('+').map_or(f.clone(), |(a, _)| a.to_string());
            *by_fn.entry(f).or_default() += n;
        }
        let mut v: Vec<_> = by_fn.into_iter().collect();
        v.sort_by(|a, b| b.1.cmp(&a.1));
        for (f, n) in v.iter().take(25) {
            eprintln!("profile: {n:>8} {f}");
        }
    }
    if let Some(f) = &args.flash {
        std::fs::write(f, &core.uc.get_data().flash.config)?;
    }
    drop(node);
    outcome
}

/// Names the device node `port` in `dir` by the USB identity the host read from the
/// firmware's string descriptors, as udev's `/dev/serial/by-id` does
/// (`usb-<manufacturer>_<product>_<serial>-if<interface>`, blanks made `_`).
fn by_id(dir: &std::path::Path, host: &usbhost::Host, port: &str) -> anyhow::Result<PathBuf> {
    let name = dir.join(host.by_id_name().context("the device's USB strings")?);
    let _ = std::fs::remove_file(&name);
    std::os::unix::fs::symlink(port, &name)
        .with_context(|| format!("linking {}", name.display()))?;
    Ok(name)
}

/// The host side of the USB link: a pseudo-terminal pair (its slave is the port a
/// host program opens) and, with `--link`, the symbolic link that names it.
struct DeviceNode {
    master: serialport::TTYPort,
    _slave: serialport::TTYPort,
    port: String,
}

impl DeviceNode {
    fn open(link: Option<&std::path::Path>) -> anyhow::Result<Self> {
        use serialport::SerialPort;
        let (mut master, slave) = serialport::TTYPort::pair().context("a pseudo-terminal")?;
        let port = slave.name().context("the pseudo-terminal's name")?;
        if let Some(link) = link {
            let _ = std::fs::remove_file(link);
            std::os::unix::fs::symlink(&port, link)
                .with_context(|| format!("linking {}", link.display()))?;
        }
        master.set_timeout(Duration::from_millis(0))?;
        Ok(Self {
            master,
            _slave: slave,
            port,
        })
    }
}

/// min / median / p99 / max of `v` (sorted here).
fn quartiles(v: &mut [u64]) -> [u64; 4] {
    v.sort_unstable();
    if v.is_empty() {
        return [0; 4];
    }
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    [at(0.0), at(0.5), at(0.99), at(1.0)]
}

/// Prints the run's figures as one JSON object on stdout.
fn report(
    core: &Core,
    wall: Duration,
    (packets, bytes): ((u64, u64), (u64, u64)),
    frames_per_ms: &[u32],
) {
    // The link's accepted frames a second: the most in any 100 ms.
    let window = 100.min(frames_per_ms.len().max(1));
    let peak = frames_per_ms
        .windows(window)
        .map(|w| w.iter().map(|&n| u64::from(n)).sum::<u64>())
        .max()
        .unwrap_or(0)
        * 1000
        / window as u64;
    let b = core.uc.get_data();
    let virt = time::to_s(b.now);
    let us = |u: u64| time::to_ns(u) as f64 / 1000.0;
    let lat = quartiles(&mut b.stats.servo_latency.clone()).map(us);
    let mut busy_all: Vec<u64> = b.stats.busy.iter().map(|p| u64::from(p.0)).collect();
    let mut busy_streaming: Vec<u64> = b
        .stats
        .busy
        .iter()
        .filter(|p| p.1)
        .map(|p| u64::from(p.0))
        .collect();
    let busy = |v: &mut Vec<u64>| {
        let n = v.len();
        let q = quartiles(v).map(|m| m as f64 / 10.0);
        format!(
            "{{\"periods\": {n}, \"min\": {:.1}, \"median\": {:.1}, \"p99\": {:.1}, \"max\": {:.1}}}",
            q[0], q[1], q[2], q[3]
        )
    };
    let taken: Vec<String> = b
        .stats
        .taken
        .iter()
        .map(|(e, n)| format!("\"{e}\": {n}"))
        .collect();
    let worst: Vec<String> = b
        .stats
        .worst_servo
        .iter()
        .map(|(l, pc)| format!("[{:.3}, {:?}]", us(*l), core.function_at(*pc)))
        .collect();
    let worst_busy: Vec<String> = b
        .stats
        .worst_busy
        .iter()
        .map(|(m, k, pc)| {
            format!(
                "[{:.1}, {k}, {:?}]",
                f64::from(*m) / 10.0,
                core.function_at(*pc)
            )
        })
        .collect();
    let (depth, untouched) = core.stack_depth();
    // What the configuration pages hold, decoded by the core's own record reader.
    let flash_machine = pkmc::wire::store::read_record(&b.flash.config)
        .map(|m| format!("{:?}", m.name.as_str()))
        .unwrap_or_else(|_| "null".into());
    let chain: Vec<String> = b
        .stats
        .min_sp
        .as_ref()
        .map(|(_, c)| {
            c.iter()
                .map(|f| {
                    let name = core.function_at(f.pc);
                    if f.interrupted {
                        format!("{:?}", format!("{name} (interrupted)"))
                    } else {
                        format!("{name:?}")
                    }
                })
                .collect()
        })
        .unwrap_or_default();
    let probe_edges: Vec<String> = b
        .machine
        .probe_edges
        .iter()
        .map(|e| {
            format!(
                "{{\"t_s\": {:.9}, \"touching\": {}, \"in_tick_us\": {:.3}, \"joint_steps\": {:?}}}",
                time::to_s(e.at),
                e.touching,
                time::to_s(e.in_tick) * 1e6,
                e.steps
            )
        })
        .collect();
    println!(
        "{{\"virtual_s\": {virt:.6}, \"wall_s\": {:.3}, \"speed\": {:.3}, \"instructions\": {}, \
         \"probe_edges\": [{}], \
         \"final_joint_steps\": {:?}, \"drive_violations\": {}, \"steps_while_disabled\": {}, \
         \"pulses_not_routed\": {}, \"exceptions\": {{{}}}, \
         \"busy_percent\": {}, \"busy_percent_streaming\": {}, \"busiest_periods_ms\": [{}], \
         \"servo_latency_us\": {{\"min\": {:.3}, \"median\": {:.3}, \"p99\": {:.3}, \"max\": {:.3}, \"jitter\": {:.3}}}, \
         \"worst_servo_latency_us\": [{}], \
         \"stack\": {{\"top\": {}, \"deepest\": {depth}, \"untouched\": {untouched}, \"lowest_sp_chain\": [{}]}}, \
         \"watchdog_resets\": {}, \"software_resets\": {}, \"pin_resets\": {}, \"flash_erases\": {}, \"flash_programs\": {}, \"flash_machine\": {flash_machine}, \"usb_packets_in_out\": [{}, {}], \"usb_bytes_in_out\": [{}, {}], \"pwm_code_range\": [{}, {}], \"led_toggles\": {}, \"fp_lazy_saves\": {}, \"fp_lazy_skipped\": {}, \"frames_per_s_peak_100ms\": {peak}}}",
        wall.as_secs_f64(),
        virt / wall.as_secs_f64().max(1e-9),
        b.instructions,
        probe_edges.join(", "),
        b.machine.joint_steps(),
        b.machine.violations(),
        b.machine.steps_disabled,
        b.machine.pulses_lost,
        taken.join(", "),
        busy(&mut busy_all),
        busy(&mut busy_streaming),
        worst_busy.join(", "),
        lat[0],
        lat[1],
        lat[2],
        lat[3],
        lat[3] - lat[0],
        worst.join(", "),
        core.stack_top - cpu::RAM,
        chain.join(", "),
        b.stats.watchdog_resets,
        b.stats.software_resets,
        b.stats.pin_resets,
        b.flash.erases,
        b.flash.programs,
        packets.0,
        packets.1,
        bytes.0,
        bytes.1,
        b.stats.pwm_range.0,
        b.stats.pwm_range.1,
        b.stats.led_toggles,
        b.stats.lazy_saves,
        b.stats.lazy_skipped,
    );
}
