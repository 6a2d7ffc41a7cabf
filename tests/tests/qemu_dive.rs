//! Sensors in the loop: the firmware ELF in QEMU reads the host's register-level chip models
//! (IMU, 4 polarization ADCs, depth) for a simulated dive and navigates; its telemetry is
//! compared with the truth. Needs `SUBNAV_FIRMWARE_QEMU_ELF` (set by `cargo xtask test`).

use std::time::Duration;

use subnav_host::sim::dive::run_dive;
use subnav_host::sim::{FaultPlan, Scenario};

fn elf() -> std::path::PathBuf {
    subnav_tests::qemu_elf()
}

/// What holds today (see docs/RELIABILITY.md for the open heading problem): the run completes,
/// the sensor chain through drivers and chip models is accurate, the compass fixes, the depth
/// channel is aided, and nothing is NaN. Heading and horizontal-position bounds are not asserted
/// yet: the filter's heading does not converge in this scenario (issue 5 stays open).
#[test]
fn dive_with_sensors_in_the_loop() {
    let sc = Scenario { duration_s: 60.0, ..Scenario::default() };
    let r = run_dive(&elf(), &sc, None, Duration::from_secs(600)).expect("dive");
    eprintln!("{}", serde_json::to_string_pretty(&r).unwrap());
    assert_eq!(r.exit_code, Some(0));
    assert_eq!(r.nonfinite_values, 0);
    assert_eq!(r.nav_messages, 601, "10 Hz for 60 s");
    assert!(r.compass_fixes > 300, "{r:?}");
    assert!(r.raw_depth_rmse_m < 0.02, "pressure chain (driver + chip model): {r:?}");
    assert!(r.compass_rmse_deg < 10.0, "compass alone: {r:?}");
    assert!(r.depth_rmse_m < 1.0, "depth-aided vertical channel: {r:?}");
}

#[test]
fn dive_with_injected_faults_completes_and_reports_them() {
    let faults = FaultPlan {
        imu_nack_s: Some((20.0, 21.0)),
        imu_stuck_axis: Some((40.0, 3)),
        occluded_unit: Some((25.0, 35.0, 1)),
        depth_nack_probability: 0.05,
    };
    let sc = Scenario { duration_s: 60.0, seed: 7, faults, ..Scenario::default() };
    let r = run_dive(&elf(), &sc, None, Duration::from_secs(600)).expect("dive");
    eprintln!("{}", serde_json::to_string_pretty(&r).unwrap());
    assert_eq!(r.exit_code, Some(0));
    assert_eq!(r.nonfinite_values, 0);
    let has = |s: &str, k: &str| r.faults.iter().any(|f| f.0.starts_with(s) && f.1 == k);
    assert!(has("Imu", "BusNack"), "{:?}", r.faults);
    assert!(has("Imu", "Stuck"), "{:?}", r.faults);
    assert!(has("Depth", "BusNack"), "{:?}", r.faults);
}
