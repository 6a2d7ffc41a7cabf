//! `subnav mavlink`: a native dive bridged to a pymavlink peer acting as the autopilot
//! (`mavlink_autopilot.py`, pymavlink from the peer venv, `SUBNAV_PEER_PYTHON`). Every message
//! the peer received is checked against the simulator's truth: position (in the autopilot's
//! re-based frame), velocity in NED and in the body frame, yaw within its reported sigma; the
//! bridge's TIMESYNC estimate of the autopilot's clock is the peer's; the stamps are the
//! solutions' times of validity in the companion's clock (the one the bridge answers TIMESYNC
//! with, which PX4 maps through its own TIMESYNC estimate; on the head's 10-Hz grid, a link delay
//! before their arrival); the GPS the peer sends at the surface
//! comes back in the head's solution, with `reset_counter` counting the head's position
//! re-acquisition and the new origin; no velocity while the head has none it can vouch for
//! (aligning, DVL lost), never zeros; bad input counted, a dead link survived.
//!
//! About 40 s: the bridge runs in real time, as an autopilot expects.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use serde_json::Value;

fn subnav() -> Command {
    Command::new(env!("CARGO_BIN_EXE_subnav"))
}

fn python() -> PathBuf {
    match std::env::var_os("SUBNAV_PEER_PYTHON") {
        Some(p) => PathBuf::from(p),
        None => panic!("SUBNAV_PEER_PYTHON is not set: run the tests with `cargo xtask test` (it builds and sets it up)"),
    }
}

fn free_udp_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// The autopilot's clock is CLOCK_MONOTONIC minus this (the companion uses CLOCK_MONOTONIC).
const BOOT_OFFSET_S: f64 = 1234.5;
const LINK_DELAY_MS: f64 = 80.0;
const DVL_SILENT_S: (f64, f64) = (24.0, 33.0);
/// The peer's GPS is this far north of the truth; its origin this far east of the head's.
const GPS_OFFSET_N_M: f64 = 15.0;
const ORIGIN_OFFSET_E_M: f64 = 10.0;

/// 38 s: 10 s aligning at the surface, at rest until 14 s, a ramp and a descent to 2 m, then a
/// leg at 1 m/s; the DVL silent for 9 s of it; no USBL.
fn scenario(dir: &Path) -> (PathBuf, subnav_sil::Scenario) {
    let raw = dir.join("raw.json");
    let out = subnav()
        .args(["sim", "--duration-s", "38", "--depth-m", "2", "--no-fixes", "--dvl-silent"])
        .arg(format!("{},{}", DVL_SILENT_S.0, DVL_SILENT_S.1))
        .arg("--out")
        .arg(&raw)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&raw).unwrap()).unwrap();
    v["survey"]["rest_s"] = 14.0.into();
    let path = dir.join("dive.json");
    std::fs::write(&path, v.to_string()).unwrap();
    let sc: subnav_sil::Scenario = serde_json::from_value(v).unwrap();
    (path, sc)
}

fn wrap_pi(a: f64) -> f64 {
    let mut a = (a + std::f64::consts::PI) % std::f64::consts::TAU;
    if a < 0.0 {
        a += std::f64::consts::TAU;
    }
    a - std::f64::consts::PI
}

fn f(v: &Value, k: &str) -> f64 {
    v[k].as_f64().unwrap_or_else(|| panic!("{k} in {v}"))
}

#[test]
fn a_native_dive_through_subnav_mavlink_into_a_pymavlink_autopilot() {
    let dir = tempfile::tempdir().unwrap();
    let (sc_path, sc) = scenario(dir.path());
    let port = free_udp_port();
    let rx = dir.path().join("received.jsonl");
    let summary_path = dir.path().join("summary.json");
    let peer = Command::new(python())
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/mavlink_autopilot.py"))
        .args([port.to_string(), rx.display().to_string(), sc.lat_deg.to_string(), sc.lon_deg.to_string()])
        // Boot offset, dead link from 26 s of the session for 4.5 s, at most 80 s.
        .args([BOOT_OFFSET_S.to_string(), "26".into(), "4.5".into(), "80".into()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(500));
    let out = subnav()
        .args(["mavlink", "--from"])
        .arg(format!("native:{}", sc_path.display()))
        .args(["--to", &format!("udpout:127.0.0.1:{port}"), "--link-delay-ms", &LINK_DELAY_MS.to_string()])
        .args(["--mavlink-max-velocity-sigma-mps", "0.02", "--mavlink-summary"])
        .arg(&summary_path)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{stderr}");
    let p = peer.wait_with_output().unwrap();
    assert!(p.status.success(), "peer: {}", String::from_utf8_lossy(&p.stderr));
    let s: Value = serde_json::from_str(&std::fs::read_to_string(&summary_path).unwrap()).unwrap();
    eprintln!("{stderr}");

    // TIMESYNC: the bridge's estimate of the autopilot's clock is the peer's own offset.
    let off_us = s["timesync"]["offset_us"].as_i64().expect("timesync converged");
    let boot_us = (BOOT_OFFSET_S * 1e6) as i64;
    assert!((off_us + boot_us).abs() < 2_000, "timesync offset {off_us} us, the peer's is {}", -boot_us);
    let t0_us = s["head_t0_companion_us"].as_i64().unwrap();
    // The stamps are in the companion's clock (the default `--mavlink-stamp-clock`).
    assert_eq!(s["stamp_clock"], "Companion", "{s}");
    assert_eq!(s["stamped_own_clock"], 0, "{s}");

    let msgs: Vec<Value> = std::fs::read_to_string(&rx).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    let of = |name: &'static str| msgs.iter().filter(move |m| m["mavpackettype"] == name);
    let traj = sc.trajectory();
    // Dive time of a stamp: companion = t0 + dive; the peer's arrival times are in its own clock,
    // autopilot = companion - boot offset.
    let dive_s = |stamp_us: f64| (stamp_us - t0_us as f64) * 1e-6;

    // Every pose: a time of validity on the head's 10-Hz grid, at least the link delay before
    // its arrival (an arrival stamp would be ~0 ms before; a loaded machine adds up to ~0.2 s).
    let vpe: Vec<&Value> = of("VISION_POSITION_ESTIMATE").collect();
    assert!(vpe.len() > 200, "{} VISION_POSITION_ESTIMATE", vpe.len());
    let mut final_counter = 0;
    for m in &vpe {
        let stamp = f(m, "usec");
        let t = dive_s(stamp);
        let grid = (t * 10.0 - (t * 10.0).round()).abs() * 100.0;
        assert!(grid < 1.0, "stamp {stamp} is {grid:.2} ms off the head's grid (t = {t:.4} s)");
        let lag_ms = (f(m, "arrival_us") + boot_us as f64 - stamp) * 1e-3;
        assert!((LINK_DELAY_MS - 1.0..LINK_DELAY_MS + 1000.0).contains(&lag_ms), "arrival - stamp {lag_ms:.1} ms at t = {t:.1} s");
        assert!(t >= 10.0, "a pose while aligning, at {t:.1} s");
        final_counter = final_counter.max(m["reset_counter"].as_u64().unwrap());
    }
    // The counter counts the new origin and the head's position re-acquisition on the GPS.
    let resets = &s["resets"];
    assert_eq!(resets["origin set"], 1, "{s}");
    assert!(resets["head position reset"].as_u64().unwrap_or(0) >= 1, "no position re-acquisition on the GPS: {s}");
    assert_eq!(final_counter, s["reset_counter"].as_u64().unwrap());
    assert!(final_counter >= 2);

    // Positions and yaw against the truth. The last counter's poses: the head has taken the GPS
    // (15 m north of the truth) and the frame is the autopilot's origin (10 m east).
    let mut checked = 0;
    for m in vpe.iter().filter(|m| m["reset_counter"].as_u64() == Some(final_counter)) {
        let t = dive_s(f(m, "usec"));
        let tr = traj.at(t);
        let c: Vec<f64> = m["covariance"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect();
        let expect = [tr.pos_ned_m.x + GPS_OFFSET_N_M, tr.pos_ned_m.y - ORIGIN_OFFSET_E_M, tr.pos_ned_m.z];
        let got = [f(m, "x"), f(m, "y"), f(m, "z")];
        for (k, var) in [(0, c[0]), (1, c[6]), (2, c[11])] {
            let tol = 3.0 * var.sqrt() + 0.3;
            assert!((got[k] - expect[k]).abs() < tol, "axis {k} at {t:.1} s: {} vs {} (tol {tol:.2})", got[k], expect[k]);
        }
        let yaw_err = wrap_pi(f(m, "yaw") - tr.yaw_rad).abs();
        assert!(
            yaw_err < 3.0 * c[20].sqrt() + 1e-3,
            "yaw off by {:.3} deg at {t:.1} s (sigma {:.3})",
            yaw_err.to_degrees(),
            c[20].sqrt().to_degrees()
        );
        checked += 1;
    }
    assert!(checked > 100, "{checked} poses after the re-acquisition");
    // The global form: the same numbers, once the origin is known.
    assert!(of("GLOBAL_VISION_POSITION_ESTIMATE").count() > 100);

    // Velocities: NED and body frame against the truth; none while withheld; never zeros.
    let outage = |t: f64| (DVL_SILENT_S.0..DVL_SILENT_S.1 + 1.0).contains(&t);
    let mut speed_in_outage = 0;
    for m in of("VISION_SPEED_ESTIMATE") {
        let t = dive_s(f(m, "usec"));
        let tr = traj.at(t);
        let c: Vec<f64> = m["covariance"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect();
        assert!(c[0].sqrt() <= 0.02 + 1e-6 && c[4].sqrt() <= 0.02 + 1e-6, "a velocity sent with sigma over the bound at {t:.1} s");
        let v = [f(m, "x"), f(m, "y"), f(m, "z")];
        for k in 0..3 {
            assert!(
                (v[k] - tr.vel_ned_mps[k]).abs() < 3.0 * c[4 * k].sqrt() + 0.03,
                "vel {k} at {t:.1} s: {} vs {}",
                v[k],
                tr.vel_ned_mps[k]
            );
        }
        if tr.vel_ned_mps.norm() > 0.3 {
            assert!(v.iter().map(|x| x * x).sum::<f64>().sqrt() > 0.1, "a zero velocity while moving at {t:.1} s");
        }
        speed_in_outage += usize::from(outage(t));
        assert!(t >= 10.0);
    }
    let mut odometry = 0;
    for m in of("ODOMETRY") {
        let t = dive_s(f(m, "time_usec"));
        let tr = traj.at(t);
        let v_b = tr.att_nb.inverse() * tr.vel_ned_mps;
        let c: Vec<f64> = m["velocity_covariance"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect();
        let v = [f(m, "vx"), f(m, "vy"), f(m, "vz")];
        for (k, var) in [(0, c[0]), (1, c[6]), (2, c[11])] {
            assert!((v[k] - v_b[k]).abs() < 3.0 * var.sqrt() + 0.03, "body vel {k} at {t:.1} s: {} vs {}", v[k], v_b[k]);
        }
        assert_eq!(m["child_frame_id"], 12, "child frame MAV_FRAME_BODY_FRD");
        odometry += 1;
    }
    assert!(odometry > 100, "{odometry} ODOMETRY");
    // The DVL silent for 9 s: the velocity's sigma passes the bound and the speed stops.
    assert!(s["velocity_withheld_uncertain"].as_u64().unwrap() > 10, "{s}");
    assert!(speed_in_outage < 90, "{speed_in_outage} speed messages in the outage");

    // Bad input counted, never fused; the link's death seen and survived.
    let refused = &s["gps_refused"];
    assert!(refused["far from the head's origin"].as_u64().unwrap_or(0) >= 1, "{refused}");
    assert!(refused["from the future"].as_u64().unwrap_or(0) >= 1, "{refused}");
    assert!(s["foreign_system"].as_u64().unwrap() >= 1, "{s}");
    assert!(s["scan"]["skipped_bytes"].as_u64().unwrap() > 0, "{s}");
    assert!(s["link_lost"].as_u64().unwrap() >= 1, "{s}");
    assert!(s["gps_sent"].as_u64().unwrap() >= 5 && s["gps_acked"].as_u64().unwrap() >= 5, "{s}");
    let last_vpe = vpe.iter().map(|m| dive_s(f(m, "usec"))).fold(0.0, f64::max);
    assert!(last_vpe > 36.0, "the bridge stopped serving at {last_vpe:.1} s");
    assert!(msgs.iter().any(|m| m["mavpackettype"] == "HEARTBEAT" && m["src_component"] == 197));
    assert!(msgs.iter().any(|m| m["mavpackettype"] == "STATUSTEXT"));
}
