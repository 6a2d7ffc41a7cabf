//! `subnav decode` on recordings with corruption: every intact frame is printed, bad ones are
//! counted, decoding never stops early.

use std::process::Command;

use subnav_wire::{self as wire, CommandAck, MAX_UPLINK_FRAME, NavMode, NavSolution, Uplink};

fn nav(t_us: u64) -> Uplink {
    Uplink::Nav(NavSolution {
        t_us,
        mode: NavMode::Inertial,
        pos_ned_m: [t_us as f32, 0.0, 10.0],
        vel_ned_mps: [1.0, 0.0, 0.0],
        att_nb_wxyz: [1.0, 0.0, 0.0, 0.0],
        sigma_pos_m: [1.0; 3],
        sigma_vel_mps: [0.1; 3],
        sigma_att_rad: [0.01; 3],
        cov_ne_m2: 0.0,
    })
}

#[test]
fn decode_file_with_spliced_corruption_reports_counts_in_json() {
    let mut bytes = vec![0x99, 0x98, 0x00]; // starts mid-frame (the tail of an earlier frame)
    let mut buf = [0u8; MAX_UPLINK_FRAME];
    let mut bad = 1; // the partial leading frame ends at the first delimiter
    for i in 0..100u64 {
        let mut frame = wire::encode(&nav(i * 100_000), &mut buf).unwrap().to_vec();
        if i % 10 == 7 {
            let mid = frame.len() / 2;
            frame[mid] = frame[mid].wrapping_add(1).max(1); // corrupt but never a delimiter
            bad += 1;
        }
        bytes.extend_from_slice(&frame);
        if i % 25 == 0 {
            bytes.extend_from_slice(b"\x01\x02garbage\x00");
            bad += 1;
        }
    }
    bytes.extend_from_slice(wire::encode(&Uplink::Ack(CommandAck { seq: 1, result: Ok(()) }), &mut buf).unwrap());
    bytes.extend_from_slice(&[0x11, 0x22]); // truncated tail
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rec.bin");
    std::fs::write(&path, &bytes).unwrap();

    let out = Command::new(env!("CARGO_BIN_EXE_subnav")).args(["--format", "json", "decode", "--file"]).arg(&path).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let lines: Vec<serde_json::Value> = String::from_utf8(out.stdout).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    let messages = lines.iter().filter(|l| l["type"] == "message").count();
    let corrupt = lines.iter().filter(|l| l["type"] == "corrupt").count();
    assert_eq!(messages, 100 - 10 + 1);
    assert_eq!(corrupt, bad);
    let summary = lines.iter().find(|l| l["type"] == "summary").unwrap();
    assert_eq!(summary["stats"]["frames_ok"], 91);
    assert_eq!(summary["stats"]["frames_bad"], bad as u64);
    assert_eq!(summary["trailing_bytes"], 2);
    // Text mode prints the same messages.
    let out = Command::new(env!("CARGO_BIN_EXE_subnav")).args(["decode", "--file"]).arg(&path).output().unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    assert_eq!(text.lines().filter(|l| l.starts_with("nav")).count(), 90);
    assert!(String::from_utf8_lossy(&out.stderr).contains(&format!("{bad} corrupt")));
}

#[test]
fn decode_without_a_source_is_a_clear_error() {
    let out = Command::new(env!("CARGO_BIN_EXE_subnav")).arg("decode").output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--file"));
    let out = Command::new(env!("CARGO_BIN_EXE_subnav")).args(["decode", "--file", "/nonexistent/x.bin"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/x.bin"));
}
