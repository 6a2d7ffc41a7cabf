//! Adaptive measurement noise with a forgetting factor (spec 004, D5/D6), for the depth gauge's
//! relative-depth update and the sonar velocity update; shared so the firmware can use it.
//!
//! After each update with measurement Jacobian `H`, posterior covariance `P_k` and post-update
//! residual `mu_k = z_k - h(x_k+)`:
//! `R_k = alpha R_{k-1} + (1 - alpha) (mu_k mu_k^T + H P_k H^T)`.
//! Both added terms are positive semi-definite, so `R_k` stays PD when `R_{k-1}` is; we add (ours)
//! an eigen-free safeguard: the result is symmetrized and its diagonal clamped to
//! `[r_min, r_max]` (a bad burst cannot make the gauge look perfect or worthless), and a non-finite
//! residual is refused and leaves `R` unchanged.
//!
//! Time alignment (D5): a depth reading at `t` between IMU samples `t_i <= t <= t_i+1` is compared
//! with the IMU-propagated vertical position interpolated linearly between the two samples
//! ([`interpolate_at`]).
//!
//! Generic over the scalar `T` (f32 on the target, f64 on the host) and the measurement size `M`.
//! no_std, no heap, no panics.

use nalgebra::{RealField, SMatrix, SVector};

/// Why an adaptive-R step was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AdaptError {
    /// Residual or `H P H^T` contains NaN or infinity; `R` is unchanged.
    NonFinite,
    /// Forgetting factor outside `[0, 1)`.
    BadAlpha,
    /// Interpolation time outside the bracketing samples, or the samples are not increasing.
    OutOfRange,
}

impl core::fmt::Display for AdaptError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            AdaptError::NonFinite => "adaptive noise: residual or H P H^T is NaN or infinite (R unchanged)",
            AdaptError::BadAlpha => "adaptive noise: forgetting factor outside [0, 1)",
            AdaptError::OutOfRange => "interpolation time outside the bracketing samples, or samples not increasing",
        })
    }
}

impl core::error::Error for AdaptError {}

/// The adaptive noise estimator `R_k` of one sensor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdaptiveNoise<T: RealField + Copy, const M: usize> {
    /// Current `R_k`.
    pub r: SMatrix<T, M, M>,
    /// Forgetting factor `alpha` in `[0, 1)`: closer to 1 remembers longer.
    pub alpha: T,
    /// Lower bound of each diagonal element (variance units of the measurement).
    pub r_min: T,
    /// Upper bound of each diagonal element.
    pub r_max: T,
    /// Number of accepted steps.
    pub steps: u32,
}

impl<T: RealField + Copy, const M: usize> AdaptiveNoise<T, M> {
    pub fn new(r0: SMatrix<T, M, M>, alpha: T, r_min: T, r_max: T) -> Result<Self, AdaptError> {
        if !(alpha >= T::zero() && alpha < T::one()) {
            return Err(AdaptError::BadAlpha);
        }
        let mut s = Self { r: r0, alpha, r_min, r_max, steps: 0 };
        s.condition();
        Ok(s)
    }

    /// One step of the recursion with the post-update residual `mu` and `H P_k H^T`.
    pub fn step(&mut self, mu: &SVector<T, M>, hph: &SMatrix<T, M, M>) -> Result<&SMatrix<T, M, M>, AdaptError> {
        if mu.iter().chain(hph.iter()).any(|v| !v.is_finite()) {
            return Err(AdaptError::NonFinite);
        }
        let one = T::one();
        self.r = self.r * self.alpha + (mu * mu.transpose() + hph) * (one - self.alpha);
        self.condition();
        self.steps = self.steps.saturating_add(1);
        Ok(&self.r)
    }

    fn condition(&mut self) {
        let half = T::one() / (T::one() + T::one());
        self.r = (self.r + self.r.transpose()) * half;
        let (lo, hi) = (self.r_min, self.r_max);
        for i in 0..M {
            if let Some(d) = self.r.get_mut((i, i)) {
                *d = if d.is_finite() { d.max(lo).min(hi) } else { hi };
            }
        }
    }
}

/// Linear interpolation of a quantity sampled at `t0 < t1` (e.g. the IMU-integrated vertical
/// position) to a sensor time `t` in `[t0, t1]`.
pub fn interpolate_at<T: RealField + Copy>(t0: T, v0: T, t1: T, v1: T, t: T) -> Result<T, AdaptError> {
    let increasing = matches!(t1.partial_cmp(&t0), Some(core::cmp::Ordering::Greater));
    if !increasing || !t.is_finite() || t < t0 || t > t1 {
        return Err(AdaptError::OutOfRange);
    }
    let w = (t - t0) / (t1 - t0);
    Ok(v0 + (v1 - v0) * w)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix1, Matrix2, Vector1, Vector2};

    #[test]
    fn scalar_recursion_hand_computed() {
        // alpha 0.9, R0 0.04:
        // R1 = 0.9*0.04 + 0.1*(0.1^2 + 0.01) = 0.036 + 0.002 = 0.038
        // R2 = 0.9*0.038 + 0.1*((-0.3)^2 + 0.02) = 0.0342 + 0.011 = 0.0452
        let mut a = AdaptiveNoise::<f64, 1>::new(Matrix1::new(0.04), 0.9, 1e-6, 10.0).unwrap();
        let r1 = a.step(&Vector1::new(0.1), &Matrix1::new(0.01)).unwrap()[(0, 0)];
        assert!((r1 - 0.038).abs() < 1e-12, "{r1}");
        let r2 = a.step(&Vector1::new(-0.3), &Matrix1::new(0.02)).unwrap()[(0, 0)];
        assert!((r2 - 0.0452).abs() < 1e-12, "{r2}");
        assert_eq!(a.steps, 2);
    }

    #[test]
    fn f32_matches_hand_values() {
        let mut a = AdaptiveNoise::<f32, 1>::new(Matrix1::new(0.04), 0.9, 1e-6, 10.0).unwrap();
        let r1 = a.step(&Vector1::new(0.1), &Matrix1::new(0.01)).unwrap()[(0, 0)];
        assert!((r1 - 0.038).abs() < 1e-7);
    }

    #[test]
    fn two_dim_cross_terms_hand_computed() {
        // alpha 0.5, R0 = I*0.02, mu = (0.2, -0.1), HPH = diag(0.01, 0.03):
        // mu mu^T = [[0.04, -0.02], [-0.02, 0.01]]
        // R1 = 0.5*[[0.02,0],[0,0.02]] + 0.5*[[0.05,-0.02],[-0.02,0.04]] = [[0.035,-0.01],[-0.01,0.03]]
        let mut a = AdaptiveNoise::<f64, 2>::new(Matrix2::identity() * 0.02, 0.5, 1e-6, 1.0).unwrap();
        let r = *a.step(&Vector2::new(0.2, -0.1), &Matrix2::new(0.01, 0.0, 0.0, 0.03)).unwrap();
        let want = Matrix2::new(0.035, -0.01, -0.01, 0.03);
        assert!((r - want).abs().max() < 1e-12, "{r}");
    }

    #[test]
    fn bounds_and_bad_input() {
        let mut a = AdaptiveNoise::<f64, 1>::new(Matrix1::new(0.04), 0.0, 0.01, 0.5).unwrap();
        // alpha 0: R = mu^2 + HPH = 4 + 0 -> clamped to r_max.
        assert_eq!(a.step(&Vector1::new(2.0), &Matrix1::new(0.0)).unwrap()[(0, 0)], 0.5);
        // Tiny residual -> clamped to r_min.
        assert_eq!(a.step(&Vector1::new(0.0), &Matrix1::new(0.0)).unwrap()[(0, 0)], 0.01);
        assert_eq!(a.step(&Vector1::new(f64::NAN), &Matrix1::new(0.0)), Err(AdaptError::NonFinite));
        assert_eq!(a.r[(0, 0)], 0.01, "a refused step leaves R unchanged");
        assert_eq!(AdaptiveNoise::<f64, 1>::new(Matrix1::new(0.04), 1.0, 0.0, 1.0).err(), Some(AdaptError::BadAlpha));
        assert_eq!(AdaptiveNoise::<f64, 1>::new(Matrix1::new(0.04), f64::NAN, 0.0, 1.0).err(), Some(AdaptError::BadAlpha));
    }

    #[test]
    fn interpolation_hand_computed() {
        // z = 10.0 at t=1.00, 10.4 at t=1.01; depth reading at t = 1.0025 -> 10.1
        let z: f64 = interpolate_at(1.0, 10.0, 1.01, 10.4, 1.0025).unwrap();
        assert!((z - 10.1).abs() < 1e-9);
        assert_eq!(interpolate_at(1.0, 0.0, 1.01, 1.0, 1.02), Err(AdaptError::OutOfRange));
        assert_eq!(interpolate_at(1.0, 0.0, 1.0, 1.0, 1.0), Err(AdaptError::OutOfRange));
        assert_eq!(interpolate_at(1.0, 0.0, 2.0, 1.0, f64::NAN), Err(AdaptError::OutOfRange));
        assert_eq!(interpolate_at(f64::NAN, 0.0, 2.0, 1.0, 1.5), Err(AdaptError::OutOfRange));
    }
}
