//! `nc-send tune JOINT`: tunes a servo joint on recorded data (issue 35,
//! docs/tuning.md). The controller adds a PRBS test signal of small amplitude to the
//! joint's position command (`pkmc::drive::excite`, its own safety checks) while the
//! recorder streams the joint's DAC output and encoder every servo period; the host
//! identifies the plant from them ([`crate::control::ident`]), designs PID and
//! feed-forward gains for a stated crossover and phase margin
//! ([`crate::control::tune`]) and, for a joint that runs LQG, the LQG gains of the
//! file's weights on the model. A second test signal, a step, is recorded under the
//! present gains and compared with what the model predicts under them, so that the
//! user sees the model is right. The gains are written into the machine file only
//! with `--write` ([`super::tune_write`]).

pub use super::tuned::{write, Tuned};
use super::{tune_write, Table};
use crate::control::ident::{self, IdentOptions, Identified, Record};
use crate::control::lqg;
use crate::control::plant::TransferFunction;
pub use crate::control::tune::Margins;
use crate::control::tune::{self, PidSpec, PidTuning};
use crate::job::{exit, Failure, RunOptions, Target};
use crate::link::{JobEnd, JobHooks, Link, LinkView, Transport};
use crate::machine_file::lqg::{LawKind, LqgModel};
use crate::machine_file::{read_file, DriveKind, JointFile, MachineFile};
use pkmc::config::{LqgGains, ServoGains};
use pkmc::drive::excite::Excite;
use pkmc::drive::servo::{
    AmpIo, Coupling, ServoAxis, SetpointInterpolator, DAC_MID, SERVO_HZ, SERVO_PER_TICK,
};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The servo period, s.
const H: f64 = 1.0 / SERVO_HZ as f64;

/// `nc-send tune`'s arguments.
#[derive(Clone, Debug, clap::Args)]
pub struct TuneArgs {
    /// The servo joint: its name in the machine file, or its number from 0.
    pub joint: String,
    /// The test signal's amplitude, mm or degrees (default: 40 % of the joint's
    /// standstill following-error limit `min_ferror`; the controller refuses one at or
    /// above it).
    #[arg(long, value_name = "MM")]
    pub amplitude: Option<f64>,
    /// How long the PRBS test signal lasts, s.
    #[arg(long, default_value_t = 2.0)]
    pub seconds: f64,
    /// How long the PRBS holds each value, ms.
    #[arg(long, default_value_t = 10)]
    pub hold_ms: u16,
    /// The PRBS's seed.
    #[arg(long, default_value_t = 1)]
    pub prbs_seed: u16,
    /// How long the measured step stays up (and then down), s.
    #[arg(long, default_value_t = 0.3)]
    pub step_seconds: f64,
    /// The designed loop's crossover, Hz (default: the present gains' crossover on the
    /// identified model).
    #[arg(long, value_name = "HZ")]
    pub bandwidth: Option<f64>,
    /// The phase margin the design aims at on the model, degrees (45 to 89).
    #[arg(long, default_value_t = 60.0, value_name = "DEG")]
    pub phase_margin: f64,
    /// Draw the predicted and measured steps and the Bode diagram (.svg or .png).
    #[arg(long, value_name = "FILE")]
    pub plot: Option<PathBuf>,
    /// Write the recorded excitation as CSV.
    #[arg(long, value_name = "FILE")]
    pub csv: Option<PathBuf>,
    /// Write the designed PID and feed-forward gains into the machine file (without
    /// it, print what would change).
    #[arg(long)]
    pub write: bool,
}

impl TuneArgs {
    /// `nc-send tune JOINT` with every option at its default (the command line's
    /// own, parsed).
    pub fn new(joint: &str) -> Self {
        #[derive(clap::Parser)]
        struct Line {
            #[command(flatten)]
            args: TuneArgs,
        }
        <Line as clap::Parser>::try_parse_from(["tune", "--", joint])
            .expect("a joint alone is a whole command line")
            .args
    }
}

fn bad(message: impl Into<String>) -> Failure {
    Failure::new(exit::BAD_INPUT, message)
}

/// The joint being tuned, as the machine file gives it.
struct Joint<'a> {
    index: usize,
    file: &'a JointFile,
    /// Encoder counts per mm or degree.
    cpu: f64,
    gains: ServoGains,
    lqg: Option<LqgGains>,
}

/// Checks the arguments before anything is sent.
fn check(args: &TuneArgs) -> Result<(), Failure> {
    for (what, v, hi) in [
        ("--seconds", args.seconds, 60.0),
        ("--step-seconds", args.step_seconds, 10.0),
    ] {
        if !(v >= 0.05 && v <= hi) {
            return Err(bad(format!("{what} {v}: give 0.05 to {hi} seconds")));
        }
    }
    if args.hold_ms == 0 {
        return Err(bad("--hold-ms 0: hold each value at least 1 ms"));
    }
    if !(args.phase_margin >= 45.0 && args.phase_margin < 90.0) {
        return Err(bad(format!(
            "--phase-margin {}: give 45 to 89 degrees (never less than 45)",
            args.phase_margin
        )));
    }
    if let Some(b) = args.bandwidth {
        if !(b > 0.0 && b < SERVO_HZ as f64 / 4.0) {
            return Err(bad(format!(
                "--bandwidth {b}: give a crossover above 0 and below {} Hz",
                SERVO_HZ / 4
            )));
        }
    }
    if let Some(a) = args.amplitude {
        if !(a > 0.0 && a.is_finite()) {
            return Err(bad(format!("--amplitude {a}: give a positive distance")));
        }
    }
    if let Some(p) = &args.plot {
        crate::analysis::plot::format_of(p).map_err(bad)?;
    }
    Ok(())
}

/// The joint named `name` (or numbered) in `mf`, which must be a servo joint.
fn find_joint<'a>(mf: &'a MachineFile, name: &str, path: &Path) -> Result<Joint<'a>, Failure> {
    let index = mf
        .joints
        .iter()
        .position(|j| j.name == name)
        .or_else(|| name.parse::<usize>().ok().filter(|&i| i < mf.joints.len()));
    let Some(index) = index else {
        let names: Vec<&str> = mf.joints.iter().map(|j| j.name.as_str()).collect();
        return Err(bad(format!(
            "tune {name}: {} has no joint `{name}`; its joints are {} (or their numbers \
             from 0)",
            path.display(),
            names.join(", ")
        )));
    };
    let file = &mf.joints[index];
    let servo = file
        .servo
        .as_ref()
        .filter(|_| file.drive == DriveKind::Servo);
    let Some(servo) = servo else {
        return Err(bad(format!(
            "tune {name}: joint {index} ({}) of {} is a stepper joint; only a servo joint \
             (drive = \"servo\") can be tuned",
            file.name,
            path.display()
        )));
    };
    let config = mf.to_config().map_err(|e| bad(e.0))?;
    Ok(Joint {
        index,
        file,
        cpu: file.steps_per_unit,
        gains: config.servo.gains[file.channel as usize],
        lqg: (servo.law == LawKind::Lqg)
            .then_some(file.lqg_gains)
            .flatten(),
    })
}

/// The machine file read and the joint to tune found in it (a servo joint): what a
/// tune checks before it moves anything ([`load`]).
#[derive(Clone, Debug)]
pub struct Loaded {
    /// The machine file.
    pub path: PathBuf,
    text: String,
    mf: MachineFile,
    /// The joint's number from 0.
    pub index: usize,
}

/// Checks `args` and reads the machine file at `path`: refused (by name) without a
/// file, with an unknown joint or a stepper joint.
pub fn load(args: &TuneArgs, path: Option<&Path>) -> Result<Loaded, Failure> {
    check(args)?;
    let path = path.ok_or_else(|| bad("tune needs the machine file: --machine FILE"))?;
    let text = std::fs::read_to_string(path)
        .map_err(|e| bad(format!("{}: cannot read it: {e}", path.display())))?;
    let mf = read_file(&text, &path.display().to_string()).map_err(|e| bad(e.to_string()))?;
    let index = find_joint(&mf, &args.joint, path)?.index;
    Ok(Loaded {
        path: path.to_path_buf(),
        text,
        mf,
        index,
    })
}

/// Runs `nc-send tune` on `link` with the machine file at `path`; how it ended (and
/// no block count: it sends no program).
pub fn run<T: Transport>(
    link: &mut Link<T>,
    args: &TuneArgs,
    path: Option<&Path>,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<(JobEnd, Option<usize>), Failure> {
    let loaded = load(args, path)?;
    if matches!(opts.target, Target::Sim) {
        // A fresh simulator is locked: home it (a machine with switches) or unlock it.
        let switches = link.machine().joints.iter().any(|j| j.homing.enabled());
        if let Some(end) = crate::job::prepare(link, switches, true, hooks)? {
            return Ok((end, None));
        }
    } else {
        crate::job::prepare(link, false, false, hooks)?;
    }
    let t = tune(link, args, &loaded, hooks)?;
    for line in &t.lines {
        println!("{line}");
    }
    if let Some(p) = &args.plot {
        t.draw(p)?;
        println!("plot: {}", p.display());
    }
    if args.write {
        let line = write(&loaded.path, &t)?;
        println!("written to {}: {line}", loaded.path.display());
    } else {
        println!(
            "would write (with --write): {}",
            super::tuned::written(&t, &t.line)
        );
        for (key, value) in &t.lqg_lines {
            println!("  {key} = {value}");
        }
    }
    Ok((JobEnd::Done, None))
}

/// The tune itself, on a machine ready for the test signal (`nc-send tune` and the
/// station's Tune): the PRBS and the step recorded, the plant identified, the gains
/// designed, the report and the plot's curves made. Nothing is written but
/// `--csv`. A control that `hooks` asks for while a test signal runs (a stop, a
/// hold) stops the signal and ends the tune.
pub fn tune<T: Transport>(
    link: &mut Link<T>,
    args: &TuneArgs,
    loaded: &Loaded,
    hooks: &mut dyn JobHooks,
) -> Result<Tuned, Failure> {
    let j = find_joint(&loaded.mf, &args.joint, &loaded.path)?;
    let amplitude = match args.amplitude {
        Some(a) => (a * j.cpu).round().max(1.0) as u32,
        None => ((0.4 * j.gains.min_ferror as f64).floor() as u32).max(1),
    };
    let prbs = Excite {
        joint: j.index as u8,
        kind: 1,
        amplitude,
        hold: args.hold_ms,
        length: (args.seconds * 1000.0).round() as u32,
        seed: args.prbs_seed,
    };
    let table = excite(link, &prbs, hooks)?;
    if let Some(p) = &args.csv {
        std::fs::write(p, table.csv())
            .map_err(|e| bad(format!("{}: cannot write the CSV: {e}", p.display())))?;
    }
    let rec = record_of(&table, &j)?.0;
    let hold = (args.step_seconds * 1000.0).round() as u16;
    let step = Excite {
        kind: 0,
        hold,
        length: 2 * hold as u32,
        ..prbs
    };
    let step_table = excite(link, &step, hooks)?;
    let o = IdentOptions::default();
    let id = ident::identify(&rec, &o).map_err(|e| {
        Failure::new(
            exit::ALARM,
            format!("tune {}: no model of the plant: {e}", j.file.name),
        )
    })?;
    let outcome = design(&j, &id, args)?;
    let measured = measured_step(&step_table, &j, &id.plant, amplitude, hold)?;
    let lines = report(&j, &id, &outcome, &measured, (amplitude, rec.u.len()));
    let (steps, bode) = curves(&j, &rec, &o, &id, &outcome, &measured)?;
    let t = &outcome.tuned;
    let designed = [t.kp, t.ki, t.kd, t.kvff, t.kaff];
    let fields = [
        ("kp", t.kp),
        ("ki", t.ki),
        ("kd", t.kd),
        ("kvff", t.kvff),
        ("kaff", t.kaff),
    ];
    let new = tune_write::rewrite(&loaded.text, j.index, &fields).map_err(bad)?;
    let lqg_lines = outcome.lqg.as_ref().map_or(Vec::new(), |l| {
        vec![
            ("lqg", lqg::weights_toml(&l.raised.weights)),
            ("lqg_gains", lqg::gains_toml(&l.raised.design.gains)),
            ("lqg_model", LqgModel::toml(&id.plant)),
        ]
    });
    // The joints that share this joint's LQG design (a hexapod's legs) get the
    // same, so that they go on sharing one (the controller holds few).
    let alike = match (&outcome.lqg, &j.lqg) {
        (Some(_), Some(g)) => loaded
            .mf
            .joints
            .iter()
            .enumerate()
            .filter(|(i, f)| {
                *i != j.index
                    && f.lqg_gains.as_ref() == Some(g)
                    && f.servo.as_ref().is_some_and(|s| s.law == LawKind::Lqg)
            })
            .map(|(i, _)| i)
            .collect(),
        _ => Vec::new(),
    };
    let g = &j.gains;
    Ok(Tuned {
        joint: j.index,
        name: j.file.name.clone(),
        unit: if j.file.rotary { "°" } else { "mm" },
        amplitude: (amplitude, amplitude as f64 / j.cpu),
        lines,
        fit_percent: id.fit_percent,
        step_error: measured.error.ratio,
        present: [g.kp, g.ki, g.kd, g.kvff, g.kaff].map(|v| v as f64),
        designed,
        present_margins: outcome.present,
        designed_margins: t.margins,
        aimed: (outcome.spec.crossover_rad_s, outcome.spec.phase_margin_deg),
        lqg: outcome.lqg.as_ref().map(|l| {
            format!(
                "present |S|max {:.2}, crossover {:.1} rad/s; designed |S|max {:.2}, \
                 crossover {:.1} rad/s; lqg = {}",
                l.present.peak_sensitivity,
                l.present.crossover_rad_s,
                l.raised.figures.peak_sensitivity,
                l.raised.figures.crossover_rad_s,
                lqg::weights_toml(&l.raised.weights)
            )
        }),
        lqg_lines,
        alike,
        line: new.line.trim().to_string(),
        title: format!("tune {} ({})", j.index, j.file.name),
        steps,
        bode,
    })
}

/// Streams the joint's output, encoder and command every servo period while the
/// controller runs the test signal `e`; a table without gaps.
fn excite<T: Transport>(
    link: &mut Link<T>,
    e: &Excite,
    hooks: &mut dyn JobHooks,
) -> Result<Table, Failure> {
    let j = e.joint;
    let setup =
        super::setup(&format!("out:{j},meas:{j},cmd:{j}"), "stream", 0, 1, true).map_err(bad)?;
    link.record_take();
    link.record_arm(&setup)?;
    link.record_listen(Duration::from_millis(50))?;
    if let Err(err) = link.record_excite(e) {
        let _ = link.record_disarm();
        return Err(Failure::new(
            exit::ALARM,
            format!("the controller refused the test signal: {err}"),
        ));
    }
    // The signal's ticks, then time for the loop to settle.
    let until = Instant::now() + Duration::from_millis(e.length as u64 + 300);
    while Instant::now() < until {
        link.record_listen(Duration::from_millis(20))?;
        if let Some(c) = hooks.control(&LinkView::default()) {
            // The operator asks for something else: the signal stops first.
            link.record_disarm()?;
            link.control(c)?;
            return Err(Failure::new(
                exit::ALARM,
                format!("tune stopped: {c:?} asked while the test signal ran"),
            ));
        }
    }
    link.record_disarm()?;
    link.record_listen(Duration::from_millis(50))?;
    let table = Table::of_stream(&link.record_take())
        .ok_or_else(|| Failure::new(exit::LINK, "the recorder streamed no sample"))?;
    if table.missing() > 0 {
        return Err(Failure::new(
            exit::LINK,
            format!(
                "{} samples of {} were lost on the way (the link fell behind): the record \
                 cannot be used; try a shorter --seconds",
                table.missing(),
                table.missing() + table.rows.len() as i64
            ),
        ));
    }
    let s = link.request_status()?;
    if let Some(a) = s.alarm {
        return Err(Failure::new(
            exit::ALARM,
            format!("the test signal ended in an alarm: {a:?}"),
        ));
    }
    Ok(table)
}

/// The identification's record (u in c.u., y in mm or degrees) from the first change
/// of the command on, and the command in counts over the same samples.
fn record_of(table: &Table, j: &Joint) -> Result<(Record, Vec<i64>, usize), Failure> {
    let cmd0 = table.rows.first().map_or(0, |r| r.1[2]);
    let first = table
        .rows
        .iter()
        .position(|r| r.1[2] != cmd0)
        .ok_or_else(|| {
            Failure::new(
                exit::ALARM,
                "the test signal never moved the joint's command (did something else move?)",
            )
        })?;
    let from = first.saturating_sub(100);
    let g = &j.gains;
    let rows = &table.rows[from..];
    let rec = Record {
        h: H,
        u: rows
            .iter()
            .map(|r| (r.1[0] - DAC_MID - g.dac_offset as i32) as f64 / g.dac_per_unit as f64)
            .collect(),
        y: rows.iter().map(|r| r.1[1] as f64 / j.cpu).collect(),
    };
    let cmd = rows.iter().map(|r| r.1[2] as i64).collect();
    Ok((rec, cmd, first - from))
}

/// What the design found.
struct Outcome {
    spec: PidSpec,
    tuned: PidTuning,
    present: tune::Margins,
    lqg: Option<LqgOutcome>,
}

/// For a joint that runs LQG: the file's weights designed on the model, and the
/// raised weights' design ([`lqg::raise_weights`]).
struct LqgOutcome {
    present: lqg::LoopFigures,
    raised: lqg::RaisedWeights,
    /// The crossover the raise stopped under, rad/s.
    cap: f64,
}

fn present(g: &ServoGains) -> [f64; 3] {
    [g.kp as f64, g.ki as f64, g.kd as f64]
}

/// The PID (and LQG, for a joint that runs it) designed on the identified model.
fn design(j: &Joint, id: &Identified, args: &TuneArgs) -> Result<Outcome, Failure> {
    let fail = |e: String| Failure::new(exit::ALARM, format!("tune {}: {e}", j.file.name));
    let present =
        tune::margins(&id.plant, j.cpu, H, present(&j.gains)).map_err(|e| fail(e.to_string()))?;
    let spec = PidSpec {
        phase_margin_deg: args.phase_margin,
        ..PidSpec::new(present.crossover_rad_s)
    };
    // A third of the band the PRBS excites (about 0.44/hold Hz): the model is not
    // trusted beyond what the data held.
    let trusted = std::f64::consts::TAU * 0.44 / (args.hold_ms as f64 * 1e-3) / 3.0;
    let crossover = match args.bandwidth {
        Some(hz) => hz * std::f64::consts::TAU,
        None => {
            // The highest crossover the model allows with margins to spare, from the
            // present one up to the trusted band.
            let range = (present.crossover_rad_s, trusted);
            tune::highest_crossover(&id.plant, j.cpu, H, &spec, range, &Default::default())
                .unwrap_or(present.crossover_rad_s)
        }
    };
    let spec = PidSpec {
        crossover_rad_s: crossover,
        ..spec
    };
    let tuned = tune::design_pid(&id.plant, j.cpu, H, &spec)
        .map_err(|e| fail(format!("no PID for {crossover:.1} rad/s: {e}")))?;
    let lqg = match (&j.lqg, &j.file.lqg) {
        (Some(_), Some(w)) => {
            let no = |e: lqg::LqgError| fail(format!("no LQG design on the model: {e}"));
            let present = lqg::design(&id.plant, j.cpu, H, w)
                .and_then(|d| d.loop_figures(&id.plant, j.cpu))
                .map_err(no)?;
            // The LQG loop as fast as the PID may be: up to --bandwidth, or the
            // trusted band.
            let cap = args
                .bandwidth
                .map_or(trusted, |hz| hz * std::f64::consts::TAU);
            let raised = lqg::raise_weights(&id.plant, j.cpu, H, w, cap).map_err(no)?;
            Some(LqgOutcome {
                present,
                raised,
                cap,
            })
        }
        _ => None,
    };
    Ok(Outcome {
        spec,
        tuned,
        present,
        lqg,
    })
}

/// The measured step and the model's prediction of it under the present gains, both
/// as fractions of the step (0 before, 1 at the target), from the step's first servo
/// period for as long as it stays up.
struct Measured {
    measured: Vec<f64>,
    predicted: Vec<f64>,
    error: tune::StepError,
}

fn measured_step(
    table: &Table,
    j: &Joint,
    model: &TransferFunction,
    amplitude: u32,
    hold: u16,
) -> Result<Measured, Failure> {
    let (_, cmd, first) = record_of(table, j)?;
    let rows: Vec<f64> = table.rows.iter().map(|r| r.1[1] as f64).collect();
    let offset = rows.len() - cmd.len();
    let meas = &rows[offset..];
    let base: f64 = meas[..first].iter().sum::<f64>() / first.max(1) as f64;
    let len = (hold as usize * SERVO_PER_TICK).min(meas.len() - first);
    let a = amplitude as f64;
    let measured: Vec<f64> = meas[first..first + len]
        .iter()
        .map(|m| (m - base) / a)
        .collect();
    let predicted = predict(model, j, &cmd, first)[first..first + len]
        .iter()
        .map(|y| y / a)
        .collect::<Vec<_>>();
    let error = tune::step_error(&measured, &predicted, H);
    Ok(Measured {
        measured,
        predicted,
        error,
    })
}

/// The joint's position (counts from its start) each servo period, predicted by
/// `model` under the core's own loop (`ServoAxis`, the present gains and law, its
/// feed-forwards, clamps and DAC) following the recorded command `cmd`, whose ticks
/// start at sample `first` (the test signal changes only at tick edges).
fn predict(model: &TransferFunction, j: &Joint, cmd: &[i64], first: usize) -> Vec<f64> {
    let mut plant = model.discretize(H);
    let max_v = (j.file.max_velocity * j.cpu) as f32;
    let mut axis = ServoAxis::new(&j.gains, max_v);
    let mut interp = SetpointInterpolator::new(0);
    let on = AmpIo {
        enable: true,
        fault: false,
    };
    let g = &j.gains;
    let mut out = Vec::with_capacity(cmd.len());
    let phase = first % SERVO_PER_TICK;
    let mut k = 0;
    while k < cmd.len() {
        if k % SERVO_PER_TICK == phase {
            let end = (k + SERVO_PER_TICK - 1).min(cmd.len() - 1);
            interp.load((cmd[end] - cmd[0]) << 16);
        }
        let y = plant.output(0.0) * j.cpu;
        out.push(y);
        let sp = interp.advance();
        let r = axis.update(&sp, y.round() as i64, on, Coupling::NONE, j.lqg.as_ref());
        let code = r.dac as i32 - DAC_MID - g.dac_offset as i32;
        plant.step(code as f64 / g.dac_per_unit as f64);
        k += 1;
    }
    out
}

#[path = "tune_report.rs"]
mod report;
use report::{curves, report};
