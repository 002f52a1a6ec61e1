//! A run's outside world on record: what the host wrote to the USB link and what was
//! done to the board (commands, injected faults), each at the virtual time the board
//! took it, and what the device wrote back. Everything else a run does follows from
//! the ELF, the machine, the flash contents and these, so replaying a recording
//! (`--replay`) runs the same instructions and gives the same trace, whatever the
//! wall clock does; the device's bytes are checked against the recording's as the
//! replay goes, and the first difference stops it.
//!
//! The file is text, one event a line: `0 setup WHAT` (the ELF, machine file and
//! wiring it was made with), `0 flash HEX` (the configuration pages at power-on),
//! `UNITS in HEX` (host to device), `UNITS out HEX` (device to host), `UNITS cmd
//! COMMAND`, and `UNITS end`; UNITS is virtual time in the board's units
//! (docs/vboard.md).

use anyhow::{bail, Context, Result};
use std::collections::VecDeque;
use std::io::Write;
use std::path::Path;

/// One recorded event.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Bytes the host wrote to the link.
    In(Vec<u8>),
    /// Bytes the device wrote to the host.
    Out(Vec<u8>),
    /// A board command (docs/vboard.md, "Commands").
    Cmd(String),
    /// The run ended.
    End,
    /// What the run was of: the ELF, the machine file and the wiring, by hash.
    Setup(String),
    /// The configuration pages' contents at power-on.
    Flash(Vec<u8>),
}

const HEADER: &str = "# pkmc-vboard recording 1";

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

fn unhex(s: &str) -> Option<Vec<u8>> {
    if s.len() % 2 != 0 {
        return None;
    }
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(s.get(i..i + 2)?, 16).ok())
        .collect()
}

/// Writes a recording.
pub struct Recorder {
    w: std::io::BufWriter<std::fs::File>,
}

impl Recorder {
    /// A new recording at `path`.
    pub fn create(path: &Path) -> Result<Self> {
        let f =
            std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        let mut w = std::io::BufWriter::new(f);
        writeln!(w, "{HEADER}")?;
        Ok(Self { w })
    }

    /// Records `kind` at `at`.
    pub fn event(&mut self, at: u64, kind: &Kind) -> Result<()> {
        match kind {
            Kind::In(b) => writeln!(self.w, "{at} in {}", hex(b))?,
            Kind::Out(b) => writeln!(self.w, "{at} out {}", hex(b))?,
            Kind::Cmd(c) => writeln!(self.w, "{at} cmd {c}")?,
            Kind::Setup(c) => writeln!(self.w, "{at} setup {c}")?,
            Kind::Flash(b) => writeln!(self.w, "{at} flash {}", hex(b))?,
            Kind::End => {
                writeln!(self.w, "{at} end")?;
                self.w.flush()?;
            }
        }
        Ok(())
    }
}

/// Parses a recording's text; errors name the line.
pub fn parse(text: &str, name: &str) -> Result<Vec<(u64, Kind)>> {
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, l)) if l == HEADER => {}
        _ => bail!("{name}:1: not a pkmc-vboard recording (expected {HEADER:?})"),
    }
    let mut out = Vec::new();
    let mut last = 0;
    for (i, line) in lines {
        let at_line = || format!("{name}:{}", i + 1);
        let mut parts = line.splitn(3, ' ');
        let at: u64 = parts
            .next()
            .and_then(|t| t.parse().ok())
            .with_context(|| format!("{}: expected a virtual time", at_line()))?;
        if at < last {
            bail!(
                "{}: time {at} before the previous event's {last}",
                at_line()
            );
        }
        last = at;
        let word = parts.next().unwrap_or("");
        let rest = parts.next().unwrap_or("");
        let kind = match word {
            "in" | "out" | "flash" => {
                let b = unhex(rest)
                    .filter(|b| !b.is_empty())
                    .with_context(|| format!("{}: expected hex bytes after {word:?}", at_line()))?;
                match word {
                    "in" => Kind::In(b),
                    "out" => Kind::Out(b),
                    _ => Kind::Flash(b),
                }
            }
            "cmd" if !rest.is_empty() => Kind::Cmd(rest.to_string()),
            "setup" if !rest.is_empty() => Kind::Setup(rest.to_string()),
            "end" => Kind::End,
            w => bail!("{}: unknown event {w:?}", at_line()),
        };
        out.push((at, kind));
    }
    if !matches!(out.last(), Some((_, Kind::End))) {
        bail!("{name}: the recording has no end (the recorded run did not finish)");
    }
    Ok(out)
}

/// A recording being replayed.
pub struct Replay {
    /// Host bytes and commands still to give, in order.
    pending: VecDeque<(u64, Kind)>,
    /// The device's recorded bytes still to see, in order.
    expected: VecDeque<(u64, Vec<u8>)>,
    /// When the recorded run ended.
    pub end: u64,
    /// What the recording was made with.
    pub setup: Option<String>,
    /// The configuration pages at the recording's power-on.
    pub flash: Option<Vec<u8>>,
    /// Events given and device bytes checked so far.
    pub given: u64,
    /// Device bytes checked.
    pub checked: u64,
}

impl Replay {
    /// The replay of `events`.
    pub fn new(events: Vec<(u64, Kind)>) -> Self {
        let mut r = Self {
            pending: VecDeque::new(),
            expected: VecDeque::new(),
            end: 0,
            setup: None,
            flash: None,
            given: 0,
            checked: 0,
        };
        for (at, k) in events {
            match k {
                Kind::Out(b) => r.expected.push_back((at, b)),
                Kind::End => r.end = at,
                Kind::Setup(c) => r.setup = Some(c),
                Kind::Flash(b) => r.flash = Some(b),
                k => r.pending.push_back((at, k)),
            }
        }
        r
    }

    /// The host bytes and commands due at `now`. An event due earlier means the run
    /// has left the recorded one: an error naming both times.
    pub fn due(&mut self, now: u64) -> Result<Vec<Kind>> {
        let mut out = Vec::new();
        while let Some((at, _)) = self.pending.front() {
            if *at > now {
                break;
            }
            if *at < now {
                bail!(
                    "the replay diverged: an event recorded at {at} units, the board at {now} \
                     units when it looked"
                );
            }
            if let Some((_, k)) = self.pending.pop_front() {
                self.given += 1;
                out.push(k);
            }
        }
        Ok(out)
    }

    /// Checks the device's bytes `got` at `now` against the recording.
    pub fn check_out(&mut self, now: u64, got: &[u8]) -> Result<()> {
        if got.is_empty() {
            if let Some((at, _)) = self.expected.front() {
                if *at < now {
                    bail!("the replay diverged: the device was silent at {at} units, where it wrote before");
                }
            }
            return Ok(());
        }
        match self.expected.pop_front() {
            Some((at, b)) if at == now && b == got => {
                self.checked += b.len() as u64;
                Ok(())
            }
            Some((at, b)) => bail!(
                "the replay diverged at {now} units: the device wrote {} ({} bytes); the \
                 recording has {} ({} bytes) at {at} units",
                hex(&got[..got.len().min(16)]),
                got.len(),
                hex(&b[..b.len().min(16)]),
                b.len()
            ),
            None => bail!(
                "the replay diverged at {now} units: the device wrote {} bytes the recording \
                 does not have",
                got.len()
            ),
        }
    }

    /// Recorded device bytes never seen (at the end of a replay: none may be left).
    pub fn unseen(&self) -> usize {
        self.expected.iter().map(|(_, b)| b.len()).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn events() -> Vec<(u64, Kind)> {
        vec![
            (0, Kind::Setup("elf=1 machine=2 wiring=w".into())),
            (0, Kind::Flash(vec![0xFF, 0x00])),
            (10, Kind::In(vec![1, 2, 0])),
            (10, Kind::Cmd("estop".into())),
            (30, Kind::Out(vec![0xAA, 0])),
            (50, Kind::End),
        ]
    }

    #[test]
    fn round_trip_through_the_text() {
        let path = std::env::temp_dir().join(format!("vboard-rec-{}.txt", std::process::id()));
        let mut r = Recorder::create(&path).unwrap();
        for (at, k) in events() {
            r.event(at, &k).unwrap();
        }
        drop(r);
        let text = std::fs::read_to_string(&path).unwrap();
        let _ = std::fs::remove_file(&path);
        assert_eq!(parse(&text, "rec").unwrap(), events());
    }

    #[test]
    fn bad_lines_are_named() {
        let e = parse(&format!("{HEADER}\n5 in 0g\n9 end\n"), "rec").unwrap_err();
        assert!(e.to_string().starts_with("rec:2:"), "{e}");
        let e = parse(&format!("{HEADER}\n5 in 01\n"), "rec").unwrap_err();
        assert!(e.to_string().contains("no end"), "{e}");
        let e = parse(&format!("{HEADER}\n5 in 01\n4 end\n"), "rec").unwrap_err();
        assert!(e.to_string().starts_with("rec:3:"), "{e}");
    }

    #[test]
    fn replay_gives_events_at_their_time_and_checks_the_device() {
        let mut r = Replay::new(events());
        assert_eq!(r.due(5).unwrap(), vec![]);
        assert_eq!(r.due(10).unwrap().len(), 2);
        r.check_out(20, &[]).unwrap();
        r.check_out(30, &[0xAA, 0]).unwrap();
        assert_eq!((r.unseen(), r.end), (0, 50));
        // A run that comes to the event's time late has diverged.
        let mut late = Replay::new(events());
        assert!(late.due(11).is_err());
        // Other bytes, or the right bytes at another time, are a divergence.
        let mut other = Replay::new(events());
        assert!(other.check_out(30, &[0xAB, 0]).is_err());
        let mut early = Replay::new(events());
        assert!(early.check_out(29, &[0xAA, 0]).is_err());
        let mut silent = Replay::new(events());
        assert!(silent.check_out(31, &[]).is_err());
    }
}

/// FNV-1a, 64 bits: a file's identity in a recording's setup line.
pub fn fnv(b: &[u8]) -> u64 {
    b.iter().fold(0xCBF2_9CE4_8422_2325, |h, &x| {
        (h ^ u64::from(x)).wrapping_mul(0x0000_0100_0000_01B3)
    })
}
