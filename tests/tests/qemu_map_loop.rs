//! The map in the loop under QEMU: the board's camera trigger (bridge GPIO 0) exposes the
//! simulated camera at the firmware's logical time, the telemetry (another thread) brings the
//! trigger times and the solutions the mapper needs, and the mapper's frames are processed
//! only once those have arrived. Checked against the native run of the same scenario (same
//! application core; the QEMU run is the reference, the native one its fast twin).
//! Needs `SUBNAV_FIRMWARE_QEMU_ELF` (set by `cargo xtask test`).

use std::time::Duration;

use subnav_sil::Scenario;
use subnav_sil::run::HeadRun;

#[test]
fn qemu_camera_and_map_follow_the_firmwares_time() {
    let mut sc = Scenario::map_survey(1);
    sc.duration_s = 240.0;
    let q = HeadRun::qemu(&sc, &subnav_tests::qemu_elf())
        .timeout(Duration::from_secs(600))
        .run()
        .and_then(|o| o.score(&sc))
        .expect("QEMU dive");
    let n = HeadRun::native(&sc).run().and_then(|o| o.score(&sc)).expect("native dive");
    let (qm, nm) = (q.map.as_ref().expect("camera"), n.map.as_ref().expect("camera"));
    eprintln!("QEMU {:?}\nnative {:?}", qm.mapper, nm.mapper);
    assert_eq!(q.exit_code, Some(0));
    assert_eq!(q.nonfinite_values, 0);
    // A frame per trigger at 2 Hz; each matched with its trigger and its telemetry in time.
    assert_eq!(qm.captures, 481);
    assert_eq!(qm.captures_without_trigger, 0);
    assert_eq!(qm.nav_wait_timeouts, 0);
    assert_eq!(qm.mapper.frames, nm.mapper.frames);
    assert_eq!(qm.mapper.frames_without_features, nm.mapper.frames_without_features);
    // ~180 m of travel at a node per 6 m; the two CPUs' solutions differ in the last bits,
    // which can move a node by a frame, not change the map.
    assert!(qm.mapper.nodes >= 20 && qm.mapper.nodes.abs_diff(nm.mapper.nodes) <= 2, "{} vs {}", qm.mapper.nodes, nm.mapper.nodes);
    assert!(q.score.horizontal_max_err_m <= 3.0 && q.score.within_3_sigma >= 0.95, "{q:?}");
}
