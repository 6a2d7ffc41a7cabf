//! A refused step changes nothing (module doc of `filter`): for every refusal path, the whole
//! filter (state, `P` and its factor, `Q`, `q`, the Sage-Husa counters and accumulators, the
//! previous spread) and the caller's noise statistics (`R`, `r`, their counter, the fading
//! factor's `V` and persistence statistics) are compared bit for bit before and after.
//!
//! Weights with `alpha = 1, beta = 0, kappa = 2` on 2 states are dyadic (`gamma = 2`, weights
//! 1/2 and 1/8), so the unrepairable covariances below are exactly singular, not "nearly".

use nalgebra::{SMatrix, SVector, Vector1, Vector2};

use super::*;
use crate::ukf::Euclidean;
use crate::ukf::gate::chi2_999;

type F = Ukf<f64, 2, 5>;

/// Every adaptive part on, the persistence test included; no eigenvalue floor (so a singular
/// `P` cannot be repaired).
fn cfg() -> UkfConfig<f64> {
    let mut c = UkfConfig::plain(1.0, 0.0, 2.0);
    c.adapt = AdaptConfig {
        k0: 20,
        q_mean: true,
        q_cov: true,
        r_mean: true,
        r_cov: true,
        fading: true,
        fading_persist: 0.5,
        ..AdaptConfig::plain()
    };
    c
}

/// Everything but the health counters, exactly: `{:?}` prints every float in its shortest
/// round-trip form, so equal text is equal bits (and `-0.0` differs from `0.0`).
fn snap(u: &F) -> String {
    let mut c = u.clone();
    c.clear_counters();
    format!("{c:?}")
}

/// The noise statistics without the gate's consecutive-rejection count.
fn snap_noise<const M: usize>(n: &MeasNoise<f64, M>) -> String {
    let mut c = *n;
    c.consecutive_rejects = 0;
    format!("{c:?}")
}

/// A filter after a few predict/update cycles, with an accepted update since the last predict
/// (so the Sage-Husa Q accumulators are non-zero), and the measurement's noise statistics.
fn warmed() -> (F, MeasNoise<f64, 2>) {
    let mut u = F::new(cfg(), Vector2::new(0.0, 0.0), SMatrix::identity(), SMatrix::identity() * 0.01).unwrap();
    let mut n = MeasNoise::new(SMatrix::<f64, 2, 2>::identity() * 0.1).with_gate(chi2_999(2), 16.0, 0).with_k0(20);
    for k in 0..12 {
        u.predict(1.0, |x| Vector2::new(x[0] + 0.1 * x[1], x[1])).unwrap();
        let z = Vector2::new(0.05 * k as f64, 0.3);
        assert!(u.update::<2, Euclidean, _>(&z, &mut n, |x| *x).unwrap().accepted, "warm-up update {k}");
    }
    assert!(u.acc_n > 0 && n.v_k > 0 && n.inn_k > 0 && n.k > 0);
    (u, n)
}

/// Run `step` on a copy of the warmed filter; it must be refused with `want`, leave the filter
/// and the noise bit for bit unchanged and count exactly one refusal in `counter`.
fn refused<R: core::fmt::Debug>(
    want: UkfError,
    counter: fn(&UkfHealth<f64>) -> u32,
    step: impl FnOnce(&mut F, &mut MeasNoise<f64, 2>) -> Result<R, UkfError>,
) {
    let (mut u, mut n) = warmed();
    let (before, before_n, h0) = (snap(&u), snap_noise(&n), *u.health());
    let r = step(&mut u, &mut n);
    assert_eq!(r.err(), Some(want));
    assert_eq!(snap(&u), before, "filter changed by a refused step ({want:?})");
    assert_eq!(snap_noise(&n), before_n, "noise statistics changed by a refused step ({want:?})");
    assert_eq!(counter(u.health()), counter(&h0) + 1, "{want:?} not counted");
    assert_eq!((u.health().predicts, u.health().updates_accepted), (h0.predicts, h0.updates_accepted));
}

fn nonfinite(h: &UkfHealth<f64>) -> u32 {
    h.nonfinite_rejects
}
fn unrepairable(h: &UkfHealth<f64>) -> u32 {
    h.unrepairable_rejects
}

#[test]
fn refused_predicts_change_nothing() {
    refused(UkfError::NonFiniteInput, nonfinite, |u, _| u.predict(f64::NAN, |x| *x));
    refused(UkfError::NonFiniteInput, nonfinite, |u, _| u.predict(-1.0, |x| *x));
    refused(UkfError::NonFiniteResult, nonfinite, |u, _| u.predict(1.0, |x| if x[0] > 0.5 { x * f64::NAN } else { *x }));
    refused(UkfError::NonFiniteResult, nonfinite, |u, _| u.predict(1.0, |x| x * 1e200));
    // The adaptive predict that fails after its Sage-Husa Q/q step: every sigma point to the
    // origin and no process noise gives P = 0, which no floor of 0 can repair. Before the step
    // was made atomic this left Q, q and k adapted and the accumulators as they were.
    refused(UkfError::CovarianceUnrepairable, unrepairable, |u, _| u.predict(0.0, |_| Vector2::zeros()));
}

#[test]
fn refused_updates_change_nothing() {
    let h = |x: &SVector<f64, 2>| *x;
    refused(UkfError::NonFiniteInput, nonfinite, |u, n| u.update::<2, Euclidean, _>(&Vector2::new(f64::INFINITY, 0.0), n, h));
    refused(UkfError::NonFiniteInput, nonfinite, |u, n| {
        let r11 = n.r[(1, 1)];
        n.r[(1, 1)] = f64::NAN;
        let r = u.update::<2, Euclidean, _>(&Vector2::zeros(), n, h);
        n.r[(1, 1)] = r11; // the caller's own write undone: only the filter's writes count
        r
    });
    refused(UkfError::NonFiniteResult, nonfinite, |u, n| u.update::<2, Euclidean, _>(&Vector2::zeros(), n, |x| x * f64::NAN));
    // Innovation covariance singular: a constant model and no measurement noise.
    refused(UkfError::NotPositiveDefinite, nonfinite, |u, n| {
        let (r, rm) = (n.r, n.r_mean);
        n.r = SMatrix::zeros();
        let out = u.update::<2, Euclidean, _>(&Vector2::zeros(), n, |_| Vector2::new(1.0, 2.0));
        (n.r, n.r_mean) = (r, rm);
        out
    });
}

/// An update whose posterior P is exactly singular: one state measured with noise 1e-40, so
/// `S = 1 + 1e-40 = 1` in f64. With dyadic weights at P = I the posterior is diag(0, 1)
/// exactly; a zero floor cannot repair it,
/// so the update is refused as `CovarianceUnrepairable` (and with a floor it is repaired).
#[test]
fn an_unrepairable_posterior_is_refused_as_such() {
    let fresh = || F::new(cfg(), Vector2::zeros(), SMatrix::identity(), SMatrix::identity() * 0.01).unwrap();
    let mut u = fresh();
    let mut n = MeasNoise::new(SMatrix::<f64, 1, 1>::new(1e-40));
    let (before, before_n) = (snap(&u), format!("{n:?}"));
    let r = u.update::<1, Euclidean, _>(&Vector1::new(0.0), &mut n, |x| Vector1::new(x[0]));
    assert_eq!(r, Err(UkfError::CovarianceUnrepairable));
    assert_eq!((snap(&u), format!("{n:?}")), (before, before_n));
    assert_eq!(u.health().unrepairable_rejects, 1);
    assert_eq!(u.health().nonfinite_rejects, 0, "an unrepairable P is not reported as non-finite");
    // The same update with an eigenvalue floor is repaired and accepted.
    let mut c = cfg();
    c.p_floor = 1e-9;
    let mut u = F::new(c, Vector2::zeros(), SMatrix::identity(), SMatrix::identity() * 0.01).unwrap();
    assert!(u.update::<1, Euclidean, _>(&Vector1::new(0.0), &mut n, |x| Vector1::new(x[0])).unwrap().accepted);
    assert_eq!((u.health().pd_repairs, u.health().unrepairable_rejects), (1, 0));
    // `set_p` with a singular matrix and no floor: refused as such too.
    let mut u = fresh();
    let before = snap(&u);
    assert_eq!(u.set_p(SMatrix::from_diagonal(&Vector2::new(1.0, 0.0))), Err(UkfError::CovarianceUnrepairable));
    assert_eq!(snap(&u), before);
}

/// A gate rejection writes nothing but the gate's count and, with Sage-Husa R on, R / r / their
/// counter from the clipped innovation (adapt module doc): not the state, P, Q, the Q
/// accumulators or the fading statistics. With R adaptation off for the measurement it writes
/// nothing but the count, and the filter goes on exactly as one that never saw it.
#[test]
fn a_gate_rejection_changes_nothing_but_the_gate_count_and_r() {
    let far = Vector2::new(50.0, -50.0);
    let (mut u, mut n) = warmed();
    let (before, h0, c0, n0) = (snap(&u), *u.health(), n.consecutive_rejects, n);
    assert!(!u.update::<2, Euclidean, _>(&far, &mut n, |x| *x).unwrap().accepted);
    assert_eq!(snap(&u), before);
    assert_eq!((u.health().gate_rejects, n.consecutive_rejects), (h0.gate_rejects + 1, c0 + 1));
    assert_eq!((n.v, n.v_k, n.inn_mean, n.inn_pow, n.inn_k), (n0.v, n0.v_k, n0.inn_mean, n0.inn_pow, n0.inn_k));
    assert_eq!(n.k, n0.k + 1, "the clipped Sage-Husa R step ran");
    // R adaptation off for this measurement: nothing but the count.
    let (mut u, mut n) = warmed();
    n.adapt = false;
    let (before, before_n) = (snap(&u), snap_noise(&n));
    assert!(!u.update::<2, Euclidean, _>(&far, &mut n, |x| *x).unwrap().accepted);
    assert_eq!((snap(&u), snap_noise(&n)), (before, before_n));
    let (mut twin, mut n_twin) = warmed();
    n_twin.adapt = false;
    let z = Vector2::new(0.7, 0.2);
    let a = u.update::<2, Euclidean, _>(&z, &mut n, |x| *x).unwrap();
    let b = twin.update::<2, Euclidean, _>(&z, &mut n_twin, |x| *x).unwrap();
    assert_eq!(a, b);
    assert_eq!((snap(&u), snap_noise(&n)), (snap(&twin), snap_noise(&n_twin)));
}
