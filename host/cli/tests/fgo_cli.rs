//! `subnav fgo simulate` writes a sensor log that `subnav fgo replay` reads back, in the CLI's
//! own build (where defmt-decoder turns on serde_json's `arbitrary_precision`).

use std::process::Command;

#[test]
fn simulated_log_replays() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("log.jsonl");
    let out = dir.path().join("est.csv");
    let o = Command::new(env!("CARGO_BIN_EXE_subnav"))
        .args(["fgo", "simulate", "--duration-s", "20", "--seed", "3", "--out"])
        .arg(&log)
        .output()
        .unwrap();
    assert!(o.status.success(), "simulate: {}", String::from_utf8_lossy(&o.stderr));
    let o = Command::new(env!("CARGO_BIN_EXE_subnav"))
        .args(["--format", "json", "fgo", "replay", "--quiet", "--input"])
        .arg(&log)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "replay: {}", String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(&out).unwrap();
    assert!(csv.lines().count() > 10, "{csv}");

    // A record without a known type is an error naming the line.
    std::fs::write(&log, "{\"type\":\"sonar\",\"t_s\":0}\n").unwrap();
    let o =
        Command::new(env!("CARGO_BIN_EXE_subnav")).args(["fgo", "replay", "--input"]).arg(&log).arg("--out").arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("line 1") && err.contains("sonar"), "{err}");
}

/// `subnav fgo pyfg`: a small range-aided survey solves and writes the trajectory and the
/// beacons; a bad file is an error naming its line, and nothing is written (an earlier good
/// output stays as it was).
#[test]
fn pyfg_solves_and_refuses_bad_files_without_writing() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("survey.pyfg");
    let out = dir.path().join("traj.csv");
    let beacons = dir.path().join("traj.beacons.csv");
    // a square with two beacons; exact odometry and ranges
    // vertices first (as the PyFactorGraph writer does), then the measurements
    let mut text = String::from("VERTEX_XY L0 12.0 7.0\nVERTEX_XY L1 -5.0 30.0\n");
    let mut edges = String::new();
    let (mut x, mut y, mut th) = (0.0f64, 0.0f64, 0.0f64);
    for k in 0..40 {
        text += &format!("VERTEX_SE2 {k} A{k} {x} {y} {th}\n");
        for (b, (bx, by)) in [(0, (12.0, 7.0)), (1, (-5.0, 30.0))] {
            let r: f64 = ((x - bx) * (x - bx) + (y - by) * (y - by)).sqrt();
            edges += &format!("EDGE_RANGE {k} A{k} L{b} {r} 0.5625\n");
        }
        let turn = if (k + 1) % 10 == 0 { std::f64::consts::FRAC_PI_2 } else { 0.0 };
        edges += &format!("EDGE_SE2 {k} A{k} A{} 2.0 0.0 {turn} 0.0004 0 0 0.0004 0 0.000004\n", k + 1);
        x += 2.0 * th.cos();
        y += 2.0 * th.sin();
        th += turn;
    }
    text += &format!("VERTEX_SE2 40 A40 {x} {y} {th}\n");
    text += &edges;
    std::fs::write(&input, &text).unwrap();
    for mode in ["known", "unknown"] {
        let o = Command::new(env!("CARGO_BIN_EXE_subnav"))
            .args(["--format", "json", "fgo", "pyfg", "--beacons", mode, "--input"])
            .arg(&input)
            .arg("--out")
            .arg(&out)
            .arg("--truth")
            .arg(&input)
            .output()
            .unwrap();
        assert!(o.status.success(), "{mode}: {}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert!(v["ape_rmse_m"].as_f64().unwrap() < 1e-3, "{mode}: {v}");
        assert_eq!(v["ranges_inflated"], 0, "{mode}: {v}");
        let csv = std::fs::read_to_string(&out).unwrap();
        assert_eq!(csv.lines().next(), Some("key,x_m,y_m,theta_rad"));
        assert_eq!(csv.lines().count(), 42);
        assert_eq!(std::fs::read_to_string(&beacons).unwrap().lines().count(), 3);
    }
    let good_out = std::fs::read(&out).unwrap();
    let good_beacons = std::fs::read(&beacons).unwrap();
    let line_of = |needle: &str| text.lines().position(|l| l.contains(needle)).unwrap() + 1;
    let cases = [
        (text.replace("EDGE_RANGE 5 A5 L0", "EDGE_RANGE3 5 A5 L0"), line_of("EDGE_RANGE 5 A5 L0"), "unknown line type"),
        (text.replace("EDGE_RANGE 7 A7 L1", "EDGE_RANGE 7 A7 L9"), line_of("EDGE_RANGE 7 A7 L1"), "undeclared beacon L9"),
        (text.replace("A3 A4 2.0 0.0 0 0.0004", "A3 A4 2.0 0.0 0 -0.0004"), line_of("A3 A4 2.0"), "variance c11"),
        (text.replace("A3 A4 2.0 0.0 0 0.0004", "A3 A4 NaN 0.0 0 0.0004"), line_of("A3 A4 2.0"), "not finite"),
        (format!("{text}VERTEX_SE2 41 A41 0 0 0\n"), text.lines().count() + 1, "not connected"),
    ];
    for (bad, line, what) in cases {
        std::fs::write(&input, &bad).unwrap();
        let o = Command::new(env!("CARGO_BIN_EXE_subnav"))
            .args(["fgo", "pyfg", "--input"])
            .arg(&input)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(&format!("survey.pyfg:{line}:")) && err.contains(what), "{what}: {err}");
        assert_eq!(std::fs::read(&out).unwrap(), good_out, "{what}: output touched");
        assert_eq!(std::fs::read(&beacons).unwrap(), good_beacons, "{what}: beacons touched");
    }
}
