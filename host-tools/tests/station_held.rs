//! Issue 33: a program run from the operator station streams as `nc-send`'s do: with
//! the program's mark and the machine's host timeout. When the station's process dies
//! in the middle of it, the controller starves the job on the path and keeps it held
//! for another host; `nc-send resume` says how much of the program was never sent and
//! resumes nothing, and `nc-send resume PROGRAM` sends the rest and ends where
//! `--sim` ends. The station is driven by a WebSocket client, as its page drives it.
//! Over the real pseudo-terminal path: `pkmc-sim`, then `nc-send --port … serve`.

mod common;

use common::{json, repo, Sim};
use std::io::BufRead;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[test]
fn a_program_from_the_station_whose_station_dies_is_held_and_resumed_to_its_end_by_nc_send() {
    let p = common::ten_second_program("station-held.ngc");
    let p = p.to_str().unwrap();
    let reference = common::ok(&common::nc_send(&["--sim", "--report", "json", p]));
    let sim = Sim::start(&["--real-time"]);
    assert_eq!(sim.send(&["reset"]).status.code(), Some(0));
    let mut station = Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .args([
            "--port",
            sim.port.as_str(),
            "serve",
            "--listen",
            "127.0.0.1:0",
            "--program",
            p,
        ])
        .current_dir(repo())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut url = String::new();
    std::io::BufReader::new(station.stdout.take().unwrap())
        .read_line(&mut url)
        .unwrap();
    let ws_url = url
        .trim()
        .replacen("http://", "ws://", 1)
        .trim_end_matches('/')
        .to_string()
        + "/ws";
    let (mut ws, _) = tungstenite::connect(ws_url.as_str()).expect("the station's WebSocket");
    let mut ask = |id: u64, cmd: &str| {
        ws.send(tungstenite::Message::text(format!(
            r#"{{"id":{id},"cmd":"{cmd}"}}"#
        )))
        .unwrap();
        // Its reply (statuses and logs come between).
        let until = Instant::now() + Duration::from_secs(20);
        loop {
            assert!(Instant::now() < until, "no reply to {cmd}");
            let m = ws.read().unwrap();
            let Ok(v) = serde_json::from_str::<serde_json::Value>(m.to_text().unwrap_or("")) else {
                continue;
            };
            if v["type"] == "reply" && v["id"] == id {
                return v;
            }
        }
    };
    let took = ask(1, "take");
    assert_eq!(took["ok"], true, "{took}");
    let ran = ask(2, "run");
    assert_eq!(ran["ok"], true, "{ran}");
    std::thread::sleep(Duration::from_millis(2500));
    // The station dies in the middle of the program.
    station.kill().unwrap();
    station.wait().unwrap();
    std::thread::sleep(Duration::from_millis(500));
    // Without the program: how much was never sent; nothing is resumed.
    let out = sim.send(&["resume"]);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(7), "{err}");
    let blocks = reference["blocks_sent"].as_u64().unwrap();
    assert!(
        err.contains(&format!("of the program's {blocks} blocks were never sent")),
        "{err}"
    );
    // With it: the rest is sent and the job ends where `--sim` ends it.
    let out = sim.send(&["resume", p]);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(0), "{err}");
    let end = json(&out);
    assert_eq!(
        (
            end["result"].clone(),
            end["state"].clone(),
            end["line"].clone()
        ),
        (
            "done".into(),
            "Idle".into(),
            reference["final_line"].clone()
        ),
        "{end}"
    );
    assert!(end["blocks_sent"].as_u64().unwrap() > 0, "{end}");
    assert_eq!(end["pose"], reference["final_pose"], "{end}");
    assert_eq!(end["joints"], reference["final_joints"], "{end}");
}
