#![allow(dead_code)] // shared by several test binaries, each using a part
//! Harness of the operator-station tests: the simulator and the station as child
//! processes, chromedriver, and a page driven through WebDriver.

use fantoccini::actions::{InputSource, MouseActions, PointerAction, MOUSE_BUTTON_LEFT};
use fantoccini::{Client, ClientBuilder, Locator};
use serde_json::{json, Value};
use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A child process killed when dropped.
pub struct Proc(pub Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// How long to wait for a condition.
#[derive(Clone, Copy)]
pub enum Timeout {
    S(u64),
}

/// Where Chromium and its WebDriver are, if installed.
fn browser() -> Option<(PathBuf, PathBuf)> {
    let find = |names: &[&str]| {
        names.iter().find_map(|n| {
            std::env::var_os("PATH").and_then(|paths| {
                std::env::split_paths(&paths)
                    .map(|d| d.join(n))
                    .find(|p| p.is_file())
            })
        })
    };
    Some((
        find(&["chromium", "chromium-browser"])?,
        find(&["chromedriver"])?,
    ))
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// The first line a child prints on stdout.
fn first_line(child: &mut Child, what: &str) -> String {
    let mut line = String::new();
    std::io::BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap_or_else(|e| panic!("{what}: {e}"));
    assert!(!line.trim().is_empty(), "{what} printed nothing");
    line.trim().to_string()
}

/// One station and its browsers at a time: each test runs a simulator in real time, a
/// station and one or two browsers, and two such at once on a small machine make
/// each other's page loads time out.
static ONE_AT_A_TIME: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// The simulator, the station in front of it, and chromedriver.
pub struct Station {
    /// The page's address as the station printed it.
    pub url: String,
    machine: PathBuf,
    port: String,
    serve: Option<Proc>,
    /// `pkmc-sim` (none: the station runs nc-send's own simulator, `--sim`).
    _sim: Option<Proc>,
    driver: Proc,
    driver_port: u16,
    chromium: PathBuf,
    profiles: Vec<tempdir::Dir>,
    _turn: tokio::sync::MutexGuard<'static, ()>,
}

mod tempdir {
    /// A browser's profile directory: the browser using it is ended and the directory
    /// removed when dropped (chromedriver's end does not end its browsers, nor does a
    /// failed test close its sessions).
    pub struct Dir(pub std::path::PathBuf);
    impl Drop for Dir {
        fn drop(&mut self) {
            let _ = std::process::Command::new("pkill")
                .args(["-f", "--"])
                .arg(format!("--user-data-dir={}", self.0.display()))
                .status();
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

impl Station {
    /// Starts everything for the machine file `machine` (relative to the repository).
    pub async fn start(machine: &str) -> Station {
        Self::start_with(machine, &[]).await
    }

    /// [`Station::start`] with more arguments for `nc-send serve`.
    pub async fn start_with(machine: &str, serve_args: &[&str]) -> Station {
        Self::launch(machine, None, serve_args).await
    }

    /// The station on nc-send's own simulator (`nc-send --sim ARGS serve`, keeping
    /// real time), with `sim_args` for it (a simulated probe: `--probe-plane Z`).
    pub async fn start_sim(machine: &str, sim_args: &[&str]) -> Station {
        Self::launch(machine, Some(sim_args), &[]).await
    }

    async fn launch(machine: &str, sim_args: Option<&[&str]>, serve_args: &[&str]) -> Station {
        // Without a browser the build script marks these tests ignored
        // (host-tools/build.rs): one that runs and finds none fails.
        let Some((chromium, chromedriver)) = browser() else {
            panic!(
                "no chromium and chromedriver on PATH (Debian: apt-get install chromium \
                 chromium-driver); the operator-station tests need a real browser"
            );
        };
        let turn = ONE_AT_A_TIME.lock().await;
        let machine = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("..")
            .join(machine);
        let (sim, port, target) = match sim_args {
            None => {
                let mut sim = Command::new(env!("CARGO_BIN_EXE_pkmc-sim"))
                    .arg("--machine")
                    .arg(&machine)
                    .arg("--real-time")
                    .stdout(Stdio::piped())
                    .spawn()
                    .unwrap();
                let port = first_line(&mut sim, "pkmc-sim");
                let target = vec!["--port".to_string(), port.clone()];
                (Some(Proc(sim)), port, target)
            }
            Some(args) => {
                let mut target = vec!["--sim".to_string()];
                target.extend(args.iter().map(|a| a.to_string()));
                (None, String::new(), target)
            }
        };
        let mut serve = Command::new(env!("CARGO_BIN_EXE_nc-send"))
            .args(&target)
            .arg("--machine")
            .arg(&machine)
            .args(["serve", "--listen", "127.0.0.1:0"])
            .args(serve_args)
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let url = first_line(&mut serve, "nc-send serve");
        let driver_port = free_port();
        let driver = Proc(
            Command::new(chromedriver)
                .arg(format!("--port={driver_port}"))
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .unwrap(),
        );
        let t = Instant::now();
        while std::net::TcpStream::connect(("127.0.0.1", driver_port)).is_err() {
            assert!(
                t.elapsed() < Duration::from_secs(20),
                "chromedriver did not start"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        Station {
            machine,
            port,
            url,
            serve: Some(Proc(serve)),
            _sim: sim,
            driver,
            driver_port,
            chromium,
            profiles: Vec::new(),
            _turn: turn,
        }
    }

    /// A new browser (its own profile) on the station's page, as `name`.
    pub async fn page(&mut self, name: &str) -> Page {
        let profile = std::env::temp_dir().join(format!(
            "pkmc-chromium-{}-{}-{name}",
            std::process::id(),
            self.profiles.len()
        ));
        std::fs::create_dir_all(profile.join("downloads")).unwrap();
        let args = json!([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--window-size=1400,900",
            format!("--user-data-dir={}", profile.display()),
        ]);
        let downloads = profile.join("downloads");
        self.profiles.push(tempdir::Dir(profile));
        let mut caps = serde_json::Map::new();
        caps.insert(
            "goog:chromeOptions".into(),
            json!({"binary": self.chromium, "args": args,
                   "prefs": {"download.default_directory": downloads,
                             "download.prompt_for_download": false}}),
        );
        let connector = hyper_util::client::legacy::connect::HttpConnector::new();
        let client = ClientBuilder::new(connector)
            .capabilities(caps)
            .connect(&format!("http://127.0.0.1:{}", self.driver_port))
            .await
            .expect("a WebDriver session");
        let sep = if self.url.contains('?') { '&' } else { '?' };
        let url = format!("{}{sep}name={name}", self.url);
        client
            .goto(&url)
            .await
            .unwrap_or_else(|e| panic!("{url}: {e}"));
        let _ = &self.driver;
        Page {
            client,
            downloads: self.profiles.last().unwrap().0.join("downloads"),
        }
    }

    /// Stops the station (Ctrl-C), waits for it to let go of the controller, and asks
    /// the controller for its status with `nc-send status`.
    pub async fn status_after_stopping_the_station(&mut self) -> Value {
        assert!(
            self._sim.is_some(),
            "the station runs its own simulator: no controller is left to ask"
        );
        if let Some(mut p) = self.serve.take() {
            // SAFETY: a plain signal to our own child.
            unsafe { libc::kill(p.0.id() as i32, libc::SIGINT) };
            let t = Instant::now();
            while p.0.try_wait().unwrap().is_none() {
                assert!(
                    t.elapsed() < Duration::from_secs(10),
                    "the station did not stop"
                );
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        }
        let out = Command::new(env!("CARGO_BIN_EXE_nc-send"))
            .args(["--port", &self.port, "--machine"])
            .arg(&self.machine)
            .args(["status", "--report", "json"])
            .output()
            .unwrap();
        assert!(out.status.success(), "nc-send status: {out:?}");
        serde_json::from_slice(&out.stdout).unwrap()
    }
}

/// A page in its own browser.
pub struct Page {
    client: Client,
    /// Where its browser saves downloads.
    pub downloads: PathBuf,
}

impl Page {
    /// The value of a JavaScript expression.
    pub async fn js(&self, expr: &str) -> Value {
        self.client
            .execute(&format!("return {expr};"), vec![])
            .await
            .unwrap_or_else(|e| panic!("{expr}: {e}"))
    }

    /// Waits until `expr` is truthy; returns its value. A timeout names `what` and
    /// shows the page's last status and log.
    pub async fn wait(&self, expr: &str, what: &str, timeout: Timeout) -> Value {
        let Timeout::S(s) = timeout;
        let t = Instant::now();
        let guarded =
            format!("(() => {{ try {{ return {expr}; }} catch (e) {{ return null; }} }})()");
        loop {
            let v = self.js(&guarded).await;
            let truthy = match &v {
                Value::Null => false,
                Value::Bool(b) => *b,
                Value::Number(n) => n.as_f64() != Some(0.0),
                Value::String(s) => !s.is_empty(),
                _ => true,
            };
            if truthy {
                return v;
            }
            if t.elapsed() > Duration::from_secs(s) {
                let st = self
                    .js("JSON.stringify(pkmc.lastStatus && Object.assign({}, pkmc.lastStatus, {scene: null}))")
                    .await;
                let log = self.js("JSON.stringify(pkmc.log.slice(-8))").await;
                panic!("timed out after {s} s waiting for: {what}\n  ({expr})\n  status {st}\n  log {log}");
            }
            tokio::time::sleep(Duration::from_millis(40)).await;
        }
    }

    /// Waits until the machine is idle with no job.
    pub async fn wait_idle(&self, timeout: Timeout) {
        self.wait(
            "pkmc.lastStatus && pkmc.lastStatus.state === 'Idle' && !pkmc.lastStatus.job",
            "the machine is idle",
            timeout,
        )
        .await;
    }

    /// Waits until the machine moves.
    pub async fn wait_moving(&self, what: &str) {
        self.wait(
            "pkmc.lastStatus.state === 'Running' && pkmc.lastStatus.feed > 0",
            what,
            Timeout::S(5),
        )
        .await;
    }

    /// Clicks a button that starts a motion and waits until it is over.
    pub async fn click_and_wait_idle(&self, css: &str, timeout: Timeout) {
        self.click(css).await;
        // The command reaches the machine thread before the status shows its job.
        tokio::time::sleep(Duration::from_millis(150)).await;
        self.wait_idle(timeout).await;
    }

    /// Reset: a controller locked after its reset is unlocked where it stands.
    pub async fn unlock(&self) {
        self.click("#reset").await;
        self.wait(
            "pkmc.lastStatus.state === 'Idle' && !pkmc.lastStatus.alarm",
            "the reset unlocks",
            Timeout::S(5),
        )
        .await;
    }

    /// Types an MDI line and sends it.
    pub async fn mdi(&self, line: &str) {
        self.type_into("#mdi", line).await;
        self.click("#mdi-send").await;
    }

    /// Waits until the machine has stopped, idle or in an alarm.
    pub async fn wait_idle_or_alarm(&self) {
        self.wait(
            "pkmc.lastStatus && ['Idle', 'Alarm'].includes(pkmc.lastStatus.state) && !pkmc.lastStatus.job",
            "the machine stops",
            Timeout::S(5),
        )
        .await;
    }

    async fn find(&self, css: &str) -> fantoccini::elements::Element {
        self.client
            .find(Locator::Css(css))
            .await
            .unwrap_or_else(|e| panic!("{css}: {e}"))
    }

    pub async fn click(&self, css: &str) {
        self.find(css)
            .await
            .click()
            .await
            .unwrap_or_else(|e| panic!("click {css}: {e}"));
    }

    /// Types `text` into a field after clearing it.
    pub async fn type_into(&self, css: &str, text: &str) {
        let e = self.find(css).await;
        e.clear().await.unwrap();
        e.send_keys(text).await.unwrap();
    }

    pub async fn select(&self, css: &str, value: &str) {
        self.find(css)
            .await
            .select_by_value(value)
            .await
            .unwrap_or_else(|e| panic!("select {value} in {css}: {e}"));
    }

    /// Chooses `file` in a file input.
    pub async fn upload(&self, css: &str, file: &Path) {
        let path = file.canonicalize().unwrap();
        self.find(css)
            .await
            .send_keys(&path.display().to_string())
            .await
            .unwrap();
    }

    /// Presses the mouse button on an element and keeps it down.
    pub async fn press(&self, css: &str) {
        let r = self
            .js(&format!(
                "(() => {{ const r = document.querySelector(\"{css}\").getBoundingClientRect(); \
                 return [r.x + r.width / 2, r.y + r.height / 2]; }})()"
            ))
            .await;
        let (x, y) = (r[0].as_f64().unwrap(), r[1].as_f64().unwrap());
        let down = MouseActions::new("mouse".into())
            .then(PointerAction::MoveTo {
                duration: None,
                x: x.round(),
                y: y.round(),
            })
            .then(PointerAction::Down {
                button: MOUSE_BUTTON_LEFT,
            });
        self.client.perform_actions(down).await.unwrap();
    }

    /// Presses the mouse button at the first point (viewport pixels), moves through
    /// the others, and lets go at the last: a click when there is one point, a drag
    /// otherwise.
    pub async fn pointer_path(&self, points: &[(f64, f64)]) {
        let mut a = MouseActions::new("mouse".into());
        for (i, &(x, y)) in points.iter().enumerate() {
            a = a.then(PointerAction::MoveTo {
                duration: (i > 0).then(|| Duration::from_millis(60)),
                x: x.round(),
                y: y.round(),
            });
            if i == 0 {
                a = a.then(PointerAction::Down {
                    button: MOUSE_BUTTON_LEFT,
                });
            }
        }
        a = a.then(PointerAction::Up {
            button: MOUSE_BUTTON_LEFT,
        });
        self.client.perform_actions(a).await.unwrap();
    }

    /// Lets the mouse button go.
    pub async fn release(&self) {
        let up = MouseActions::new("mouse".into()).then(PointerAction::Up {
            button: MOUSE_BUTTON_LEFT,
        });
        self.client.perform_actions(up).await.unwrap();
    }

    /// Presses keys on the element (`\u{e014}` is the right arrow).
    pub async fn keys(&self, css: &str, keys: &str) {
        self.find(css).await.send_keys(keys).await.unwrap();
    }

    /// Sets the browser window so that the page's viewport is `w` × `h` CSS pixels
    /// (checked against the page's own `innerWidth` and `innerHeight`).
    pub async fn set_viewport(&self, w: u32, h: u32) {
        self.client.set_window_size(w, h).await.unwrap();
        let got = self.js("[window.innerWidth, window.innerHeight]").await;
        let (iw, ih) = (got[0].as_i64().unwrap(), got[1].as_i64().unwrap());
        if (iw, ih) != (w as i64, h as i64) {
            let (dw, dh) = (w as i64 - iw, h as i64 - ih);
            self.client
                .set_window_size((w as i64 + dw) as u32, (h as i64 + dh) as u32)
                .await
                .unwrap();
        }
        let got = self.js("[window.innerWidth, window.innerHeight]").await;
        assert_eq!(
            (got[0].as_i64().unwrap(), got[1].as_i64().unwrap()),
            (w as i64, h as i64),
            "the viewport"
        );
    }

    /// Presses `key` (a WebDriver key code, e.g. `\u{e014}` for the right arrow)
    /// with the modifier keys `mods` held, on whatever has the focus.
    pub async fn key_with(&self, mods: &[char], key: char) {
        use fantoccini::actions::{KeyAction, KeyActions};
        let mut a = KeyActions::new("keyboard".into());
        for &m in mods {
            a = a.then(KeyAction::Down { value: m });
        }
        a = a
            .then(KeyAction::Down { value: key })
            .then(KeyAction::Up { value: key });
        for &m in mods.iter().rev() {
            a = a.then(KeyAction::Up { value: m });
        }
        self.client.perform_actions(a).await.unwrap();
    }

    /// Saves the page as a PNG. `to` is its place in the docs, written only when
    /// `PKMC_UPDATE_SCREENSHOTS` is set; otherwise it goes under the same name to the
    /// tests' temporary directory, so that a test run leaves the tree as it was.
    pub async fn screenshot(&self, to: &Path) {
        let png = self.client.screenshot().await.unwrap();
        assert!(
            png.starts_with(b"\x89PNG"),
            "the browser's screenshot is not a PNG"
        );
        let to = if std::env::var_os("PKMC_UPDATE_SCREENSHOTS").is_some() {
            to.to_path_buf()
        } else {
            let dir = std::env::temp_dir().join(format!("pkmc-tests-{}", std::process::id()));
            std::fs::create_dir_all(&dir).unwrap();
            dir.join(to.file_name().expect("a file name"))
        };
        std::fs::write(&to, png).unwrap();
    }

    /// Closes the browser (its page goes with it, whatever is held down).
    pub async fn close(self) {
        let _ = self.client.close().await;
    }
}
