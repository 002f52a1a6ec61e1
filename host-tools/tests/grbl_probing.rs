//! G38.2–G38.5 sent by a sender to `nc-send --sim grbl`, against the simulator's
//! probe (`--probe-plane`): the bridge lets the motion before the probing move end,
//! runs it, and answers as Grbl 1.1 does: `[PRB:x,y,z:1]` in machine position then
//! `ok`; `:0` without the change; `ALARM:5` for a G38.2 or G38.4 that finds nothing;
//! `ALARM:4` for a probe already in the state sought; `$#` repeats the last `[PRB:…]`;
//! the status shows `Pn:P` while the probe is triggered.

mod common;
mod grbl;

use grbl::{field, Bridge, Client, Via};
use std::time::Duration;

/// The plane the simulated probe touches, mm.
const PLANE: f64 = -3.25;
/// Its trigger noise (standard deviation), µm.
const NOISE_UM: f64 = 0.5;

over_both! {
    a_probe_onto_a_plane_reports_prb_in_machine_position_and_sets_5061 => onto_plane;
}

fn bridge() -> Bridge {
    Bridge::start(&[
        "--probe-plane",
        &PLANE.to_string(),
        "--probe-noise-um",
        &NOISE_UM.to_string(),
    ])
}

/// `[PRB:x,y,z:c]` → (x y z, c); panics on anything else.
fn prb(line: &str) -> (Vec<f64>, u8) {
    let body = line
        .strip_prefix("[PRB:")
        .and_then(|l| l.strip_suffix(']'))
        .unwrap_or_else(|| panic!("not a PRB line: {line}"));
    let (xyz, c) = body.rsplit_once(':').unwrap();
    let v = xyz.split(',').map(|v| v.parse().unwrap()).collect();
    (v, c.parse().unwrap())
}

/// The G38.2 comes while a move runs: it waits for it (Grbl synchronises), then its
/// `[PRB:…]` is the machine position of the contact: the plane within 1 µm plus 4 σ
/// of the noise (and the report's 0.5 µm rounding). #5061–#5063 hold it in program
/// coordinates (the G54 offset taken off), as LinuxCNC's do.
fn onto_plane(via: Via) {
    let bridge = bridge();
    let mut c = Client::open(&bridge, via);
    assert_eq!(c.command("G10 L2 P1 X2 Y-1"), vec!["ok"]);
    assert_eq!(c.command("G1 X1 Y1 F600"), vec!["ok"]);
    let got = c.command("G38.2 Z-10 F100");
    assert_eq!(got.len(), 2, "[PRB:…] then ok: {got:?}");
    assert_eq!(got[1], "ok");
    let (at, contact) = prb(&got[0]);
    assert_eq!(contact, 1, "{got:?}");
    assert_eq!(&at[..2], &[3.0, 0.0], "machine X Y of the contact: {got:?}");
    let bound = 1e-3 + 4.0 * NOISE_UM * 1e-3 + 0.5e-3;
    assert!(
        (at[2] - PLANE).abs() <= bound,
        "the contact {} against the plane {PLANE} (bound {bound}): {got:?}",
        at[2]
    );
    let s = c.status();
    println!(
        "{via:?}: {} (the plane {PLANE}, {:.2} µm off), then {s}",
        got[0],
        (at[2] - PLANE).abs() * 1e3
    );
    assert!(s.contains("|Pn:P"), "the probe stopped touching: {s}");
    assert!(s.starts_with("<Idle|"), "{s}");
    let stopped = field(&s, "MPos")[2];
    assert!(
        stopped < at[2] && stopped > at[2] - 0.2,
        "stopped a little past the contact: {s}"
    );
    let offsets = c.command("$#");
    assert_eq!(offsets[offsets.len() - 2], got[0], "$# repeats it");
    // #5061 is in program coordinates: X 3 machine is X 1 in G54 (offset X2).
    assert_eq!(c.command("G0 X[#5061+1] Z[#5063+1]"), vec!["ok"]);
    let s = c.wait_state("Idle", Duration::from_secs(10));
    let mpos = field(&s, "MPos");
    assert!((mpos[0] - 4.0).abs() < 1e-3, "{s}");
    assert!((mpos[2] - (at[2] + 1.0)).abs() <= 1e-3, "{s}");
    assert!(!s.contains("|Pn:"), "off the plane: {s}");
    let summary = bridge.stop();
    assert_eq!(summary["errors"], 0, "{summary}");
}

/// G38.3 that finds nothing: `[PRB:…:0]` where it stopped, `ok`, no alarm. G38.2
/// that finds nothing: `ALARM:5`, then `[PRB:…:0]` repeating the last probe's
/// position (Grbl keeps it), then `ok`; G-code is locked out until `$X`.
#[test]
fn a_probe_that_finds_nothing_is_prb_0_or_alarm_5() {
    let bridge = bridge();
    let mut c = Client::open(&bridge, Via::Tcp);
    let got = c.command("G38.3 Z-1 F300");
    assert_eq!(got, vec!["[PRB:0.000,0.000,-1.000:0]", "ok"]);
    let got = c.command("G38.2 Z-2 F300");
    assert_eq!(got[0], "ALARM:5", "{got:?}");
    assert!(
        got[1].starts_with("[MSG:sender:") && got[1].contains("without contact"),
        "{got:?}"
    );
    assert_eq!(&got[2..], &["[PRB:0.000,0.000,-1.000:0]", "ok"]);
    let s = c.status();
    assert!(s.starts_with("<Alarm|"), "{s}");
    assert_eq!(field(&s, "MPos")[2], -2.0, "{s}");
    assert_eq!(c.command("G0 Z0").last().unwrap(), "error:9");
    assert_eq!(
        c.command("$#")[10],
        "[PRB:0.000,0.000,-1.000:0]",
        "$# in the alarm"
    );
    // A soft reset keeps the alarm, as Grbl's state outlives its reset.
    c.send(&[0x18]);
    c.line_until(|l| l.starts_with("Grbl 1.1h"), Duration::from_secs(5));
    let unlock = c.line(Duration::from_secs(5)).unwrap();
    assert!(unlock.contains("ALARM:5"), "{unlock}");
    assert!(c.status().starts_with("<Alarm|"));
    assert_eq!(c.command("$X"), vec!["[MSG:Caution: Unlocked]", "ok"]);
    assert!(c.status().starts_with("<Idle|"));
    // A stop on the probing move's line would come after it: refused.
    assert_eq!(c.command("G38.2 Z-10 F100 M0").last().unwrap(), "error:20");
    // Check mode: nothing moves, the line is answered at once, and the lines after
    // it read the front end as if the probe had touched at the move's end.
    assert_eq!(c.command("$C"), vec!["[MSG:Enabled]", "ok"]);
    assert_eq!(c.command("G38.2 Z-10 F100"), vec!["ok"]);
    assert_eq!(c.command("G0 Z[#5063+9]"), vec!["ok"]);
    assert_eq!(c.command("$C"), vec!["[MSG:Disabled]", "ok"]);
    let s = c.status();
    assert_eq!(
        field(&s, "MPos")[2],
        -2.0,
        "nothing moved in check mode: {s}"
    );
    let summary = bridge.stop();
    assert_eq!(
        summary["errors"], 2,
        "the G0 in the alarm, the G38.2 with M0: {summary}"
    );
}

/// A probe already touching when a G38.2 starts: the controller's `ProbeAtStart`,
/// `ALARM:4` and its cause, then `ok` (as Grbl answers the line); nothing moved.
/// G38.4 and G38.5 seek the loss of contact: from under the plane up through it,
/// `[PRB:…:1]` at the plane; one that stays under it is `:0` (G38.5) or `ALARM:5`
/// (G38.4).
#[test]
fn g38_4_and_g38_5_seek_losing_contact_and_a_probe_touching_at_the_start_is_alarm_4() {
    let bridge = bridge();
    let mut c = Client::open(&bridge, Via::Tcp);
    assert_eq!(c.command("G0 Z-5"), vec!["ok"]);
    let s = c.wait_state("Idle", Duration::from_secs(10));
    assert!(s.contains("|Pn:P"), "under the plane: {s}");
    let got = c.command("G38.2 Z-6 F100");
    assert_eq!(got[0], "ALARM:4", "{got:?}");
    assert!(got[1].starts_with("[MSG:"), "{got:?}");
    assert_eq!(got.last().unwrap(), "ok");
    let s = c.status();
    assert!(s.starts_with("<Alarm|"), "{s}");
    assert_eq!(field(&s, "MPos")[2], -5.0, "nothing moved: {s}");
    assert_eq!(c.command("$X"), vec!["[MSG:Caution: Unlocked]", "ok"]);
    // G38.5 staying under the plane: no loss, no alarm.
    let got = c.command("G38.5 Z-4 F200");
    assert_eq!(got, vec!["[PRB:0.000,0.000,-4.000:0]", "ok"]);
    // G38.4 up through the plane: the loss of contact, at the plane.
    let got = c.command("G38.4 Z0 F100");
    assert_eq!(got.len(), 2, "{got:?}");
    let (at, contact) = prb(&got[0]);
    assert_eq!(contact, 1, "{got:?}");
    let bound = 1e-3 + 4.0 * NOISE_UM * 1e-3 + 0.5e-3;
    assert!((at[2] - PLANE).abs() <= bound, "{got:?}");
    let s = c.status();
    assert!(!s.contains("|Pn:"), "clear of the plane: {s}");
    // G38.4 from above the plane: the probe is already clear, ALARM:4.
    let got = c.command("G38.4 Z1 F100");
    assert_eq!(got[0], "ALARM:4", "{got:?}");
    assert_eq!(c.command("$X"), vec!["[MSG:Caution: Unlocked]", "ok"]);
    // G38.4 staying under the plane finds no loss: ALARM:5, the last probe kept.
    assert_eq!(c.command("G0 Z-5"), vec!["ok"]);
    let got = c.command("G38.4 Z-4 F200");
    assert_eq!(got[0], "ALARM:5", "{got:?}");
    let (kept, contact) = prb(&got[2]);
    assert_eq!((kept, contact), (at, 0), "{got:?}");
    bridge.stop();
}
