//! The host's side of the controller's data recorder (`pkmc::drive::recorder`,
//! docs/recorder.md): signals named as a user writes them, a capture or a stream as a
//! table of samples, its CSV and its plot ([`plot`]), `nc-send record` ([`cli`]), and
//! servo tuning on recorded data ([`tune`]). The station's scope panel uses the same
//! table and CSV, so both exports are equal for the same capture.

pub mod cli;
pub mod plot;
pub mod tune;
pub mod tune_plot;
pub mod tune_write;
pub mod tuned;

use pkmc::drive::recorder::{Setup, Signal, Trigger, MAX_SIGNALS};

/// A signal's name on the command line and in CSV headers: `cmd:J`, `meas:J`,
/// `ferr:J`, `out:J` (joint J from 0), `speed`, `contour`, `direction`, `line`,
/// `state`.
pub fn parse_signal(text: &str) -> Result<Signal, String> {
    let t = text.trim();
    let (kind, joint) = match t.split_once(':') {
        Some((k, j)) => {
            let j: u8 = j
                .trim()
                .parse()
                .map_err(|_| format!("signal `{t}`: `{j}` is not a joint number (0, 1, 2, …)"))?;
            (k.trim(), Some(j))
        }
        None => (t, None),
    };
    let per_joint = |f: fn(u8) -> Signal| match joint {
        Some(j) if (j as usize) < pkmc::config::MAX_JOINTS => Ok(f(j)),
        Some(j) => Err(format!(
            "signal `{t}`: joint {j} is beyond the {} a controller has",
            pkmc::config::MAX_JOINTS
        )),
        None => Err(format!("signal `{t}` needs a joint: `{kind}:0`")),
    };
    let whole = |s: Signal| match joint {
        None => Ok(s),
        Some(_) => Err(format!("signal `{t}` takes no joint: `{kind}`")),
    };
    match kind {
        "cmd" => per_joint(Signal::Commanded),
        "meas" => per_joint(Signal::Measured),
        "ferr" => per_joint(Signal::FollowingError),
        "out" => per_joint(Signal::Output),
        "speed" => whole(Signal::PathSpeed),
        "contour" => whole(Signal::ContourError),
        "direction" => whole(Signal::DirectionError),
        "line" => whole(Signal::Line),
        "state" => whole(Signal::State),
        _ => Err(format!(
            "signal `{t}`: not one of cmd:J, meas:J, ferr:J, out:J, speed, contour, \
             direction, line, state"
        )),
    }
}

/// A CSV column's name, with the unit: `ferr0_counts`, `speed_nm_s`, …
pub fn column(s: Signal) -> String {
    match s {
        Signal::Commanded(j) => format!("cmd{j}_counts"),
        Signal::Measured(j) => format!("meas{j}_counts"),
        Signal::FollowingError(j) => format!("ferr{j}_counts"),
        Signal::Output(j) => format!("out{j}_dac_or_steps"),
        Signal::PathSpeed => "speed_nm_s".into(),
        Signal::ContourError => "contour_nm".into(),
        Signal::DirectionError => "direction_udeg".into(),
        Signal::Line => "line".into(),
        Signal::State => "state".into(),
    }
}

/// A trigger as written: `now`, `job`, `line:N`, `alarm`, `rise:K:LEVEL`,
/// `fall:K:LEVEL` (K the signal's place in the list, from 0), `stream`.
pub fn parse_trigger(text: &str, count: usize) -> Result<Trigger, String> {
    let parts: Vec<&str> = text.trim().split(':').collect();
    let num = |s: &str, what: &str| -> Result<i64, String> {
        s.trim()
            .parse()
            .map_err(|_| format!("trigger `{text}`: `{s}` is not a whole number ({what})"))
    };
    Ok(match parts.as_slice() {
        ["now"] => Trigger::Now,
        ["job"] => Trigger::JobStart,
        ["alarm"] => Trigger::Alarm,
        ["stream"] => Trigger::Stream,
        ["line", n] => Trigger::Line(
            u32::try_from(num(n, "the NC line")?)
                .map_err(|_| format!("trigger `{text}`: a line number is 0 or more"))?,
        ),
        [dir @ ("rise" | "fall"), k, level] => {
            let k = num(k, "the signal's place in --signals")?;
            if k < 0 || k as usize >= count {
                return Err(format!(
                    "trigger `{text}`: signal {k} is not in --signals (0 to {})",
                    count.saturating_sub(1)
                ));
            }
            let level = i32::try_from(num(level, "the level")?)
                .map_err(|_| format!("trigger `{text}`: the level is beyond 32 bits"))?;
            Trigger::Level {
                signal: k as u8,
                level,
                rising: *dir == "rise",
            }
        }
        _ => {
            return Err(format!(
                "trigger `{text}`: not one of now, job, line:N, alarm, rise:K:LEVEL, \
                 fall:K:LEVEL, stream"
            ))
        }
    })
}

/// A request from its parts; the signal list as written (comma-separated).
pub fn setup(
    signals: &str,
    trigger: &str,
    pre: u16,
    decimate: u16,
    servo: bool,
) -> Result<Setup, String> {
    let list: Vec<Signal> = signals
        .split(',')
        .filter(|s| !s.trim().is_empty())
        .map(parse_signal)
        .collect::<Result<_, _>>()?;
    if list.is_empty() || list.len() > MAX_SIGNALS {
        return Err(format!(
            "--signals `{signals}`: give 1 to {MAX_SIGNALS} signals, comma-separated"
        ));
    }
    let mut ids = [0; MAX_SIGNALS];
    for (id, s) in ids.iter_mut().zip(&list) {
        *id = s.id();
    }
    Ok(Setup {
        signals: ids,
        count: list.len() as u8,
        servo,
        decimate,
        trigger: parse_trigger(trigger, list.len())?,
        pre,
    })
}

/// Samples as a table: what a capture or a stream gave, each sample with its number.
#[derive(Clone, Debug, PartialEq)]
pub struct Table {
    /// The signals, in order.
    pub signals: Vec<Signal>,
    /// Seconds between consecutive sample numbers.
    pub period_s: f64,
    /// The sample number at time 0 (the trigger's; 0 for a stream).
    pub zero: i64,
    /// (number, values), in order.
    pub rows: Vec<(i64, Vec<i32>)>,
}

impl Table {
    /// A finished capture: numbered from its first sample, time 0 at the trigger.
    pub fn of_capture(rec: &crate::link::Recording) -> Self {
        Self {
            signals: rec.signals.clone(),
            period_s: rec.period_s(),
            zero: rec.pre as i64,
            rows: (0..)
                .zip(rec.samples.iter().cloned())
                .collect::<Vec<(i64, Vec<i32>)>>(),
        }
    }

    /// Streamed pieces, in order: numbered as the controller numbered them (a gap
    /// is samples lost on the way), time 0 at sample 0.
    pub fn of_stream(pieces: &[crate::link::Piece]) -> Option<Self> {
        let first = pieces.first()?;
        let hz = if first.servo {
            pkmc::drive::servo::SERVO_HZ as f64
        } else {
            pkmc::units::TICK_HZ as f64
        };
        let mut rows = Vec::new();
        // Sample numbers wrap at 2^32: unwrap them against the last one.
        let mut last: Option<i64> = None;
        for p in pieces {
            let mut n = p.first as i64;
            if let Some(l) = last {
                n = l + 1 + (p.first.wrapping_sub((l as u32).wrapping_add(1)) as i32) as i64;
            }
            for s in &p.samples {
                rows.push((n, s.clone()));
                last = Some(n);
                n += 1;
            }
        }
        Some(Self {
            signals: first.signals.clone(),
            period_s: first.decimate as f64 / hz,
            zero: 0,
            rows,
        })
    }

    /// Samples missing between the first and the last (lost on the way).
    pub fn missing(&self) -> i64 {
        match (self.rows.first(), self.rows.last()) {
            (Some(a), Some(b)) => b.0 - a.0 + 1 - self.rows.len() as i64,
            _ => 0,
        }
    }

    /// A sample's time, s.
    pub fn time(&self, number: i64) -> f64 {
        (number - self.zero) as f64 * self.period_s
    }

    /// The CSV text: `sample,t_s,` and a column per signal ([`column`]); one row per
    /// sample, the time to the microsecond.
    pub fn csv(&self) -> String {
        let mut out = String::from("sample,t_s");
        for s in &self.signals {
            out.push(',');
            out.push_str(&column(*s));
        }
        out.push('\n');
        for (n, values) in &self.rows {
            out.push_str(&format!("{n},{:.6}", self.time(*n)));
            for v in values {
                out.push_str(&format!(",{v}"));
            }
            out.push('\n');
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_and_refuse_by_what_is_wrong() {
        assert_eq!(parse_signal("ferr:2"), Ok(Signal::FollowingError(2)));
        assert_eq!(parse_signal(" speed "), Ok(Signal::PathSpeed));
        assert!(parse_signal("ferr").unwrap_err().contains("needs a joint"));
        assert!(parse_signal("speed:1")
            .unwrap_err()
            .contains("takes no joint"));
        assert!(parse_signal("ferr:x")
            .unwrap_err()
            .contains("not a joint number"));
        assert!(parse_signal("ferr:99").unwrap_err().contains("beyond"));
        assert!(parse_signal("torque").unwrap_err().contains("not one of"));
        let s = setup("ferr:0,cmd:0", "rise:0:40", 10, 1, false).unwrap();
        assert_eq!(s.count, 2);
        assert_eq!(
            s.trigger,
            Trigger::Level {
                signal: 0,
                level: 40,
                rising: true
            }
        );
        assert!(setup("ferr:0", "rise:1:4", 0, 1, false)
            .unwrap_err()
            .contains("signal 1 is not in --signals"));
        assert!(setup("", "now", 0, 1, false)
            .unwrap_err()
            .contains("1 to 8"));
        assert!(setup("ferr:0", "soon", 0, 1, false)
            .unwrap_err()
            .contains("not one of"));
    }

    #[test]
    fn a_stream_with_a_gap_keeps_its_numbers() {
        let piece = |first: u32, n: i32| crate::link::Piece {
            first,
            signals: vec![Signal::Line],
            servo: false,
            decimate: 2,
            samples: (0..n).map(|i| vec![i]).collect(),
        };
        let t = Table::of_stream(&[piece(u32::MAX - 1, 3), piece(5, 2)]).unwrap();
        let numbers: Vec<i64> = t.rows.iter().map(|r| r.0).collect();
        let base = (u32::MAX - 1) as i64;
        assert_eq!(numbers, [base, base + 1, base + 2, base + 7, base + 8]);
        assert_eq!(t.missing(), 4);
        assert!((t.period_s - 0.002).abs() < 1e-12);
        assert!(t.csv().starts_with("sample,t_s,line\n"));
    }
}
