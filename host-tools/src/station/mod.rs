//! The operator station (`nc-send serve`): a web page served from this binary over
//! HTTP and a WebSocket (axum on tokio), in front of the controller's link. The
//! machine thread ([`machine`]) owns the link; the web side ([`web`]) turns the pages'
//! messages into [`Request`]s for it and fans its statuses out to every page; what
//! they share is the [`hub::Hub`]. Programs are compiled and dry-run on worker
//! threads ([`program`]); the mechanism is drawn from the machine file ([`scene`]).
//! See `docs/ui.md`.

mod hub;
mod machine;
mod program;
mod scene;
mod scope;
mod tune;
mod web;

use crate::job::{exit, Failure, RunOptions, Target};
use pkmc::config::MachineConfig;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

/// Where and how the station serves.
#[derive(Clone, Debug)]
pub struct StationOptions {
    /// Address to listen on (`127.0.0.1:8180`; port 0: any free port).
    pub listen: String,
    /// Secret every request must carry (`?token=`); required off loopback.
    pub token: Option<String>,
    /// Program to load at start.
    pub program: Option<PathBuf>,
    /// Joint names (from the machine file); empty: named by the machine's kind.
    pub joint_names: Vec<String>,
    /// How long the controller runs a program from the page on while the station is
    /// silent, before it holds it (the machine file's `host_timeout_s`); `None`: the
    /// short link watch, as for MDI and jogs.
    pub host_timeout: Option<Duration>,
    /// The machine file (Tune reads the joint's gains from it, Write gains writes
    /// them into it); `None`: a built-in machine, not tuned from the page.
    pub machine_file: Option<PathBuf>,
}

impl Default for StationOptions {
    fn default() -> Self {
        Self {
            listen: "127.0.0.1:8180".into(),
            token: None,
            program: None,
            joint_names: Vec::new(),
            host_timeout: Some(Duration::from_millis(
                pkmc::controller::DEFAULT_HOST_TIMEOUT_MS as u64,
            )),
            machine_file: None,
        }
    }
}

/// A page's command, as the page sends it (`{"id": N, "cmd": "...", ...}`).
#[derive(Clone, Debug, serde::Deserialize, serde::Serialize)]
#[serde(tag = "cmd", rename_all = "snake_case", deny_unknown_fields)]
pub(crate) enum Cmd {
    Heartbeat,
    Take,
    Release,
    Load {
        name: String,
        text: String,
    },
    Check,
    Run,
    Step,
    Hold,
    Resume,
    Stop,
    Override {
        percent: f64,
    },
    Jog {
        axis: String,
        distance: f64,
        feed: f64,
    },
    JogStart {
        axis: String,
        dir: f64,
        feed: f64,
    },
    JogStop,
    Mdi {
        text: String,
    },
    Joint {
        joint: usize,
        distance: f64,
        feed: f64,
    },
    TeachSet,
    TeachRemove {
        index: usize,
    },
    TeachMove {
        index: usize,
        to: usize,
    },
    TeachSpeed {
        speed: f64,
    },
    TeachRun,
    TeachStep,
    TeachSave,
    TeachLoad {
        name: String,
        text: String,
    },
    TeachClear,
    Home,
    Reset,
    Estop,
    /// Arms the recorder (`stream`: live traces).
    ScopeArm {
        signals: String,
        trigger: String,
        pre: f64,
        decimate: f64,
    },
    ScopeStop,
    /// A drawing of the scope's samples for this page: `from`..`to` (s), else the
    /// last `window` s, else all; `width` pixels wide.
    ScopeView {
        from: Option<f64>,
        to: Option<f64>,
        window: Option<f64>,
        width: f64,
    },
    /// Tunes a servo joint as `nc-send tune JOINT` does (an option not given: its
    /// default).
    Tune {
        joint: String,
        amplitude: Option<f64>,
        bandwidth: Option<f64>,
        phase_margin: Option<f64>,
    },
    /// Writes the last tune's gains into the machine file (`nc-send tune --write`).
    TuneWrite,
}

impl Cmd {
    /// The command's name as the page writes it (its `cmd` field).
    pub fn name(&self) -> String {
        serde_json::to_value(self)
            .ok()
            .and_then(|v| v["cmd"].as_str().map(String::from))
            .unwrap_or_default()
    }
}

/// A command for the machine thread, from page `page`, answered under `id`.
#[derive(Debug)]
pub(crate) struct Request {
    pub page: u64,
    pub id: u64,
    pub cmd: Cmd,
}

/// `nc-send serve`: connects to the controller as `run` says, serves the page, and
/// prints its address on stdout (`http://ADDRESS/`, with the token) until `stop`.
pub fn run(
    machine: &MachineConfig,
    run: &RunOptions<'_>,
    opts: &StationOptions,
    stop: &dyn Fn() -> bool,
) -> Result<i32, Failure> {
    let addr: std::net::SocketAddr = opts.listen.parse().map_err(|e| {
        Failure::new(
            exit::BAD_INPUT,
            format!("--listen {}: not an address ({e})", opts.listen),
        )
    })?;
    if !addr.ip().is_loopback() && opts.token.as_deref().is_none_or(str::is_empty) {
        return Err(Failure::new(
            exit::BAD_INPUT,
            format!(
                "--listen {addr}: an address other than loopback opens the machine to the \
                 network; give --token too"
            ),
        ));
    }
    let names = if opts.joint_names.is_empty() {
        scene::default_joint_names(machine)
    } else {
        opts.joint_names.clone()
    };
    let hub = Arc::new(hub::Hub::new(scene::describe(machine, &names)));
    let mut link_opts = run.clone();
    // Statuses for the page while a job streams: asked every 30 ms besides the
    // controller's own every 50 ms.
    link_opts.link.keepalive = Duration::from_millis(30);
    let (tx, rx) = std::sync::mpsc::channel();
    let server = web::start(
        addr,
        opts.token.clone(),
        hub.clone(),
        tx,
        machine,
        &link_opts,
    )?;
    {
        use std::io::Write;
        let token = opts
            .token
            .as_ref()
            .map_or(String::new(), |t| format!("?token={t}"));
        let mut out = std::io::stdout().lock();
        let _ = writeln!(out, "http://{}/{token}", server.addr);
        let _ = out.flush();
    }
    if let Some(p) = &opts.program {
        let text = crate::input::read_text(p, crate::input::MAX_PROGRAM_BYTES)
            .map_err(|m| Failure::new(exit::BAD_INPUT, m))?;
        let name = p
            .file_name()
            .map_or("program.ngc".into(), |n| n.to_string_lossy().to_string());
        web::load_program(&hub, machine, &link_opts, &name, &text);
    }
    crate::job::with_link(machine, &link_opts, |link| {
        if matches!(link_opts.target, Target::Sim) {
            // A fresh simulator is locked after its reset: unlock it where it stands.
            crate::job::prepare(link, false, true, &mut crate::link::NoHooks)?;
        }
        let start = link.request_status()?.pose;
        let mut options = crate::job::front_end_options(machine, start, &run.tools);
        // G38 in MDI runs its probing move (`machine::Machine::mdi_probe`).
        options.probing = true;
        let mut m = machine::Machine {
            last_job: "",
            hub: &hub,
            machine,
            rx,
            mdi: machine::Mdi {
                pipeline: crate::job::LinePipeline::new(&options, machine, "MDI"),
                lines: 0,
            },
            tools: run.tools.clone(),
            // A program run from the page streams as nc-send's do (host silence
            // starves it, and holds it after the host timeout, with its mark); MDI,
            // jogs and teach runs keep the short watch.
            program_timeout: opts.host_timeout,
            machine_file: opts.machine_file.clone(),
        };
        m.serve(link, stop)
    })?;
    server.shutdown();
    Ok(exit::OK)
}
