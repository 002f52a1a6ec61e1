//! The operator station on a tablet and on small and large monitors, in headless
//! Chromium (see `operator_station.rs` for the harness): at 800 × 1280, 1024 × 768
//! and 1920 × 1080 E-STOP, Hold and Stop are inside the viewport and are what a
//! click there hits, every control is at least 9 mm high, and everything else is
//! reachable by scrolling. Then the operator's aids on the H-4: the range bars at
//! home, the keyboard jog, inches, an e-stop worded as one with Run and Jog refused,
//! the alarm history, a quiet log, a teach file saved and loaded back exactly, and a
//! program with a pre-flight error drawn with its error marked.
//! Screenshots: `docs/ui-800x1280.png`, `docs/ui-1024x768.png` and
//! `docs/ui-1920x1080.png`, written there with `PKMC_UPDATE_SCREENSHOTS=1` (docs/ui.md).

mod station;

use station::{Page, Station, Timeout};
use std::path::Path;
use std::time::Duration;

const H4: &str = "examples/machines/h4-table.toml";

fn repo(p: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(p)
}

/// 9 mm in CSS pixels (96 per inch).
const NINE_MM_PX: f64 = 9.0 / 25.4 * 96.0;

/// Is the element's whole rectangle inside the viewport, and does a click at its
/// centre reach it (nothing drawn over it)? Returns the rectangle or a reason.
async fn in_view_and_clickable(page: &Page, css: &str) -> serde_json::Value {
    page.js(&format!(
        "(() => {{ const e = document.querySelector('{css}'); if (!e) return 'missing'; \
         const r = e.getBoundingClientRect(); \
         const inside = r.width > 0 && r.height > 0 && r.left >= 0 && r.top >= 0 && \
           r.right <= innerWidth && r.bottom <= innerHeight; \
         const hit = document.elementFromPoint(r.left + r.width / 2, r.top + r.height / 2); \
         const reach = hit === e || e.contains(hit); \
         return inside && reach ? [r.left, r.top, r.width, r.height] : \
           `{css} at ${{JSON.stringify(r)}} in ${{innerWidth}}x${{innerHeight}}: inside ${{inside}}, hit ${{hit && hit.outerHTML.slice(0, 120)}} in ${{hit && hit.parentElement && hit.parentElement.outerHTML.slice(0, 160)}}`; }})()"
    ))
    .await
}

/// The layout at one size: the safety buttons in view and clickable, before and
/// after scrolling the page to its end; controls ≥ 9 mm; every panel reachable.
async fn check_layout(page: &Page, w: u32, h: u32) {
    page.set_viewport(w, h).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    for scroll in ["0", "1e6"] {
        page.js(&format!(
            "(() => {{ const m = document.getElementById('layout'); m.scrollTop = {scroll}; \
             window.scrollTo(0, {scroll}); return true; }})()"
        ))
        .await;
        tokio::time::sleep(Duration::from_millis(100)).await;
        for css in ["#estop", "#hold", "#stop"] {
            let r = in_view_and_clickable(page, css).await;
            assert!(
                r.is_array(),
                "{w}x{h}, scrolled to {scroll}: {css} not in view or covered: {r}"
            );
        }
    }
    let small = page
        .js(&format!(
            "[...document.querySelectorAll('button, select, input:not([type=file]), .filebtn')] \
             .filter(e => e.offsetParent !== null && !e.closest('.filebtn, #teach-list')) \
             .map(e => e.type === 'checkbox' && e.closest('label') ? e.closest('label') : e) \
             .map(e => [e.id || e.className || e.tagName, Math.min(e.getBoundingClientRect().height, e.getBoundingClientRect().width)]) \
             .filter(([, h]) => h < {NINE_MM_PX})"
        ))
        .await;
    assert_eq!(
        small,
        serde_json::json!([]),
        "{w}x{h}: controls under 9 mm ({NINE_MM_PX:.1} px) high or wide"
    );
    // Everything else is reachable: scrolled into view, each panel's last control
    // lies inside the viewport and is what a click there hits.
    for css in [
        "#joint-plus",
        "button.jog[data-axis='Z'][data-dir='1']",
        "#mdi-send",
        "#check",
        "#teach-run",
        "#view-fit-prog",
        "#override-100",
    ] {
        page.js(&format!(
            "(() => {{ document.querySelector(\"{css}\").scrollIntoView({{block: 'center'}}); return true; }})()"
        ))
        .await;
        tokio::time::sleep(Duration::from_millis(50)).await;
        let r = in_view_and_clickable(page, &css.replace('\'', "\\'")).await;
        assert!(r.is_array(), "{w}x{h}: {css} cannot be reached: {r}");
    }
    page.js("(() => { document.getElementById('layout').scrollTop = 0; window.scrollTo(0, 0); return true; })()")
        .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[cfg_attr(
    pkmc_no_browser,
    ignore = "needs Chromium and chromedriver on PATH (Debian: chromium, chromium-driver)"
)]
async fn the_station_fits_a_tablet_and_a_small_monitor_and_helps_the_operator() {
    let mut st = Station::start(H4).await;
    let page = st.page("tablet").await;
    page.wait(
        "pkmc.machine && pkmc.lastStatus && pkmc.lock && pkmc.lock.holder === pkmc.you",
        "the page connects and takes control",
        Timeout::S(10),
    )
    .await;
    // Unhomed at start: the alarm says what to do, and jogs are not offered.
    let unhomed = page
        .wait(
            "pkmc.lastStatus.alarm && document.getElementById('alarm').textContent",
            "the not-homed alarm is shown",
            Timeout::S(5),
        )
        .await;
    assert!(
        unhomed
            .as_str()
            .unwrap()
            .contains("Home the machine, or Reset"),
        "{unhomed}"
    );
    page.wait(
        "[...document.querySelectorAll('#jog-buttons button')].every(b => b.disabled)",
        "no jog while not homed",
        Timeout::S(3),
    )
    .await;
    page.click("#home").await;
    page.wait_idle(Timeout::S(30)).await;

    // Range bars at home: a joint that homes at an end of its travel shows "at home",
    // not red.
    let bars = page
        .js(
            "[...document.querySelectorAll('#dro-joints tr[data-joint]')].map(r => { \
             const b = r.querySelector('.bar'); return [r.querySelector('td.name').textContent, \
             b.classList.contains('near'), b.classList.contains('at-home')]; })",
        )
        .await;
    let ends = page
        .js("pkmc.machine.joints.filter(j => j.home != null && \
             Math.min(j.home - j.min, j.max - j.home) < 0.05 * (j.max - j.min)).map(j => j.name)")
        .await;
    assert!(
        !ends.as_array().unwrap().is_empty(),
        "the H-4 has a joint homing at an end of its travel: {bars}"
    );
    for row in bars.as_array().unwrap() {
        assert_eq!(row[1], false, "no bar is red at home: {bars}");
        assert_eq!(row[2], true, "every bar says at home: {bars}");
    }

    // The program, drawn and fitted, for the screenshots.
    page.upload("#file", &repo("examples/h4-table-tilt.ngc"))
        .await;
    page.wait(
        "pkmc.program && pkmc.program.name === 'h4-table-tilt.ngc' && pkmc.preview && pkmc.preview.points > 0",
        "the example loads and is drawn",
        Timeout::S(20),
    )
    .await;
    for (w, h) in [(800u32, 1280u32), (1024, 768), (1920, 1080)] {
        check_layout(&page, w, h).await;
        page.click("#view-fit").await;
        let machine = page.js("pkmc.programExtent()").await;
        page.click("#view-fit-prog").await;
        tokio::time::sleep(Duration::from_millis(300)).await;
        // Fitted, the program spans at least 40 % of the view's width or height (its
        // box, padded 5 %, is what is fitted), many times what it spans with the
        // machine fitted, and lies inside the view.
        let e = page.js("pkmc.programExtent()").await;
        let f = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap();
        let fill = ((f(&e, "right") - f(&e, "left")) / f(&e, "w"))
            .max((f(&e, "bottom") - f(&e, "top")) / f(&e, "h"));
        let before = ((f(&machine, "right") - f(&machine, "left")) / f(&machine, "w"))
            .max((f(&machine, "bottom") - f(&machine, "top")) / f(&machine, "h"));
        println!("{w}x{h}: the program spans {fill:.2} of the view fitted, {before:.2} with the machine fitted");
        assert!(
            fill > 0.4 && fill > 5.0 * before,
            "{w}x{h}: fitted {e}, machine {machine}"
        );
        assert!(
            f(&e, "left") >= 0.0
                && f(&e, "top") >= 0.0
                && f(&e, "right") <= f(&e, "w")
                && f(&e, "bottom") <= f(&e, "h"),
            "{w}x{h}: the fitted program lies inside the view: {e}"
        );
        page.screenshot(&repo(&format!("docs/ui-{w}x{h}.png")))
            .await;
    }
    page.set_viewport(1024, 768).await;
    // The preview and the tool meet: run the program; where it ends is the path's
    // last point, in the same workpiece coordinates the tool marker is drawn in.
    page.click("#run").await;
    page.wait(
        "pkmc.lastStatus.job != null",
        "the example runs",
        Timeout::S(5),
    )
    .await;
    page.wait_idle(Timeout::S(60)).await;
    let gap = page
        .js(
            "(() => { const p = pkmc.program.path, e = p[p.length - 1], q = pkmc.lastStatus.pose; \
             return Math.hypot(e[0] - q[0], e[1] - q[1], e[2] - q[2]); })()",
        )
        .await;
    assert!(
        gap.as_f64().unwrap() < 0.01,
        "the path's end and the tool are {gap} mm apart"
    );

    // Keyboard jog: → X + step, Shift+↑ Y + 10 steps, Alt+PgDn Z − a tenth.
    page.select("#jog-step", "1").await;
    page.js("(() => { document.activeElement.blur(); return true; })()")
        .await;
    let pose = |v: &serde_json::Value, k: usize| v[k].as_f64().unwrap();
    for (mods, key, axis, d) in [
        (vec![], '\u{e014}', 0usize, 1.0),
        (vec!['\u{e008}'], '\u{e013}', 1, 10.0),
        (vec!['\u{e00a}'], '\u{e00f}', 2, -0.1),
    ] {
        let before = page.js("pkmc.lastStatus.pose").await;
        page.key_with(&mods, key).await;
        page.wait(
            &format!(
                "Math.abs(pkmc.lastStatus.pose[{axis}] - {}) < 0.0005 && pkmc.lastStatus.state === 'Idle' && !pkmc.lastStatus.job",
                pose(&before, axis) + d
            ),
            &format!("the key jogs axis {axis} by {d}"),
            Timeout::S(15),
        )
        .await;
    }
    let log = page
        .js("pkmc.log.filter(l => /^\\s*(done|jog done)\\s*$/.test(l.text)).length")
        .await;
    assert_eq!(log, 0, "jogs end without a log line each");

    // Inches: the DRO shows X in inches, 4 decimals, unit "in".
    page.click("#units").await;
    let x = page.js("pkmc.lastStatus.pose[0]").await.as_f64().unwrap();
    let shown = page
        .wait(
            "document.querySelector('.dro-row[data-axis=X] .unit').textContent === 'in' && \
             document.getElementById('dro-x').textContent",
            "inches shown",
            Timeout::S(2),
        )
        .await;
    assert_eq!(shown, format!("{:.4}", x / 25.4));
    page.click("#units").await;

    // A teach file saved and loaded back exactly: the speed 2000 mm/min (2000 mm/min
    // is 33 333 333 nm/s inside) and two positions.
    page.click("#teach-clear").await;
    // The speed set in its field as an operator's edit ends (a change event); typed
    // keys could land after the clear's answer rewrites the field.
    page.js(
        "(() => { const f = document.getElementById('teach-speed'); f.focus(); f.value = '2000'; \
             f.dispatchEvent(new Event('change')); f.blur(); return true; })()",
    )
    .await;
    page.wait(
        "pkmc.teach && pkmc.teach.speed === 2000 && pkmc.teach.points.length === 0",
        "speed 2000",
        Timeout::S(5),
    )
    .await;
    for n in 1..=2 {
        page.key_with(&['\u{e00a}'], '\u{e014}').await;
        page.wait_idle(Timeout::S(10)).await;
        page.click("#teach-set").await;
        page.wait(
            &format!("pkmc.teach.points.length === {n}"),
            "recorded",
            Timeout::S(5),
        )
        .await;
    }
    let first = save_teach(&page).await;
    // The Load dialog offers the file the page saves.
    assert_eq!(
        page.js("document.getElementById('teach-load').accept.split(',').includes('.ngc')")
            .await,
        true
    );
    page.click("#teach-clear").await;
    page.wait("pkmc.teach.points.length === 0", "cleared", Timeout::S(5))
        .await;
    page.js("(() => { document.getElementById('teach-speed').value = '1'; return true; })()")
        .await;
    let load_from = std::env::temp_dir().join(format!("pkmc-teach-{}.ngc", std::process::id()));
    std::fs::write(&load_from, &first).unwrap();
    page.upload("#teach-load", &load_from).await;
    page.wait(
        "pkmc.teach.points.length === 2 && document.getElementById('teach-speed').value === '2000'",
        "loaded back with its speed as written",
        Timeout::S(5),
    )
    .await;
    let second = save_teach(&page).await;
    assert_eq!(
        first, second,
        "saved, loaded and saved again: the same file"
    );
    let _ = std::fs::remove_file(&load_from);

    // E-STOP: worded as an e-stop, what to do next, Run and Jog refused, in the
    // history; a key jog does nothing.
    page.click("#estop").await;
    let words = page
        .wait(
            "pkmc.lastStatus.alarm && document.getElementById('state').textContent === 'E-STOP' && \
             document.getElementById('alarm').textContent",
            "the e-stop is shown as E-STOP",
            Timeout::S(5),
        )
        .await;
    let words = words.as_str().unwrap().to_string();
    assert!(
        words.starts_with("E-STOP") && words.contains("Reset"),
        "{words}"
    );
    assert!(!words.contains("Aborted"), "{words}");
    page.wait(
        "document.getElementById('run').disabled && \
         [...document.querySelectorAll('#jog-buttons button')].every(b => b.disabled)",
        "Run and Jog are disabled in the e-stop",
        Timeout::S(3),
    )
    .await;
    let before = page.js("pkmc.lastStatus.pose").await;
    page.key_with(&[], '\u{e014}').await;
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert_eq!(page.js("pkmc.lastStatus.pose").await, before);
    let history = page
        .js("[...document.querySelectorAll('#alarm-history li')].map(l => l.textContent)")
        .await;
    assert!(history[0].as_str().unwrap().contains("E-STOP"), "{history}");
    page.click("#reset").await;
    page.wait(
        "!pkmc.lastStatus.alarm && !document.getElementById('run').disabled",
        "Reset clears it and Run is offered again",
        Timeout::S(5),
    )
    .await;

    // A program with a pre-flight error is drawn, the error marked, Run refused.
    let bad = std::env::temp_dir().join(format!("pkmc-reach-{}.ngc", std::process::id()));
    std::fs::write(&bad, "G21 G90\nG1 X5 Y5 F600\nG1 X5000\nG1 X0 Y0\nM2\n").unwrap();
    page.upload("#file", &bad).await;
    let preview = page
        .wait(
            "pkmc.program && pkmc.program.errors.length > 0 && pkmc.preview && pkmc.preview",
            "the unreachable program is drawn",
            Timeout::S(10),
        )
        .await;
    assert!(preview["points"].as_u64().unwrap() >= 3, "{preview}");
    assert!(preview["errors"].as_u64().unwrap() >= 1, "{preview}");
    assert_eq!(
        page.js("document.getElementById('run').disabled").await,
        true
    );
    let _ = std::fs::remove_file(&bad);
    let _ = st.status_after_stopping_the_station().await;
}

/// Saves the teach list through the browser; returns the file's text.
async fn save_teach(page: &Page) -> String {
    let saved = page.downloads.join("teach.ngc");
    let _ = std::fs::remove_file(&saved);
    page.click("#teach-save").await;
    let t = std::time::Instant::now();
    loop {
        if let Ok(text) = std::fs::read_to_string(&saved) {
            if !text.is_empty() {
                return text;
            }
        }
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "the browser saved no teach.ngc"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}
