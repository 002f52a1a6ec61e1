//! A program that probes (G38.2), run from the operator station in headless Chromium
//! (the harness of `operator_station.rs`): the station on nc-send's own simulator
//! (`--sim`, real time) with its simulated probe touching a ball on the H-4. The page
//! loads the program, says it probes and previews it; Run runs it a stage at a time;
//! the probing panel shows the touch (contact, the probed Z within 1 µm plus four
//! times the probe's noise of the ball's top) and the branch on #5070 and the move to
//! #5063 + 2 follow from it; the run ends done. A G38.2 that touches nothing is
//! refused at its line, on the panel. Stop during a stage ends the run as a stop.
//! The panel stays inside the page at 800 × 1280, 1024 × 768 and 1920 × 1080.
//! Screenshot: `docs/ui-probing.png`, written there with `PKMC_UPDATE_SCREENSHOTS=1`
//! (docs/ui.md).

mod station;

use station::{Page, Station, Timeout};
use std::time::Duration;

const H4: &str = "examples/machines/h4-table.toml";

fn repo(p: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(p)
}

/// The ball (centre X Y Z, radius: the artefact's plus the tip's), mm, as
/// `host-tools/tests/probing.rs` puts it within the H-4's reach.
const BALL: [f64; 4] = [0.0, 0.0, -96.0, 6.0];
/// The simulated probe's trigger noise, µm (standard deviation).
const NOISE_UM: f64 = 0.5;

/// G54 at the ball's top (Z −90); touches the top, then moves 2 mm above the probed
/// point (#5063, in G54) if it touched.
const TOUCH: &str = "G21 G90\nG10 L2 P1 X0 Y0 Z-90\nG54\nG0 X0 Y0 Z4\nG38.2 Z-3 F300\n\
                     O100 if [#5070 EQ 1]\nG0 Z[#5063 + 2]\nO100 else\nG0 Z10\nO100 endif\nM2\n";

/// A G38.2 high above the ball: it ends without contact.
const MISS: &str = "G21 G90\nG0 X0 Y0 Z-80\nG38.2 Z-84 F300\nG0 Z-80\nM2\n";

/// A slow approach before the touch, for Stop to end.
const SLOW: &str = "G21 G90\nG0 X0 Y0 Z-86\nG1 X8 F60\nG38.2 Z-93 F300\nM2\n";

/// Types `text` into the editor, loads it, and waits for its dry run.
async fn load(page: &Page, text: &str, probing_line: u32) {
    page.type_into("#editor", text).await;
    page.click("#load-editor").await;
    page.wait(
        &format!(
            "pkmc.program && pkmc.program.check && pkmc.program.text === {} && \
             pkmc.program.probing && pkmc.program.probing.moves[0].line === {probing_line}",
            serde_json::to_string(text).unwrap()
        ),
        "the program loads, checked, its probing move named",
        Timeout::S(20),
    )
    .await;
}

/// The numbers of a probing panel row's line `which` (`probed`, `stopped`): X Y Z.
async fn row_xyz(page: &Page, row: usize, which: &str) -> Vec<f64> {
    let text = page
        .js(&format!(
            "document.querySelectorAll('#probe-list li.probe')[{row}]\
             .querySelector('.pxyz.{which}').textContent"
        ))
        .await;
    let text = text.as_str().unwrap().to_string();
    let nums: Vec<f64> = text
        .split_whitespace()
        .filter_map(|w| w.parse().ok())
        .collect();
    assert_eq!(nums.len(), 3, "{which}: {text}");
    nums
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[cfg_attr(
    pkmc_no_browser,
    ignore = "needs Chromium and chromedriver on PATH (Debian: chromium, chromium-driver)"
)]
async fn a_program_that_probes_runs_from_the_page_and_the_panel_shows_each_touch() {
    let ball = format!("{},{},{},{}", BALL[0], BALL[1], BALL[2], BALL[3]);
    let noise = NOISE_UM.to_string();
    let mut st = Station::start_sim(
        H4,
        &[
            "--probe-sphere",
            &ball,
            "--probe-noise-um",
            &noise,
            "--seed",
            "11",
        ],
    )
    .await;
    let page = st.page("op").await;
    page.wait(
        "pkmc.lastStatus && pkmc.lock && pkmc.lock.holder === pkmc.you && \
         pkmc.lastStatus.state === 'Idle'",
        "the page takes control of the unlocked simulator",
        Timeout::S(10),
    )
    .await;

    // Loaded: no error (G38 is no longer refused), the preview takes the probing move
    // to its end and says so, Run is offered and Step is not.
    load(&page, TOUCH, 5).await;
    assert_eq!(page.js("pkmc.program.errors.length").await, 0);
    let note = page
        .js("document.getElementById('probe-note').textContent")
        .await;
    let note = note.as_str().unwrap();
    assert!(
        note.contains("1 probing move(s), line 5") && note.contains("programmed end"),
        "{note}"
    );
    assert_eq!(
        page.js("getComputedStyle(document.getElementById('probe-panel')).display")
            .await,
        "block"
    );
    assert_eq!(
        page.js("document.getElementById('run').disabled").await,
        false
    );
    assert_eq!(
        page.js("document.getElementById('step').disabled").await,
        true
    );

    page.click("#run").await;
    page.wait(
        "pkmc.probes && pkmc.probes.end === 'done' && pkmc.lastStatus.state === 'Idle' && \
         !pkmc.lastStatus.job",
        "the run ends done",
        Timeout::S(30),
    )
    .await;
    let rows = page
        .js("[...document.querySelectorAll('#probe-list li.probe')].map(l => [l.className, l.querySelector('.phead').textContent])")
        .await;
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.len(), 1, "{rows:?}");
    let (class, head) = (rows[0][0].as_str().unwrap(), rows[0][1].as_str().unwrap());
    assert!(class.contains("last"), "the newest is highlighted: {class}");
    assert!(
        head.contains("line 5") && head.contains("G38.2") && head.ends_with("contact"),
        "{head}"
    );
    assert!(!head.contains("no contact"), "{head}");
    // The probed point: on the ball's top within 1 µm plus 4 σ of the noise (the
    // panel shows 0.1 µm).
    let probed = row_xyz(&page, 0, "probed").await;
    let top = BALL[2] + BALL[3];
    let bound = 0.001 + 4.0 * NOISE_UM / 1000.0 + 0.00005;
    assert!(
        (probed[2] - top).abs() <= bound && probed[0].abs() <= 0.001 && probed[1].abs() <= 0.001,
        "probed {probed:?}, the ball's top Z {top} (bound {bound} mm)"
    );
    // Where it stopped: past the surface, within the probe's stopping distance.
    let stopped = row_xyz(&page, 0, "stopped").await;
    println!(
        "probed {probed:?}: {:.2} µm from the ball's top (bound {:.2}); stopped {stopped:?}",
        (probed[2] - top) * 1000.0,
        bound * 1000.0
    );
    assert!(
        stopped[2] < probed[2] && stopped[2] > top - 0.2,
        "stopped {stopped:?}"
    );
    // In the program's frame (G54 at Z −90) the same point, 90 mm up.
    let program = row_xyz(&page, 0, "program").await;
    assert!(
        (program[2] - (probed[2] + 90.0)).abs() <= 0.00011 && program[0] == probed[0],
        "program frame {program:?}, probed {probed:?}"
    );
    // The branch on #5070 took the touch, and the move went to #5063 + 2.
    let z = page.js("pkmc.lastStatus.pose[2]").await.as_f64().unwrap();
    assert!(
        (z - (probed[2] + 2.0)).abs() <= 0.0011,
        "final Z {z}, probed {}",
        probed[2]
    );
    // The station logs the end once the job's stream returns, which may be after the
    // controller's idle status has reached the page.
    page.wait(
        "pkmc.log.some(l => l.text === 'program done')",
        "the end is logged",
        Timeout::S(5),
    )
    .await;
    assert!(
        page.js("pkmc.lastStatus.alarm === null")
            .await
            .as_bool()
            .unwrap(),
        "no alarm"
    );

    // The panel on a tablet and on monitors: inside the page's width, its newest row
    // reachable by scrolling.
    for (w, h) in [(800, 1280), (1024, 768), (1920, 1080)] {
        page.set_viewport(w, h).await;
        tokio::time::sleep(Duration::from_millis(300)).await;
        let r = page
            .js(
                "(() => { const p = document.getElementById('probe-panel'); \
                 const li = document.querySelector('#probe-list li.last'); \
                 li.scrollIntoView({block: 'center'}); \
                 const r = li.getBoundingClientRect(), q = p.getBoundingClientRect(); \
                 const hit = document.elementFromPoint(r.left + 20, r.top + r.height / 2); \
                 return [q.left >= 0 && q.right <= innerWidth, \
                         r.top >= 0 && r.bottom <= innerHeight, li.contains(hit), \
                         p.scrollWidth <= p.clientWidth + 1]; })()",
            )
            .await;
        assert_eq!(
            r,
            serde_json::json!([true, true, true, true]),
            "{w}x{h}: panel in width, row in view, row reachable, nothing cut off"
        );
        if w == 1920 {
            page.screenshot(&repo("docs/ui-probing.png")).await;
        }
    }
    page.set_viewport(1400, 900).await;

    // A G38.2 that touches nothing: the program stops at the next stage, refused at
    // the probing move's line; the panel shows the move without contact and why.
    load(&page, MISS, 3).await;
    page.click("#run").await;
    page.wait(
        "pkmc.probes && pkmc.probes.end === 'refused' && !pkmc.lastStatus.job",
        "the run is refused after the miss",
        Timeout::S(30),
    )
    .await;
    let head = page
        .js("document.querySelector('#probe-list li.probe .phead').textContent")
        .await;
    assert!(head.as_str().unwrap().contains("no contact"), "{head}");
    let refusal = page
        .js("document.querySelector('#probe-list li.refusal').textContent")
        .await;
    assert!(
        refusal
            .as_str()
            .unwrap()
            .starts_with("line 3:1: G38.2: the move ended without contact"),
        "{refusal}"
    );
    // It is at its line: a click selects the line in the editor.
    page.click("#probe-list li.refusal").await;
    let sel = page
        .js("(() => { const e = document.getElementById('editor'); return e.value.slice(e.selectionStart, e.selectionEnd); })()")
        .await;
    assert_eq!(sel, "G38.2 Z-84 F300");
    let z = page.js("pkmc.lastStatus.pose[2]").await.as_f64().unwrap();
    assert!(
        (z + 84.0).abs() < 0.001,
        "the move after the miss never ran: Z {z}"
    );

    // Stop during a stage: the run ends as a stop, no probing move runs.
    load(&page, SLOW, 4).await;
    page.click("#run").await;
    page.wait(
        "pkmc.lastStatus.line === 3 && pkmc.lastStatus.feed > 0",
        "the slow move runs",
        Timeout::S(20),
    )
    .await;
    page.click("#stop").await;
    page.wait(
        "pkmc.probes && pkmc.probes.end === 'stopped' && !pkmc.lastStatus.job",
        "Stop ends the run",
        Timeout::S(10),
    )
    .await;
    assert_eq!(
        page.js("pkmc.probes.records.length").await,
        0,
        "no probing move after Stop"
    );

    // A probing move typed into MDI: its result joins the panel, marked as MDI's
    // (its line is MDI's, not the editor's: a click selects nothing).
    page.wait_idle_or_alarm().await;
    page.mdi("G0 X0 Y0 Z-86").await;
    page.wait(
        "Math.abs(pkmc.lastStatus.pose[0]) < 0.001 && !pkmc.lastStatus.job",
        "at the ball's axis",
        Timeout::S(20),
    )
    .await;
    page.mdi("G38.2 Z-93 F300").await;
    page.wait(
        "pkmc.probes && pkmc.probes.program === 'MDI' && pkmc.probes.records.length === 1",
        "the MDI probe on the panel",
        Timeout::S(20),
    )
    .await;
    let head = page
        .js("document.querySelector('#probe-list li.last .phead').textContent")
        .await;
    let head = head.as_str().unwrap();
    assert!(head.starts_with("MDIG38.2contact"), "{head}");
    let z = page
        .js("pkmc.probes.records[0].position[2]")
        .await
        .as_f64()
        .unwrap();
    assert!((z + 90.0).abs() < 0.003, "MDI probed Z {z}");
    assert_eq!(
        page.js("document.querySelector('#probe-list li.last').dataset.line === undefined")
            .await,
        true
    );
    page.close().await;
    drop(st);
}
