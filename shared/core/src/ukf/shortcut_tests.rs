//! The shortcuts of the filter against its plain path (issue 38): the exact linear update
//! (`update_linear`), the update of a model that reads a prefix of the state (`update_dep`) and
//! the predict of a model affine in a suffix of the state (`predict_dep`) give what the full
//! sigma-point update / predict gives, to rounding, with every adaptive part on (fading factor,
//! Sage-Husa R and Q) and through gate rejections. The plain path is itself checked against
//! FilterPy (`tests/tests/peer_filterpy.rs`).

use nalgebra::{SMatrix, SVector, Vector2, Vector3};

use super::*;
use crate::ukf::Euclidean;
use crate::ukf::gate::chi2_999;

const N: usize = 6;
const S: usize = 2 * N + 1;
type F = Ukf<f64, N, S>;

fn lcg(seed: &mut u64) -> f64 {
    *seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    ((*seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5
}

fn filter(adapt: bool) -> F {
    let mut c = UkfConfig::plain(0.5, 2.0, 0.0);
    c.p_floor = 1e-12;
    c.p_rel_floor = 1e-12;
    if adapt {
        c.adapt =
            AdaptConfig { b: 0.95, k0: 5, r_cov: true, q_cov: true, fading: true, fading_s: 1.0, lambda_max: 3.0, ..AdaptConfig::plain() };
    }
    let mut seed = 99u64;
    let a = SMatrix::<f64, N, N>::from_fn(|_, _| lcg(&mut seed));
    let p0 = a * a.transpose() + SMatrix::<f64, N, N>::identity() * 0.05;
    let q = SMatrix::<f64, N, N>::from_diagonal(&SVector::<f64, N>::from_fn(|i, _| 1e-3 * (1.0 + i as f64)));
    Ukf::new(c, SVector::zeros(), p0, q).unwrap()
}

/// Nonlinear in states 0..2, linear (for a fixed state 0..2) in the others.
fn f(x: &SVector<f64, N>) -> SVector<f64, N> {
    let (a, b) = (x[0], x[1]);
    let mut y = *x;
    y[0] = a + 0.1 * b.sin();
    y[1] = b + 0.2 * a * a;
    y[2] += 0.1 * x[3] * a.cos() + 0.05 * x[4];
    y[3] += 0.1 * x[2] * b.cos();
    y[5] = 0.9 * x[5] + a.sin() * x[4];
    y
}

fn close<const R: usize, const C: usize>(a: &SMatrix<f64, R, C>, b: &SMatrix<f64, R, C>, tol: f64) -> bool {
    (a - b).abs().max() <= tol * (1.0 + b.abs().max())
}

/// Run the same sequence through the plain and the short paths; compare after every step.
fn twin_run(adapt: bool) {
    let (mut plain, mut short) = (filter(adapt), filter(adapt));
    let mut nl_plain = MeasNoise::new(SMatrix::<f64, 2, 2>::identity() * 0.01).with_gate(chi2_999(2), 16.0, 3);
    let mut nl_short = nl_plain;
    let mut lin_plain = MeasNoise::new(SMatrix::<f64, 3, 3>::identity() * 0.04).with_gate(chi2_999(3), 16.0, 3);
    let mut lin_short = lin_plain;
    // Linear: positions 2..5 (after the predict the mean is zero there only by chance).
    let hm = SMatrix::<f64, 3, N>::from_fn(|i, j| {
        if j == i + 2 {
            1.0
        } else if j == 5 && i == 0 {
            0.5
        } else {
            0.0
        }
    });
    let mut seed = 5u64;
    let (mut accepted, mut rejected, mut faded) = (0, 0, 0);
    for k in 0..60 {
        // Predict from a mean without error in the nonlinear states, as the navigation filter
        // does after an injection (the shortcut's promise).
        let mut x = *plain.x();
        x[0] = 0.0;
        x[1] = 0.0;
        plain.set_x(x).unwrap();
        short.set_x(x).unwrap();
        plain.predict(1.0, f).unwrap();
        short.predict_dep(1.0, 2, f).unwrap();
        assert!(close(short.x(), plain.x(), 1e-12) && close(short.p(), plain.p(), 1e-12), "predict {k}");
        // Nonlinear model of states 0..3 only.
        let h = |x: &SVector<f64, N>| Vector2::new(x[0].sin() + x[2], x[1] * x[1] + x[0]);
        let big = if k % 11 == 10 { 3.0 } else { 0.1 };
        let z = Vector2::new(big * lcg(&mut seed), 0.1 * lcg(&mut seed));
        let a = plain.update::<2, Euclidean, _>(&z, &mut nl_plain, h).unwrap();
        let b = short.update_dep::<2, Euclidean, _>(&z, &mut nl_short, 3, h).unwrap();
        assert_eq!(a.accepted, b.accepted, "update {k}");
        assert!((a.nis - b.nis).abs() <= 1e-9 * (1.0 + a.nis) && (a.lambda - b.lambda).abs() < 1e-9, "{a:?} {b:?}");
        assert!(close(short.x(), plain.x(), 1e-11) && close(short.p(), plain.p(), 1e-11), "update_dep {k}");
        assert!(close(&nl_short.r, &nl_plain.r, 1e-11), "R {k}");
        let hl = |x: &SVector<f64, N>| hm * x + Vector3::new(1.0, -2.0, 0.5);
        let z = Vector3::new(1.0 + big * lcg(&mut seed), -2.0 + 0.2 * lcg(&mut seed), 0.5 + 0.2 * lcg(&mut seed));
        let a = plain.update::<3, Euclidean, _>(&z, &mut lin_plain, hl).unwrap();
        let b = short.update_linear::<3, _>(&z, &mut lin_short, &hm, hl).unwrap();
        assert_eq!(a.accepted, b.accepted, "linear {k}");
        assert!((a.nis - b.nis).abs() <= 1e-9 * (1.0 + a.nis) && (a.lambda - b.lambda).abs() < 1e-9, "{a:?} {b:?}");
        assert!(close(short.x(), plain.x(), 1e-11) && close(short.p(), plain.p(), 1e-11), "update_linear {k}");
        assert!(close(&lin_short.r, &lin_plain.r, 1e-11), "linear R {k}");
        for r in [a, b] {
            accepted += usize::from(r.accepted);
            rejected += usize::from(!r.accepted);
            faded += usize::from(r.lambda > 1.0);
        }
    }
    // The sequence exercised the gate (and, adaptive, the fading factor).
    assert!(accepted > 0 && rejected > 0, "accepted {accepted} rejected {rejected}");
    if adapt {
        assert!(faded > 0, "no fading event");
    }
}

#[test]
fn shortcuts_equal_the_plain_sigma_point_steps() {
    twin_run(false);
    twin_run(true);
}
