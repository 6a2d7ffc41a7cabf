//! Sensors in the loop: the firmware ELF in QEMU reads the host's register-level chip models
//! (IMU, 4 polarization ADCs, depth) for a simulated 5-minute dive (the default scenario: rest
//! at the surface, descent to 10 m, lawnmower survey at 1 m/s, a USBL-like position fix every
//! 5 s with 2 m 1-sigma per axis) and navigates; its telemetry is compared with the truth.
//! Needs `SUBNAV_FIRMWARE_QEMU_ELF` (set by `cargo xtask test`).
//!
//! Bounds and why (figures measured in docs/PERFORMANCE.md, "Sensor head dives"):
//! - heading RMSE <= 1 deg once converged (reported yaw sigma <= 5 deg, within 30 s of boot):
//!   the compass's model error is budgeted at 0.5 deg 1-sigma (firmware `estimator`), so 1 deg
//!   is 2 sigma of what the filter is told; measured 0.19-0.26 deg. At least 95 % of the
//!   samples within 3 reported sigma (consistency).
//! - horizontal RMS error <= 5 m: the position fixes alone have a horizontal RMS of
//!   2 m * sqrt(2) = 2.8 m; the filter must do no worse than that plus the inertial drift
//!   between fixes (MEMS accelerometer bias 0.02 m/s^2: under 1 m over 5 s). Measured 2.0-3.5 m.
//!   At least 95 % of the samples within 3 reported sigma.
//! - depth RMSE <= 0.05 m: the pressure chain's own noise is 3-5 mm; the rest is filter lag at
//!   the ends of the descent.

use std::time::Duration;

use subnav_sil::dive::DiveResult;
use subnav_sil::run::HeadRun;
use subnav_sil::{DvlPlan, FaultPlan, Scenario};

fn elf() -> std::path::PathBuf {
    subnav_tests::qemu_elf()
}

fn dive(sc: &Scenario) -> DiveResult {
    let r = HeadRun::qemu(sc, &elf()).timeout(Duration::from_secs(900)).run().and_then(|o| o.score(sc)).expect("dive");
    eprintln!("{}", serde_json::to_string_pretty(&r).unwrap());
    r
}

#[test]
fn five_minute_dive_with_sensors_in_the_loop_meets_the_stated_bounds() {
    let sc = Scenario::default();
    assert_eq!(sc.duration_s, 300.0);
    let r = dive(&sc);
    assert_eq!(r.exit_code, Some(0));
    assert_eq!(r.nonfinite_values, 0);
    assert_eq!(r.nav_messages, 3001, "10 Hz for 300 s");
    assert!(r.compass_fixes > 2500, "{r:?}");
    assert!(r.raw_depth_rmse_m < 0.02, "pressure chain (driver + chip model): {r:?}");
    assert!(r.score.heading_converged_s.is_some_and(|t| t <= 30.0), "heading converged at {:?}", r.score.heading_converged_s);
    assert!(r.score.heading_rmse_deg <= 1.0, "heading RMSE {} deg", r.score.heading_rmse_deg);
    assert!(r.score.heading_within_3_sigma >= 0.95, "heading consistency {}", r.score.heading_within_3_sigma);
    assert!(r.score.horizontal_rms_err_m <= 5.0, "horizontal RMS {} m", r.score.horizontal_rms_err_m);
    assert!(r.score.within_3_sigma >= 0.95, "position consistency {}", r.score.within_3_sigma);
    assert!(r.score.depth_rmse_m <= 0.05, "depth RMSE {} m", r.score.depth_rmse_m);
}

/// Bus NACKs on the IMU (1 s) and 5 % of the depth reads, an occluded polarization unit (10 s),
/// from 240 s on a stuck gyro axis for the rest of the dive, and a DVL that goes silent for
/// 20 s, flags 5 % of its pings invalid and sends 2 % of its sentences with a bad checksum and
/// 2 % cut short: the run completes, every fault is reported, nothing is NaN, and the filter
/// (coasting on compass, depth, DVL and fixes while the IMU is out) still meets the clean
/// dive's bounds.
#[test]
fn five_minute_dive_with_injected_faults_completes_and_reports_them() {
    let faults = FaultPlan {
        imu_nack_s: Some((100.0, 101.0)),
        imu_stuck_axis: Some((240.0, 3)),
        occluded_unit: Some((120.0, 130.0, 1)),
        depth_nack_probability: 0.05,
        ..FaultPlan::default()
    };
    let dvl = DvlPlan {
        silent_s: Some((150.0, 170.0)),
        invalid_probability: 0.05,
        bad_checksum_probability: 0.02,
        truncate_probability: 0.02,
        ..DvlPlan::default()
    };
    let sc = Scenario { seed: 7, faults, dvl: Some(dvl), ..Scenario::default() };
    let r = dive(&sc);
    assert_eq!(r.exit_code, Some(0));
    assert_eq!(r.nonfinite_values, 0);
    assert_eq!(r.nav_messages, 3001);
    let has = |s: &str, k: &str| r.faults.iter().any(|f| f.0.starts_with(s) && f.1 == k);
    assert!(has("Imu", "BusNack"), "{:?}", r.faults);
    assert!(has("Imu", "Stuck"), "{:?}", r.faults);
    assert!(has("Depth", "BusNack"), "{:?}", r.faults);
    assert!(has("Polarization { unit: 1 }", "Occluded"), "{:?}", r.faults);
    assert!(has("Dvl", "Invalid") && has("Dvl", "BadCrc") && has("Dvl", "Malformed"), "{:?}", r.faults);
    // The compass went on with the other three units.
    assert!(r.compass_fixes > 2500, "{r:?}");
    assert!(r.score.heading_rmse_deg <= 1.0, "heading RMSE {} deg", r.score.heading_rmse_deg);
    assert!(r.score.heading_within_3_sigma >= 0.95, "heading consistency {}", r.score.heading_within_3_sigma);
    assert!(r.score.horizontal_rms_err_m <= 5.0, "horizontal RMS {} m", r.score.horizontal_rms_err_m);
    assert!(r.score.within_3_sigma >= 0.95, "position consistency {}", r.score.within_3_sigma);
}

/// Stack painting: the board reports its stack peak at the end of a run. 12 s with the sensors
/// covers the deepest paths measured so far (boot, the end of the alignment at 10 s, the filter).
/// The bound is the 32 KiB RAM goal less this board's static RAM (24 B, `cargo xtask size`):
/// today's figure is 31,992 B (docs/PERFORMANCE.md, "Firmware size and RAM", which also says why
/// the STM32 board, with 1,100 B of static RAM, is estimated 0.7 KiB over the goal).
#[test]
fn the_stack_peak_is_painted_and_reported() {
    use subnav_link::qemu::{Downlinker, QemuEvent};
    let sc = Scenario { duration_s: 12.0, ..Scenario::default() };
    let mut logs = Vec::new();
    let mut hook = |e: &QemuEvent, _: &mut Downlinker| {
        if let QemuEvent::Log(l) = e {
            logs.push(l.message.clone());
        }
    };
    let out = HeadRun::qemu(&sc, &elf()).timeout(Duration::from_secs(300)).qemu_events(&mut hook).run().expect("QEMU run");
    assert_eq!(out.exit_code, Some(0));
    let line = logs.iter().find(|l| l.starts_with("stack peak")).unwrap_or_else(|| panic!("no stack report in {logs:?}"));
    let words: Vec<&str> = line.split_whitespace().collect();
    let (peak, size): (u32, u32) = (words[2].parse().unwrap(), words[5].parse().unwrap());
    eprintln!("{line}");
    assert!(peak > 1024 && peak < size, "{line}");
    const QEMU_STATIC_RAM_B: u32 = 24;
    // The goal is 32 KiB with the stack. Measured 33,064 B with this landing's refusal-safe UKF
    // predict (one more 15x15 candidate P) and the downlink duplicate filter: the goal is missed
    // by 296 B (docs/PERFORMANCE.md, "Firmware size and RAM"). The bound guards against a
    // further regression (a first duplicate filter took the peak to 40.7 KB) until it is won back.
    // Issue 34 took it to 33,760 B (the IMU noise scale in every `NavConfig` copy on the
    // alignment's path, the warm-start record, and protocol 7's named aid-source statuses: 176 B
    // kept in the estimator, a larger `Health` on the telemetry path): the bound is 33.25 KiB
    // until issue 38 wins it back. Issue 38 did: 31,992 B (the Sage-Husa Q step's two symmetric
    // matrices in one and the sigma-point weights stored compact, 1 KB less per filter, which
    // the boot path holds twice; docs/PERFORMANCE.md, "Firmware size and RAM"). The bound is the
    // goal again.
    const RAM_BOUND_B: u32 = 32 * 1024;
    assert!(peak + QEMU_STATIC_RAM_B <= RAM_BOUND_B, "stack peak + static RAM over {RAM_BOUND_B} B (goal 32 KiB): {line}");
}
