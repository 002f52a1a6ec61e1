//! `nc-send record`: arms the controller's recorder, runs a program while it records
//! if given one, and writes the capture or the stream as CSV and a plot.

use super::{plot, Table};
use crate::job::{exit, Failure, RunOptions};
use crate::link::{JobEnd, JobHooks, Link, Transport};
use pkmc::config::MachineConfig;
use pkmc::drive::recorder::{Phase, Trigger};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// `nc-send record`'s arguments.
#[derive(Clone, Debug, clap::Args)]
pub struct RecordArgs {
    /// Up to 8 signals, comma-separated: cmd:J, meas:J, ferr:J, out:J (joint J from 0),
    /// speed, contour, direction, line, state (docs/recorder.md).
    #[arg(long, value_name = "LIST")]
    pub signals: String,
    /// now, job, line:N, alarm, rise:K:LEVEL, fall:K:LEVEL (K: the signal's place in
    /// --signals, from 0), or stream (continuous, no trigger).
    #[arg(long, default_value = "job")]
    pub trigger: String,
    /// Samples to keep before the trigger's.
    #[arg(long, default_value_t = 0)]
    pub pre: u16,
    /// Keep every Nth sample.
    #[arg(long, default_value_t = 1)]
    pub decimate: u16,
    /// Sample every servo period (10 kHz) rather than every tick (1 kHz).
    #[arg(long)]
    pub servo: bool,
    /// Run this program while recording.
    #[arg(long, value_name = "FILE")]
    pub during: Option<PathBuf>,
    /// Streaming without a program: how long, s.
    #[arg(long, default_value_t = 1.0)]
    pub seconds: f64,
    /// After the program (or at once): how long to wait for the capture to finish, s.
    #[arg(long, default_value_t = 5.0)]
    pub wait: f64,
    /// Write the CSV here.
    #[arg(long, value_name = "FILE")]
    pub csv: PathBuf,
    /// Draw the traces here (.svg or .png).
    #[arg(long, value_name = "FILE")]
    pub plot: Option<PathBuf>,
}

fn bad(message: impl Into<String>) -> Failure {
    Failure::new(exit::BAD_INPUT, message)
}

/// Checks the arguments before anything is sent.
pub fn check(args: &RecordArgs) -> Result<pkmc::drive::recorder::Setup, Failure> {
    let setup = super::setup(
        &args.signals,
        &args.trigger,
        args.pre,
        args.decimate,
        args.servo,
    )
    .map_err(bad)?;
    if let Some(p) = &args.plot {
        crate::analysis::plot::format_of(p).map_err(bad)?;
    }
    for (what, v) in [("--seconds", args.seconds), ("--wait", args.wait)] {
        if !(v > 0.0 && v <= 3600.0) {
            return Err(bad(format!("{what} {v}: give 0 to 3600 seconds")));
        }
    }
    if args.decimate == 0 {
        return Err(bad("--decimate 0: keep every sample with 1"));
    }
    Ok(setup)
}

/// Runs `nc-send record` on `link`; returns how the program (if any) ended.
pub fn run<T: Transport>(
    link: &mut Link<T>,
    args: &RecordArgs,
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<JobEnd, Failure> {
    let setup = check(args)?;
    let compiled = match &args.during {
        Some(p) => Some(crate::job::compile_for(p, machine, opts)?),
        None => None,
    };
    link.record_take();
    link.record_arm(&setup)?;
    if compiled.is_some() && !matches!(setup.trigger, Trigger::Now | Trigger::Stream) {
        // The pre-trigger samples are taken from the arming on: a program started at
        // once would trigger before they exist (the capture keeps only those there
        // are), so it waits until they can.
        let hz = if setup.servo {
            pkmc::drive::servo::SERVO_HZ
        } else {
            pkmc::units::TICK_HZ
        };
        let fill = setup.pre as f64 * setup.decimate as f64 / hz as f64 + 0.02;
        let until = Instant::now() + Duration::from_secs_f64(fill);
        while Instant::now() < until {
            link.record_listen(Duration::from_millis(5))?;
        }
    }
    let end = match &compiled {
        Some(c) => link.run_job(&c.blocks, hooks)?,
        None => JobEnd::Done,
    };
    let table = if setup.trigger == Trigger::Stream {
        if compiled.is_none() {
            let until = Instant::now() + Duration::from_secs_f64(args.seconds);
            while Instant::now() < until {
                link.record_listen(Duration::from_millis(20))?;
            }
        }
        link.record_disarm()?;
        link.record_listen(Duration::from_millis(50))?;
        Table::of_stream(&link.record_take())
            .ok_or_else(|| Failure::new(exit::LINK, "the recorder streamed no sample"))?
    } else {
        Table::of_capture(&wait_capture(link, args.wait)?)
    };
    if table.missing() > 0 {
        eprintln!(
            "nc-send record: {} samples of {} were lost on the way (the link fell behind)",
            table.missing(),
            table.missing() + table.rows.len() as i64
        );
    }
    std::fs::write(&args.csv, table.csv())
        .map_err(|e| bad(format!("{}: cannot write the CSV: {e}", args.csv.display())))?;
    if let Some(p) = &args.plot {
        plot::draw(p, &table).map_err(bad)?;
    }
    eprintln!(
        "nc-send record: {} samples of {} signals, {} s apart",
        table.rows.len(),
        table.signals.len(),
        table.period_s
    );
    Ok(end)
}

/// Waits up to `wait_s` for the armed capture to finish and reads it out.
pub fn wait_capture<T: Transport>(
    link: &mut Link<T>,
    wait_s: f64,
) -> Result<crate::link::Recording, Failure> {
    let until = Instant::now() + Duration::from_secs_f64(wait_s);
    loop {
        if let Some(rec) = link.record_read()? {
            return Ok(rec);
        }
        if Instant::now() >= until {
            let (reply, _) = link.record_query(0)?;
            let phase = match reply.capture.phase {
                Phase::Armed => "armed: its trigger never came",
                Phase::Triggered => "triggered, still filling",
                _ => "not armed",
            };
            return Err(Failure::new(
                exit::ALARM,
                format!("the recorder's capture did not finish within {wait_s} s ({phase})"),
            ));
        }
        link.record_listen(Duration::from_millis(20))?;
    }
}
