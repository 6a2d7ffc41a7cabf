//! Fusion at the time of validity: the same 5-minute native dive with its position fixes
//! arriving 0, 1 and 3 s after their time must give the same accuracy (horizontal RMS within
//! 10 % of each other), with the fixes as the only position aiding and with the DVL as well.
//! Beside it, the figure a head gets that fuses each fix as if it were current (the fix stamped
//! with its arrival time): at 1 m/s a 3-s-old fix is 3 m behind the vehicle, so it must be
//! clearly worse (this is what the delayed fusion buys).

use subnav_sil::dive::DiveResult;
use subnav_sil::sil::run_dive_native;
use subnav_sil::{FixPlan, Scenario};

fn dive(latency_s: f64, as_if_current: bool, dvl: bool) -> DiveResult {
    let base = Scenario::default();
    let fixes = FixPlan { period_s: 5.0, sigma_m: 2.0, latency_s, as_if_current };
    let sc = Scenario { seed: 1, position_fixes: Some(fixes), dvl: if dvl { base.dvl } else { None }, ..base };
    let r = run_dive_native(&sc);
    assert_eq!(r.nonfinite_values, 0);
    r
}

fn check(dvl: bool) {
    let rms: Vec<f64> = [0.0, 1.0, 3.0].iter().map(|&l| dive(l, false, dvl).horizontal_rms_err_m).collect();
    let current = dive(3.0, true, dvl);
    eprintln!(
        "dvl {dvl}: horizontal RMS at latency 0 / 1 / 3 s: {:.3} / {:.3} / {:.3} m; 3 s fused as if current: {:.3} m (final {:.2} m, {:.1} % within 3 sigma)",
        rms[0],
        rms[1],
        rms[2],
        current.horizontal_rms_err_m,
        current.horizontal_final_err_m,
        100.0 * current.within_3_sigma
    );
    let (lo, hi) = rms.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &r| (lo.min(r), hi.max(r)));
    assert!(hi <= 1.10 * lo, "latency changes the accuracy: {rms:?}");
    assert!(current.horizontal_rms_err_m > 1.2 * rms[2], "as-if-current fusion should be worse: {} vs {:?}", current.horizontal_rms_err_m, rms);
}

#[test]
fn fix_latency_does_not_change_the_accuracy_fixes_only() {
    check(false);
}

#[test]
fn fix_latency_does_not_change_the_accuracy_with_the_dvl() {
    check(true);
}
