//! The operator station end to end in a real browser: `pkmc-sim` (real time) on a
//! pseudo-terminal, `nc-send --port PTY serve` in front of it, and headless Chromium
//! driven through WebDriver (chromedriver, by fantoccini). The page is clicked and
//! typed into as an operator would; what it shows is compared with `nc-send status`
//! on the same controller once the station has let go of it.
//!
//! Needs Debian's `chromium` and `chromium-driver` (`.ci/run` installs them); where
//! they are missing each test says so and passes without running.
//! Screenshots: `docs/ui-h4.png` and `docs/ui-hexapod.png`, written there with
//! `PKMC_UPDATE_SCREENSHOTS=1` (docs/ui.md).

mod station;

use serde_json::Value;
use station::{Page, Station, Timeout};
use std::path::Path;
use std::time::Duration;

const H4: &str = "examples/machines/h4-table.toml";
const HEXAPOD: &str = "examples/machines/hexapod.toml";

fn repo(p: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(p)
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

/// The page's pose and joints as its DRO shows them (the numbers on the screen).
async fn dro(page: &Page) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let v = page
        .js(
            "(() => { const n = id => parseFloat(document.getElementById(id).textContent); \
             const rows = [...document.querySelectorAll('#dro-joints tr[data-joint]')]; \
             return { pose: ['x','y','z','a','b','c'].map(a => n('dro-' + a)), \
             cmd: rows.map(r => parseFloat(r.querySelector('td.cmd').textContent)), \
             meas: rows.map(r => parseFloat(r.querySelector('td.meas').textContent)) }; })()",
        )
        .await;
    let nums = |k: &str| -> Vec<f64> {
        v[k].as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap_or(f64::NAN))
            .collect()
    };
    (nums("pose"), nums("cmd"), nums("meas"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[cfg_attr(
    pkmc_no_browser,
    ignore = "needs Chromium and chromedriver on PATH (Debian: chromium, chromium-driver)"
)]
async fn h4_page_marks_errors_runs_holds_resumes_jogs_teaches_and_agrees_with_nc_send_status() {
    let mut st = Station::start(H4).await;
    let page = st.page("operator").await;
    page.wait(
        "pkmc.machine && pkmc.lastStatus && pkmc.lock && pkmc.lock.holder === pkmc.you",
        "the page connects and takes control",
        Timeout::S(10),
    )
    .await;

    // A broken program: the error is marked at its line and column before anything runs.
    let dir = std::env::temp_dir().join(format!("pkmc-ui-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let broken = dir.join("broken.ngc");
    std::fs::write(
        &broken,
        "G21 G90\nG0 X0 Y0 Z-70\nG1 X10 Y5 F600\nG1 X12 Q3\nM2\n",
    )
    .unwrap();
    page.upload("#file", &broken).await;
    page.wait(
        "pkmc.program && pkmc.program.name === 'broken.ngc'",
        "the broken program loads",
        Timeout::S(10),
    )
    .await;
    let err = page
        .wait(
            "(() => { const e = document.querySelector('#errors li.error'); \
         return e && [e.dataset.line, e.dataset.col, e.textContent]; })()",
            "an error is listed",
            Timeout::S(5),
        )
        .await;
    assert_eq!(err[0], "4", "error line: {err}");
    assert_eq!(err[1], "8", "error column (the Q word): {err}");
    assert!(err[2].as_str().unwrap().contains("Q word"), "{err}");
    page.wait(
        "document.querySelector('#gutter [data-line=\"4\"]').classList.contains('err')",
        "line 4 is marked in the gutter",
        Timeout::S(2),
    )
    .await;
    page.wait(
        "document.getElementById('run').disabled",
        "Run is disabled with an error",
        Timeout::S(2),
    )
    .await;
    // In the editor, a line under the word at line 4, column 8 ("Q3"): where the
    // browser's own text layout puts those characters (measured in a copy of the line
    // in the editor's font).
    let placed = page
        .wait(
            "(() => { const m = document.querySelector('#marks .mark[data-line=\"4\"][data-col=\"8\"]'); \
             if (!m) return null; const ed = document.getElementById('editor'); \
             const cs = getComputedStyle(ed); const pre = document.createElement('pre'); \
             pre.style.cssText = `position:absolute;margin:0;padding:0;font:${cs.font};white-space:pre`; \
             pre.textContent = ed.value.split('\\n')[3]; document.body.appendChild(pre); \
             const r = document.createRange(); r.setStart(pre.firstChild, 7); r.setEnd(pre.firstChild, 9); \
             const q = r.getBoundingClientRect(), p0 = pre.getBoundingClientRect(); pre.remove(); \
             const e = ed.getBoundingClientRect(), b = m.getBoundingClientRect(); \
             const x = b.left - e.left - parseFloat(cs.paddingLeft) - ed.clientLeft; \
             const y = b.top - e.top - parseFloat(cs.paddingTop) - ed.clientTop; \
             return [x, q.left - p0.left, b.width, q.width, y, parseFloat(cs.lineHeight)]; })()",
            "the error is marked at its column in the editor",
            Timeout::S(2),
        )
        .await;
    let v = |i: usize| placed[i].as_f64().unwrap();
    assert!(
        (v(0) - v(1)).abs() < 1.0,
        "mark starts at x {} where column 8 is at {}",
        v(0),
        v(1)
    );
    assert!(
        (v(2) - v(3)).abs() < 1.0,
        "mark {} px wide, the word {} px",
        v(2),
        v(3)
    );
    assert!(
        v(4) > 3.0 * v(5) && v(4) < 4.0 * v(5) + 1.0,
        "mark at y {} is not under line 4",
        v(4)
    );

    // A controller after its reset is locked until homed: Home.
    page.click("#home").await;
    page.wait(
        "pkmc.lastStatus.homed && pkmc.lastStatus.state === 'Idle' && !pkmc.lastStatus.job",
        "the machine homes",
        Timeout::S(60),
    )
    .await;

    // The example program: checked (dry run) and run, held, resumed.
    page.upload("#file", &repo("examples/h4-table-tilt.ngc"))
        .await;
    page.wait(
        "pkmc.program && pkmc.program.name === 'h4-table-tilt.ngc' && pkmc.program.check \
        && pkmc.program.errors.length === 0 && !document.getElementById('run').disabled",
        "the example loads and its dry run ends",
        Timeout::S(30),
    )
    .await;
    let margin = page
        .js("document.getElementById('margin').textContent")
        .await;
    assert!(
        margin.as_str().unwrap().contains("line"),
        "singularity margin shown: {margin}"
    );
    page.click("#run").await;
    page.wait(
        "pkmc.lastStatus.state === 'Running' && pkmc.lastStatus.line >= 4",
        "the program runs",
        Timeout::S(10),
    )
    .await;
    tokio::time::sleep(Duration::from_millis(700)).await;
    page.click("#hold").await;
    page.wait(
        "pkmc.lastStatus.state === 'Hold' && pkmc.lastStatus.feed === 0",
        "the hold stops the machine",
        Timeout::S(5),
    )
    .await;
    let held = page.js("pkmc.lastStatus.pose").await;
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert_eq!(
        page.js("pkmc.lastStatus.pose").await,
        held,
        "nothing moves while held"
    );
    page.click("#resume").await;
    page.wait_moving("the program resumes").await;
    tokio::time::sleep(Duration::from_millis(600)).await;
    page.screenshot(&repo("docs/ui-h4.png")).await;
    page.wait_idle(Timeout::S(30)).await;
    // The station logs the end once the job's stream returns, which may be after the
    // controller's idle status has reached the page (and later still under load).
    page.wait(
        "pkmc.log.some(e => e.text === 'program done')",
        "the end is logged",
        Timeout::S(5),
    )
    .await;
    let end = page.js("pkmc.lastStatus.pose").await;
    for (i, want) in [-10.0, -10.0, -60.0, 30.0, 0.0, -10.0].iter().enumerate() {
        assert!(
            close(end[i].as_f64().unwrap(), *want, 0.001),
            "program end pose {end}"
        );
    }

    // Jog by a step, and MDI.
    page.click("button.jog[data-axis='X'][data-dir='1']").await;
    page.wait(
        "Math.abs(pkmc.lastStatus.pose[0] - (-9)) < 0.0005 && pkmc.lastStatus.state === 'Idle'",
        "X+ jogs by the 1 mm step",
        Timeout::S(10),
    )
    .await;
    page.wait_idle(Timeout::S(5)).await;
    page.mdi("G1 X0 Y0 Z-70 A10 C0 F1500").await;
    page.wait("Math.abs(pkmc.lastStatus.pose[0]) < 0.0005 && Math.abs(pkmc.lastStatus.pose[2] + 70) < 0.0005 \
        && Math.abs(pkmc.lastStatus.pose[3] - 10) < 0.0005", "the MDI line moves", Timeout::S(15)).await;
    page.wait_idle(Timeout::S(5)).await;

    // Teach three positions, move away, and run them by step.
    page.click("#teach-clear").await;
    let mut taught = Vec::new();
    for (axis, dir) in [("Y", "1"), ("Z", "-1"), ("X", "-1")] {
        page.select("#jog-step", "10").await;
        page.click_and_wait_idle(
            &format!("button.jog[data-axis='{axis}'][data-dir='{dir}']"),
            Timeout::S(10),
        )
        .await;
        taught.push(page.js("pkmc.lastStatus.pose").await);
        page.click("#teach-set").await;
        let n = taught.len();
        page.wait(
            &format!("pkmc.teach && pkmc.teach.points.length === {n}"),
            "the position is set",
            Timeout::S(5),
        )
        .await;
    }
    page.type_into("#teach-speed", "1800\t").await;
    page.wait(
        "pkmc.teach.speed === 1800",
        "the teach speed is set",
        Timeout::S(5),
    )
    .await;
    page.click_and_wait_idle("button.jog[data-axis='X'][data-dir='1']", Timeout::S(10))
        .await;
    for (i, want) in taught.iter().enumerate() {
        page.click("#teach-step").await;
        let cond = format!(
            "pkmc.lastStatus.state === 'Idle' && !pkmc.lastStatus.job && \
             pkmc.lastStatus.pose.every((v, k) => Math.abs(v - {want}[k]) < 0.0005)"
        );
        page.wait(
            &cond,
            &format!("Run by Step reaches P{}", i + 1),
            Timeout::S(15),
        )
        .await;
    }

    // The servos settle after the move ends (Idle comes with the command, not the feedback):
    // read the page once its measured joints are within 2 µm of the commanded ones, as they are
    // when `nc-send status` reads them after the station stops.
    page.wait(
        "(pkmc.lastStatus.measured || []).length > 0 && \
         pkmc.lastStatus.measured.every((m, k) => Math.abs(m - pkmc.lastStatus.joints[k]) <= 0.0025)",
        "the servos settle on the taught point",
        Timeout::S(10),
    )
    .await;
    // The page's numbers against `nc-send status` on the same controller.
    let (pose, cmd, meas) = dro(&page).await;
    let status = st.status_after_stopping_the_station().await;
    let axes = ["x", "y", "z", "a", "b", "c"];
    for (k, a) in axes.iter().enumerate() {
        let s = status["pose"][a].as_f64().unwrap();
        assert!(
            close(pose[k], s, 0.0011),
            "{a}: page {} status {s}",
            pose[k]
        );
    }
    for (j, q) in cmd.iter().enumerate() {
        let s = status["joints"][j].as_f64().unwrap();
        assert!(close(*q, s, 0.0011), "joint {}: page {q} status {s}", j + 1);
        // A live reading: a servo holding its place dithers by a count or two (1 µm).
        let m = status["measured"][j].as_f64().unwrap();
        assert!(
            close(meas[j], m, 0.005),
            "joint {} measured: page {} status {m}",
            j + 1,
            meas[j]
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[cfg_attr(
    pkmc_no_browser,
    ignore = "needs Chromium and chromedriver on PATH (Debian: chromium, chromium-driver)"
)]
async fn hexapod_page_runs_moves_one_arm_shares_its_state_and_stops_a_jog_when_its_page_closes() {
    let mut st = Station::start(HEXAPOD).await;
    let first = st.page("first").await;
    first
        .wait(
            "pkmc.lastStatus && pkmc.lock && pkmc.lock.holder === pkmc.you",
            "the first page takes control",
            Timeout::S(10),
        )
        .await;
    let second = st.page("second").await;
    second
        .wait(
            "pkmc.lastStatus && pkmc.lock && pkmc.lock.name === 'first'",
            "the second page is told who holds control",
            Timeout::S(10),
        )
        .await;
    let lock_text = second
        .js("document.getElementById('lock').textContent")
        .await;
    assert!(lock_text.as_str().unwrap().contains("first"), "{lock_text}");

    // The second page may not command: its Reset is refused with the holder's name.
    second.click("#reset").await;
    second
        .wait(
            "pkmc.log.some(e => e.text.includes('first holds control'))",
            "the refusal names the holder",
            Timeout::S(5),
        )
        .await;

    // Unlocked where it stands (the simulated hexapod's drives are where it believes).
    first.unlock().await;

    // A program on the hexapod; both pages see the same state.
    first
        .upload("#file", &repo("examples/hexapod-orbit.ngc"))
        .await;
    first
        .wait(
            "pkmc.program && pkmc.program.check && !document.getElementById('run').disabled",
            "the program is checked",
            Timeout::S(30),
        )
        .await;
    first.click("#run").await;
    first
        .wait(
            "pkmc.lastStatus.state === 'Running' && pkmc.lastStatus.line >= 4",
            "the program runs",
            Timeout::S(10),
        )
        .await;
    tokio::time::sleep(Duration::from_millis(1500)).await;
    first.screenshot(&repo("docs/ui-hexapod.png")).await;
    first.wait_idle(Timeout::S(40)).await;
    second.wait_idle(Timeout::S(5)).await;
    let a = first.js("pkmc.lastStatus.pose").await;
    let b = second.js("pkmc.lastStatus.pose").await;
    assert_eq!(a, b, "two pages, one state");

    // Arm1 alone: +2 mm, the other legs stay.
    let before = first.js("pkmc.lastStatus.joints").await;
    first
        .type_into("#joint-distance", "\u{e009}a\u{e000}2")
        .await;
    first.select("#joint-select", "0").await;
    first
        .click_and_wait_idle("#joint-plus", Timeout::S(10))
        .await;
    let after = first.js("pkmc.lastStatus.joints").await;
    let leg = |v: &Value, j: usize| v[j].as_f64().unwrap();
    assert!(
        close(leg(&after, 0) - leg(&before, 0), 2.0, 0.002),
        "Arm1 {before} -> {after}"
    );
    for j in 1..6 {
        assert!(
            close(leg(&after, j), leg(&before, j), 0.002),
            "leg {} moved: {before} -> {after}",
            j + 1
        );
    }

    // Hold to jog, and the page freezes (its script busy for 4 s: no heartbeat, no
    // button released): the jog stops.
    first.click("#jog-continuous").await;
    first
        .press("button.jog[data-axis='Y'][data-dir='-1']")
        .await;
    second.wait_moving("the held jog moves").await;
    first.js("(setTimeout(() => { const t = performance.now(); while (performance.now() - t < 4000) {} }, 0), 1)").await;
    let frozen = std::time::Instant::now();
    second
        .wait(
            "pkmc.lastStatus.state === 'Idle' && pkmc.lastStatus.feed === 0",
            "the jog of a frozen page stops",
            Timeout::S(3),
        )
        .await;
    let stopped_after = frozen.elapsed();
    assert!(
        stopped_after < Duration::from_millis(3500),
        "stopped after {stopped_after:?}, while the page was still frozen"
    );
    first.release().await;
    first.wait_idle(Timeout::S(10)).await;

    // Hold to jog, then the page closes with the button still down: the jog stops.
    first.press("button.jog[data-axis='X'][data-dir='1']").await;
    second.wait_moving("the held jog moves").await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    first.close().await;
    second
        .wait(
            "pkmc.lastStatus.state === 'Idle' && pkmc.lastStatus.feed === 0",
            "the jog stops when its page closes",
            Timeout::S(3),
        )
        .await;
    let x = second.js("pkmc.lastStatus.pose[0]").await;
    tokio::time::sleep(Duration::from_millis(400)).await;
    assert_eq!(
        second.js("pkmc.lastStatus.pose[0]").await,
        x,
        "nothing moves after the stop"
    );
    second
        .wait(
            "pkmc.lock.holder === null || pkmc.lock.holder === pkmc.you",
            "the lock is freed",
            Timeout::S(3),
        )
        .await;
    second.click("#take").await;
    second
        .wait(
            "pkmc.lock.holder === pkmc.you",
            "the second page takes control",
            Timeout::S(3),
        )
        .await;
    let _ = st.status_after_stopping_the_station().await;
}

/// One raw HTTP request to the station; its status line.
fn http_status(url: &str, path_and_query: &str, extra_headers: &str) -> String {
    use std::io::{Read, Write};
    let host = url
        .trim_start_matches("http://")
        .split('/')
        .next()
        .unwrap()
        .to_string();
    let mut s = std::net::TcpStream::connect(&host).unwrap();
    write!(
        s,
        "GET {path_and_query} HTTP/1.1\r\nHost: {host}\r\n{extra_headers}Connection: close\r\n\r\n"
    )
    .unwrap();
    let mut out = String::new();
    let _ = s.read_to_string(&mut out);
    out.lines().next().unwrap_or("").to_string()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[cfg_attr(
    pkmc_no_browser,
    ignore = "needs Chromium and chromedriver on PATH (Debian: chromium, chromium-driver)"
)]
async fn cartesian_page_steps_overrides_stops_e_stops_saves_and_loads_teach_behind_a_token() {
    let mut st = Station::start_with(
        "examples/machines/cartesian-xyz.toml",
        &["--token", "s3cret"],
    )
    .await;
    // The token: nothing without it, and no socket for a page of another origin.
    assert!(st.url.ends_with("/?token=s3cret"), "{}", st.url);
    assert!(
        http_status(&st.url, "/", "").contains("401"),
        "page without the token"
    );
    let upgrade = "Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\n\
                   Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n";
    assert!(http_status(&st.url, "/ws?token=wrong", upgrade).contains("401"));
    let evil = format!("{upgrade}Origin: http://example.invalid\r\n");
    assert!(http_status(&st.url, "/ws?token=s3cret", &evil).contains("403"));
    assert!(http_status(&st.url, "/?token=s3cret", "").contains("200"));

    let page = st.page("op").await;
    page.wait(
        "pkmc.lastStatus && pkmc.lock && pkmc.lock.holder === pkmc.you",
        "the page takes control",
        Timeout::S(10),
    )
    .await;
    page.unlock().await;

    // A program typed into the editor, run by step: one block per press. It streams
    // 7 blocks when run (its three corners blended within G64's 1 µm), and steps
    // through its 4 moves as programmed.
    let text = "G21 G90\nG1 X10 F3000\nG1 Y10\nG1 X0\nG1 Y0\nM2\n";
    page.type_into("#editor", text).await;
    page.click("#load-editor").await;
    page.wait(
        "pkmc.program && pkmc.program.check && pkmc.program.blocks === 7",
        "the typed program loads",
        Timeout::S(20),
    )
    .await;
    page.click("#step").await;
    page.wait("Math.abs(pkmc.lastStatus.pose[0] - 10) < 0.0005 && pkmc.lastStatus.job && pkmc.lastStatus.job.step",
        "the first press runs the first block and waits", Timeout::S(10)).await;
    tokio::time::sleep(Duration::from_millis(400)).await;
    assert!(
        close(
            page.js("pkmc.lastStatus.pose[1]").await.as_f64().unwrap(),
            0.0,
            1e-6
        ),
        "no block without a press"
    );
    page.click("#step").await;
    page.wait("Math.abs(pkmc.lastStatus.pose[1] - 10) < 0.0005 && pkmc.lastStatus.job.step && pkmc.lastStatus.job.executed === 2",
        "the second press runs the second block", Timeout::S(10)).await;
    page.click("#stop").await;
    page.wait_idle(Timeout::S(5)).await;
    assert!(
        close(
            page.js("pkmc.lastStatus.pose[0]").await.as_f64().unwrap(),
            10.0,
            1e-6
        ),
        "Stop ends run by step"
    );

    // Feed override from the slider (keyboard), then Stop mid-run.
    let slow = "G21 G90\nG1 X100 F600\nG1 X0\nM2\n";
    page.type_into("#editor", slow).await;
    page.click("#load-editor").await;
    page.wait(
        "pkmc.program && pkmc.program.check && pkmc.program.blocks === 2",
        "the slow program loads",
        Timeout::S(20),
    )
    .await;
    page.click("#run").await;
    page.wait_moving("it runs").await;
    page.keys("#override", "\u{e014}\u{e014}\u{e014}\u{e014}")
        .await;
    page.wait(
        "pkmc.lastStatus.override === 120 && Math.abs(pkmc.lastStatus.feed - 720) < 2",
        "the override speeds the feed to 120 %",
        Timeout::S(5),
    )
    .await;
    let eta = page.js("pkmc.lastStatus.job.eta_s").await;
    assert!(
        eta.as_f64().is_some_and(|e| e > 0.0),
        "an ETA while it runs: {eta}"
    );
    page.click("#stop").await;
    page.wait_idle(Timeout::S(5)).await;
    let x = page.js("pkmc.lastStatus.pose[0]").await.as_f64().unwrap();
    assert!(x > 0.0 && x < 100.0, "stopped on the way: X {x}");

    // E-stop: the motion ends at once, the alarm names its cause; Reset clears it.
    page.click("#run").await;
    page.wait_moving("it runs again").await;
    page.click("#estop").await;
    page.wait("pkmc.lastStatus.state === 'Alarm' && document.getElementById('alarm').textContent.startsWith('E-STOP')",
        "the e-stop raises an alarm shown as an e-stop", Timeout::S(5)).await;
    page.wait_idle_or_alarm().await;
    page.unlock().await;

    // MDI keeps its modal state from line to line: G91 and F hold for the next line.
    let x0 = page.js("pkmc.lastStatus.pose[0]").await.as_f64().unwrap();
    page.mdi("G91 G1 X2 F900").await;
    page.wait(&format!("Math.abs(pkmc.lastStatus.pose[0] - {}) < 0.0005 && pkmc.lastStatus.state === 'Idle' && !pkmc.lastStatus.job", x0 + 2.0),
        "the first MDI line moves 2 mm", Timeout::S(10)).await;
    page.mdi("X2").await;
    page.wait(&format!("Math.abs(pkmc.lastStatus.pose[0] - {}) < 0.0005 && pkmc.lastStatus.state === 'Idle' && !pkmc.lastStatus.job", x0 + 4.0),
        "the second, still G91 G1 at F900, 2 mm more", Timeout::S(10)).await;
    page.mdi("G90").await;

    // The teach list saved as G-code by the browser, cleared, and loaded back.
    page.click("#teach-clear").await;
    for (axis, n) in [("X", 1), ("Y", 2)] {
        page.click_and_wait_idle(
            &format!("button.jog[data-axis='{axis}'][data-dir='1']"),
            Timeout::S(10),
        )
        .await;
        page.click("#teach-set").await;
        page.wait(
            &format!("pkmc.teach && pkmc.teach.points.length === {n}"),
            "set",
            Timeout::S(5),
        )
        .await;
    }
    let taught = page.js("pkmc.teach.points.map(p => p.pose)").await;
    page.click("#teach-save").await;
    let saved = page.downloads.join("teach.ngc");
    let t = std::time::Instant::now();
    while !saved.is_file()
        || std::fs::read_to_string(&saved)
            .unwrap_or_default()
            .is_empty()
    {
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "the browser saved no teach.ngc"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let gcode = std::fs::read_to_string(&saved).unwrap();
    assert_eq!(
        gcode.lines().filter(|l| l.starts_with("G1 ")).count(),
        2,
        "{gcode}"
    );
    page.click("#teach-clear").await;
    page.wait("pkmc.teach.points.length === 0", "cleared", Timeout::S(5))
        .await;
    page.upload("#teach-load", &saved).await;
    page.wait(
        "pkmc.teach.points.length === 2",
        "loaded back",
        Timeout::S(5),
    )
    .await;
    assert_eq!(
        page.js("pkmc.teach.points.map(p => p.pose)").await,
        taught,
        "{gcode}"
    );

    // Reorder (P2 up), Run all: the machine ends on the last, which is now P1; remove.
    page.click("#teach-list li[data-index='1'] .up").await;
    page.wait(&format!("JSON.stringify(pkmc.teach.points.map(p => p.pose)) === JSON.stringify([{t}[1], {t}[0]])", t = taught),
        "P2 moves up", Timeout::S(5)).await;
    page.click_and_wait_idle("#teach-run", Timeout::S(15)).await;
    let end = page.js("pkmc.lastStatus.pose").await;
    for k in 0..6 {
        let (a, b) = (end[k].as_f64().unwrap(), taught[0][k].as_f64().unwrap());
        assert!(
            close(a, b, 0.0005),
            "Run all ends on the last position: {end} vs {}",
            taught[0]
        );
    }
    page.click("#teach-list li[data-index='0'] .remove").await;
    page.wait(
        "pkmc.teach.points.length === 1",
        "a position is removed",
        Timeout::S(5),
    )
    .await;

    // Hold to jog: moves while held, stops on release.
    page.click("#jog-continuous").await;
    page.press("button.jog[data-axis='Y'][data-dir='1']").await;
    page.wait_moving("the held jog moves").await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    page.release().await;
    page.wait_idle(Timeout::S(3)).await;
    let _ = st.status_after_stopping_the_station().await;
}

/// The page during a whole 3D_Chips run on the H-4 (from the shared corpus): how often
/// statuses arrive and how long frames take, as the page itself measures them
/// (`pkmc.stats`). A report, not a timed test: run it with
/// `cargo test -p pkmc-host --release --test operator_station -- --ignored --nocapture`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "a report of about two minutes; .ci/run runs it"]
async fn report_page_responsiveness_during_3d_chips() {
    let program = repo("../shared/corpus/linuxcnc/3D_Chips.ngc");
    if !program.is_file() {
        eprintln!(
            "SKIPPED: {} is not there (the shared corpus)",
            program.display()
        );
        return;
    }
    let mut st = Station::start(H4).await;
    let page = st.page("report").await;
    page.wait(
        "pkmc.lastStatus && pkmc.lock && pkmc.lock.holder === pkmc.you",
        "the page takes control",
        Timeout::S(10),
    )
    .await;
    page.unlock().await;
    page.upload("#file", &program).await;
    page.wait("pkmc.program && pkmc.program.name === '3D_Chips.ngc' && pkmc.program.check && !document.getElementById('run').disabled",
        "3D_Chips is checked", Timeout::S(300)).await;
    let planned = page.js("pkmc.program.check.run_time_s").await;
    page.click("#run").await;
    page.wait("pkmc.lastStatus.job", "it starts", Timeout::S(10))
        .await;
    let start = page.js("[performance.now(), pkmc.stats.frames.length, pkmc.stats.status.length, pkmc.stats.draw.length, pkmc.stats.handle.length, pkmc.stats.longtasks.length]").await;
    // The program pauses for its tool changes (M6) and M0: the operator resumes.
    let t = std::time::Instant::now();
    let mut resumed = 0;
    loop {
        let s = page
            .js("[pkmc.lastStatus.state, !!pkmc.lastStatus.job, pkmc.lastStatus.feed]")
            .await;
        if s[0] == "Idle" && s[1] == false {
            break;
        }
        if s[0] == "Hold" && s[2] == 0 {
            page.click("#resume").await;
            resumed += 1;
        }
        assert!(
            t.elapsed() < Duration::from_secs(600),
            "3D_Chips did not end: {s}"
        );
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    let r = page
        .js(&format!(
            "(() => {{ const s = {start}; const t = performance.now() - s[0]; \
             const f = pkmc.stats.frames.slice(s[1]).sort((a, b) => a - b); \
             const d = pkmc.stats.draw.slice(s[3]).sort((a, b) => a - b); \
             const st = pkmc.stats.status.slice(s[2]); \
             const h = pkmc.stats.handle.slice(s[4]).sort((a, b) => a - b); \
             const lt = pkmc.stats.longtasks.slice(s[5]).sort((a, b) => a - b); \
             let gap = 0; for (let i = 1; i < st.length; i++) gap = Math.max(gap, st[i] - st[i - 1]); \
             const q = (a, p) => a.length ? a[Math.min(a.length - 1, Math.floor(p * a.length))] : null; \
             return {{ run_s: t / 1000, frames: f.length, fps: f.length / (t / 1000), \
                frame_ms: {{ median: q(f, 0.5), p99: q(f, 0.99), max: f[f.length - 1] }}, \
                draw_ms: {{ median: q(d, 0.5), p99: q(d, 0.99), max: d[d.length - 1] }}, \
                message_ms: {{ count: h.length, median: q(h, 0.5), p99: q(h, 0.99), max: h[h.length - 1] }}, \
                long_tasks: {{ count: lt.length, max: lt.length ? lt[lt.length - 1] : 0 }}, \
                slow_messages: pkmc.stats.slow.filter(m => m.at >= s[0]).map(m => [m.type, Math.round(m.ms), Math.round(m.at - s[0])]), \
                status_hz: st.length / (t / 1000), status_max_gap_ms: gap }}; }})()"
        ))
        .await;
    println!("3D_Chips on the H-4, planned {planned} s, {resumed} pauses resumed (each waits up to 0.5 s for the press): page {r}");
    let _ = st.status_after_stopping_the_station().await;
}
