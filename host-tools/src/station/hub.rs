//! What the pages share: who is connected, who holds the lock, the loaded program,
//! the teach list, the last status; and the ways out to the pages (one message to
//! all, or a reply to one).

use super::program::Program;
use pkmc::wire::Status;
use serde_json::{json, Value};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use tokio::sync::{broadcast, mpsc};

/// A page that has not been heard from for this long has lost its heartbeat: a jog it
/// started is stopped (the page sends one every 250 ms; a browser slows the timers of a
/// page in the background to one a second).
pub const HEARTBEAT_LOST: Duration = Duration::from_millis(1500);

/// A page silent for this long may be relieved of control by another.
pub const LOCK_LAPSES: Duration = Duration::from_secs(5);

/// A connected page.
struct Page {
    name: String,
    tx: mpsc::UnboundedSender<Arc<str>>,
    heard: Instant,
}

/// The teach list: positions (mm, degrees) in order, the speed they are run at, and
/// the next one Run by Step goes to.
#[derive(Clone, Debug)]
pub struct Teach {
    pub points: Vec<[f64; 6]>,
    pub speed: f64,
    pub next: Option<usize>,
}

/// A run of a program that probes, as the pages show it: each probing move's result
/// as it came, and how the run ended.
#[derive(Clone, Debug, Default)]
pub struct ProbeRun {
    /// The program's name.
    pub program: String,
    /// Each probing move's result, in order (`ProbeRecord`'s JSON).
    pub records: Vec<crate::job::probing::ProbeRecord>,
    /// Each record's probed X Y Z in the program's frame, mm, where known.
    pub program_frame: Vec<Option<[f64; 3]>>,
    /// Where the program was refused, when it was: line, column, message.
    pub refusal: Option<(usize, usize, String)>,
    /// Still running.
    pub running: bool,
    /// How it ended (`done`, `alarm`, `stopped`, `paused`, `refused`, `failed`).
    pub end: Option<&'static str>,
}

impl ProbeRun {
    /// The `probes` message.
    pub fn message(&self) -> Value {
        json!({
            "type": "probes",
            "program": self.program,
            "records": self.records,
            "program_frame": self.program_frame,
            "refusal": self.refusal.as_ref()
                .map(|(line, col, message)| json!({"line": line, "col": col, "message": message})),
            "running": self.running,
            "end": self.end,
        })
    }
}

/// State shared by the web side and the machine thread.
pub struct Hub {
    all: broadcast::Sender<Arc<str>>,
    pages: Mutex<HashMap<u64, Page>>,
    lock: Mutex<Option<u64>>,
    next_id: AtomicU64,
    pub program: Mutex<Program>,
    pub teach: Mutex<Teach>,
    pub status: Mutex<Option<Status>>,
    /// The last `status` and `program` messages, for a page that connects.
    last_status: Mutex<Option<Arc<str>>>,
    last_program: Mutex<Option<Arc<str>>>,
    /// The probing moves of the last run that probed, for the pages.
    pub probes: Mutex<ProbeRun>,
    last_probes: Mutex<Option<Arc<str>>>,
    /// The scope panel: the recorder's request and samples.
    pub scope: Mutex<super::scope::Scope>,
    last_scope: Mutex<Option<Arc<str>>>,
    /// The Tune panel: the tune running, the last result.
    pub tune: Mutex<super::tune::Tune>,
    last_tune: Mutex<Option<Arc<str>>>,
    /// The `hello` message's `machine`.
    pub machine: Value,
    /// A page's E-STOP raised the alarm in force (the controller calls it an
    /// immediate stop, `Aborted`; the pages say e-stop). Cleared with the alarm
    /// ([`Hub::estop_shown`]).
    estop: AtomicBool,
    /// A status with an alarm has come since the E-STOP: the next one without an
    /// alarm clears `estop` (a status already on its way when the E-STOP was asked
    /// for, with no alarm yet, must not).
    estop_alarm_seen: AtomicBool,
}

/// Locks a mutex, whatever a panicking holder left.
pub fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Hub {
    /// A page asked for an E-STOP: the alarm it raises is shown as an e-stop.
    pub fn request_estop(&self) {
        self.estop_alarm_seen.store(false, Ordering::Relaxed);
        self.estop.store(true, Ordering::Relaxed);
    }

    /// Is the alarm of a status (`alarm`: it has one) an e-stop's? Kept from the
    /// E-STOP until a status shows an alarm and a later one shows none.
    pub fn estop_shown(&self, alarm: bool) -> bool {
        let asked = self.estop.load(Ordering::Relaxed);
        if alarm {
            if asked {
                self.estop_alarm_seen.store(true, Ordering::Relaxed);
            }
        } else if self.estop_alarm_seen.swap(false, Ordering::Relaxed) {
            self.estop.store(false, Ordering::Relaxed);
        }
        asked && alarm
    }

    pub fn new(machine: Value) -> Self {
        Self {
            all: broadcast::channel(256).0,
            pages: Mutex::new(HashMap::new()),
            lock: Mutex::new(None),
            next_id: AtomicU64::new(1),
            estop: AtomicBool::new(false),
            estop_alarm_seen: AtomicBool::new(false),
            program: Mutex::new(Program::default()),
            teach: Mutex::new(Teach {
                points: Vec::new(),
                speed: 1000.0,
                next: None,
            }),
            status: Mutex::new(None),
            last_status: Mutex::new(None),
            last_program: Mutex::new(None),
            probes: Mutex::new(ProbeRun::default()),
            last_probes: Mutex::new(None),
            scope: Mutex::new(Default::default()),
            last_scope: Mutex::new(None),
            tune: Mutex::new(Default::default()),
            last_tune: Mutex::new(None),
            machine,
        }
    }

    /// A page connects: its id, what it receives, and the messages it starts with.
    pub fn connect(
        &self,
        name: &str,
    ) -> (
        u64,
        mpsc::UnboundedReceiver<Arc<str>>,
        broadcast::Receiver<Arc<str>>,
    ) {
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let (tx, rx) = mpsc::unbounded_channel();
        let hello = json!({"type": "hello", "you": id, "machine": self.machine});
        let _ = tx.send(hello.to_string().into());
        for m in [
            &self.last_program,
            &self.last_status,
            &self.last_probes,
            &self.last_scope,
            &self.last_tune,
        ] {
            if let Some(m) = lock(m).clone() {
                let _ = tx.send(m);
            }
        }
        let _ = tx.send(self.teach_message().to_string().into());
        let all = self.all.subscribe();
        lock(&self.pages).insert(
            id,
            Page {
                name: name.to_string(),
                tx,
                heard: Instant::now(),
            },
        );
        (id, rx, all)
    }

    /// A page went: its lock is released.
    pub fn disconnect(&self, id: u64) {
        let name = lock(&self.pages).remove(&id).map(|p| p.name);
        let mut l = lock(&self.lock);
        if *l == Some(id) {
            *l = None;
            drop(l);
            self.log(
                "warn",
                &format!(
                    "{} closed its page and gave up control",
                    name.unwrap_or_default()
                ),
            );
        }
    }

    pub fn heard(&self, id: u64) {
        if let Some(p) = lock(&self.pages).get_mut(&id) {
            p.heard = Instant::now();
        }
    }

    /// Is page `id` connected and heard from within `within`?
    pub fn heard_within(&self, id: u64, within: Duration) -> bool {
        lock(&self.pages)
            .get(&id)
            .is_some_and(|p| p.heard.elapsed() < within)
    }

    /// Is page `id` still connected?
    pub fn connected(&self, id: u64) -> bool {
        lock(&self.pages).contains_key(&id)
    }

    /// Who holds the lock: id and name.
    pub fn holder(&self) -> Option<(u64, String)> {
        let id = (*lock(&self.lock))?;
        let name = lock(&self.pages).get(&id).map(|p| p.name.clone());
        Some((id, name.unwrap_or_default()))
    }

    /// Page `id` takes the lock if nobody holds it, or if its holder has been silent
    /// for [`LOCK_LAPSES`]; otherwise says who holds it.
    pub fn take(&self, id: u64) -> Result<(), String> {
        let mut l = lock(&self.lock);
        match *l {
            Some(h) if h != id && self.heard_within(h, LOCK_LAPSES) => {
                drop(l);
                let name = self.holder().map(|h| h.1).unwrap_or_default();
                Err(format!("{name} holds control of the machine"))
            }
            _ => {
                *l = Some(id);
                Ok(())
            }
        }
    }

    pub fn release(&self, id: u64) {
        let mut l = lock(&self.lock);
        if *l == Some(id) {
            *l = None;
        }
    }

    /// May page `id` command the machine? `Err` names who holds it.
    pub fn may_command(&self, id: u64) -> Result<(), String> {
        match self.holder() {
            Some((h, _)) if h == id => Ok(()),
            Some((_, name)) => Err(format!(
                "{name} holds control of the machine: commands from this page are refused"
            )),
            None => Err("take control first (nobody holds it)".to_string()),
        }
    }

    /// A message to every page (none is lost: the pages' own queues).
    pub fn broadcast(&self, msg: &Value) {
        let text: Arc<str> = msg.to_string().into();
        for p in lock(&self.pages).values() {
            let _ = p.tx.send(text.clone());
        }
    }

    /// A message to one page.
    pub fn send_to(&self, id: u64, msg: &Value) {
        if let Some(p) = lock(&self.pages).get(&id) {
            let _ = p.tx.send(msg.to_string().into());
        }
    }

    pub fn reply(&self, page: u64, id: u64, result: Result<String, String>) {
        let (ok, text) = match result {
            Ok(t) => (true, t),
            Err(t) => (false, t),
        };
        self.send_to(
            page,
            &json!({"type": "reply", "id": id, "ok": ok, "text": text}),
        );
    }

    pub fn log(&self, level: &str, text: &str) {
        self.broadcast(&json!({"type": "log", "level": level, "text": text}));
    }

    /// A status message to every page (kept for pages that connect later); a page
    /// too slow for them skips some (each is a whole snapshot).
    pub fn publish_status(&self, status: &Status, msg: Value) {
        *lock(&self.status) = Some(status.clone());
        let text: Arc<str> = msg.to_string().into();
        *lock(&self.last_status) = Some(text.clone());
        let _ = self.all.send(text);
    }

    /// The loaded program to every page.
    pub fn publish_program(&self) {
        let msg = lock(&self.program).message();
        *lock(&self.last_program) = Some(msg.to_string().into());
        self.broadcast(&msg);
    }

    /// The probing moves of the run to every page (kept for pages that connect later).
    pub fn publish_probes(&self) {
        let msg = lock(&self.probes).message();
        *lock(&self.last_probes) = Some(msg.to_string().into());
        self.broadcast(&msg);
    }

    /// The scope panel's state to every page (kept for pages that connect later).
    pub fn publish_scope(&self) {
        let msg = lock(&self.scope).message();
        *lock(&self.last_scope) = Some(msg.to_string().into());
        self.broadcast(&msg);
    }

    /// The Tune panel's state to every page (kept for pages that connect later).
    pub fn publish_tune(&self) {
        let msg = lock(&self.tune).message();
        *lock(&self.last_tune) = Some(msg.to_string().into());
        self.broadcast(&msg);
    }

    pub fn teach_message(&self) -> Value {
        let t = lock(&self.teach);
        let points: Vec<Value> = t
            .points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                json!({"name": format!("P{}", i + 1), "pose": p.map(super::program::round3)})
            })
            .collect();
        json!({"type": "teach", "points": points, "speed": t.speed, "next": t.next})
    }

    pub fn publish_teach(&self) {
        self.broadcast(&self.teach_message());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_e_stops_alarm_is_shown_as_one_until_it_clears_whatever_status_came_between() {
        let hub = Hub::new(json!({}));
        assert!(!hub.estop_shown(true), "an alarm no page asked for");
        hub.request_estop();
        // A status sent before the controller took the stop: no alarm yet.
        assert!(!hub.estop_shown(false));
        assert!(hub.estop_shown(true), "the stop's alarm is the e-stop's");
        assert!(hub.estop_shown(true));
        // Reset: the alarm clears, and a later alarm is not an e-stop's.
        assert!(!hub.estop_shown(false));
        assert!(!hub.estop_shown(true));
    }

    impl Hub {
        /// Makes page `id` look silent for `by`.
        fn age(&self, id: u64, by: Duration) {
            if let Some(p) = lock(&self.pages).get_mut(&id) {
                p.heard -= by;
            }
        }
    }

    #[test]
    fn one_page_commands_the_others_are_told_who_and_a_silent_holder_lapses() {
        let hub = Hub::new(serde_json::json!({}));
        let (a, _ra, _ba) = hub.connect("first");
        let (b, _rb, _bb) = hub.connect("second");
        assert!(hub.may_command(a).is_err(), "nobody holds control yet");
        hub.take(a).unwrap();
        assert!(hub.may_command(a).is_ok());
        let refused = hub.may_command(b).unwrap_err();
        assert!(refused.contains("first holds control"), "{refused}");
        assert!(hub.take(b).unwrap_err().contains("first"));
        // Silent for less than the lapse: still held. Longer: another may take it.
        hub.age(a, LOCK_LAPSES - Duration::from_millis(500));
        assert!(hub.take(b).is_err());
        hub.age(a, Duration::from_secs(1));
        hub.take(b).unwrap();
        assert!(hub.may_command(a).is_err());
        // A page that closes gives control up.
        hub.disconnect(b);
        assert_eq!(hub.holder(), None);
        assert!(!hub.connected(b));
    }

    #[test]
    fn a_heartbeat_keeps_a_page_alive_and_silence_loses_it() {
        let hub = Hub::new(serde_json::json!({}));
        let (a, _r, _b) = hub.connect("p");
        assert!(hub.heard_within(a, HEARTBEAT_LOST));
        hub.age(a, HEARTBEAT_LOST);
        assert!(!hub.heard_within(a, HEARTBEAT_LOST));
        hub.heard(a);
        assert!(hub.heard_within(a, HEARTBEAT_LOST));
    }
}
