//! Simulated survey with revisits (3 laps of a racetrack over a seafloor with look-alike places):
//! node recognition precision/recall and the drift with loop-closure fixes vs dead reckoning.
//! The same figures for docs/PERFORMANCE.md come from `subnav map --format json` (see there).

use subnav_topo::survey::{SurveyConfig, run};

#[test]
fn loop_closures_bound_the_drift_with_precise_recognition() {
    let cfg = SurveyConfig::default();
    let res = run(&cfg, &mut |_| {}).expect("survey");
    let r = &res.report;
    println!("{}", serde_json::to_string_pretty(r).unwrap());
    assert!(r.recognitions > 20, "too few recognitions: {}", r.recognitions);
    assert!(r.precision >= 0.9, "precision {}", r.precision);
    assert!(r.recall >= 0.3, "recall {}", r.recall);
    assert!(r.fixes > 5 && res.fix_frames.len() == r.fixes);
    assert!(
        r.final_drift_slam_m < 0.5 * r.final_drift_dr_m,
        "with fixes {} m vs dead reckoning {} m",
        r.final_drift_slam_m,
        r.final_drift_dr_m
    );
    assert!(r.max_drift_last_lap_slam_m < r.max_drift_last_lap_dr_m);
    assert_eq!(r.pd_repairs, 0);
}
