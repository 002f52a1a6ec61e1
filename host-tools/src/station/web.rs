//! The web side: axum on a tokio runtime of its own thread. Serves the page and its
//! assets (built into the binary), and one WebSocket per page: the page's commands
//! are checked (the token, the lock, the JSON) and handed to the hub or the machine
//! thread; the hub's messages and the statuses go out.

use super::hub::{lock, Hub};
use super::program::Program;
use super::{Cmd, Request};
use crate::job::{exit, Failure, RunOptions, Target};
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Query, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use pkmc::config::MachineConfig;
use serde_json::{json, Value};
use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::mpsc::Sender;
use std::sync::{Arc, Mutex};
use tokio::sync::broadcast::error::RecvError;

const INDEX: &str = include_str!("page/index.html");
const APP: &str = include_str!("page/app.js");
const STYLE: &str = include_str!("page/style.css");
const SCOPE: &str = include_str!("page/scope.js");
const TUNE: &str = include_str!("page/tune.js");

/// What every request handler sees.
struct App {
    hub: Arc<Hub>,
    tx: Mutex<Sender<Request>>,
    token: Option<String>,
    machine: MachineConfig,
    opts: RunOptions<'static>,
}

/// The running web server.
pub struct Server {
    pub addr: SocketAddr,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Server {
    /// Stops serving and waits for the server's thread.
    pub fn shutdown(mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// What a dry run needs of the options, owned: the simulator in this process.
fn owned(opts: &RunOptions<'_>) -> RunOptions<'static> {
    RunOptions {
        target: Target::Sim,
        sim: crate::job::SimSetup {
            trace: None,
            faults: None,
            record_path: true,
            plants: opts.sim.plants.clone(),
            inject: Vec::new(),
            clock: Default::default(),
            deviation: None,
            probe: None,
            truth: None,
        },
        link: opts.link,
        home: false,
        tools: opts.tools.clone(),
        statics: opts.statics.clone(),
        compress: opts.compress,
    }
}

/// Binds `addr` and serves on a thread of its own.
pub fn start(
    addr: SocketAddr,
    token: Option<String>,
    hub: Arc<Hub>,
    tx: Sender<Request>,
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
) -> Result<Server, Failure> {
    let link_err = |e: std::io::Error| Failure::new(exit::LINK, format!("serve: {addr}: {e}"));
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(link_err)?;
    let listener = rt
        .block_on(tokio::net::TcpListener::bind(addr))
        .map_err(link_err)?;
    let bound = listener.local_addr().map_err(link_err)?;
    let app = Arc::new(App {
        hub,
        tx: Mutex::new(tx),
        token,
        machine: machine.clone(),
        opts: owned(opts),
    });
    let router = Router::new()
        .route("/", get(index))
        .route("/app.js", get(app_js))
        .route("/style.css", get(style))
        .route("/scope.js", get(scope_js))
        .route("/tune.js", get(tune_js))
        .route("/scope.csv", get(scope_csv))
        .route("/ws", get(ws))
        .with_state(app);
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let thread = std::thread::spawn(move || {
        rt.block_on(async move {
            let _ = axum::serve(listener, router)
                .with_graceful_shutdown(async {
                    let _ = stop_rx.await;
                })
                .await;
        });
        rt.shutdown_background();
    });
    Ok(Server {
        addr: bound,
        stop: Some(stop_tx),
        thread: Some(thread),
    })
}

type Q = Query<HashMap<String, String>>;

/// Refuses a request without the token (when one is set).
fn authorised(app: &App, q: &HashMap<String, String>) -> Result<(), Box<Response>> {
    match &app.token {
        Some(t) if q.get("token") != Some(t) => Err(Box::new(
            (
                StatusCode::UNAUTHORIZED,
                "this station needs its token: open the address nc-send serve printed \
                 (?token=…)",
            )
                .into_response(),
        )),
        _ => Ok(()),
    }
}

fn asset(kind: &'static str, body: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, kind),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        body,
    )
        .into_response()
}

async fn index(State(app): State<Arc<App>>, Query(q): Q) -> Response {
    if let Err(r) = authorised(&app, &q) {
        return *r;
    }
    asset("text/html; charset=utf-8", INDEX)
}

async fn app_js() -> Response {
    asset("text/javascript; charset=utf-8", APP)
}

async fn style() -> Response {
    asset("text/css; charset=utf-8", STYLE)
}

async fn scope_js() -> Response {
    asset("text/javascript; charset=utf-8", SCOPE)
}

async fn tune_js() -> Response {
    asset("text/javascript; charset=utf-8", TUNE)
}

/// The scope's samples as CSV, a download: [`crate::scope::Table::csv`], the text
/// `nc-send record --csv` writes for the same capture.
async fn scope_csv(State(app): State<Arc<App>>, Query(q): Q) -> Response {
    if let Err(r) = authorised(&app, &q) {
        return *r;
    }
    let Some(table) = lock(&app.hub.scope).table() else {
        return (
            StatusCode::NOT_FOUND,
            "the scope has recorded nothing yet: Live or Arm first",
        )
            .into_response();
    };
    (
        [
            (header::CONTENT_TYPE, "text/csv; charset=utf-8"),
            (
                header::CONTENT_DISPOSITION,
                "attachment; filename=\"scope.csv\"",
            ),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        table.csv(),
    )
        .into_response()
}

/// A page from another site may not open the socket (a browser sends its Origin; the
/// WebSocket handshake is not held back by the same-origin rule).
fn same_origin(headers: &HeaderMap) -> bool {
    let Some(origin) = headers.get(header::ORIGIN).and_then(|o| o.to_str().ok()) else {
        return true;
    };
    let host = headers
        .get(header::HOST)
        .and_then(|h| h.to_str().ok())
        .unwrap_or("");
    origin
        .split_once("://")
        .is_some_and(|(_, rest)| rest.trim_end_matches('/') == host)
}

async fn ws(
    State(app): State<Arc<App>>,
    Query(q): Q,
    headers: HeaderMap,
    upgrade: WebSocketUpgrade,
) -> Response {
    if let Err(r) = authorised(&app, &q) {
        return *r;
    }
    if !same_origin(&headers) {
        return (
            StatusCode::FORBIDDEN,
            "a page from another origin may not command this machine",
        )
            .into_response();
    }
    let name: String = q
        .get("name")
        .map_or("page", String::as_str)
        .chars()
        .filter(|c| c.is_alphanumeric() || "-_.@ ".contains(*c))
        .take(40)
        .collect();
    upgrade.on_upgrade(move |socket| page(socket, app, name))
}

/// One page's socket until it closes.
async fn page(mut socket: WebSocket, app: Arc<App>, name: String) {
    let (id, mut own, mut all) = app.hub.connect(&name);
    loop {
        let out: Arc<str> = tokio::select! {
            m = socket.recv() => match m {
                Some(Ok(Message::Text(t))) => {
                    handle(&app, id, t.as_str());
                    continue;
                }
                Some(Ok(Message::Close(_))) | Some(Err(_)) | None => break,
                Some(Ok(_)) => continue,
            },
            Some(m) = own.recv() => m,
            r = all.recv() => match r {
                Ok(m) => m,
                Err(RecvError::Lagged(_)) => continue,
                Err(RecvError::Closed) => break,
            },
        };
        if socket
            .send(Message::Text(out.as_ref().into()))
            .await
            .is_err()
        {
            break;
        }
    }
    app.hub.disconnect(id);
}

/// One message from page `page`.
fn handle(app: &Arc<App>, page: u64, text: &str) {
    app.hub.heard(page);
    let (id, cmd) = match parse(text) {
        Ok(c) => c,
        Err((id, why)) => return app.hub.reply(page, id, Err(why)),
    };
    let hub = &app.hub;
    match cmd {
        Cmd::Heartbeat => {}
        Cmd::Take => {
            let r = hub.take(page);
            if r.is_ok() {
                let who = hub.holder().map(|h| h.1).unwrap_or_default();
                hub.log("info", &format!("{who} has control"));
            }
            hub.reply(page, id, r.map(|_| "you have control".into()));
        }
        Cmd::Release => {
            hub.release(page);
            hub.reply(page, id, Ok("released".into()));
        }
        Cmd::TeachSave => {
            let t = lock(&hub.teach).clone();
            let axes = crate::job::machine_axes(&app.machine);
            let text = super::program::teach_gcode(&t.points, &axes, t.speed);
            hub.send_to(
                page,
                &json!({"type": "file", "name": "teach.ngc", "text": text}),
            );
            hub.reply(page, id, Ok("saved".into()));
        }
        Cmd::ScopeView {
            from,
            to,
            window,
            width,
        } => {
            let app = app.clone();
            tokio::task::spawn_blocking(move || {
                let scope = lock(&app.hub.scope).clone();
                match super::scope::plot_message(&scope, from, to, window, width) {
                    Ok(m) => app.hub.send_to(page, &m),
                    Err(why) => app.hub.reply(page, id, Err(why)),
                }
            });
        }
        cmd => {
            if let Err(why) = hub.may_command(page) {
                return hub.reply(page, id, Err(why));
            }
            if let Cmd::ScopeArm {
                signals,
                trigger,
                pre,
                decimate,
            } = &cmd
            {
                if let Err(why) = super::scope::check(signals, trigger, *pre, *decimate) {
                    lock(&hub.scope).error = Some(why.clone());
                    hub.publish_scope();
                    return hub.reply(page, id, Err(why));
                }
            }
            command(app, page, id, cmd);
        }
    }
}

/// `{"id": N, "cmd": ...}` into its id and command; an error names what is wrong.
fn parse(text: &str) -> Result<(u64, Cmd), (u64, String)> {
    let mut v: Value = serde_json::from_str(text)
        .map_err(|e| (0, format!("message: not JSON ({e}): {}", clip(text))))?;
    let Some(obj) = v.as_object_mut() else {
        return Err((0, format!("message: not an object: {}", clip(text))));
    };
    let id = obj.remove("id").and_then(|i| i.as_u64()).unwrap_or(0);
    let name = obj
        .get("cmd")
        .and_then(|c| c.as_str())
        .unwrap_or("")
        .to_string();
    if name.is_empty() {
        return Err((id, format!("message {id}: no \"cmd\": {}", clip(text))));
    }
    serde_json::from_value(v)
        .map(|c| (id, c))
        .map_err(|e| (id, format!("command {name} (message {id}): {e}")))
}

fn clip(text: &str) -> String {
    text.chars().take(80).collect()
}

/// A command that needs the lock: the hub's own (program, teach list) on a worker, or
/// the machine thread's.
fn command(app: &Arc<App>, page: u64, id: u64, cmd: Cmd) {
    let hub = &app.hub;
    match cmd {
        Cmd::Load { name, text } => {
            if text.len() as u64 > crate::input::MAX_PROGRAM_BYTES {
                return hub.reply(
                    page,
                    id,
                    Err(format!(
                        "{name}: {} bytes, larger than a program may be ({} bytes)",
                        text.len(),
                        crate::input::MAX_PROGRAM_BYTES
                    )),
                );
            }
            let app = app.clone();
            tokio::task::spawn_blocking(move || {
                let n = load_program(&app.hub, &app.machine, &app.opts, &name, &text);
                let r = match n {
                    0 => Ok(format!("{name} loaded")),
                    n => Err(format!("{name}: {n} error(s); marked in the editor")),
                };
                app.hub.reply(page, id, r);
            });
        }
        Cmd::Check => {
            let app = app.clone();
            tokio::task::spawn_blocking(move || {
                let p = lock(&app.hub.program).clone();
                let n = load_program(&app.hub, &app.machine, &app.opts, &p.name, &p.text);
                app.hub
                    .reply(page, id, Ok(format!("checked: {n} problem(s)")));
            });
        }
        Cmd::TeachSet
        | Cmd::TeachRemove { .. }
        | Cmd::TeachMove { .. }
        | Cmd::TeachSpeed { .. }
        | Cmd::TeachClear
        | Cmd::TeachLoad { .. } => {
            let r = teach(app, cmd);
            if r.is_ok() {
                hub.publish_teach();
            }
            hub.reply(page, id, r);
        }
        cmd => {
            let sent = lock(&app.tx).send(Request { page, id, cmd });
            if sent.is_err() {
                hub.reply(page, id, Err("the machine thread has stopped".into()));
            }
        }
    }
}

/// Loads `text` as the program, tells every page, then dry-runs it and tells them
/// again. Returns the errors and problems found.
pub fn load_program(
    hub: &Hub,
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
    name: &str,
    text: &str,
) -> usize {
    let mut p = Program::load(name, text, machine, opts);
    *lock(&hub.program) = p.clone();
    hub.publish_program();
    if !p.runnable() {
        return p.errors.len();
    }
    p.dry_run(machine, opts);
    let found = p.check.as_ref().map_or(0, |c| c.findings.len());
    {
        let mut now = lock(&hub.program);
        if now.text != p.text || now.name != p.name {
            return found; // another program was loaded meanwhile
        }
        *now = p;
    }
    hub.publish_program();
    found
}

/// The teach list's commands.
fn teach(app: &App, cmd: Cmd) -> Result<String, String> {
    let hub = &app.hub;
    let mut t = lock(&hub.teach);
    let n = t.points.len();
    let bad_index = |i: usize| format!("teach: position {} does not exist ({n} listed)", i + 1);
    match cmd {
        Cmd::TeachSet => {
            let s = lock(&hub.status)
                .clone()
                .ok_or("no status from the controller yet")?;
            t.points.push(crate::link::view::StatusView::new(&s).pose);
            Ok(format!("P{} set", t.points.len()))
        }
        Cmd::TeachRemove { index } if index < n => {
            t.points.remove(index);
            t.next = None;
            Ok(format!("P{} removed", index + 1))
        }
        Cmd::TeachMove { index, to } if index < n && to < n => {
            let p = t.points.remove(index);
            t.points.insert(to, p);
            t.next = None;
            Ok(format!("P{} moved to {}", index + 1, to + 1))
        }
        Cmd::TeachRemove { index } | Cmd::TeachMove { index, .. } => Err(bad_index(index)),
        Cmd::TeachSpeed { speed } if speed.is_finite() && speed > 0.0 => {
            t.speed = speed;
            Ok(format!("speed {speed} mm/min"))
        }
        Cmd::TeachSpeed { speed } => Err(format!("teach: speed {speed}: must be positive")),
        Cmd::TeachClear => {
            t.points.clear();
            t.next = None;
            Ok("cleared".into())
        }
        Cmd::TeachLoad { name, text } => {
            let (points, speed) = super::program::teach_points(&name, &text, &app.machine)?;
            t.points = points;
            t.next = None;
            if let Some(s) = speed {
                t.speed = s;
            }
            Ok(format!("{name}: {} positions", t.points.len()))
        }
        _ => Err("not a teach command".into()),
    }
}
