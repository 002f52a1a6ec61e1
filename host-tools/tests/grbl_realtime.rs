//! Grbl 1.1's real-time rules in every state of `nc-send grbl`, one test per rule,
//! each driven with raw bytes over the pseudo-terminal (`rule::pty`) and over TCP
//! (`rule::tcp`). Every read has a timeout; the times asked are printed with what was
//! measured.

mod common;
mod grbl;

use grbl::{field, stream_counting, Bridge, Client, Via};
use std::time::{Duration, Instant};

/// How soon a `?` must be answered, in every state.
const STATUS_LIMIT: Duration = Duration::from_millis(50);

/// Sends `line` and returns what came back up to its answer (`ok` or `error:N`),
/// which must come within `limit`; status reports are left out.
fn command_within(c: &mut Client, line: &str, limit: Duration) -> Vec<String> {
    let start = Instant::now();
    c.send(format!("{line}\n").as_bytes());
    let mut got = Vec::new();
    loop {
        let left = limit.saturating_sub(start.elapsed());
        let Some(l) = c.line(left) else {
            panic!("no answer to {line:?} within {limit:?}; got {got:?}");
        };
        if l.starts_with('<') {
            continue;
        }
        let end = l == "ok" || l.starts_with("error:");
        got.push(l);
        if end {
            assert!(start.elapsed() <= limit, "{line:?} answered late: {got:?}");
            return got;
        }
    }
}

/// Polls `?` (each answered within [`STATUS_LIMIT`]) until the state is `state`;
/// returns that report and every state word seen on the way.
fn poll_until(c: &mut Client, state: &str, limit: Duration) -> (String, Vec<String>) {
    let end = Instant::now() + limit;
    let mut seen = Vec::new();
    loop {
        let s = c.status_within(STATUS_LIMIT);
        let word = s[1..].split('|').next().unwrap_or("").to_string();
        if seen.last() != Some(&word) {
            seen.push(word.clone());
        }
        if word == state {
            return (s, seen);
        }
        assert!(Instant::now() < end, "state {state} not reached: {seen:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A setting from `$$`.
fn setting(c: &mut Client, n: u32) -> f64 {
    let all = c.command("$$");
    let key = format!("${n}=");
    all.iter()
        .find_map(|l| l.strip_prefix(&key))
        .unwrap_or_else(|| panic!("{key} in {all:?}"))
        .parse()
        .unwrap()
}

/// Point 1 of issue 32: `$X`, `$H`, `$C` and `$J=` in a paused job get Grbl's answers
/// at once, and `?` is answered within 50 ms at every step.
fn paused_job_keeps_answering(c: &mut Client) {
    assert_eq!(
        command_within(c, "G21 G90 G1 X50 F600", Duration::from_secs(1)),
        vec!["ok"]
    );
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(1) {
        c.status_within(STATUS_LIMIT);
        std::thread::sleep(Duration::from_millis(100));
    }
    c.send(b"!");
    let (held, _) = poll_until(c, "Hold:0", Duration::from_secs(5));
    let x = field(&held, "MPos")[0];
    assert!(x > 5.0 && x < 50.0, "{held}");
    for (line, answer) in [
        ("$X", "ok"),
        ("$H", "error:8"),
        ("$C", "error:8"),
        ("$J=G91 X1 F100", "error:8"),
    ] {
        let got = command_within(c, line, Duration::from_millis(500));
        assert_eq!(got.last().unwrap(), answer, "{line}: {got:?}");
        let s = c.status_within(STATUS_LIMIT);
        assert!(s.starts_with("<Hold:0|"), "after {line}: {s}");
        assert_eq!(field(&s, "MPos")[0], x, "nothing moved after {line}");
    }
    println!("status waits: {}; {:?}", c.wait_figures(), c.waits);
}

over_both! {
    a_paused_job_answers_grbl_commands_and_status_then_resumes => paused_job_resumes;
    a_paused_job_answers_and_ctrl_c_still_ends_the_bridge => paused_job_ctrl_c;
    a_jog_reports_jog_and_0x85_or_a_feed_hold_cancels_it_within_its_deceleration => jog_cancels;
    jogs_queue_each_answered_at_once_and_g_code_is_locked_out_meanwhile => jogs_queue;
    a_jog_runs_at_its_own_feed_whatever_the_feed_override => jog_ignores_override;
    a_second_sender_is_told_busy_and_never_evicts_the_first => second_sender_busy;
    the_startup_echo_is_one_line_and_a_counting_sender_runs_a_thousand_lines => startup_echo_and_counting;
    an_error_while_moving_neither_holds_nor_stops_the_answers => error_while_moving;
    m6_is_error_20_as_on_grbl_unless_a_tool_change_pause_is_asked_for => m6_error_20;
    a_new_sender_is_told_of_a_held_job_and_its_reset_clears_it => held_job_handed_over;
    settings_show_max_travel_m2_says_pgm_end_and_check_mode_refuses_jogs => settings_pgm_end_check;
    dollar_commands_are_refused_in_a_cycle_a_hold_a_jog_and_check_mode_as_on_grbl => dollar_by_state;
    overrides_and_reset_act_while_held_jogging_and_in_check_mode => overrides_and_reset;
    g_code_errors_carry_grbls_numbers => g_code_errors;
    every_grbl_error_number_is_given_for_a_line_that_has_its_fault => every_error_number;
    unlock_is_refused_while_the_e_stop_is_latched => unlock_refused_in_e_stop;
    homing_answers_status_and_a_reset_cancels_it_with_alarm_6 => homing_reset;
}

fn paused_job_resumes(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut c = Client::open(&bridge, via);
    paused_job_keeps_answering(&mut c);
    c.send(b"~");
    let (s, _) = poll_until(&mut c, "Idle", Duration::from_secs(10));
    assert_eq!(field(&s, "MPos")[0], 50.0, "{s}");
    if via == Via::Tcp {
        // A new TCP sender (the first has gone) is greeted at once.
        drop(c);
        let mut c = Client::connect(&bridge.tcp);
        c.status_within(STATUS_LIMIT);
    }
    let summary = bridge.stop();
    assert_eq!(summary["status"]["pose"]["x"], 50.0, "{summary}");
}

fn paused_job_ctrl_c(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut c = Client::open(&bridge, via);
    paused_job_keeps_answering(&mut c);
    // Ctrl-C while the job is held: the bridge ends, with its summary.
    let summary = bridge.stop();
    let x = summary["status"]["pose"]["x"].as_f64().unwrap();
    assert!(x > 5.0 && x < 50.0, "{summary}");
}

/// Jog, cancel it with `cancel` half a second in; returns (the report just before
/// the cancel, the report at rest, every state seen after the cancel).
fn jog_and_cancel(c: &mut Client, cancel: u8) -> (String, String, Vec<String>) {
    let x0 = field(&c.status_within(STATUS_LIMIT), "MPos")[0];
    assert_eq!(
        command_within(c, "$J=G91 X30 F1200", Duration::from_millis(300)),
        vec!["ok"]
    );
    let start = Instant::now();
    let mut states = Vec::new();
    while start.elapsed() < Duration::from_millis(470) {
        let s = c.status_within(STATUS_LIMIT);
        states.push(s[1..4].to_string());
        std::thread::sleep(Duration::from_millis(30));
    }
    assert!(
        states.iter().any(|s| s == "Jog"),
        "a jog reports Jog: {states:?}"
    );
    // The cancel goes out right after this report.
    let before = c.status_within(STATUS_LIMIT);
    c.send(&[cancel]);
    let (rest, seen) = poll_until(c, "Idle", Duration::from_secs(3));
    let x = field(&rest, "MPos")[0];
    assert!(x - x0 < 30.0 - 1.0, "the jog was cut short: {x0} → {x}");
    (before, rest, seen)
}

fn jog_cancels(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut c = Client::open(&bridge, via);
    let accel = setting(&mut c, 120);
    for cancel in [0x85u8, b'!'] {
        let (before, rest, seen) = jog_and_cancel(&mut c, cancel);
        assert!(
            !seen.iter().any(|s| s.starts_with("Hold")),
            "a cancelled jog holds nothing: {seen:?}"
        );
        // From the report just before the cancel: its speed v stops within v²/2a,
        // plus what it covers in the 50 ms the cancel may take to act.
        let v = field(&before, "FS")[0] / 60.0;
        let x_before = field(&before, "MPos")[0];
        let x_rest = field(&rest, "MPos")[0];
        let allowed = v * v / (2.0 * accel) + v * 0.05;
        println!(
            "cancel 0x{cancel:02X}: {v:.1} mm/s, stopped {:.3} mm after the last report (allowed {allowed:.3}); states {seen:?}",
            x_rest - x_before
        );
        assert!(v > 15.0, "the jog was at speed: {before}");
        assert!(x_rest - x_before <= allowed, "{before} → {rest}");
        // Nothing latched: still Idle a moment later, and the next jog runs.
        std::thread::sleep(Duration::from_millis(300));
        let s = c.status_within(STATUS_LIMIT);
        assert!(s.starts_with("<Idle|"), "{s}");
        assert_eq!(field(&s, "MPos")[0], x_rest);
    }
    println!("status waits: {}", c.wait_figures());
    let x0 = field(&c.status_within(STATUS_LIMIT), "MPos")[0];
    assert_eq!(
        command_within(&mut c, "$J=G91 X-2 F600", Duration::from_millis(300)),
        vec!["ok"]
    );
    let (s, _) = poll_until(&mut c, "Idle", Duration::from_secs(5));
    assert!((field(&s, "MPos")[0] - (x0 - 2.0)).abs() < 1e-3, "{s}");
    bridge.stop();
}

fn jogs_queue(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut c = Client::open(&bridge, via);
    let y0 = field(&c.status_within(STATUS_LIMIT), "MPos")[1];
    let start = Instant::now();
    for _ in 0..3 {
        assert_eq!(
            command_within(&mut c, "$J=G91 Y4 F600", Duration::from_millis(300)),
            vec!["ok"]
        );
    }
    let answered = start.elapsed();
    let s = c.status_within(STATUS_LIMIT);
    assert!(
        s.starts_with("<Jog|"),
        "three jogs of 0.4 s each are not over after {answered:?}: {s}"
    );
    let g = command_within(&mut c, "G0 X5", Duration::from_millis(300));
    assert_eq!(g.last().unwrap(), "error:9", "{g:?}");
    // The three run as one: no slowing down where one jog meets the next.
    let end = Instant::now() + Duration::from_secs(10);
    let mut speeds = Vec::new();
    let s = loop {
        let s = c.status_within(STATUS_LIMIT);
        let y = field(&s, "MPos")[1] - y0;
        if y > 0.5 && y < 11.5 {
            speeds.push(field(&s, "FS")[0]);
        }
        if s.starts_with("<Idle|") {
            break s;
        }
        assert!(Instant::now() < end, "the jogs did not end: {s}");
        std::thread::sleep(Duration::from_millis(10));
    };
    let slowest = speeds.iter().cloned().fold(f64::INFINITY, f64::min);
    println!(
        "{} reports between 0.5 and 11.5 mm, slowest {slowest} mm/min",
        speeds.len()
    );
    assert!(speeds.len() >= 20 && slowest >= 570.0, "{speeds:?}");
    assert!((field(&s, "MPos")[1] - (y0 + 12.0)).abs() < 1e-3, "{s}");
    println!("three queued jogs answered in {answered:?}");
    bridge.stop();
}

/// The first sender is on `via`; the others are a TCP sender and, when the first is
/// on TCP, the pseudo-terminal too. They are told Busy and nothing they send is read.
fn second_sender_busy(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut first = Client::open(&bridge, via);
    assert_eq!(
        command_within(&mut first, "G1 X30 F600", Duration::from_secs(1)),
        vec!["ok"]
    );
    poll_until(&mut first, "Run", Duration::from_secs(2));
    let mut tcp = Client::tcp(&bridge.tcp);
    let told = tcp
        .line(Duration::from_secs(2))
        .expect("the TCP sender is told something");
    assert!(told.starts_with("[MSG:Busy"), "{told}");
    tcp.send(b"!G0 X0\n");
    let mut others = vec![tcp];
    if via == Via::Tcp {
        // The pseudo-terminal says nothing when opened: its sender is told Busy when
        // it sends.
        let mut pty = Client::pty(&bridge.pty);
        pty.send(b"!G0 X0\n");
        let told = pty
            .line(Duration::from_secs(2))
            .expect("the sender on the pseudo-terminal is told something");
        assert!(told.starts_with("[MSG:Busy"), "{told}");
        others.push(pty);
    }
    let s = first.status_within(STATUS_LIMIT);
    assert!(s.starts_with("<Run|"), "the others' ! was not read: {s}");
    // The first sender still commands the job.
    first.send(b"!");
    poll_until(&mut first, "Hold:0", Duration::from_secs(3));
    first.send(b"~");
    let (s, _) = poll_until(&mut first, "Idle", Duration::from_secs(10));
    assert_eq!(field(&s, "MPos")[0], 30.0, "{s}");
    for o in &mut others {
        assert!(
            o.line(Duration::from_millis(200))
                .is_none_or(|l| l.starts_with("[MSG:Busy")),
            "the other senders get no banner and no answers"
        );
    }
    bridge.stop();
}

/// A 1,000-line program: a spiral of short G1 moves (about 0.3 mm each).
fn spiral() -> Vec<(String, [f64; 2])> {
    (0..1000)
        .map(|i| {
            let t = i as f64 * std::f64::consts::TAU / 250.0;
            let r = 10.0 + i as f64 * 0.01;
            let p = [
                (r * t.cos() * 1000.0).round() / 1000.0,
                (r * t.sin() * 1000.0).round() / 1000.0,
            ];
            (format!("G1 X{:.3} Y{:.3} F3000", p[0], p[1]), p)
        })
        .collect()
}

fn startup_echo_and_counting(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut c = Client::open(&bridge, via);
    assert_eq!(c.command("G10 L2 P2 X1 Y2"), vec!["ok"]);
    assert_eq!(c.command("$N0=G55"), vec!["ok"]);
    c.send(&[0x18]);
    c.line_until(|l| l.starts_with("Grbl 1.1h"), Duration::from_secs(5));
    assert_eq!(c.line(Duration::from_secs(5)).unwrap(), ">G55:ok");
    let program = spiral();
    let text: Vec<String> = program.iter().map(|(l, _)| l.clone()).collect();
    let start = Instant::now();
    let errors = stream_counting(&mut c, &text, Duration::from_secs(120));
    let streamed = start.elapsed();
    assert_eq!(errors, 0);
    let (s, _) = poll_until(&mut c, "Idle", Duration::from_secs(60));
    let last = program.last().unwrap().1;
    let mpos = field(&s, "MPos");
    assert!(
        (mpos[0] - (last[0] + 1.0)).abs() < 1e-3 && (mpos[1] - (last[1] + 2.0)).abs() < 1e-3,
        "ends on the last line in G55: {s}"
    );
    println!(
        "1000 lines answered in {streamed:?}, at rest after {:?}",
        start.elapsed()
    );
    let summary = bridge.stop();
    assert_eq!(summary["errors"], 0, "{summary}");
}

fn error_while_moving(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut c = Client::open(&bridge, via);
    assert_eq!(
        command_within(&mut c, "G1 X20 F600", Duration::from_secs(1)),
        vec!["ok"]
    );
    poll_until(&mut c, "Run", Duration::from_secs(2));
    let bad = command_within(&mut c, "G1 X1 Q", Duration::from_millis(500));
    assert!(bad.last().unwrap().starts_with("error:"), "{bad:?}");
    assert_eq!(
        command_within(&mut c, "G1 Y5", Duration::from_millis(500)),
        vec!["ok"]
    );
    let s = c.status_within(STATUS_LIMIT);
    assert!(s.starts_with("<Run|"), "{s}");
    let (s, seen) = poll_until(&mut c, "Idle", Duration::from_secs(15));
    assert!(!seen.iter().any(|w| w.starts_with("Hold")), "{seen:?}");
    assert_eq!(field(&s, "MPos")[..2], [20.0, 5.0], "{s}");
    bridge.stop();
}

fn m6_error_20(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut c = Client::open(&bridge, via);
    let got = command_within(&mut c, "T2 M6", Duration::from_millis(500));
    assert_eq!(got.last().unwrap(), "error:20", "{got:?}");
    assert!(
        got[0].contains("M6") && got[0].contains("--tool-change"),
        "{got:?}"
    );
    assert!(c.status_within(STATUS_LIMIT).starts_with("<Idle|"));
    bridge.stop();

    let bridge = Bridge::start_with(&[], &["--tool-change", "pause"]);
    let mut c = Client::open(&bridge, via);
    for line in ["G1 X5 F600", "T2 M6", "G1 X10"] {
        assert_eq!(
            command_within(&mut c, line, Duration::from_secs(1)),
            vec!["ok"]
        );
    }
    let (s, _) = poll_until(&mut c, "Hold:0", Duration::from_secs(5));
    assert_eq!(
        field(&s, "MPos")[0],
        5.0,
        "held for the tool at the M6: {s}"
    );
    c.send(b"~");
    let (s, _) = poll_until(&mut c, "Idle", Duration::from_secs(5));
    assert_eq!(field(&s, "MPos")[0], 10.0, "{s}");
    bridge.stop();
}

/// The previous sender is on `via`; the new one is on TCP (a pseudo-terminal does not
/// tell the bridge that a new sender has opened it). The sender on the
/// pseudo-terminal holds the bridge while it has sent a byte in the last 5 s.
fn held_job_handed_over(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut a = Client::open(&bridge, via);
    assert_eq!(
        command_within(&mut a, "G1 X50 F600", Duration::from_secs(1)),
        vec!["ok"]
    );
    poll_until(&mut a, "Run", Duration::from_secs(2));
    a.send(b"!");
    let (held, _) = poll_until(&mut a, "Hold:0", Duration::from_secs(5));
    drop(a);
    let quiet = match via {
        Via::Tcp => Duration::from_millis(200),
        Via::Pty => Duration::from_millis(5_300),
    };
    std::thread::sleep(quiet);
    let mut b = Client::connect(&bridge.tcp);
    let msg = b
        .line(Duration::from_secs(1))
        .expect("a word about the held job");
    assert!(
        msg.starts_with("[MSG:A job of the previous sender is held") && msg.contains("Ctrl-X"),
        "{msg}"
    );
    b.send(&[0x18]);
    b.line_until(|l| l.starts_with("Grbl 1.1h"), Duration::from_secs(5));
    let (s, _) = poll_until(&mut b, "Idle", Duration::from_secs(3));
    b.send(b"~");
    std::thread::sleep(Duration::from_millis(500));
    let after = b.status_within(STATUS_LIMIT);
    assert!(after.starts_with("<Idle|"), "{after}");
    assert_eq!(
        field(&after, "MPos"),
        field(&s, "MPos"),
        "the old job is gone: {held} {after}"
    );
    bridge.stop();
}

fn settings_pgm_end_check(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut c = Client::open(&bridge, via);
    // On the Cartesian machine X is joint 1: $130 is its travel, $201 − $200.
    let travel = setting(&mut c, 130);
    let (min, max) = (setting(&mut c, 200), setting(&mut c, 201));
    assert!(
        (travel - (max - min)).abs() < 1e-3,
        "$130={travel} for [{min}, {max}]"
    );
    assert!(setting(&mut c, 131) > 0.0 && setting(&mut c, 132) > 0.0);
    assert_eq!(c.command("G0 X1"), vec!["ok"]);
    assert_eq!(c.command("M2"), vec!["[MSG:Pgm End]", "ok"]);
    // While the move runs, $C is refused as Grbl refuses it outside Idle.
    assert_eq!(c.command("$C").last().unwrap(), "error:8");
    poll_until(&mut c, "Idle", Duration::from_secs(5));
    assert_eq!(c.command("$C"), vec!["[MSG:Enabled]", "ok"]);
    assert!(c.status_within(STATUS_LIMIT).starts_with("<Check|"));
    assert_eq!(c.command("$J=G91 X1 F100").last().unwrap(), "error:8");
    assert_eq!(c.command("$H").last().unwrap(), "error:8");
    assert_eq!(c.command("$C"), vec!["[MSG:Disabled]", "ok"]);
    bridge.stop();
}

/// Sends each `$` line and checks its answer (`ok` or `error:N`, within 500 ms),
/// then that a `?` within 50 ms still reports a state starting with `state`.
fn dollar_answers(c: &mut Client, expected: &[(&str, &str)], state: &str) {
    for (line, answer) in expected {
        let got = command_within(c, line, Duration::from_millis(500));
        assert_eq!(got.last().unwrap(), answer, "{line} in {state}: {got:?}");
        if *answer == "error:8" {
            assert_eq!(got.len(), 2, "{line}: a message, then the error: {got:?}");
        }
        let s = c.status_within(STATUS_LIMIT);
        assert!(s.starts_with(&format!("<{state}")), "after {line}: {s}");
    }
}

/// Grbl 1.1's `system_execute_line` answers `$` lines by state: `$`, `$G` and `$X`
/// always; `$$` except in a cycle or a hold; `$#`, `$I`, `$N`, settings only idle or
/// in an alarm; storing a start-up line only idle.
fn dollar_by_state(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut c = Client::open(&bridge, via);
    let idle = [
        ("$$", "ok"),
        ("$#", "ok"),
        ("$I", "ok"),
        ("$N", "ok"),
        ("$130", "ok"),
        ("$G", "ok"),
        ("$", "ok"),
    ];
    dollar_answers(&mut c, &idle, "Idle");
    assert_eq!(
        command_within(&mut c, "G21 G90 G1 X40 F600", Duration::from_secs(1)),
        vec!["ok"]
    );
    poll_until(&mut c, "Run", Duration::from_secs(2));
    let cycle = [
        ("$$", "error:8"),
        ("$#", "error:8"),
        ("$I", "error:8"),
        ("$N", "error:8"),
        ("$N0=G54", "error:8"),
        ("$130", "error:8"),
        ("$G", "ok"),
        ("$", "ok"),
        ("$X", "ok"),
    ];
    dollar_answers(&mut c, &cycle, "Run");
    c.send(b"!");
    let (held, _) = poll_until(&mut c, "Hold:0", Duration::from_secs(5));
    dollar_answers(&mut c, &cycle, "Hold:0");
    let s = c.status_within(STATUS_LIMIT);
    assert_eq!(field(&s, "MPos"), field(&held, "MPos"), "nothing moved");
    c.send(b"~");
    let (s, _) = poll_until(&mut c, "Idle", Duration::from_secs(10));
    assert_eq!(field(&s, "MPos")[0], 40.0, "{s}");
    dollar_answers(&mut c, &idle, "Idle");
    // The start-up line refused during the cycle was not stored.
    let n = command_within(&mut c, "$N", Duration::from_millis(500));
    assert_eq!(n, vec!["$N0=", "$N1=", "ok"]);

    assert_eq!(
        command_within(&mut c, "$J=G91 X-30 F600", Duration::from_millis(300)),
        vec!["ok"]
    );
    poll_until(&mut c, "Jog", Duration::from_secs(1));
    let jog = [
        ("$$", "ok"),
        ("$#", "error:8"),
        ("$N", "error:8"),
        ("$G", "ok"),
        ("$X", "ok"),
    ];
    dollar_answers(&mut c, &jog, "Jog");
    c.send(&[0x85]);
    poll_until(&mut c, "Idle", Duration::from_secs(3));

    assert_eq!(
        command_within(&mut c, "$C", Duration::from_millis(500)),
        vec!["[MSG:Enabled]", "ok"]
    );
    let check = [
        ("$$", "ok"),
        ("$#", "error:8"),
        ("$I", "error:8"),
        ("$G", "ok"),
    ];
    dollar_answers(&mut c, &check, "Check");
    assert_eq!(
        command_within(&mut c, "$C", Duration::from_millis(500)),
        vec!["[MSG:Disabled]", "ok"]
    );
    println!("status waits: {}", c.wait_figures());
    let summary = bridge.stop();
    let x = summary["status"]["pose"]["x"].as_f64().unwrap();
    assert!(
        x > 10.5 && x < 40.0,
        "the jog was cancelled on its way: {summary}"
    );
}

/// Polls `?` (each answered within [`STATUS_LIMIT`]) until the feed override reads
/// `ov`; returns that report.
fn poll_override(c: &mut Client, ov: f64, limit: Duration) -> String {
    let end = Instant::now() + limit;
    loop {
        let s = c.status_within(STATUS_LIMIT);
        if field(&s, "Ov")[0] == ov {
            return s;
        }
        assert!(Instant::now() < end, "Ov {ov} not reached: {s}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Feed override and soft reset act while held, jogging and in check mode: the
/// override is reported within 300 ms, the reset's banner comes within 1 s and
/// leaves the machine Idle where it stopped (check mode ends, as Grbl's reset
/// returns to Idle).
fn overrides_and_reset(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut c = Client::open(&bridge, via);
    let banner = |c: &mut Client| {
        c.send(&[0x18]);
        c.line_until(|l| l.starts_with("Grbl 1.1h"), Duration::from_secs(1));
    };
    assert_eq!(
        command_within(&mut c, "G21 G90 G1 X40 F600", Duration::from_secs(1)),
        vec!["ok"]
    );
    poll_until(&mut c, "Run", Duration::from_secs(2));
    c.send(b"!");
    let (held, _) = poll_until(&mut c, "Hold:0", Duration::from_secs(3));
    c.send(&[0x91]);
    let s = poll_override(&mut c, 110.0, Duration::from_millis(300));
    assert!(s.starts_with("<Hold:0|"), "{s}");
    banner(&mut c);
    let (s, seen) = poll_until(&mut c, "Idle", Duration::from_secs(2));
    assert_eq!(field(&s, "MPos"), field(&held, "MPos"), "{seen:?}");

    assert_eq!(
        command_within(&mut c, "$J=G91 Y20 F600", Duration::from_millis(300)),
        vec!["ok"]
    );
    poll_until(&mut c, "Jog", Duration::from_secs(1));
    // The reset must find the jog moving: the state says Jog once the jog is taken,
    // which on a loaded machine can be a tick or more before the tool leaves Y 0.
    let moving = Instant::now() + Duration::from_secs(1);
    loop {
        let s = c.status_within(STATUS_LIMIT);
        assert!(s.starts_with("<Jog|"), "{s}");
        if field(&s, "MPos")[1] > 0.0 {
            break;
        }
        assert!(Instant::now() < moving, "the jog does not move: {s}");
        std::thread::sleep(Duration::from_millis(10));
    }
    c.send(&[0x90]);
    let s = poll_override(&mut c, 100.0, Duration::from_millis(300));
    assert!(s.starts_with("<Jog|"), "{s}");
    banner(&mut c);
    let (s, seen) = poll_until(&mut c, "Idle", Duration::from_secs(2));
    assert!(!seen.iter().any(|w| w.starts_with("Hold")), "{seen:?}");
    let y = field(&s, "MPos")[1];
    assert!(y > 0.0 && y < 19.0, "the jog was stopped by the reset: {s}");
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(field(&c.status_within(STATUS_LIMIT), "MPos")[1], y);

    assert_eq!(
        command_within(&mut c, "$C", Duration::from_millis(500)),
        vec!["[MSG:Enabled]", "ok"]
    );
    assert!(c.status_within(STATUS_LIMIT).starts_with("<Check|"));
    banner(&mut c);
    let s = c.status_within(STATUS_LIMIT);
    assert!(s.starts_with("<Idle|"), "check mode ends with a reset: {s}");
    println!("status waits: {}", c.wait_figures());
    bridge.stop();
}

/// G-code errors carry Grbl 1.1's numbers (its `doc/csv/error_codes_en_US.csv`) where
/// Grbl has one for the fault, each after a `[MSG:]` with our words.
fn g_code_errors(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut c = Client::open(&bridge, via);
    let cases = [
        // No feed rate set yet since the start.
        ("G1 X1", "error:22"),
        ("G1 X1 X2 F100", "error:25"),
        ("G1 X1 F-100", "error:4"),
        ("G4 P-1", "error:4"),
        ("G4", "error:28"),
        ("G10 L2 X1", "error:28"),
        ("G17 G18", "error:21"),
        ("G1 X1 M3 M5 F100", "error:21"),
        ("G2 X1 Y1 F100", "error:35"),
        ("G53 G2 X1 Y1 I1 F100", "error:30"),
        ("G1 X1 Y1 F100 G1.5", "error:20"),
        ("G0 X99999", "error:33"),
    ];
    let mut wrong = Vec::new();
    for (line, want) in cases {
        let got = command_within(&mut c, line, Duration::from_millis(500));
        let answer = got.last().unwrap();
        assert!(
            got.len() >= 2 && got[got.len() - 2].starts_with("[MSG:"),
            "{got:?}"
        );
        if answer != want {
            wrong.push(format!("{line}: {answer}, Grbl {want} ({got:?})"));
        }
    }
    assert!(wrong.is_empty(), "{wrong:#?}");
    // Nothing moved and nothing is held.
    let s = c.status_within(STATUS_LIMIT);
    assert!(s.starts_with("<Idle|"), "{s}");
    bridge.stop();
}

/// One line for each of Grbl 1.1's error numbers that a G-code or `$` line can get
/// (`doc/csv/error_codes_en_US.csv` of github.com/gnea/grbl), answered with exactly
/// that number after a `[MSG:]` with our words. The front end's errors carry their
/// kind from where they are raised; the bridge maps the kind, not the words.
fn every_error_number(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut c = Client::open(&bridge, via);
    let long = format!("G0 X1 ({})", "a".repeat(300));
    let cases = [
        // No feed rate set yet since the start.
        ("G1 X1", "error:22"),
        ("G0 X1 &", "error:1"),
        ("G0 X1.2.3", "error:2"),
        ("$Q", "error:3"),
        ("G1 X1 F-100", "error:4"),
        (long.as_str(), "error:11"),
        ("$J=G90 X1000 F600", "error:15"),
        ("G1.5 X1", "error:20"),
        ("G17 G18", "error:21"),
        ("T1.5", "error:23"),
        ("G1 G92 X1 F100", "error:24"),
        ("G1 X1 X2 F100", "error:25"),
        ("G92", "error:26"),
        ("G4", "error:28"),
        ("G53 G2 X1 Y1 I1 F100", "error:30"),
        ("G80 X1", "error:31"),
        ("G17 G2 Z1 R5 F100", "error:32"),
        ("G2 X10 I1 F100", "error:33"),
        ("G0 X99999", "error:33"),
        ("G2 X10 R1 F100", "error:34"),
        ("G2 X1 Y1 F100", "error:35"),
        ("G1 X1 F100 K1", "error:36"),
        ("G43 H1", "error:38"),
    ];
    let mut wrong = Vec::new();
    for (line, want) in cases {
        let got = command_within(&mut c, line, Duration::from_millis(500));
        let answer = got.last().unwrap();
        assert!(
            got.len() >= 2 && got[got.len() - 2].starts_with("[MSG:"),
            "{line}: {got:?}"
        );
        if answer != want {
            wrong.push(format!("{line}: {answer}, Grbl {want} ({got:?})"));
        }
    }
    assert!(wrong.is_empty(), "{wrong:#?}");
    let s = c.status_within(STATUS_LIMIT);
    assert!(s.starts_with("<Idle|MPos:0.000,0.000,0.000|"), "{s}");
    // Grbl's 27 (line number), 29 (G59.x) and 37 (G43.1 on another axis than the
    // tool length's) are faults of Grbl's smaller dialect; ours takes these lines.
    for line in ["N12345678 G4 P0", "G59.1", "G54", "G43.1 X1", "G49"] {
        let got = command_within(&mut c, line, Duration::from_millis(500));
        assert_eq!(got, vec!["ok"], "{line}");
    }
    let summary = bridge.stop();
    assert_eq!(summary["errors"], cases.len(), "{summary}");
}

/// The time from a jog's `ok` until the machine is Idle again, and the fastest
/// speed reported meanwhile (mm/min).
fn timed_jog(c: &mut Client, jog: &str) -> (Duration, f64) {
    assert_eq!(
        command_within(c, jog, Duration::from_millis(300)),
        vec!["ok"]
    );
    let start = Instant::now();
    let mut fastest = 0.0f64;
    loop {
        let s = c.status_within(STATUS_LIMIT);
        fastest = fastest.max(field(&s, "FS")[0]);
        if s.starts_with("<Idle|") {
            return (start.elapsed(), fastest);
        }
        assert!(start.elapsed() < Duration::from_secs(10), "{jog}: {s}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Grbl's jogs are not slowed or sped up by the feed override (its jogging interface,
/// `doc/markdown/jogging.md` of github.com/gnea/grbl); G-code moves still are.
fn jog_ignores_override(via: Via) {
    let bridge = Bridge::start(&[]);
    let mut c = Client::open(&bridge, via);
    // 20 mm at 1200 mm/min: a second at speed.
    let (full, full_speed) = timed_jog(&mut c, "$J=G91 X20 F1200");
    c.send(&[0x92; 5]);
    poll_override(&mut c, 50.0, Duration::from_millis(300));
    let (half, half_speed) = timed_jog(&mut c, "$J=G91 X-20 F1200");
    println!("jog at 100 %: {full:?}, {full_speed} mm/min; at 50 %: {half:?}, {half_speed} mm/min");
    assert!(
        (half_speed - 1200.0).abs() < 15.0,
        "the jog ran at its F whatever the override: {half_speed} mm/min"
    );
    assert!(
        half.as_secs_f64() < full.as_secs_f64() * 1.15 + 0.05,
        "a jog at 50 % takes {half:?}, at 100 % {full:?}"
    );
    let s = c.status_within(STATUS_LIMIT);
    assert_eq!(field(&s, "Ov")[0], 50.0, "the override is kept: {s}");
    assert_eq!(field(&s, "MPos")[0], 0.0, "{s}");
    // A G-code move after the jog runs at the override.
    assert_eq!(
        command_within(&mut c, "G1 X20 F1200", Duration::from_secs(1)),
        vec!["ok"]
    );
    let (_, seen) = poll_until(&mut c, "Run", Duration::from_secs(2));
    assert!(!seen.is_empty());
    let mut fastest = 0.0f64;
    let end = Instant::now() + Duration::from_secs(10);
    loop {
        let s = c.status_within(STATUS_LIMIT);
        fastest = fastest.max(field(&s, "FS")[0]);
        if s.starts_with("<Idle|") {
            break;
        }
        assert!(Instant::now() < end, "{s}");
        std::thread::sleep(Duration::from_millis(10));
    }
    println!("G1 F1200 at 50 %: fastest {fastest} mm/min");
    assert!(
        (fastest - 600.0).abs() < 15.0,
        "G1 at 50 %: {fastest} mm/min"
    );
    bridge.stop();
}

fn unlock_refused_in_e_stop(via: Via) {
    // The simulator's clock runs while the machine moves: the e-stop comes 1 s in.
    let bridge = Bridge::start(&["--inject", "estop@1.0"]);
    let mut c = Client::open(&bridge, via);
    assert_eq!(c.command("G1 X50 F600"), vec!["ok"]);
    let alarm = c.line_until(|l| l.starts_with("ALARM:"), Duration::from_secs(5));
    assert_eq!(alarm, "ALARM:10");
    poll_until(&mut c, "Alarm", Duration::from_secs(3));
    let got = command_within(&mut c, "$X", Duration::from_secs(1));
    assert_eq!(got.last().unwrap(), "error:9", "{got:?}");
    assert!(
        got.iter().any(|l| l.contains("e-stop is still latched")),
        "{got:?}"
    );
    assert_eq!(c.command("$J=G91 X1 F100").last().unwrap(), "error:8");
    assert_eq!(c.command("G0 X1").last().unwrap(), "error:9");
    // In an alarm Grbl still shows its settings and offsets, but stores no start-up
    // line.
    dollar_answers(
        &mut c,
        &[("$$", "ok"), ("$#", "ok"), ("$N0=G54", "error:8")],
        "Alarm",
    );
    bridge.stop();
}

fn homing_reset(via: Via) {
    let bridge = Bridge::start(&["--machine", "examples/machines/h4-table.toml"]);
    let mut c = Client::open(&bridge, via);
    c.send(b"$H\n");
    let (s, _) = poll_until(&mut c, "Home", Duration::from_secs(2));
    for _ in 0..5 {
        let s = c.status_within(STATUS_LIMIT);
        assert!(s.starts_with("<Home|"), "{s}");
        std::thread::sleep(Duration::from_millis(50));
    }
    c.send(&[0x18]);
    let alarm = c.line_until(|l| l.starts_with("ALARM:"), Duration::from_secs(3));
    assert_eq!(
        alarm, "ALARM:6",
        "a reset during homing, as Grbl numbers it; {s}"
    );
    c.line_until(|l| l.starts_with("Grbl 1.1h"), Duration::from_secs(3));
    let (s, _) = poll_until(&mut c, "Alarm", Duration::from_secs(3));
    assert!(
        c.line(Duration::from_millis(300))
            .is_none_or(|l| !l.starts_with("ALARM:")),
        "the alarm is said once: {s}"
    );
    println!("status waits: {}", c.wait_figures());
    bridge.stop();
}
