//! `subnav sim` + `subnav run --native`: a scenario file round trip, a recorded run whose
//! summary, recording and truth the other tools accept, and clear errors for bad input.

use std::process::Command;

fn subnav() -> Command {
    Command::new(env!("CARGO_BIN_EXE_subnav"))
}

#[test]
fn sim_then_native_run_records_telemetry_and_truth_and_reports_errors() {
    let dir = tempfile::tempdir().unwrap();
    let sc = dir.path().join("dive.json");
    let st = subnav().args(["sim", "--duration-s", "60", "--seed", "4", "--occluded", "30,40,2", "--out"]).arg(&sc).status().unwrap();
    assert!(st.success());
    let (rec, truth) = (dir.path().join("dive.snrec"), dir.path().join("truth.csv"));
    let out = subnav()
        .args(["--format", "json", "run", "--native", "--quiet"])
        .arg(&sc)
        .arg("--record")
        .arg(&rec)
        .arg("--truth")
        .arg(&truth)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let r: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(r["nav_messages"], 601);
    assert_eq!(r["nonfinite_values"], 0);
    assert!(r["heading_rmse_deg"].as_f64().unwrap() < 1.0, "{r}");
    let faults = r["faults"].as_array().unwrap();
    assert!(faults.iter().any(|f| f[0] == "Polarization { unit: 2 }" && f[1] == "Occluded"), "{faults:?}");
    // The truth is 10 Hz CSV over the dive; the recording decodes to the same nav messages.
    let truth_text = std::fs::read_to_string(&truth).unwrap();
    assert_eq!(truth_text.lines().count(), 1 + 601);
    let dec = subnav().args(["--format", "json", "decode", "--file"]).arg(&rec).output().unwrap();
    assert!(dec.status.success(), "{}", String::from_utf8_lossy(&dec.stderr));
    let nav_lines = String::from_utf8_lossy(&dec.stdout).lines().filter(|l| l.contains("\"Nav\"")).count();
    assert_eq!(nav_lines, 601);
    let rep = subnav()
        .args(["report", "recording"])
        .arg(&rec)
        .arg("--truth")
        .arg(&truth)
        .arg("--out")
        .arg(dir.path().join("rep"))
        .output()
        .unwrap();
    assert!(rep.status.success(), "{}", String::from_utf8_lossy(&rep.stderr));
    assert!(dir.path().join("rep/report.md").exists());
}

#[test]
fn bad_scenarios_and_arguments_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let out = subnav().args(["sim", "--imu-stuck", "10,9", "--out"]).arg(dir.path().join("x.json")).output().unwrap();
    assert!(!out.status.success());
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.contains("--imu-stuck") && e.contains("the axis must be an integer 0..=5") && !e.contains("panicked"), "{e}");
    let junk = dir.path().join("junk.json");
    std::fs::write(&junk, "{\"x\": 1}").unwrap();
    let out = subnav().args(["run", "--native"]).arg(&junk).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("is not a scenario"));
    let sc = dir.path().join("ok.json");
    assert!(subnav().args(["sim", "--duration-s", "5", "--out"]).arg(&sc).status().unwrap().success());
    let out = subnav().args(["run", "--elf", "/nonexistent/fw.elf"]).arg(&sc).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("cargo xtask build"));
}

/// `subnav run` without a scenario: the main job (camera and map in the loop), shortened; the
/// summary has the map's lines and `--report` writes the recording, the truth and the page.
#[test]
fn run_without_a_scenario_runs_the_closed_loop_and_writes_the_report() {
    let dir = tempfile::tempdir().unwrap();
    let out = subnav().args(["run", "--native", "--quiet", "--duration-s", "180", "--report"]).arg(dir.path()).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("map ") && text.contains("map fixes") && text.contains("camera frames"), "{text}");
    for f in ["dive.snrec", "truth.csv", "report.html", "report.md", "trajectory.png", "position_error.png"] {
        assert!(dir.path().join(f).exists(), "{f} missing; stdout:\n{text}");
    }
    let md = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    assert!(md.contains("Map in the loop: ") && md.contains("horizontal RMS |"), "{md}");
    // The open-loop switch needs a camera: a scenario without one is refused with a reason.
    let sc = dir.path().join("plain.json");
    assert!(subnav().args(["sim", "--duration-s", "30", "--out"]).arg(&sc).status().unwrap().success());
    let bad = subnav().args(["run", "--native", "--quiet", "--no-map-fixes"]).arg(&sc).output().unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("has no camera"), "{}", String::from_utf8_lossy(&bad.stderr));
}
