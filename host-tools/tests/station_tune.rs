//! The operator station's Tune panel in headless Chromium (the harness of
//! `operator_station.rs`), on nc-send's own simulator (`--sim`, real time) of a copy
//! of the servo machine whose X and Y carry the simulator's default plant written out
//! with encoder noise (as `tune.rs` does). Refusals show on the panel in the
//! controller's or the tuner's words: Tune before the machine is homed (the
//! controller refuses the test signal), on the stepper joint Z, and while a program
//! runs. Homed and idle, Tune on X shows the designed gains, the margins and the
//! plot (the step responses and the Bode diagram of `nc-send tune --plot`); the
//! machine file is unchanged until Write gains is pressed, and then it is exactly
//! what `nc-send tune --write` writes for those gains (`scope::tune_write::rewrite`
//! of the file): X's servo line and the comment above it, nothing else; the gains
//! read back are the designed ones.

mod station;

use pkmc_host::machine_file::read_file;
use serde_json::Value;
use station::{Page, Station, Timeout};
use std::path::{Path, PathBuf};
use std::time::Duration;

const SERVO: &str = "examples/machines/cartesian-servo.toml";
const PROGRAM: &str = "examples/square.ngc";
const NOISE: f64 = 0.3;

fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(p)
}

/// The servo machine with the simulator's default plant written out on each servo
/// joint, with encoder noise.
fn noisy_machine() -> String {
    let text = std::fs::read_to_string(repo(SERVO)).unwrap();
    let mut out = String::new();
    for line in text.lines() {
        out.push_str(line);
        out.push('\n');
        let t = line.trim_start();
        if t.starts_with("servo") && t[5..].trim_start().starts_with('=') {
            // Both servo joints count 1000 per mm.
            let k = pkmc_host::sim::DEFAULT_PLANT_GAIN / 1000.0;
            let tau = pkmc_host::sim::DEFAULT_PLANT_TAU_S;
            out.push_str(&format!(
                "plant = {{ num = [{k}], den = [{tau}, 1.0, 0.0], input_per_count = 1.0, \
                 encoder_noise = {NOISE} }}\n"
            ));
        }
    }
    out
}

/// Presses Tune and waits for the refusal the panel shows.
async fn tune_refused(page: &Page, what: &str) -> String {
    page.js("document.getElementById('tune-error').textContent = ''")
        .await;
    page.click("#tune-run").await;
    let e = page
        .wait(
            "document.getElementById('tune-error').textContent",
            what,
            Timeout::S(10),
        )
        .await;
    e.as_str().unwrap().to_string()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[cfg_attr(
    pkmc_no_browser,
    ignore = "needs Chromium and chromedriver on PATH (Debian: chromium, chromium-driver)"
)]
async fn the_tune_panel_tunes_a_servo_joint_and_writes_its_gains_only_when_asked() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("station-tune");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("cartesian-servo-noisy.toml");
    let original = noisy_machine();
    std::fs::write(&file, &original).unwrap();
    let mut st = Station::start_sim(file.to_str().unwrap(), &[]).await;
    let page = st.page("op").await;
    page.wait(
        "pkmc.lastStatus && pkmc.lock && pkmc.lock.holder === pkmc.you && \
         pkmc.lastStatus.state === 'Idle'",
        "the page takes control of the unlocked simulator",
        Timeout::S(10),
    )
    .await;
    page.click("#tune-panel summary").await;
    let joints = page
        .js("[...document.querySelectorAll('#tune-joint option')].map(o => o.value)")
        .await;
    assert_eq!(joints, serde_json::json!(["X", "Y"]), "servo joints only");

    // Not homed: the controller refuses the test signal, in its words.
    let e = tune_refused(&page, "Tune is refused before homing").await;
    assert!(
        e.contains("refused the test signal") && e.contains("hom"),
        "{e}"
    );
    // The stepper joint (a page that offers it anyway): the tuner names it.
    page.js("(() => { const s = document.getElementById('tune-joint'); \
         const o = document.createElement('option'); o.value = o.textContent = 'Z'; \
         s.appendChild(o); s.value = 'Z'; })()")
        .await;
    let e = tune_refused(&page, "Tune is refused on a stepper").await;
    assert!(e.contains("Z") && e.contains("stepper joint"), "{e}");
    page.select("#tune-joint", "X").await;

    page.click_and_wait_idle("#home", Timeout::S(60)).await;
    page.wait("pkmc.lastStatus.homed", "homed", Timeout::S(5))
        .await;

    // A program runs: Tune waits, and says so.
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
    page.click("#run").await;
    page.wait_moving("the program runs").await;
    let e = tune_refused(&page, "Tune is refused while a program runs").await;
    assert!(
        e.contains("busy") && e.contains("program") && e.contains("tune"),
        "{e}"
    );
    page.click("#stop").await;
    page.wait_idle(Timeout::S(10)).await;
    assert_eq!(std::fs::read_to_string(&file).unwrap(), original);

    // Tune X: the result, the gains, the plot.
    page.js("document.getElementById('tune-error').textContent = ''")
        .await;
    page.click("#tune-run").await;
    page.wait(
        "pkmc.tune.state && pkmc.tune.state.running === 'X'",
        "the tune runs",
        Timeout::S(5),
    )
    .await;
    let r = page
        .wait(
            "pkmc.tune.state && !pkmc.tune.state.running && \
             (pkmc.tune.state.result || pkmc.tune.state.error) && pkmc.tune.state",
            "the tune ends",
            Timeout::S(60),
        )
        .await;
    assert!(r["error"].is_null(), "{}", r["error"]);
    let result = &r["result"];
    assert_eq!(result["name"], "X");
    let fit = result["fit_percent"].as_f64().unwrap();
    assert!(fit > 60.0, "fit {fit}");
    let pm = result["margins"]["designed"]["phase_margin_deg"]
        .as_f64()
        .unwrap();
    assert!((pm - 60.0).abs() < 2.0, "designed PM {pm}");
    let designed: Vec<f64> = ["kp", "ki", "kd", "kvff", "kaff"]
        .iter()
        .map(|k| result["designed"][k].as_f64().unwrap())
        .collect();
    assert!(designed[0] > 0.0 && designed[1] > 0.0, "{designed:?}");
    // Shown: the designed row of the gains' table, and the plot's panels.
    let shown = page
        .js("document.querySelector('#tune-gains tr[data-which=designed]').textContent")
        .await;
    assert!(shown.as_str().unwrap().contains("designed"), "{shown}");
    let kp_cell = page
        .js("document.querySelector('#tune-gains tr[data-which=designed]').children[1].textContent")
        .await;
    let kp_shown: f64 = kp_cell.as_str().unwrap().parse().unwrap();
    assert!(
        (kp_shown - designed[0]).abs() < 1e-3 * designed[0],
        "{kp_shown}"
    );
    let plot = page
        .js("(() => { const s = document.querySelector('#tune-plot svg'); \
             if (!s) return null; const r = s.getBoundingClientRect(); \
             return {text: s.textContent, width: r.width, lines: s.querySelectorAll('polyline, path').length}; })()")
        .await;
    let text = plot["text"].as_str().unwrap_or_default();
    for caption in [
        "step response",
        "magnitude (dB)",
        "phase (deg)",
        "measured, present gains",
    ] {
        assert!(text.contains(caption), "the plot lacks {caption}: {plot}");
    }
    assert!(plot["width"].as_f64().unwrap() > 200.0, "{plot}");
    assert!(plot["lines"].as_u64().unwrap() >= 5, "{plot}");
    // Nothing written yet.
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert_eq!(
        std::fs::read_to_string(&file).unwrap(),
        original,
        "the machine file is unchanged until Write gains"
    );

    // Write gains: X's servo line (and a comment giving the old one), as
    // `nc-send tune --write` writes those gains.
    page.click("#tune-write").await;
    let written = page
        .wait(
            "document.getElementById('tune-written').textContent",
            "Write gains answers",
            Timeout::S(10),
        )
        .await;
    let written = written.as_str().unwrap().to_string();
    let now = std::fs::read_to_string(&file).unwrap();
    let names = ["kp", "ki", "kd", "kvff", "kaff"];
    let fields: Vec<(&str, f64)> = names.iter().copied().zip(designed.clone()).collect();
    let expect = pkmc_host::scope::tune_write::rewrite(&original, 0, &fields).unwrap();
    assert_eq!(now, expect.text, "the file nc-send tune --write writes");
    assert!(written.contains(expect.line.trim()), "{written}");
    let (before, after): (Vec<&str>, Vec<&str>) =
        (original.lines().collect(), now.lines().collect());
    assert_eq!(after.len(), before.len() + 1, "one comment line added");
    let changed: Vec<&str> = after
        .iter()
        .filter(|l| !before.contains(l))
        .copied()
        .collect();
    assert_eq!(
        changed.len(),
        2,
        "the comment and X's servo line: {changed:?}"
    );
    assert!(
        changed[0].starts_with("# nc-send tune: was servo ="),
        "{changed:?}"
    );
    assert!(changed[1].starts_with("servo ="), "{changed:?}");
    let mf = read_file(&now, "written").unwrap();
    let g = mf.joints[0].servo.as_ref().unwrap();
    let back = [g.kp, g.ki, g.kd, g.kvff, g.kaff];
    for (k, (b, d)) in back.iter().zip(&designed).enumerate() {
        assert!(
            (*b as f64 - d).abs() <= 1e-4 * d.abs() + 1e-12,
            "{}: read back {b}, designed {d}",
            names[k]
        );
    }
    // Y's line is untouched.
    let y = |t: &str| {
        t.lines()
            .filter(|l| l.trim_start().starts_with("servo"))
            .nth(1)
            .unwrap()
            .to_string()
    };
    assert_eq!(y(&now), y(&original));
    let state: Value = page.js("pkmc.tune.state.written").await;
    assert!(state.as_str().unwrap().contains("X"), "{state}");
}
