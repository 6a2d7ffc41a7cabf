//! SO(3) helpers: hat, exponential/logarithm and the right Jacobian ("dexp") with the derivative of
//! its inverse applied to a vector. The formulas and small-angle branches follow the conventions
//! of GTSAM's `so3::DexpFunctor` (right Jacobian, tangent perturbations on the right:
//! `R * Exp(delta)`), because the preintegration is checked against GTSAM to 1e-9.
//! nalgebra's `Rotation3` has exp/log but no right Jacobian or its derivative, hence this file.
//! [`orthonormalize`] is the one re-orthonormalisation of the host's rotation matrices (factor
//! graph and under-ice odometry).

use nalgebra::{Matrix3, Vector3};

/// Skew-symmetric matrix `[v]x` with `[v]x w = v x w`.
pub fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Threshold below which the first-order forms are used (same as GTSAM: theta^2 <= eps).
const NEAR_ZERO_THETA2: f64 = f64::EPSILON;

/// Precomputed quantities of the exponential map at `omega`.
struct ExpParts {
    theta2: f64,
    theta: f64,
    w: Matrix3<f64>,
    k: Matrix3<f64>,
    kk: Matrix3<f64>,
    sin_theta: f64,
    one_minus_cos: f64,
    near_zero: bool,
}

impl ExpParts {
    fn new(omega: &Vector3<f64>) -> Self {
        let theta2 = omega.dot(omega);
        let theta = theta2.sqrt();
        let w = hat(omega);
        let near_zero = theta2 <= NEAR_ZERO_THETA2;
        let (k, kk, sin_theta, one_minus_cos) = if near_zero {
            (Matrix3::zeros(), Matrix3::zeros(), 0.0, 0.0)
        } else {
            let k = w / theta;
            let s2 = (theta / 2.0).sin();
            (k, k * k, theta.sin(), 2.0 * s2 * s2)
        };
        Self { theta2, theta, w, k, kk, sin_theta, one_minus_cos, near_zero }
    }

    fn expmap(&self) -> Matrix3<f64> {
        if self.near_zero {
            Matrix3::identity() + self.w
        } else {
            Matrix3::identity() + self.k * self.sin_theta + self.kk * self.one_minus_cos
        }
    }
}

/// Exponential map so(3) -> SO(3) (Rodrigues).
pub fn exp(omega: &Vector3<f64>) -> Matrix3<f64> {
    ExpParts::new(omega).expmap()
}

/// Logarithm SO(3) -> so(3), robust near 0 and pi. `r` must be a rotation matrix.
pub fn log(r: &Matrix3<f64>) -> Vector3<f64> {
    let (r11, r12, r13) = (r[(0, 0)], r[(0, 1)], r[(0, 2)]);
    let (r21, r22, r23) = (r[(1, 0)], r[(1, 1)], r[(1, 2)]);
    let (r31, r32, r33) = (r[(2, 0)], r[(2, 1)], r[(2, 2)]);
    let tr = r11 + r22 + r33;
    if tr + 1.0 < 1e-3 {
        // theta near pi: recover the axis from the largest diagonal element.
        if r33 > r22 && r33 > r11 {
            let q = 2.0 + 2.0 * r33;
            let v = Vector3::new(r31 + r13, r32 + r23, q) / q.sqrt();
            return atan_correct(r, v);
        } else if r22 > r11 {
            let q = 2.0 + 2.0 * r22;
            let v = Vector3::new(r21 + r12, q, r32 + r23) / q.sqrt();
            return atan_correct(r, v);
        } else {
            let q = 2.0 + 2.0 * r11;
            let v = Vector3::new(q, r21 + r12, r31 + r13) / q.sqrt();
            return atan_correct(r, v);
        }
    }
    let w = Vector3::new(r32 - r23, r13 - r31, r21 - r12);
    let s = 0.5 * w.norm(); // sin(theta)
    let c = 0.5 * (tr - 1.0); // cos(theta)
    let theta = s.atan2(c);
    if theta < 1e-7 {
        // log(R) ~ (R - R^T)/2 (vee), third-order accurate
        return w * (0.5 + theta * theta / 12.0);
    }
    w * (theta / (2.0 * s))
}

/// Near pi, `v` is the unnormalised-to-unit axis scaled by 2cos(theta/2)-ish terms; rebuild the
/// rotation vector from the unit axis and the angle from the trace, with the sign fixed by the
/// antisymmetric part.
fn atan_correct(r: &Matrix3<f64>, v: Vector3<f64>) -> Vector3<f64> {
    let axis = v / v.norm();
    let tr = r[(0, 0)] + r[(1, 1)] + r[(2, 2)];
    let c = (0.5 * (tr - 1.0)).clamp(-1.0, 1.0);
    let anti = Vector3::new(r[(2, 1)] - r[(1, 2)], r[(0, 2)] - r[(2, 0)], r[(1, 0)] - r[(0, 1)]);
    let s = 0.5 * anti.dot(&axis); // sin(theta) along the chosen axis
    let theta = s.atan2(c);
    axis * theta
}

/// Right Jacobian of SO(3) (GTSAM's `dexp`): `Exp(w + dw) ~ Exp(w) Exp(dexp(w) dw)`.
pub fn dexp(omega: &Vector3<f64>) -> Matrix3<f64> {
    dexp_parts(&ExpParts::new(omega)).0
}

fn dexp_parts(e: &ExpParts) -> (Matrix3<f64>, f64, f64) {
    if e.near_zero {
        (Matrix3::identity() - 0.5 * e.w, 0.0, 0.0)
    } else {
        let a = e.one_minus_cos / e.theta;
        let b = 1.0 - e.sin_theta / e.theta;
        (Matrix3::identity() - e.k * a + e.kk * b, a, b)
    }
}

/// Derivative with respect to `omega` of `dexp(omega) * v`.
fn apply_dexp_h1(e: &ExpParts, omega: &Vector3<f64>, a: f64, b: f64, v: &Vector3<f64>) -> Matrix3<f64> {
    if e.near_zero {
        0.5 * hat(v)
    } else {
        let kv = e.k * v;
        let da = (e.sin_theta - 2.0 * a) / e.theta2;
        let db = (e.one_minus_cos - 3.0 * b) / e.theta2;
        (e.k * db - Matrix3::identity() * da) * kv * omega.transpose() - hat(&(kv * (b / e.theta)))
            + (Matrix3::identity() * a - e.k * b) * hat(&(v / e.theta))
    }
}

/// Result of [`apply_inv_dexp`].
pub struct InvDexp {
    /// `dexp(omega)^-1 v`
    pub value: Vector3<f64>,
    /// d value / d omega
    pub d_omega: Matrix3<f64>,
    /// d value / d v (= `dexp(omega)^-1`)
    pub d_v: Matrix3<f64>,
    /// `Exp(omega)`, computed on the way.
    pub rot: Matrix3<f64>,
    /// `dexp(omega)`
    pub dexp: Matrix3<f64>,
}

/// `dexp(omega)^-1 v` with its derivatives (GTSAM `DexpFunctor::applyInvDexp`).
pub fn apply_inv_dexp(omega: &Vector3<f64>, v: &Vector3<f64>) -> InvDexp {
    let e = ExpParts::new(omega);
    let (dexp, a, b) = dexp_parts(&e);
    // dexp is I + small antisymmetric/symmetric terms with |theta| < pi: always invertible.
    let inv = dexp.try_inverse().unwrap_or_else(Matrix3::identity);
    let c = inv * v;
    let h = apply_dexp_h1(&e, omega, a, b, &c);
    InvDexp { value: c, d_omega: -inv * h, d_v: inv, rot: e.expmap(), dexp }
}

/// The nearest rotation to `r` (polar decomposition through the SVD, `U Vᵀ`): keeps a matrix
/// built from long products of rotations on SO(3). Why the SVD: its polar factor is the closest
/// rotation in the Frobenius norm in one step, whereas a round trip through a quaternion
/// (nalgebra's `from_matrix`, an iterative fit stopped at machine epsilon) only approximates it.
/// A matrix the SVD cannot make a proper rotation of (no convergence, a reflection) is returned
/// as it is.
pub fn orthonormalize(r: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = r.svd(true, true);
    match (svd.u, svd.v_t) {
        (Some(u), Some(vt)) => {
            let m = u * vt;
            if m.determinant() > 0.0 { m } else { *r }
        }
        _ => *r,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_log_roundtrip_including_near_pi() {
        for w in [
            Vector3::new(0.1, -0.2, 0.3),
            Vector3::new(1e-9, 0.0, -2e-9),
            Vector3::new(0.0, 0.0, std::f64::consts::PI - 1e-6),
            Vector3::new(1.2, -1.9, 1.5).normalize() * (std::f64::consts::PI - 1e-4),
            Vector3::new(2.0, 0.5, -0.3),
        ] {
            let r = exp(&w);
            let back = log(&r);
            assert!((back - w).norm() < 1e-8, "{w:?} -> {back:?}");
            assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-12);
        }
    }

    #[test]
    fn dexp_is_the_right_jacobian() {
        let w = Vector3::new(0.4, -0.3, 0.9);
        let j = dexp(&w);
        let h = 1e-6;
        for i in 0..3 {
            let mut d = Vector3::zeros();
            d[i] = h;
            let num = log(&(exp(&w).transpose() * exp(&(w + d)))) / h;
            assert!((num - j.column(i)).norm() < 1e-5);
        }
    }

    #[test]
    fn inv_dexp_derivative_matches_numeric() {
        let w = Vector3::new(0.2, 0.7, -0.5);
        let v = Vector3::new(1.0, -2.0, 0.5);
        let r = apply_inv_dexp(&w, &v);
        let h = 1e-6;
        for i in 0..3 {
            let mut d = Vector3::zeros();
            d[i] = h;
            let num = (apply_inv_dexp(&(w + d), &v).value - apply_inv_dexp(&(w - d), &v).value) / (2.0 * h);
            assert!((num - r.d_omega.column(i)).norm() < 1e-7, "{num:?} vs {:?}", r.d_omega.column(i));
        }
    }
}
