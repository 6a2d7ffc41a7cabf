//! `subnav bathy` end to end on small surveys: simulate -> CSV export -> run on the CSV as a
//! user would; outputs exist and are well formed; bad input gives errors, not panics.

use std::process::Command;

fn subnav() -> Command {
    Command::new(env!("CARGO_BIN_EXE_subnav"))
}

// Seed 1 has a DVL dropout (DR error ~7 m); on a survey whose DR error is already below the
// closure accuracy (~1 m, e.g. seed 3) the correction cannot reduce it and is not expected to.
#[test]
fn simulate_then_run_on_exported_csv() {
    let dir = tempfile::tempdir().unwrap();
    let sim_dir = dir.path().join("sim");
    let st = subnav()
        .args(["bathy", "simulate", "--small", "--seeds", "1", "--export-csv", "--no-plots", "--format", "json", "--out"])
        .arg(&sim_dir)
        .output()
        .unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    let v: serde_json::Value = serde_json::from_slice(&st.stdout).unwrap();
    let p = &v["pooled"];
    assert!(p["dead_reckoning"]["mean_m"].as_f64().unwrap() > 0.0);
    assert!(p["spring"]["mean_m"].as_f64().unwrap() < p["dead_reckoning"]["mean_m"].as_f64().unwrap());
    for f in ["nav.csv", "soundings.csv", "truth_nav.csv", "evaluation.json", "bathymetry_corrected.asc", "trajectory_corrected.csv"] {
        assert!(sim_dir.join(f).exists(), "{f} missing");
    }
    let out = dir.path().join("csv");
    let st = subnav()
        .args(["bathy", "run", "--format", "json", "--soundings"])
        .arg(sim_dir.join("soundings.csv"))
        .arg("--nav")
        .arg(sim_dir.join("nav.csv"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    let v: serde_json::Value = serde_json::from_slice(&st.stdout).unwrap();
    assert!(v["closures_kept"].as_u64().unwrap() >= 1, "{v}");
    assert!(out.join("map_before_after.png").exists());
    let g = std::fs::read_to_string(out.join("bathymetry_corrected.asc")).unwrap();
    subnav_bathy::grid::Grid::read_esri_ascii(&g).unwrap();
}

#[test]
fn bad_csv_input_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let nav = dir.path().join("nav.csv");
    let snd = dir.path().join("s.csv");
    std::fs::write(&nav, "t_s,north_m,east_m,depth_m,heading_rad\n0,0,0,10,0\n1,NaN,0,10,0\n").unwrap();
    std::fs::write(&snd, "t_s,beam_angle_rad,range_m\n0,0,10\n").unwrap();
    let run = |n: &std::path::Path, s: &std::path::Path| {
        subnav()
            .arg("bathy")
            .arg("run")
            .arg("--soundings")
            .arg(s)
            .arg("--nav")
            .arg(n)
            .arg("--out")
            .arg(dir.path().join("o"))
            .output()
            .unwrap()
    };
    let o = run(&nav, &snd);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("not finite") && e.contains("line 3") && !e.contains("panicked"), "{e}");
    std::fs::write(&nav, "").unwrap();
    let o = run(&nav, &snd);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("empty") && !e.contains("panicked"), "{e}");
    let o = run(&dir.path().join("missing.csv"), &snd);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("missing.csv"));
}
