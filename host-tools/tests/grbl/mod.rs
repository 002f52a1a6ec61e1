#![allow(dead_code)] // shared by several test binaries, each using a part
//! A running `nc-send --sim grbl` and a plain TCP client of it, for the bridge's tests.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A bridge on the simulator; killed (Ctrl-C first, for its summary) when dropped.
pub struct Bridge {
    child: Option<Child>,
    pub pty: String,
    pub tcp: String,
}

impl Bridge {
    /// `nc-send --sim ARGS… grbl --tcp 127.0.0.1:0`.
    pub fn start(sim_args: &[&str]) -> Self {
        Self::start_with(sim_args, &[])
    }

    /// `nc-send --sim SIM_ARGS… grbl --tcp 127.0.0.1:0 GRBL_ARGS…`.
    pub fn start_with(sim_args: &[&str], grbl_args: &[&str]) -> Self {
        let mut args: Vec<&str> = vec!["--sim"];
        args.extend_from_slice(sim_args);
        args.extend_from_slice(&["grbl", "--tcp", "127.0.0.1:0"]);
        args.extend_from_slice(grbl_args);
        let mut child = Command::new(env!("CARGO_BIN_EXE_nc-send"))
            .args(&args)
            .current_dir(super::common::repo())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("nc-send starts");
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let (mut pty, mut tcp) = (String::new(), String::new());
        for _ in 0..2 {
            let mut l = String::new();
            out.read_line(&mut l)
                .expect("nc-send grbl announces its ports");
            if let Some(p) = l.strip_prefix("pty ") {
                pty = p.trim().into();
            }
            if let Some(t) = l.strip_prefix("tcp ") {
                tcp = t.trim().into();
            }
        }
        assert!(
            !pty.is_empty() && !tcp.is_empty(),
            "ports announced: {pty:?} {tcp:?}"
        );
        child.stdout = Some(out.into_inner());
        Self {
            child: Some(child),
            pty,
            tcp,
        }
    }

    /// Stops the bridge with Ctrl-C and returns its summary (JSON); it must exit
    /// within 20 s.
    pub fn stop(mut self) -> serde_json::Value {
        let mut child = self.child.take().unwrap();
        unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
        let mut out = child.stdout.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut text = String::new();
            let _ = out.read_to_string(&mut text);
            let _ = tx.send(text);
        });
        let Ok(text) = rx.recv_timeout(Duration::from_secs(20)) else {
            let _ = child.kill();
            let _ = child.wait();
            panic!("nc-send grbl did not end within 20 s of Ctrl-C");
        };
        let status = child.wait().unwrap();
        assert!(
            status.success(),
            "nc-send grbl exits cleanly: {status}\n{text}"
        );
        let line = text
            .lines()
            .find_map(|l| l.strip_prefix("summary "))
            .unwrap_or_else(|| panic!("a summary line in {text:?}"));
        serde_json::from_str(line).unwrap()
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// The two ways a sender reaches the bridge: every rule is tested over both.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Via {
    /// The pseudo-terminal, opened as a serial port.
    Pty,
    /// The TCP port.
    Tcp,
}

/// `over_both! { name => body; … }`: the tests `name::pty` and `name::tcp`, each
/// calling `body` (a `fn(Via)` of the test file) with its transport.
#[macro_export]
macro_rules! over_both {
    ($($name:ident => $body:ident;)*) => {$(
        mod $name {
            #[test]
            fn pty() {
                super::$body(super::grbl::Via::Pty)
            }
            #[test]
            fn tcp() {
                super::$body(super::grbl::Via::Tcp)
            }
        }
    )*};
}

/// What a test sender talks through: a TCP stream or the pseudo-terminal, each
/// read with a short timeout (no read waits unbounded).
pub trait Wire: Read + Write + Send {}
impl<T: Read + Write + Send> Wire for T {}

/// A sender written for the tests: sends bytes, reads lines.
pub struct Client {
    s: Box<dyn Wire>,
    buf: Vec<u8>,
    /// How long each [`Client::status_within`] waited for its report.
    pub waits: Vec<Duration>,
}

impl Client {
    /// Connects over TCP and waits for the banner.
    pub fn connect(addr: &str) -> Self {
        let mut c = Self::tcp(addr);
        let banner = c.line_until(|l| l.starts_with("Grbl "), Duration::from_secs(5));
        assert!(banner.contains("1.1"), "{banner}");
        c
    }

    /// A sender on `via`: over TCP once the banner has come; on the pseudo-terminal
    /// (which says nothing when it is opened) once a `?` has been answered.
    pub fn open(bridge: &Bridge, via: Via) -> Self {
        match via {
            Via::Tcp => Self::connect(&bridge.tcp),
            Via::Pty => {
                let mut c = Self::pty(&bridge.pty);
                c.status();
                c
            }
        }
    }

    /// Connects over TCP without waiting for anything.
    pub fn tcp(addr: &str) -> Self {
        let s = TcpStream::connect(addr).expect("connects");
        s.set_read_timeout(Some(Duration::from_millis(20))).unwrap();
        Self {
            s: Box::new(s),
            buf: Vec::new(),
            waits: Vec::new(),
        }
    }

    /// Opens the bridge's pseudo-terminal as a serial port (raw, 115200 baud).
    pub fn pty(path: &str) -> Self {
        let port = serialport::new(path, 115_200)
            .timeout(Duration::from_millis(20))
            .open_native()
            .unwrap_or_else(|e| panic!("opens {path}: {e}"));
        Self {
            s: Box::new(port),
            buf: Vec::new(),
            waits: Vec::new(),
        }
    }

    pub fn send(&mut self, bytes: &[u8]) {
        self.s.write_all(bytes).unwrap();
    }

    /// The next line, waiting up to `limit`.
    pub fn line(&mut self, limit: Duration) -> Option<String> {
        let end = Instant::now() + limit;
        loop {
            if let Some(i) = self.buf.iter().position(|&b| b == b'\n') {
                let l: Vec<u8> = self.buf.drain(..=i).collect();
                return Some(String::from_utf8_lossy(&l).trim().to_string());
            }
            if Instant::now() > end {
                return None;
            }
            let mut chunk = [0u8; 4096];
            // Every read returns within 20 ms (the stream's timeout).
            match self.s.read(&mut chunk) {
                Ok(0) => return None,
                Ok(n) => self.buf.extend_from_slice(&chunk[..n]),
                Err(_) => {}
            }
        }
    }

    /// Lines until one satisfies `done` (returned); panics after `limit`.
    pub fn line_until(&mut self, done: impl Fn(&str) -> bool, limit: Duration) -> String {
        let end = Instant::now() + limit;
        let mut seen = Vec::new();
        while Instant::now() < end {
            if let Some(l) = self.line(end - Instant::now()) {
                if done(&l) {
                    return l;
                }
                seen.push(l);
            }
        }
        panic!("no such line within {limit:?}; saw {seen:?}");
    }

    /// Sends `line` and returns every line up to its answer (`ok` or `error:N`),
    /// answer last; status reports in between are left out.
    pub fn command(&mut self, line: &str) -> Vec<String> {
        self.send(format!("{line}\n").as_bytes());
        let mut got = Vec::new();
        loop {
            let l = self
                .line(Duration::from_secs(20))
                .unwrap_or_else(|| panic!("an answer to {line:?}; got {got:?}"));
            if l.starts_with('<') {
                continue;
            }
            let end = l == "ok" || l.starts_with("error:");
            got.push(l);
            if end {
                return got;
            }
        }
    }

    /// A status report.
    pub fn status(&mut self) -> String {
        self.send(b"?");
        self.line_until(|l| l.starts_with('<'), Duration::from_secs(5))
    }

    /// A status report that must come within `limit` of the `?`; lines before it are
    /// kept for [`Client::line`].
    pub fn status_within(&mut self, limit: Duration) -> String {
        let start = Instant::now();
        self.send(b"?");
        let mut other = Vec::new();
        loop {
            let left = limit.saturating_sub(start.elapsed());
            match self.line(left) {
                Some(l) if l.starts_with('<') => {
                    let took = start.elapsed();
                    self.waits.push(took);
                    assert!(
                        took <= limit,
                        "status report after {took:?} (limit {limit:?}): {l}"
                    );
                    self.unread(other);
                    return l;
                }
                Some(l) => other.push(l),
                None => panic!(
                    "no status report within {limit:?} of '?' (waited {:?}); saw {other:?}",
                    start.elapsed()
                ),
            }
        }
    }

    /// The status waits so far: count, median and largest.
    pub fn wait_figures(&self) -> String {
        let mut w = self.waits.clone();
        w.sort();
        match w.len() {
            0 => "no status reports".into(),
            n => format!("{n} reports, median {:?}, largest {:?}", w[n / 2], w[n - 1]),
        }
    }

    /// Puts `lines` back in front of what is still to be read.
    fn unread(&mut self, lines: Vec<String>) {
        let mut front: Vec<u8> = Vec::new();
        for l in lines {
            front.extend_from_slice(l.as_bytes());
            front.push(b'\n');
        }
        front.extend_from_slice(&self.buf);
        self.buf = front;
    }

    /// Waits until a status report shows `state` (polling as senders do).
    pub fn wait_state(&mut self, state: &str, limit: Duration) -> String {
        let end = Instant::now() + limit;
        loop {
            let s = self.status();
            if s.starts_with(&format!("<{state}")) {
                return s;
            }
            assert!(Instant::now() < end, "state {state} not reached: {s}");
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

/// The value list of a report field: `MPos:1.000,2.000` → [1.0, 2.0].
pub fn field(report: &str, name: &str) -> Vec<f64> {
    let body = report.trim_matches(['<', '>']);
    body.split('|')
        .find_map(|f| f.strip_prefix(&format!("{name}:")))
        .unwrap_or_else(|| panic!("{name} in {report}"))
        .split(',')
        .map(|v| v.parse().unwrap())
        .collect()
}

/// A character-counting sender, as Grbl's interface describes one: at most 127
/// bytes in flight, and every `ok` or `error:` answers the oldest line.
pub fn stream_counting(c: &mut Client, lines: &[String], limit: Duration) -> usize {
    let start = Instant::now();
    let mut in_flight: std::collections::VecDeque<usize> = Default::default();
    let (mut next, mut answered, mut errors) = (0, 0, 0);
    while answered < lines.len() {
        assert!(
            start.elapsed() < limit,
            "{answered} of {} answered in {limit:?}",
            lines.len()
        );
        let sum: usize = in_flight.iter().sum();
        if next < lines.len() && sum + lines[next].len() < 127 {
            // The line and its \n fit in Grbl's 128-byte receive buffer (127 used).
            c.send(format!("{}\n", lines[next]).as_bytes());
            in_flight.push_back(lines[next].len() + 1);
            next += 1;
            continue;
        }
        let Some(l) = c.line(Duration::from_millis(200)) else {
            continue;
        };
        if l == "ok" || l.starts_with("error:") {
            assert!(
                in_flight.pop_front().is_some(),
                "{l:?} answers no line sent"
            );
            answered += 1;
            errors += l.starts_with("error:") as usize;
        }
    }
    assert!(
        c.line(Duration::from_millis(300)).is_none_or(|l| l != "ok"),
        "a stray ok"
    );
    errors
}
