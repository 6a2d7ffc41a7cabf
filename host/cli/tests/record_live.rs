//! `subnav record --tcp`: a live source (a TCP server sending frames in odd-sized pieces, with a
//! corrupt frame) is recorded losslessly; the JSON summary counts what was seen. A recorder
//! started again mid-dive writes the next recording of the series and says what it missed.

use std::io::Write;
use std::process::Command;

use subnav_link::record::{Stream, read_file};
use subnav_wire::*;

#[test]
fn records_a_tcp_source_losslessly() {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let mut bytes = vec![];
    let mut buf = [0u8; MAX_UPLINK_FRAME];
    bytes.extend_from_slice(
        encode(
            &Uplink::Boot(boot_message(
                Board::Stm32F405,
                [1, 0, 0],
                0,
                subnav_wire::CalibrationInUse::NO_STORE,
                subnav_wire::ResetCause::PowerOn,
            )),
            &mut buf,
        )
        .unwrap(),
    );
    for i in 0..200u64 {
        bytes.extend(nav_frame(i * 100_000, i as f32, &mut buf));
    }
    // The head re-acquired its position once.
    let health = FilterHealth {
        t_us: 19_950_000,
        aid: subnav_wire::AidStatuses {
            heading: subnav_wire::AidStatus {
                nis: 1.0,
                test_ratio: 0.1,
                noise_var: 1e-4,
                fused: true,
                fused_count: 3,
                ..Default::default()
            },
            depth: subnav_wire::AidStatus { nis: f32::NAN, ..Default::default() },
            ..Default::default()
        },
        imu_q_scale: 1.0,
        lambda: 1.0,
        q_diag: [0.0; 5],
        pd_repairs: 0,
        cov_unrepairable: 0,
        gate_rejects: 5,
        nonfinite_rejects: 0,
        late_fused: 0,
        late_refused: 0,
        heading_resets: 0,
        position_resets: 1,
        cpu_load_permille: 100,
    };
    bytes.extend_from_slice(encode(&Uplink::Health(health), &mut buf).unwrap());
    bytes.extend_from_slice(&[0x05, 0x01, 0x02, 0x03, 0x04, 0x00]);
    let sent = bytes.clone();
    let server = std::thread::spawn(move || {
        let (mut s, _) = listener.accept().unwrap();
        for piece in bytes.chunks(333) {
            s.write_all(piece).unwrap();
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
    });
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("live.snrec");
    let o =
        Command::new(env!("CARGO_BIN_EXE_subnav")).args(["--format", "json", "record", "--tcp", &addr, "-o"]).arg(&out).output().unwrap();
    server.join().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["status"]["link"]["frames_ok"], 202);
    assert_eq!(v["status"]["resets"], serde_json::json!([0, 1]), "the position re-acquisition is in the summary");
    assert_eq!(v["status"]["link"]["frames_bad"], 1);
    assert_eq!(v["status"]["latest_fix"][1], serde_json::json!([199.0, 0.0, 5.0]));
    let l = read_file(&out).unwrap();
    assert_eq!(l.stream_bytes(Stream::Uplink), sent, "every byte recorded as received");
    assert!(l.meta.source.contains(&addr));
    // Host times are in order.
    assert!(l.chunks.windows(2).all(|w| w[0].t_host_us <= w[1].t_host_us));
}

#[test]
fn record_without_a_source_says_what_to_give() {
    let o = Command::new(env!("CARGO_BIN_EXE_subnav")).args(["record", "-o", "/tmp/never.snrec"]).output().unwrap();
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("--tcp") && e.contains("--serial"), "{e}");
}

/// A navigation frame at `t_us`, `north_m` north, moving north at 1 m/s.
fn nav_frame(t_us: u64, north_m: f32, buf: &mut [u8]) -> Vec<u8> {
    let nav = NavSolution {
        t_us,
        mode: NavMode::Aided,
        pos_ned_m: [north_m, 0.0, 5.0],
        vel_ned_mps: [1.0, 0.0, 0.0],
        att_nb_wxyz: [1.0, 0.0, 0.0, 0.0],
        sigma_pos_m: [1.0; 3],
        sigma_vel_mps: [0.1; 3],
        sigma_att_rad: [0.01; 3],
        cov_ne_m2: 0.0,
    };
    encode(&Uplink::Nav(nav), buf).unwrap().to_vec()
}

/// Serve `bytes` once on a fresh port and record them to `out`; returns stderr.
fn record_once(bytes: Vec<u8>, out: &std::path::Path) -> String {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let server = std::thread::spawn(move || {
        let (mut s, _) = listener.accept().unwrap();
        s.write_all(&bytes).unwrap();
    });
    let o = Command::new(env!("CARGO_BIN_EXE_subnav")).args(["record", "--tcp", &addr, "-o"]).arg(out).output().unwrap();
    server.join().unwrap();
    let e = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{e}");
    e
}

/// The host is killed 20 s into a dive and started again at 50 s with the same command line:
/// the first recording stays as it was, the second joins the running head mid-frame, and the
/// 30 s neither has are reported.
#[test]
fn a_restarted_recorder_starts_the_next_recording_and_reports_the_gap() {
    let mut buf = [0u8; MAX_UPLINK_FRAME];
    let boot = Uplink::Boot(boot_message(Board::Stm32F405, [1, 0, 0], 0, CalibrationInUse::NO_STORE, ResetCause::PowerOn));
    let mut before = encode(&boot, &mut buf).unwrap().to_vec();
    for i in 0..=200 {
        before.extend(nav_frame(i * 100_000, 0.0, &mut buf));
    }
    // The new host's first bytes are the end of a frame.
    let mut after = nav_frame(49_900_000, 0.0, &mut buf).split_off(9);
    for i in 500..600 {
        after.extend(nav_frame(i * 100_000, 0.0, &mut buf));
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("dive.snrec");
    let e = record_once(before, &out);
    assert!(!e.contains("joined"), "{e}");
    let first = std::fs::read(&out).unwrap();

    let e = record_once(after, &out);
    let second = dir.path().join("dive.2.snrec");
    assert!(e.contains(&format!("{} exists: recording to {}", out.display(), second.display())), "{e}");
    assert!(
        e.contains(&format!(
            "joined a running head at head time 50.0 s: {} ends at head time 20.0 s: 30.0 s of telemetry are in neither",
            out.display()
        )),
        "{e}"
    );
    assert_eq!(std::fs::read(&out).unwrap(), first, "the first recording is untouched");
    let l = read_file(&second).unwrap();
    assert!(l.stream_bytes(Stream::Uplink).ends_with(&nav_frame(59_900_000, 0.0, &mut buf)));
    // `decode` of the second recording says the same.
    let o = Command::new(env!("CARGO_BIN_EXE_subnav")).args(["decode", "--quiet", "--file"]).arg(&second).output().unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success() && e.contains("coverage: joined a running head at head time 50.0 s"), "{e}");
    assert!(e.contains("series: continues") && e.contains("30.0 s of telemetry are in neither"), "{e}");
    assert_eq!(l.meta.continues.as_deref(), Some("dive.snrec"));
    // `report` on the first recording takes in the series, and says what is in neither.
    let o = Command::new(env!("CARGO_BIN_EXE_subnav"))
        .args(["report", "recording"])
        .arg(&out)
        .arg("-o")
        .arg(dir.path().join("report"))
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{e}");
    assert!(e.contains("continues") && e.contains("included: 30.0 s of head time (20.0-50.0 s) are in neither"), "{e}");
    let md = std::fs::read_to_string(dir.path().join("report").join("report.md")).unwrap();
    assert!(md.contains("301 navigation solutions"), "both recordings' solutions: {md}");
}
