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

/// Circular weighted mean of angles: `atan2(sum w sin, sum w cos)`.
pub fn circular_mean<T: RealField + Copy, const S: usize>(angles: impl Iterator<Item = T>, wm: &[T; S]) -> T {
    let (mut s, mut c) = (T::zero(), T::zero());
    for (a, w) in angles.zip(wm.iter()) {
        s += a.sin() * *w;
        c += a.cos() * *w;
    }
    s.atan2(c)
}

impl<T: RealField + Copy, const D: usize> Space<T, D> for AngleSpace {
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
    }
}
