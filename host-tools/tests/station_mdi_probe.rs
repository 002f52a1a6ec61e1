//! G38 typed into the operator station's MDI (`nc-send --sim serve`, the simulator's
//! probe touching a plane): the probing move runs as `nc-send` runs one, every page
//! gets `{"type": "probe", "source": "mdi", "probe": {line, code, contact, position,
//! joints, stopped}}` (the report's shape), the next MDI lines read #5061–#5070, and a
//! G38.2 that finds nothing is refused at its line and column. The station is driven
//! by a WebSocket client, as its page drives it.

mod common;

use common::repo;
use serde_json::Value;
use std::io::BufRead;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The plane the simulated probe touches, mm.
const PLANE: f64 = -3.25;

/// The station's process, killed when dropped.
struct Served(Child);

impl Drop for Served {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

type Socket = tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<std::net::TcpStream>>;

/// Sends command `cmd` (a JSON object's fields) as request `id`.
fn send(ws: &mut Socket, id: u64, cmd: &str) {
    ws.send(tungstenite::Message::text(format!(
        r#"{{"id":{id},{cmd}}}"#
    )))
    .unwrap();
}

/// Messages until one satisfies `want` (returned); panics after 20 s.
fn until(ws: &mut Socket, want: impl Fn(&Value) -> bool) -> Value {
    let end = Instant::now() + Duration::from_secs(20);
    loop {
        assert!(Instant::now() < end, "no such message within 20 s");
        let m = ws.read().unwrap();
        if let Ok(v) = serde_json::from_str::<Value>(m.to_text().unwrap_or("")) {
            if want(&v) {
                return v;
            }
        }
    }
}

fn reply(id: u64) -> impl Fn(&Value) -> bool {
    move |v| v["type"] == "reply" && v["id"] == id
}

fn probe(v: &Value) -> bool {
    v["type"] == "probe" && v["source"] == "mdi"
}

fn z(v: &Value, field: &str) -> f64 {
    v["probe"][field][2].as_f64().unwrap()
}

#[test]
fn g38_in_the_stations_mdi_probes_publishes_the_result_and_sets_5061() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .args(["--sim", "--probe-plane", &PLANE.to_string()])
        .args(["serve", "--listen", "127.0.0.1:0"])
        .current_dir(repo())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut url = String::new();
    std::io::BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut url)
        .unwrap();
    let _served = Served(child);
    let ws_url = url
        .trim()
        .replacen("http://", "ws://", 1)
        .trim_end_matches('/')
        .to_string()
        + "/ws";
    let (mut ws, _) = tungstenite::connect(ws_url.as_str()).expect("the station's WebSocket");
    send(&mut ws, 1, r#""cmd":"take""#);
    assert_eq!(until(&mut ws, reply(1))["ok"], true);

    send(&mut ws, 2, r#""cmd":"mdi","text":"G38.2 Z-10 F100""#);
    let started = until(&mut ws, reply(2));
    assert_eq!(started["ok"], true, "{started}");
    let touched = until(&mut ws, probe);
    let p = &touched["probe"];
    assert_eq!(
        (p["line"].as_u64(), p["code"].as_str()),
        (Some(1), Some("G38.2"))
    );
    assert_eq!(p["contact"], true, "{touched}");
    assert_eq!(p["joints"].as_array().unwrap().len(), 3, "{touched}");
    // Within 1 µm plus 4 σ of the simulator's default 0.5 µm noise.
    let at = z(&touched, "position");
    assert!((at - PLANE).abs() <= 3e-3, "{touched}");
    let stopped = z(&touched, "stopped");
    assert!(stopped < at && stopped > at - 0.2, "{touched}");

    // The next lines read what it found: up 1 mm from the contact, then a G38.2 that
    // ends 1.5 mm above it, above the plane, without contact: refused at its column,
    // after its result has been published.
    send(&mut ws, 3, r#""cmd":"mdi","text":"G0 Z[#5063+1]""#);
    let r = until(&mut ws, reply(3));
    assert_eq!(r["ok"], true, "{r}");
    // The move has ended: a status with no job, the pose there.
    until(&mut ws, |v| {
        v["type"] == "status"
            && v["job"].is_null()
            && v["pose"][2]
                .as_f64()
                .is_some_and(|z| (z - (at + 1.0)).abs() < 2e-3)
    });
    send(
        &mut ws,
        4,
        r#""cmd":"mdi","text":"G38.2 Z[#5063+1.5] F100""#,
    );
    let r = until(&mut ws, reply(4));
    assert_eq!(r["ok"], true, "{r}");
    let missed = until(&mut ws, probe);
    assert_eq!(missed["probe"]["line"], 3, "{missed}");
    assert_eq!(missed["probe"]["contact"], false, "{missed}");
    assert!(
        (z(&missed, "stopped") - (at + 1.5)).abs() <= 1e-3,
        "#5063 + 1.5: {missed}"
    );
    let refused = until(&mut ws, reply(4));
    assert_eq!(refused["ok"], false, "{refused}");
    let text = refused["text"].as_str().unwrap();
    assert!(
        text.starts_with("MDI:3:1: G38.2: the move ended without contact"),
        "{text}"
    );
}
