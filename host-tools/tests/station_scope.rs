//! The operator station's scope panel in headless Chromium (the harness of
//! `operator_station.rs`), on nc-send's own simulator (`--sim`, real time) of the
//! servo machine: bad signals and triggers are refused on the panel naming the
//! field; a capture triggered by the job's start with pre-trigger samples is shown
//! when done, while the program still runs, zoomed by a drag across it and read with two cursors; its CSV,
//! downloaded from the panel, equals byte for byte the one `nc-send record` writes
//! for the same machine, signals, trigger, pre-trigger and program; the live traces
//! grow while a job runs and show a following error that is not zero. A second test
//! presses Live and Arm (a line trigger) while a program already runs: the traces
//! grow, and the capture comes while the program still runs.
//! Screenshot: `docs/ui-scope.png`, written there with `PKMC_UPDATE_SCREENSHOTS=1`
//! (docs/ui.md).

mod station;

use serde_json::Value;
use station::{Page, Station, Timeout};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

const SERVO: &str = "examples/machines/cartesian-servo.toml";
const PROGRAM: &str = "examples/square.ngc";
/// The capture's signals: Z's joint (the program starts with a move up) and the
/// path speed.
const SIGNALS: &str = "cmd:2,meas:2,ferr:2,speed";
/// The live traces' signals: X's joint (the square's sides).
const LIVE: &str = "ferr:0,cmd:0,meas:0,state";
const TRIGGER: &str = "job";
const PRE: u32 = 20;

fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(p)
}

/// Where the panel's drawing of the traces is on the screen: left, top, width,
/// height (viewport pixels), after scrolling it into view.
async fn plot_box(page: &Page) -> [f64; 4] {
    let r = page
        .js("(() => { const o = document.getElementById('scope-over'); \
             o.scrollIntoView({block: 'center'}); const r = o.getBoundingClientRect(); \
             return [r.left, r.top, r.width, r.height]; })()")
        .await;
    let n = |i: usize| r[i].as_f64().unwrap();
    [n(0), n(1), n(2), n(3)]
}

/// The pixel mapping the server sent with the drawing: the time axis' ends (pixels)
/// and the first panel's middle.
async fn time_axis(page: &Page) -> (f64, f64, f64) {
    let l = page.js("pkmc.scope.plot.layout").await;
    let f = |v: &Value| v.as_f64().unwrap();
    let p = &l["panels"][0];
    (
        f(&l["x0"]),
        f(&l["x1"]),
        (f(&p["top"]) + f(&p["bottom"])) / 2.0,
    )
}

/// Waits until the drawing shown is of the panel's latest samples.
async fn drawn(page: &Page, what: &str) {
    page.wait(
        "pkmc.scope.plot && pkmc.scope.state && pkmc.scope.plot.version === pkmc.scope.state.version \
         && !pkmc.scope.asked",
        what,
        Timeout::S(10),
    )
    .await;
}

/// The file the browser downloaded as `name`, once it is complete.
async fn downloaded(page: &Page, name: &str) -> Vec<u8> {
    let path = page.downloads.join(name);
    let t = Instant::now();
    loop {
        let partial = std::fs::read_dir(&page.downloads).unwrap().any(|e| {
            e.unwrap()
                .file_name()
                .to_string_lossy()
                .ends_with(".crdownload")
        });
        if path.is_file() && !partial {
            return std::fs::read(&path).unwrap();
        }
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "no {name} downloaded"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// `nc-send --sim record` of the same capture: its CSV.
fn nc_send_record() -> Vec<u8> {
    let csv = std::env::temp_dir().join(format!("pkmc-scope-{}.csv", std::process::id()));
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .arg("--sim")
        .arg("--machine")
        .arg(repo(SERVO))
        .args(["record", "--signals", SIGNALS, "--trigger", TRIGGER])
        .args(["--pre", &PRE.to_string(), "--during"])
        .arg(repo(PROGRAM))
        .arg("--csv")
        .arg(&csv)
        .output()
        .unwrap();
    assert!(out.status.success(), "nc-send record: {out:?}");
    let bytes = std::fs::read(&csv).unwrap();
    let _ = std::fs::remove_file(&csv);
    bytes
}

/// Arms with the fields as typed; the error shown on the panel, if one is expected.
async fn arm_refused(page: &Page, signals: &str, trigger: &str) -> String {
    page.type_into("#scope-signals", signals).await;
    page.type_into("#scope-trigger", trigger).await;
    page.click("#scope-arm").await;
    let e = page
        .wait(
            "document.getElementById('scope-error').textContent",
            "the panel shows the refusal",
            Timeout::S(5),
        )
        .await;
    e.as_str().unwrap().to_string()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[cfg_attr(
    pkmc_no_browser,
    ignore = "needs Chromium and chromedriver on PATH (Debian: chromium, chromium-driver)"
)]
async fn the_scope_panel_streams_live_captures_on_a_trigger_and_exports_nc_send_records_csv() {
    let mut st = Station::start_sim(SERVO, &[]).await;
    let page = st.page("op").await;
    page.wait(
        "pkmc.lastStatus && pkmc.lock && pkmc.lock.holder === pkmc.you && \
         pkmc.lastStatus.state === 'Idle'",
        "the page takes control of the unlocked simulator",
        Timeout::S(10),
    )
    .await;
    let program = std::fs::read_to_string(repo(PROGRAM)).unwrap();
    page.type_into("#editor", &program).await;
    page.click("#load-editor").await;
    page.wait(
        &format!(
            "pkmc.program && pkmc.program.check && pkmc.program.text === {}",
            serde_json::to_string(&program).unwrap()
        ),
        "the program loads, checked",
        Timeout::S(20),
    )
    .await;
    page.click("#scope-panel summary").await;

    // Bad input: refused on the panel, naming the field.
    let e = arm_refused(&page, "ferr:0,torque", TRIGGER).await;
    assert!(e.contains("Signals") && e.contains("torque"), "{e}");
    let e = arm_refused(&page, SIGNALS, "soon").await;
    assert!(e.contains("Trigger") && e.contains("soon"), "{e}");

    // A capture triggered by the job's start, with pre-trigger samples: armed, the
    // ring fills with them, Run; shown when done.
    page.type_into("#scope-trigger", TRIGGER).await;
    page.type_into("#scope-pre", &PRE.to_string()).await;
    page.click("#scope-arm").await;
    page.wait(
        "pkmc.scope.state.mode === 'armed' && !document.getElementById('scope-error').textContent",
        "the recorder is armed",
        Timeout::S(5),
    )
    .await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    page.click("#run").await;
    page.wait_moving("the program runs").await;
    // Read out beside the program's blocks as soon as it is done, while the program
    // still runs (it takes 12 s; the capture, 0.14 s from its start).
    let during = page
        .wait(
            "pkmc.scope.state.mode === 'done' && [!!pkmc.lastStatus.job]",
            "the capture is read out",
            Timeout::S(10),
        )
        .await;
    assert_eq!(
        during[0], true,
        "the program still runs when the capture shows"
    );
    page.wait_idle(Timeout::S(30)).await;
    drawn(&page, "the capture is drawn").await;
    let samples = page.js("pkmc.scope.state.samples").await.as_u64().unwrap();
    assert!(samples > PRE as u64, "{samples} samples");
    let span = page.js("pkmc.scope.state.span").await;
    let state = page.js("JSON.stringify(pkmc.scope.state)").await;
    let first = span[0].as_f64().unwrap();
    assert!(
        (first + PRE as f64 * 0.001).abs() < 1e-9,
        "the first sample is {PRE} ticks before the trigger: {span} {state}"
    );
    let traces = page
        .js("document.querySelectorAll('#scope-svg svg polyline, #scope-svg svg path').length")
        .await;
    assert!(traces.as_u64().unwrap() >= 4, "{traces}");

    // Zoom: a drag across the middle half of the time axis.
    let [left, top, _, _] = plot_box(&page).await;
    let (x0, x1, y) = time_axis(&page).await;
    let before = page
        .js("[pkmc.scope.plot.layout.t0, pkmc.scope.plot.layout.t1]")
        .await;
    let (a, b) = (x0 + 0.25 * (x1 - x0), x0 + 0.75 * (x1 - x0));
    page.pointer_path(&[
        (left + a, top + y),
        (left + (a + b) / 2.0, top + y),
        (left + b, top + y),
    ])
    .await;
    page.wait(
        &format!("pkmc.scope.plot.layout.t0 > {} + 1e-6", before[0]),
        "the zoomed drawing comes",
        Timeout::S(10),
    )
    .await;
    let zoomed = page
        .js("[pkmc.scope.plot.layout.t0, pkmc.scope.plot.layout.t1]")
        .await;
    let t = |v: &Value, i: usize| v[i].as_f64().unwrap();
    let full = t(&before, 1) - t(&before, 0);
    assert!(
        (t(&zoomed, 1) - t(&zoomed, 0) - full / 2.0).abs() < full * 0.02,
        "a drag over half the axis shows half the time: {before} then {zoomed}"
    );

    // Two cursors, a click each: their times, the values there, and B − A.
    let [left, top, _, _] = plot_box(&page).await;
    let (x0, x1, y) = time_axis(&page).await;
    page.pointer_path(&[(left + x0 + 0.2 * (x1 - x0), top + y)])
        .await;
    page.pointer_path(&[(left + x0 + 0.8 * (x1 - x0), top + y)])
        .await;
    let rows = page
        .wait(
            "(() => { const r = [...document.querySelectorAll('#scope-cursors tr')]\
             .map(tr => [...tr.children].map(c => c.textContent)); \
             return r.length === 6 && r[1][1] !== '—' && r[1][2] !== '—' ? r : null; })()",
            "the cursors' table",
            Timeout::S(5),
        )
        .await;
    let num = |r: usize, c: usize| rows[r][c].as_str().unwrap().parse::<f64>().unwrap();
    let (ta, tb, dt) = (num(1, 1), num(1, 2), num(1, 3));
    assert!(tb > ta && (dt - (tb - ta)).abs() < 2e-6, "{rows}");
    let zw = t(&zoomed, 1) - t(&zoomed, 0);
    assert!(
        (dt - 0.6 * zw).abs() < 0.05 * zw,
        "B − A is 60 % of the view: {rows}"
    );
    assert_eq!(rows[2][0], "cmd2_counts");
    for r in 2..6 {
        assert!((num(r, 3) - (num(r, 2) - num(r, 1))).abs() < 0.5, "{rows}");
    }

    // The CSV from the panel is nc-send record's, byte for byte.
    page.click("#scope-csv").await;
    let from_page = downloaded(&page, "scope.csv").await;
    let from_cli = nc_send_record();
    assert_eq!(
        String::from_utf8_lossy(&from_page),
        String::from_utf8_lossy(&from_cli),
        "the panel's CSV and nc-send record's"
    );

    // Live: the traces grow while a job runs, and the following error moves.
    page.type_into("#scope-signals", LIVE).await;
    page.click("#scope-live").await;
    page.wait(
        "pkmc.scope.state.mode === 'live' && pkmc.scope.state.samples > 0",
        "the recorder streams",
        Timeout::S(5),
    )
    .await;
    page.click("#run").await;
    page.wait_moving("the program runs").await;
    let count = "pkmc.scope.plot ? pkmc.scope.plot.version : 0";
    let n1 = page.js("pkmc.scope.state.samples").await.as_u64().unwrap();
    let v1 = page.js(count).await.as_u64().unwrap();
    tokio::time::sleep(Duration::from_millis(800)).await;
    let running = page.js("!!pkmc.lastStatus.job").await;
    let n2 = page.js("pkmc.scope.state.samples").await.as_u64().unwrap();
    let v2 = page.js(count).await.as_u64().unwrap();
    assert_eq!(running, true, "the job still runs");
    assert!(n2 > n1 + 300, "samples while the job runs: {n1} then {n2}");
    assert!(v2 > v1, "the drawing follows: version {v1} then {v2}");
    let ferr = page
        .js("Math.max(...pkmc.scope.plot.values[0].map(Math.abs))")
        .await;
    assert!(ferr.as_f64().unwrap() > 0.0, "a following error: {ferr}");
    page.wait_idle(Timeout::S(30)).await;
    // Stopped, the samples stay: all of them drawn, two cursors on them.
    page.click("#scope-stop").await;
    page.wait(
        "pkmc.scope.state.mode === 'off'",
        "the recorder stops",
        Timeout::S(5),
    )
    .await;
    drawn(&page, "the run's traces are drawn").await;
    let [left, top, _, _] = plot_box(&page).await;
    let (x0, x1, y) = time_axis(&page).await;
    page.pointer_path(&[(left + x0 + 0.3 * (x1 - x0), top + y)])
        .await;
    page.pointer_path(&[(left + x0 + 0.62 * (x1 - x0), top + y)])
        .await;
    page.wait(
        "document.querySelectorAll('#scope-cursors tr').length === 6",
        "the cursors' table",
        Timeout::S(5),
    )
    .await;
    page.js("document.getElementById('scope-cursors').scrollIntoView({block: 'end'})")
        .await;
    page.screenshot(&repo("docs/ui-scope.png")).await;
}

/// Live and Arm pressed while a program already runs: the recorder is armed beside
/// the job's blocks. Live: the traces grow while the job runs. Arm with a line
/// trigger: the capture comes while the job still runs, its trigger's sample the
/// first on that line, its pre-trigger samples on the line before.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[cfg_attr(
    pkmc_no_browser,
    ignore = "needs Chromium and chromedriver on PATH (Debian: chromium, chromium-driver)"
)]
async fn live_and_arm_pressed_during_a_running_program_trace_and_capture_it() {
    let mut st = Station::start_sim(SERVO, &[]).await;
    let page = st.page("op").await;
    page.wait(
        "pkmc.lastStatus && pkmc.lock && pkmc.lock.holder === pkmc.you && \
         pkmc.lastStatus.state === 'Idle'",
        "the page takes control of the unlocked simulator",
        Timeout::S(10),
    )
    .await;
    let program = std::fs::read_to_string(repo(PROGRAM)).unwrap();
    page.type_into("#editor", &program).await;
    page.click("#load-editor").await;
    page.wait(
        &format!(
            "pkmc.program && pkmc.program.check && pkmc.program.text === {}",
            serde_json::to_string(&program).unwrap()
        ),
        "the program loads, checked",
        Timeout::S(20),
    )
    .await;
    page.click("#scope-panel summary").await;
    page.click("#run").await;
    page.wait_moving("the program runs").await;

    // Live, pressed while the program runs.
    page.type_into("#scope-signals", LIVE).await;
    page.click("#scope-live").await;
    page.wait(
        "pkmc.scope.state && pkmc.scope.state.mode === 'live' && pkmc.scope.state.samples > 0",
        "the recorder streams during the job",
        Timeout::S(5),
    )
    .await;
    let n1 = page.js("pkmc.scope.state.samples").await.as_u64().unwrap();
    tokio::time::sleep(Duration::from_millis(800)).await;
    let n2 = page.js("pkmc.scope.state.samples").await.as_u64().unwrap();
    let running = page.js("!!pkmc.lastStatus.job").await;
    assert_eq!(running, true, "the job still runs");
    assert!(n2 > n1 + 300, "samples while the job runs: {n1} then {n2}");
    let error = page
        .js("document.getElementById('scope-error').textContent")
        .await;
    assert_eq!(error, "", "no refusal");

    // Arm with a line trigger, pressed while the program runs (line 7, the third
    // side, starts about 6 s after Run).
    let line = 7;
    page.click("#scope-stop").await;
    page.type_into("#scope-signals", "line,ferr:0,cmd:0").await;
    page.type_into("#scope-trigger", &format!("line:{line}"))
        .await;
    page.type_into("#scope-pre", "20").await;
    page.click("#scope-arm").await;
    let armed = page
        .wait(
            "pkmc.scope.state.mode === 'armed' && [pkmc.lastStatus.line, !!pkmc.lastStatus.job]",
            "the recorder is armed during the job",
            Timeout::S(5),
        )
        .await;
    assert!(
        armed[0].as_u64().unwrap() < line && armed[1] == true,
        "armed before line {line}, the job running: {armed}"
    );
    let during = page
        .wait(
            "pkmc.scope.state.mode === 'done' && [!!pkmc.lastStatus.job]",
            "the capture is read out",
            Timeout::S(15),
        )
        .await;
    assert_eq!(during[0], true, "the job still runs when the capture shows");
    drawn(&page, "the capture is drawn").await;
    let plot = page
        .js("[pkmc.scope.plot.times, pkmc.scope.plot.values[0], pkmc.scope.plot.columns]")
        .await;
    let times: Vec<f64> = serde_json::from_value(plot[0].clone()).unwrap();
    let lines: Vec<i64> = serde_json::from_value(plot[1].clone()).unwrap();
    assert_eq!(plot[2][0], "line");
    let at = times.iter().position(|t| t.abs() < 1e-9).unwrap();
    assert_eq!(at, 20, "20 samples before the trigger: {times:?}");
    assert_eq!(lines[at], line as i64, "{lines:?}");
    assert!(
        lines[..at].iter().all(|&l| l == line as i64 - 1),
        "before the trigger, line {}: {lines:?}",
        line - 1
    );
    page.wait_idle(Timeout::S(30)).await;
}
