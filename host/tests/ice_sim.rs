//! Seeded simulated under-ice runs, short enough for CI (120 m): the full odometry stays under
//! 1 % drift, is not overconfident (NEES), beats IMU-only dead reckoning by far, and gives the
//! same result when its inputs go through the file format (`--input DIR`). The sonar front end
//! (thresholding + phase correlation + geometry) measures the line-of-sight speed of the truth.

use subnav_host::ice::data::Dataset;
use subnav_host::ice::eval::evaluate;
use subnav_host::ice::montecarlo::{RPE_LENGTHS_M, Variant, run_seed};
use subnav_host::ice::odometry::{OdometryConfig, run};
use subnav_host::ice::sim::{SimConfig, simulate};
use subnav_host::ice::sonar;

#[test]
fn full_system_beats_imu_only_and_is_consistent() {
    let sim = SimConfig { seed: 7, distance_m: 120.0, ..SimConfig::default() };
    let res = run_seed(&sim, &OdometryConfig::default(), &[Variant::Full, Variant::ImuOnly]).unwrap();
    let (full, imu) = (&res[0].metrics, &res[1].metrics);
    eprintln!("full: {full:?}\n{:?}\nimu-only: {imu:?}", res[0].stats);
    assert!(full.distance_m > 115.0);
    assert!(full.drift_pct < 1.0, "drift {:.3} %", full.drift_pct);
    assert!(full.ate_pos_m < 0.5, "ATE {:.3} m", full.ate_pos_m);
    // 3-dof NEES averages 3 for a consistent filter; 9 would be a filter 3x overconfident in variance.
    assert!(full.nees_pos < 9.0 && full.nees_ori < 9.0, "NEES {:.2} / {:.2}", full.nees_ori, full.nees_pos);
    assert!(full.drift_pct * 20.0 < imu.drift_pct, "full {:.3} % vs IMU-only {:.3} %", full.drift_pct, imu.drift_pct);
    // The updates actually ran, and the gate rejected some (the simulator injects 1 % mismatches).
    let st = &res[0].stats;
    assert!(st.features_used > 1000 && st.features_gated > 0 && st.depth_used > 500 && st.sonar_used > 300, "{st:?}");
}

#[test]
fn sonar_velocity_from_images_matches_truth() {
    let sim = SimConfig { seed: 3, distance_m: 60.0, ..SimConfig::default() };
    let data = simulate(&sim);
    let cfg = OdometryConfig::default().sonar;
    let v = sonar::velocities(&data.sonar_frames, &cfg);
    assert!(v.len() > 250);
    let mut errs = Vec::new();
    for m in v.iter().filter(|m| m.t_s > sim.still_s + 6.0) {
        let i = data.truth.partition_point(|s| s.t_s < m.t_s);
        let tr = &data.truth[i.min(data.truth.len() - 1)];
        let los = cfg.boresight_b().dot(&(tr.rot.transpose() * tr.vel_w_mps));
        errs.push((m.los_mps, los));
    }
    let n = errs.len() as f64;
    let scale = errs.iter().map(|e| e.0).sum::<f64>() / errs.iter().map(|e| e.1).sum::<f64>();
    let rms = (errs.iter().map(|e| (e.0 - e.1).powi(2)).sum::<f64>() / n).sqrt();
    eprintln!("sonar: {} pairs, scale {scale:.4}, rms {rms:.4} m/s", errs.len());
    assert!((scale - 1.0).abs() < 0.03, "scale {scale}");
    assert!(rms < 0.04, "rms {rms}");
}

#[test]
fn file_round_trip_gives_the_same_estimate() {
    let sim = SimConfig { seed: 11, distance_m: 30.0, ..SimConfig::default() };
    let cfg = OdometryConfig::default();
    let mut data = simulate(&sim);
    data.sonar_velocity = sonar::velocities(&data.sonar_frames, &cfg.sonar);
    let dir = tempfile::tempdir().unwrap();
    data.write_dir(dir.path()).unwrap();
    let back = Dataset::read_dir(dir.path()).unwrap();
    assert_eq!(back.frames.len(), data.frames.len());
    let (a, _) = run(&data, &cfg, &data.cam).unwrap();
    let (b, _) = run(&back, &cfg, &back.cam).unwrap();
    assert_eq!(a.len(), b.len());
    let (ma, mb) = (evaluate(&a, &data.truth, &RPE_LENGTHS_M), evaluate(&b, &back.truth, &RPE_LENGTHS_M));
    assert!((ma.ate_pos_m - mb.ate_pos_m).abs() < 0.01, "{} vs {}", ma.ate_pos_m, mb.ate_pos_m);
    // Bad input is an error, not a panic.
    std::fs::write(dir.path().join("depth.csv"), "t_s,depth_m\n1.0,nan\n").unwrap();
    assert!(Dataset::read_dir(dir.path()).is_err());
    std::fs::write(dir.path().join("depth.csv"), "t_s,depth_m\n1.0\n").unwrap();
    assert!(Dataset::read_dir(dir.path()).is_err());
}
