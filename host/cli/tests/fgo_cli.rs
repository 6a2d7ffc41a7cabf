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
