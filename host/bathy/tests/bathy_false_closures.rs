//! Issue 9 "Done when": false loop closures on flat terrain are rejected. A survey over flat
//! sand (plus depth noise, sound-speed error and a drifting dead reckoning) is run through the
//! whole chain: every closure attempt must be rejected and the navigation left uncorrected.
//! The control survey over rugged terrain (same plan and drift) must close loops, so the test
//! cannot pass by never matching anything.

use subnav_bathy::pipeline::{self, PipelineConfig};
use subnav_bathy::sim::{self, SimConfig};

fn config(flat: bool) -> SimConfig {
    let mut c = SimConfig::small(3, 320.0, 140.0);
    c.terrain.all_flat = flat;
    // Strong drift so that wrong matches would have room to appear.
    c.dropout_rate_hz = 1.0 / 100.0;
    c
}

#[test]
fn flat_sand_survey_yields_no_closures_and_no_correction() {
    for seed in [11u64] {
        let s = sim::simulate(&config(true), seed);
        let cfg = PipelineConfig::for_altitude(20.0);
        let out = pipeline::run(&s.survey, &cfg).unwrap();
        assert!(!out.attempts.is_empty(), "overlapping submaps must be tried");
        let matched: Vec<_> = out.attempts.iter().filter(|a| a.result.is_ok()).collect();
        assert!(matched.is_empty(), "seed {seed}: flat terrain produced closures: {matched:?}");
        assert!(out.offsets_spring.iter().all(|o| o.norm() < 1e-6));
    }
}

#[test]
fn flat_sand_false_closures_are_rejected_even_without_relief_gates() {
    // Switch the relief/information gates off: the ambiguity test and the vote must still keep
    // every false closure out of the solution.
    let s = sim::simulate(&config(true), 13);
    let mut cfg = PipelineConfig::for_altitude(20.0);
    cfg.matching.min_relief_m = 0.0;
    cfg.matching.min_mean_don = 0.0;
    let out = pipeline::run(&s.survey, &cfg).unwrap();
    assert!(!out.attempts.is_empty());
    assert!(out.attempts.iter().all(|a| !a.kept), "{:?}", out.attempts);
}

#[test]
fn rugged_control_survey_closes_loops_and_reduces_error() {
    let s = sim::simulate(&config(false), 11);
    let cfg = PipelineConfig::for_altitude(20.0);
    let out = pipeline::run(&s.survey, &cfg).unwrap();
    let kept = out.attempts.iter().filter(|a| a.kept).count();
    assert!(kept >= 2, "rugged terrain must close loops: {:?}", out.attempts.iter().map(|a| &a.result).collect::<Vec<_>>());
    let ev = pipeline::evaluate(&s, &out, &cfg);
    assert_eq!(ev.closures.kept_false, 0);
    assert!(
        ev.spring.sounding_error.mean_m < 0.5 * ev.dead_reckoning.sounding_error.mean_m,
        "DR {:.2} m, spring {:.2} m",
        ev.dead_reckoning.sounding_error.mean_m,
        ev.spring.sounding_error.mean_m
    );
}
