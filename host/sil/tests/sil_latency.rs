//! Fusion at the time of validity: the same 5-minute native dive (DVL on, a fix every 5 s)
//! with its position fixes arriving 0, 1 and 3 s after their time must give the same accuracy
//! (horizontal RMS within 10 % of each other). Beside it, the figure of a head that fuses each
//! fix as if it were current (the fix stamped with its arrival time; at 1 m/s a 3-s-old fix is
//! 3 m behind the vehicle), printed with `--nocapture` and recorded in docs/PERFORMANCE.md.

use subnav_sil::dive::DiveResult;
use subnav_sil::run::HeadRun;
use subnav_sil::{FixPlan, Scenario};

fn dive(latency_s: f64, as_if_current: bool, dvl: bool) -> DiveResult {
    let base = Scenario::default();
    let fixes = FixPlan { as_if_current, ..FixPlan::usbl(5.0, 2.0, latency_s) };
    let sc = Scenario { seed: 1, position_fixes: Some(fixes), dvl: if dvl { base.dvl } else { None }, ..base };
    let r = HeadRun::native(&sc).run().unwrap().score(&sc).unwrap();
    assert_eq!(r.nonfinite_values, 0);
    r
}

fn figures(dvl: bool) -> (Vec<DiveResult>, DiveResult) {
    let at_time: Vec<DiveResult> = [0.0, 1.0, 3.0].iter().map(|&l| dive(l, false, dvl)).collect();
    let current = dive(3.0, true, dvl);
    let rms: Vec<f64> = at_time.iter().map(|r| r.score.horizontal_rms_err_m).collect();
    eprintln!(
        "dvl {dvl}: horizontal RMS at latency 0 / 1 / 3 s: {:.3} / {:.3} / {:.3} m ({:.1} / {:.1} / {:.1} % within 3 sigma); 3 s fused as if current: {:.3} m ({:.1} % within 3 sigma)",
        rms[0],
        rms[1],
        rms[2],
        100.0 * at_time[0].score.within_3_sigma,
        100.0 * at_time[1].score.within_3_sigma,
        100.0 * at_time[2].score.within_3_sigma,
        current.score.horizontal_rms_err_m,
        100.0 * current.score.within_3_sigma
    );
    (at_time, current)
}

/// The sensor head as it dives (DVL on): the fixes' latency must not matter.
#[test]
fn fix_latency_does_not_change_the_accuracy_with_the_dvl() {
    let (at_time, _current) = figures(true);
    let rms: Vec<f64> = at_time.iter().map(|r| r.score.horizontal_rms_err_m).collect();
    let (lo, hi) = rms.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &r| (lo.min(r), hi.max(r)));
    assert!(hi <= 1.10 * lo, "latency changes the accuracy: {rms:?}");
    for r in &at_time {
        assert!(r.score.within_3_sigma >= 0.99, "late fixes fused at their time stay consistent: {}", r.score.within_3_sigma);
    }
}

/// Fixes as the only position aiding: between fixes the position is free-inertial and drifts
/// fast, so a fix that arrives 3 s late leaves the real-time estimate 3 s longer without it and
/// the RMS grows with the latency (information, not fusion: after the arrival the late-fused
/// estimate is what on-time fusion gives). Fusing the same late fix as if current must be worse
/// than fusing it at its time.
#[test]
fn late_fixes_fused_at_their_time_beat_fusing_them_as_current() {
    let (at_time, current) = figures(false);
    assert!(
        at_time[2].score.horizontal_rms_err_m < current.score.horizontal_rms_err_m,
        "{} vs {}",
        at_time[2].score.horizontal_rms_err_m,
        current.score.horizontal_rms_err_m
    );
}
