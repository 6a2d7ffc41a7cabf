//! How states and measurements are added, differenced and averaged.
//!
//! The UKF never uses `+`, `-` or a weighted sum on a state or measurement directly: it calls a
//! [`Space`]. Vector quantities use [`Euclidean`]; angles need a wrapped residual and a circular
//! mean ([`AngleSpace`] for a vector whose components are all angles, or your own impl that
//! wraps only some components). Attitude is handled one level up, by keeping the UKF state an
//! error state (see [`crate::nav`]), so sigma points never leave SO(3).

use nalgebra::{RealField, SVector};

/// Operations the unscented transform needs on a `D`-dimensional quantity.
///
/// All functions are static: a space is a type, not a value.
pub trait Space<T: RealField + Copy, const D: usize> {
    /// `x (+) dx`: move `x` by the tangent vector `dx` (sigma-point spreading and `x + K e`).
    fn add(x: &SVector<T, D>, dx: &SVector<T, D>) -> SVector<T, D> {
        x + dx
    }

    /// `a (-) b`: the tangent vector that takes `b` to `a`.
    fn residual(a: &SVector<T, D>, b: &SVector<T, D>) -> SVector<T, D> {
        a - b
    }

    /// Weighted mean of sigma points (weights sum to one, some may be negative).
    fn mean<const S: usize>(points: &[SVector<T, D>; S], wm: &[T; S]) -> SVector<T, D> {
        let mut m = SVector::<T, D>::zeros();
        for (p, w) in points.iter().zip(wm.iter()) {
            m += p * *w;
        }
        m
    }
}

/// Plain vector space.
#[derive(Debug, Clone, Copy, Default)]
pub struct Euclidean;

impl<T: RealField + Copy, const D: usize> Space<T, D> for Euclidean {}

/// Every component is an angle in radians: residuals wrap to (-pi, pi], means are circular.
#[derive(Debug, Clone, Copy, Default)]
pub struct AngleSpace;

/// Wrap an angle to (-pi, pi].
pub fn wrap_pi<T: RealField + Copy>(a: T) -> T {
    let two_pi = T::two_pi();
    let pi = T::pi();
    if a > -pi && a <= pi {
        return a;
    }
    let mut y = a % two_pi; // in (-2pi, 2pi), sign of a
    if y > pi {
        y -= two_pi;
    } else if y <= -pi {
        y += two_pi;
    }
    y
}

/// Wrap an angle in degrees to [-180, 180): the one degree wrap of the host's heading errors
/// and innovations (scoring, reports, live topics). `%` and the sign fix are what
/// `f64::rem_euclid` does, which `no_std` lacks, so the result is the same to the bit.
pub fn wrap_deg(x_deg: f64) -> f64 {
    let r = (x_deg + 180.0) % 360.0;
    (if r < 0.0 { r + 360.0 } else { r }) - 180.0
}

/// A scalar with a sine/cosine for [`AngleSpace`]. f32 uses the single-precision kernel of
/// `ephemeris::phase` (abs error ~2e-7): `libm`'s `sinf`/`cosf`, which nalgebra's `RealField`
/// calls, compute in f64, which is software emulation on the Cortex-M4F (the heading update's
/// circular mean made 62 such calls). f64 keeps `RealField`'s.
pub trait AngleScalar: RealField + Copy {
    fn sin_cos_rad(self) -> (Self, Self);
    /// `atan2(self, x)`. f32 calls `libm::atan2f` on every build: `RealField::atan2` is the host
    /// maths library's with `std` (glibc's differs from libm's by 1 ulp for ~0.3 % of inputs),
    /// and the host replay of a target recording (`subnav replay`) must compute what the target did.
    fn atan2_rad(self, x: Self) -> Self;
}

impl AngleScalar for f32 {
    fn sin_cos_rad(self) -> (f32, f32) {
        // The phase conversion would map NaN/inf to a finite angle; keep NaN propagating.
        if !self.is_finite() {
            return (f32::NAN, f32::NAN);
        }
        crate::ephemeris::phase::sincos_rad(self)
    }
    fn atan2_rad(self, x: f32) -> f32 {
        libm::atan2f(self, x)
    }
}

impl AngleScalar for f64 {
    fn sin_cos_rad(self) -> (f64, f64) {
        nalgebra::ComplexField::sin_cos(self)
    }
    fn atan2_rad(self, x: f64) -> f64 {
        nalgebra::RealField::atan2(self, x)
    }
}

/// Circular weighted mean of angles: `atan2(sum w sin, sum w cos)`.
pub fn circular_mean<T: AngleScalar, const S: usize>(angles: impl Iterator<Item = T>, wm: &[T; S]) -> T {
    let (mut s, mut c) = (T::zero(), T::zero());
    for (a, w) in angles.zip(wm.iter()) {
        let (sa, ca) = a.sin_cos_rad();
        s += sa * *w;
        c += ca * *w;
    }
    s.atan2_rad(c)
}

impl<T: AngleScalar, const D: usize> Space<T, D> for AngleSpace {
    fn add(x: &SVector<T, D>, dx: &SVector<T, D>) -> SVector<T, D> {
        (x + dx).map(wrap_pi)
    }
    fn residual(a: &SVector<T, D>, b: &SVector<T, D>) -> SVector<T, D> {
        (a - b).map(wrap_pi)
    }
    fn mean<const S: usize>(points: &[SVector<T, D>; S], wm: &[T; S]) -> SVector<T, D> {
        SVector::<T, D>::from_fn(|i, _| circular_mean(points.iter().map(|p| p[i]), wm))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_is_in_range_and_preserves_angle() {
        for k in -2000..2000 {
            let a = k as f64 * 0.0123;
            let w = wrap_pi(a);
            assert!(w > -core::f64::consts::PI && w <= core::f64::consts::PI, "{a} -> {w}");
            assert!((w.sin() - a.sin()).abs() < 1e-12 && (w.cos() - a.cos()).abs() < 1e-12);
        }
    }

    #[test]
    fn circular_mean_across_the_cut() {
        let pts = [SVector::<f64, 1>::new(3.1), SVector::<f64, 1>::new(-3.1)];
        let m = AngleSpace::mean(&pts, &[0.5, 0.5]);
        assert!((m[0].abs() - core::f64::consts::PI).abs() < 1e-9, "{m}");
        // f32 (own sine/cosine) against f64 on random angle sets with unscented weights.
        let wm = [0.4f64, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1];
        let mut worst = 0.0f64;
        for k in 0..2000 {
            let centre = -3.2 + 6.4 * (k as f64 / 2000.0);
            let p64: [SVector<f64, 1>; 7] = core::array::from_fn(|i| SVector::<f64, 1>::new(wrap_pi(centre + 0.05 * (i as f64 - 3.0))));
            let p32: [SVector<f32, 1>; 7] = core::array::from_fn(|i| p64[i].map(|v| v as f32));
            let m64 = AngleSpace::mean(&p32.map(|p| p.map(f64::from)), &wm)[0];
            let m32 = AngleSpace::mean(&p32, &wm.map(|w| w as f32))[0];
            worst = worst.max(wrap_pi(f64::from(m32) - m64).abs());
        }
        assert!(worst < 1e-6, "worst {worst}");
        let bad = [SVector::<f32, 1>::new(0.1), SVector::<f32, 1>::new(f32::NAN)];
        assert!(AngleSpace::mean(&bad, &[0.5, 0.5])[0].is_nan());
    }
}
