//! `--foxglove`: a native dive served live to Foxglove WebSocket protocol clients that subscribe
//! to every advertised channel and validate every message against its channel's JSON Schema
//! (and find no JSON `null` in any: while aligning, what is not a number yet is left out and named
//! with why in `no_value`):
//! `foxglove_client.py` (the `websockets` and `jsonschema` packages of the peer venv,
//! `SUBNAV_PEER_PYTHON`) offering each subprotocol, and the official npm client
//! `@foxglove/ws-protocol` 0.8.0 (`foxglove_ws_client.cjs`, node with the `target/peers-node`
//! modules of `cargo xtask setup`, `SUBNAV_PEER_NODE_MODULES`); the recording of the same run is compared chunk for chunk
//! with one made without the server. A client that never reads must not delay the run or cost
//! the recording anything.

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn subnav() -> Command {
    Command::new(env!("CARGO_BIN_EXE_subnav"))
}

fn python() -> PathBuf {
    match std::env::var_os("SUBNAV_PEER_PYTHON") {
        Some(p) => PathBuf::from(p),
        None => panic!("SUBNAV_PEER_PYTHON is not set: run the tests with `cargo xtask test` (it builds and sets it up)"),
    }
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

fn client(mode: &str, port: u16, timeout_s: u32) -> std::process::Child {
    client_offering(mode, port, timeout_s, "foxglove.sdk.v1")
}

/// A client that offers only `subprotocol`.
fn client_offering(mode: &str, port: u16, timeout_s: u32, subprotocol: &str) -> std::process::Child {
    Command::new(python())
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/foxglove_client.py"))
        .args([mode, &format!("ws://127.0.0.1:{port}"), &timeout_s.to_string(), subprotocol])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// The official ws-protocol client (npm `@foxglove/ws-protocol`), which offers
/// `foxglove.websocket.v1`.
fn npm_client(port: u16, timeout_s: u32) -> std::process::Child {
    let modules = match std::env::var_os("SUBNAV_PEER_NODE_MODULES") {
        Some(p) => PathBuf::from(p),
        None => panic!("SUBNAV_PEER_NODE_MODULES is not set: run the tests with `cargo xtask test` (it installs the npm peers)"),
    };
    Command::new("node")
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/foxglove_ws_client.cjs"))
        .args([&format!("ws://127.0.0.1:{port}"), &timeout_s.to_string()])
        .env("NODE_PATH", modules)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// The default job (camera and map in the loop), shortened: `subnav run --native`.
fn run_args(rec: &Path) -> Vec<String> {
    ["run", "--native", "--quiet", "--duration-s", "60", "--record"]
        .iter()
        .map(|s| s.to_string())
        .chain([rec.display().to_string()])
        .collect()
}

/// The chunks of a recording (stream, host time, bytes) and its metadata without the wall-clock
/// start time (which differs between two runs by construction).
fn recording(p: &Path) -> (Vec<(String, u64, Vec<u8>)>, String) {
    let r = subnav_link::record::read_file(p).unwrap();
    assert!(r.header_error.is_none() && r.damage.is_empty());
    let chunks = r.chunks.iter().map(|c| (format!("{:?}", c.stream), c.t_host_us, c.data.clone())).collect();
    let mut meta = r.meta.clone();
    meta.start_unix_us = 0;
    (chunks, format!("{meta:?}"))
}

#[test]
fn a_native_dive_is_served_on_every_topic_with_valid_messages_and_the_same_recording() {
    let dir = tempfile::tempdir().unwrap();
    let (live_rec, plain_rec) = (dir.path().join("live.snrec"), dir.path().join("plain.snrec"));
    let port = free_port();
    // The Foxglove app's subprotocol and the classic one (ws-protocol clients, Lichtblick).
    let viewers = [
        ("foxglove.sdk.v1", client("read", port, 120)),
        ("foxglove.websocket.v1", client_offering("read", port, 120, "foxglove.websocket.v1")),
        ("foxglove.websocket.v1", npm_client(port, 120)),
    ];
    let out = subnav()
        .args(run_args(&live_rec))
        .args(["--foxglove", &format!("127.0.0.1:{port}"), "--foxglove-wait-s", "60", "--speed", "10"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("foxglove: 3 clients") && stderr.contains(" 0 dropped"), "{stderr}");
    let mut saw_aligning = 0;
    for (subprotocol, viewer) in viewers {
        let v = viewer.wait_with_output_timeout();
        let s: serde_json::Value = serde_json::from_str(v.lines().last().unwrap_or("")).unwrap_or_else(|e| panic!("{e}: {v}"));
        check_viewer(&s, subprotocol);
        saw_aligning += s["no_value"]["/subnav/nav"]["aligning"].as_u64().unwrap_or(0);
    }
    // The alignment was served (at least to the viewer the run waited for), without a null.
    assert!(saw_aligning > 0, "no viewer saw a solution while aligning");
    // The same run without the server: the same recording, chunk for chunk.
    let out = subnav().args(run_args(&plain_rec)).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let (live, plain) = (recording(&live_rec), recording(&plain_rec));
    assert!(live.0.len() > 1000, "{} chunks", live.0.len());
    assert_eq!(live.1, plain.1);
    assert!(live.0 == plain.0, "the recordings differ ({} vs {} chunks)", live.0.len(), plain.0.len());
}

/// A viewer's summary: every topic advertised and validated against its channel's schema.
fn check_viewer(s: &serde_json::Value, subprotocol: &str) {
    // The subprotocol the client offered is the one the server answered with.
    assert_eq!(s["subprotocol"], subprotocol, "{s}");
    assert!(s["closed_by_server"].as_bool().unwrap(), "{s}");
    assert_eq!(s["invalid"].as_array().unwrap().len(), 0, "{s}");
    assert_eq!(s["nulls"].as_array().unwrap().len(), 0, "{s}");
    assert_eq!(s["errors"].as_array().unwrap().len(), 0, "{s}");
    let advertised: Vec<&str> = s["advertised"].as_array().unwrap().iter().map(|t| t.as_str().unwrap()).collect();
    for t in [
        "/subnav/boot",
        "/subnav/nav",
        "/subnav/raw.imu",
        "/subnav/raw.depth",
        "/subnav/compass",
        "/subnav/health",
        "/subnav/camera.trigger",
        "/subnav/pose",
        "/subnav/pose/covariance",
        "/subnav/trajectory",
        "/subnav/truth/pose",
        "/subnav/truth/error",
        "/subnav/compass/fix",
        "/subnav/health/summary",
        "/subnav/map",
    ] {
        assert!(advertised.contains(&t), "{t} not advertised: {advertised:?}");
    }
    // Every advertised topic delivered messages; the continuous ones many.
    for t in &advertised {
        let n = s["validated"][t].as_u64().unwrap_or(0);
        assert!(n >= 1, "no valid message on {t}: {s}");
    }
    assert!(s["counts"]["/subnav/nav"].as_u64().unwrap() > 300, "{s}");
    assert_eq!(s["schemas"]["/subnav/pose"], "foxglove.PoseInFrame");
    assert_eq!(s["schemas"]["/subnav/map"], "foxglove.SceneUpdate");
}

trait WaitOutput {
    fn wait_with_output_timeout(self) -> String;
}
impl WaitOutput for std::process::Child {
    /// The client's stdout (it exits on its own: the server closes, or its timeout passes).
    fn wait_with_output_timeout(self) -> String {
        let out = self.wait_with_output().unwrap();
        assert!(out.status.success(), "client failed: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).to_string()
    }
}

#[test]
fn a_client_that_never_reads_neither_delays_the_run_nor_costs_the_recording() {
    let dir = tempfile::tempdir().unwrap();
    let (live_rec, plain_rec) = (dir.path().join("live.snrec"), dir.path().join("plain.snrec"));
    let t0 = Instant::now();
    let out = subnav().args(run_args(&plain_rec)).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let plain_s = t0.elapsed();

    let port = free_port();
    let mut stalled = client("stall", port, 600);
    let t0 = Instant::now();
    let out =
        subnav().args(run_args(&live_rec)).args(["--foxglove", &format!("127.0.0.1:{port}"), "--foxglove-wait-s", "60"]).output().unwrap();
    let live_s = t0.elapsed();
    let _ = stalled.kill();
    let _ = stalled.wait();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("foxglove: 1 clients"), "{stderr}");
    // On time: the run with a stalled viewer takes no longer than the plain one plus the wait
    // for the viewer and the server's linger (seconds, not the client's 600 s).
    assert!(live_s < plain_s * 2 + Duration::from_secs(15), "{live_s:?} vs {plain_s:?}");
    let (live, plain) = (recording(&live_rec), recording(&plain_rec));
    assert_eq!(live.1, plain.1);
    assert!(live.0 == plain.0, "the recordings differ ({} vs {} chunks)", live.0.len(), plain.0.len());
}

/// `subnav export --foxglove --speed`: a recording served to the same client on the same topics.
#[test]
fn a_recording_is_served_by_export_at_a_speed() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("dive.snrec");
    let out = subnav().args(run_args(&rec)).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let port = free_port();
    let viewer = client("read", port, 120);
    let t0 = Instant::now();
    let out = subnav()
        .arg("export")
        .arg(&rec)
        .args(["--foxglove", &format!("127.0.0.1:{port}"), "--foxglove-wait-s", "60", "--speed", "20"])
        .output()
        .unwrap();
    let took = t0.elapsed();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("foxglove: 1 clients") && stderr.contains(" 0 dropped"), "{stderr}");
    // 60 s recorded at 20x: about 3 s of serving (paced, not all at once).
    assert!(took >= Duration::from_millis(2500), "{took:?}");
    let v = viewer.wait_with_output_timeout();
    let s: serde_json::Value = serde_json::from_str(v.lines().last().unwrap_or("")).unwrap_or_else(|e| panic!("{e}: {v}"));
    assert_eq!(s["invalid"].as_array().unwrap().len(), 0, "{s}");
    assert_eq!(s["nulls"].as_array().unwrap().len(), 0, "{s}");
    for t in s["advertised"].as_array().unwrap() {
        assert!(s["validated"][t.as_str().unwrap()].as_u64().unwrap_or(0) >= 1, "no valid message on {t}: {s}");
    }
    assert!(s["counts"]["/subnav/nav"].as_u64().unwrap() > 550, "{s}");
    assert!(s["advertised"].as_array().unwrap().iter().any(|t| t == "/subnav/trajectory"), "{s}");
}
