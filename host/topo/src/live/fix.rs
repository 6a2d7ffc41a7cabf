//! The loop-closure fix as an equivalent independent measurement (see the module doc of
//! [`super`] for the model), and the 2x2 symmetric helpers it needs. Everything f64, symmetric by
//! construction (explicitly symmetrised), PD checked, no NaN out.
//!
//! With `m = x1 - x0`, `D` the drift covariance (PD), `S = D + V`:
//! - posterior of the position at t1: `mu = x1 - D S^-1 m`, `Sigma = P1 - D S^-1 D`;
//! - equivalent measurement `R = (Sigma^-1 - P1^-1)^-1`, `z = x1 + R Sigma^-1 (mu - x1)`, which
//!   simplify (using `Sigma^-1 - P1^-1 = Sigma^-1 (P1 - Sigma) P1^-1`) to
//!   `R = P1 D^-1 S D^-1 P1 - P1` and `z = x1 - P1 D^-1 m`: no difference of near-equal
//!   information matrices, so `D -> 0` gives a large, accurate `R` instead of cancellation noise;
//! - gate statistic `m^T S^-1 m` (chi-square, 2 dof).

use nalgebra::{Matrix2, Vector2};

/// Symmetric 2x2 from (NN, NE, EE).
pub fn sym(c: [f64; 3]) -> Matrix2<f64> {
    Matrix2::new(c[0], c[1], c[1], c[2])
}

/// (NN, NE, EE) of a matrix, symmetrised.
pub fn tri(m: &Matrix2<f64>) -> [f64; 3] {
    [m[(0, 0)], 0.5 * (m[(0, 1)] + m[(1, 0)]), m[(1, 1)]]
}

/// `(m + m^T) / 2`.
pub fn symmetrise(m: &Matrix2<f64>) -> Matrix2<f64> {
    (m + m.transpose()) * 0.5
}

/// Eigenvalues (ascending) and the unit eigenvector of the larger one of a symmetric 2x2.
pub fn eig_sym(m: &Matrix2<f64>) -> ([f64; 2], [f64; 2]) {
    let (a, b, c) = (m[(0, 0)], 0.5 * (m[(0, 1)] + m[(1, 0)]), m[(1, 1)]);
    let mean = 0.5 * (a + c);
    let r = (0.25 * (a - c) * (a - c) + b * b).sqrt();
    let th = 0.5 * (2.0 * b).atan2(a - c);
    ([mean - r, mean + r], [th.cos(), th.sin()])
}

/// The PSD projection of a symmetric 2x2 with its eigenvalues floored at `floor`.
pub fn floor_eig(m: &Matrix2<f64>, floor: f64) -> Matrix2<f64> {
    let ([l_lo, l_hi], [c, s]) = eig_sym(m);
    let (l_lo, l_hi) = (l_lo.max(floor), l_hi.max(floor));
    // v_hi = (c, s), v_lo = (-s, c).
    let v_hi = Vector2::new(c, s);
    let v_lo = Vector2::new(-s, c);
    symmetrise(&(v_hi * v_hi.transpose() * l_hi + v_lo * v_lo.transpose() * l_lo))
}

/// Positive definite (both eigenvalues > 0) and finite.
pub fn is_pd(m: &Matrix2<f64>) -> bool {
    m.iter().all(|v| v.is_finite()) && m[(0, 0)] > 0.0 && m[(0, 0)] * m[(1, 1)] - m[(0, 1)] * m[(1, 0)] > 0.0
}

/// Inverse of a PD symmetric 2x2, symmetrised; `None` when not PD.
pub fn inv_pd(m: &Matrix2<f64>) -> Option<Matrix2<f64>> {
    if !is_pd(m) {
        return None;
    }
    m.try_inverse().map(|i| symmetrise(&i)).filter(|i| i.iter().all(|v| v.is_finite()))
}

/// Everything the fix computation produces.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FixMath {
    /// Drift covariance used (`P1 - P0` projected onto PSD, eigenvalues floored).
    pub drift: Matrix2<f64>,
    /// Estimated displacement `m = x1 - x0` and the gate statistic `m^T (D + V)^-1 m`.
    pub m: Vector2<f64>,
    pub gate_d2: f64,
    /// Posterior of the position at t1.
    pub mu: Vector2<f64>,
    pub sigma: Matrix2<f64>,
    /// The equivalent independent measurement.
    pub z: Vector2<f64>,
    pub r: Matrix2<f64>,
}

/// Why a fix cannot be computed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FixMathError {
    /// An input is NaN or infinite.
    NonFinite,
    /// `P0`, `P1` or `V` is not positive definite (or `P0` not PSD).
    NotPositiveDefinite,
    /// A result (posterior or equivalent covariance) came out not PD or not finite.
    Degenerate,
}

/// The posterior and the equivalent measurement of a recognition at t1 of a node placed at
/// `x0` (cov `p0`, PSD), the firmware's estimate `x1` (cov `p1`, PD) at t1, recognition
/// covariance `v` (PD), drift eigenvalue floor `min_drift_m2` (> 0).
pub fn equivalent_fix(
    x0: Vector2<f64>,
    p0: &Matrix2<f64>,
    x1: Vector2<f64>,
    p1: &Matrix2<f64>,
    v: &Matrix2<f64>,
    min_drift_m2: f64,
) -> Result<FixMath, FixMathError> {
    let finite = x0.iter().chain(x1.iter()).chain(p0.iter()).chain(p1.iter()).chain(v.iter()).all(|a| a.is_finite());
    if !finite || !min_drift_m2.is_finite() {
        return Err(FixMathError::NonFinite);
    }
    let (p0, p1, v) = (symmetrise(p0), symmetrise(p1), symmetrise(v));
    if eig_sym(&p0).0[0] < 0.0 || !is_pd(&p1) || !is_pd(&v) || min_drift_m2 <= 0.0 {
        return Err(FixMathError::NotPositiveDefinite);
    }
    let d = floor_eig(&(p1 - p0), min_drift_m2);
    let m = x1 - x0;
    let s = symmetrise(&(d + v));
    let s_inv = inv_pd(&s).ok_or(FixMathError::Degenerate)?;
    let d_inv = inv_pd(&d).ok_or(FixMathError::Degenerate)?;
    let gate_d2 = (m.transpose() * s_inv * m)[(0, 0)];
    let gain = d * s_inv;
    let mu = x1 - gain * m;
    let sigma = symmetrise(&(p1 - gain * d));
    let r = symmetrise(&(p1 * d_inv * s * d_inv * p1 - p1));
    let z = x1 - p1 * d_inv * m;
    let ok = is_pd(&sigma) && is_pd(&r) && gate_d2.is_finite() && mu.iter().chain(z.iter()).all(|a| a.is_finite());
    if !ok {
        return Err(FixMathError::Degenerate);
    }
    Ok(FixMath { drift: d, m, gate_d2, mu, sigma, z, r })
}

/// Standard Kalman update of a prior `(x, p)` with a direct measurement `(z, r)` of the state:
/// Joseph form, symmetrised. `None` if the innovation covariance is not PD.
pub fn kalman_update(x: Vector2<f64>, p: &Matrix2<f64>, z: Vector2<f64>, r: &Matrix2<f64>) -> Option<(Vector2<f64>, Matrix2<f64>)> {
    let s_inv = inv_pd(&symmetrise(&(p + r)))?;
    let k = p * s_inv;
    let i_k = Matrix2::identity() - k;
    let x_post = x + k * (z - x);
    let p_post = symmetrise(&(i_k * p * i_k.transpose() + k * r * k.transpose()));
    Some((x_post, p_post))
}
