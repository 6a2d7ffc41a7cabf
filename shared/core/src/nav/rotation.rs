//! Rotation vector -> unit quaternion (the SO(3) exponential) in single precision.
//!
//! Why not nalgebra's `UnitQuaternion::from_scaled_axis`: for f32 it calls `libm::sincosf`, whose
//! kernels compute in f64, which is software emulation on the Cortex-M4F's single-precision FPU.
//! The UKF predict calls it twice per sigma point (62 times per predict); measured on the target
//! (`cargo xtask bench-target`, docs/PERFORMANCE.md) it was most of the predict's cost.
//! Here `cos(h)` and `sin(h) / h` (half angle `h`) are Taylor polynomials in `h^2` for `|h| <= pi/4`,
//! which covers every error-state rotation, and accurate to f32 rounding even for tiny angles
//! (no division by the angle); larger angles use the f32 sine/cosine of `ephemeris::phase`.

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use crate::ephemeris::phase::sincos_rad;

/// `(pi / 4)^2`: the polynomial range of the half angle.
const H2_MAX: f32 = core::f32::consts::FRAC_PI_4 * core::f32::consts::FRAC_PI_4;

/// The unit quaternion rotating by `|phi_rad|` about `phi_rad` (nalgebra's `from_scaled_axis`).
/// A non-finite input gives an all-NaN quaternion (callers check the state for finiteness).
pub fn quat_from_rotation_vector(phi_rad: &Vector3<f32>) -> UnitQuaternion<f32> {
    let h2 = 0.25 * phi_rad.norm_squared();
    if !h2.is_finite() {
        return UnitQuaternion::new_unchecked(Quaternion::new(f32::NAN, f32::NAN, f32::NAN, f32::NAN));
    }
    let (c, k) = if h2 <= H2_MAX {
        // Truncation at |h| = pi/4: cos 2.5e-8, sin(h)/h 2.2e-9 (the next terms).
        let c = 1.0 + h2 * (-0.5 + h2 * (1.0 / 24.0 + h2 * (-1.0 / 720.0 + h2 * (1.0 / 40_320.0))));
        let sinc = 1.0 + h2 * (-1.0 / 6.0 + h2 * (1.0 / 120.0 + h2 * (-1.0 / 5040.0 + h2 * (1.0 / 362_880.0))));
        // sin(h) / |phi| = sinc(h) / 2.
        (c, 0.5 * sinc)
    } else {
        let theta = libm::sqrtf(4.0 * h2);
        let (s, c) = sincos_rad(0.5 * theta);
        (c, s / theta)
    };
    UnitQuaternion::new_unchecked(Quaternion::new(c, phi_rad.x * k, phi_rad.y * k, phi_rad.z * k))
}

// Plain 3-vector arithmetic for the per-sample and per-entry code (the strapdown step, the
// history correction): with nalgebra's quaternion and small-matrix operations, which
// `opt-level = "s"` keeps out of line, those cost 2-3x the instructions on the M4F.
pub(crate) fn a3(v: &Vector3<f32>) -> [f32; 3] {
    [v.x, v.y, v.z]
}
pub(crate) fn add(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
pub(crate) fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub(crate) fn scale(a: [f32; 3], s: f32) -> [f32; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}
pub(crate) fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
pub(crate) fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
pub(crate) fn mul(m: &[[f32; 3]; 3], v: [f32; 3]) -> [f32; 3] {
    [dot(m[0], v), dot(m[1], v), dot(m[2], v)]
}
/// Rows of the rotation matrix of the unit quaternion `(w, x, y, z)`.
pub(crate) fn rows_of(w: f32, x: f32, y: f32, z: f32) -> [[f32; 3]; 3] {
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

/// Microseconds to seconds. A difference that fits 32 bits converts in hardware on the M4F
/// (`u64 as f32` is a software routine); the same value either way (both round the exact
/// integer to nearest).
pub(crate) fn us_to_s(d_us: u64) -> f32 {
    match u32::try_from(d_us) {
        Ok(d) => d as f32 * 1e-6,
        Err(_) => d_us as f32 * 1e-6,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against nalgebra's f64 `from_scaled_axis` over tiny to large angles and random axes.
    #[test]
    fn matches_f64_from_scaled_axis() {
        let mut seed = 7u64;
        let mut next = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        // Worst component error: polynomial range (|phi| <= pi/2), then larger angles, where the
        // f32 phase reduction of `ephemeris::phase` adds about an ulp of the angle.
        let (mut worst_poly, mut worst_large) = (0.0f64, 0.0f64);
        for k in 0..20_000 {
            let mag = 10f64.powf(-9.0 + 10.0 * (k as f64 / 20_000.0)); // 1e-9 .. 10 rad
            let axis = Vector3::new(next(), next(), next()).normalize();
            let phi64 = axis * mag;
            let phi32 = phi64.map(|v| v as f32);
            let q = quat_from_rotation_vector(&phi32);
            // Reference from the f32-rounded input, so only our error is measured.
            let r = UnitQuaternion::from_scaled_axis(phi32.map(f64::from));
            let d = (q.quaternion().coords.map(f64::from) - r.quaternion().coords).amax();
            if mag <= core::f64::consts::FRAC_PI_2 {
                worst_poly = worst_poly.max(d);
            } else {
                worst_large = worst_large.max(d);
            }
            // Small angles: the vector part keeps its relative precision.
            if mag < 1e-3 {
                let rel = (q.quaternion().imag().map(f64::from) - r.quaternion().imag()).norm() / r.quaternion().imag().norm();
                assert!(rel < 3e-7, "relative error {rel} at {mag}");
            }
        }
        assert!(worst_poly < 1.5e-7 && worst_large < 1e-6, "worst component error {worst_poly} / {worst_large}");
        assert_eq!(quat_from_rotation_vector(&Vector3::zeros()), UnitQuaternion::identity());
        for bad in [f32::NAN, f32::INFINITY] {
            assert!(quat_from_rotation_vector(&Vector3::new(bad, 0.0, 0.0)).quaternion().coords.iter().all(|v| v.is_nan()));
        }
    }
}
