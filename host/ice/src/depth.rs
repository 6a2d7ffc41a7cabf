//! Depth-gauge update (D5). Time alignment: a reading at `t_d` between IMU samples `t_i < t_d <=
//! t_i+1` is compared with the gauge depth predicted from the IMU-integrated state at both samples,
//! interpolated to `t_d` (`subnav_core::depth_adaptive::interpolate_at`). Relative depth: the
//! residual is the change of the reading since the reference reading taken at initialization (which
//! removes the gauge's offset: surface pressure, ice draft) against the change of the gauge's
//! predicted depth `p_z + (R l)_z` (lever arm `l` in the body frame), so the update needs no
//! absolute depth. Noise: fixed, or adaptive with forgetting factor (shared `AdaptiveNoise`).
//!
//! The reference ([`robust_reference`]) is the mean of the still readings after a median/MAD
//! outlier test (the gauge has spikes; one spike in 20 readings moved a plain mean by 2.5 cm).
//! Its error `e` is the same in every later residual, so it cannot be averaged away: it is a state
//! (`DEPTH_REF`, prior variance = the reference's variance, no process noise) and the model is
//! `h(x) = p_z + (R l)_z - e`. (Putting that variance into the initial `p_z` instead, as before,
//! let the depth updates shrink `P_zz` below it: vertical NEES 25 on a run with a spike.)

use nalgebra::{DMatrix, DVector, Matrix1, Vector1, Vector3};
use subnav_core::depth_adaptive::{AdaptiveNoise, interpolate_at};

use super::state::{DEPTH_REF, FilterState, ImuState, POS, TH};
use subnav_base::so3::hat;

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DepthConfig {
    /// Gauge position in the body frame, m.
    pub lever_b_m: Vector3<f64>,
    /// Initial (and, without adaptivity, fixed) noise sigma, m.
    pub sigma_m: f64,
    /// Forgetting factor of the adaptive R.
    pub alpha: f64,
    pub adaptive: bool,
    /// Chi-square gate probability (1 dof).
    pub gate: f64,
}

impl Default for DepthConfig {
    fn default() -> Self {
        Self { lever_b_m: Vector3::new(-0.3, 0.0, 0.1), sigma_m: 0.05, alpha: 0.98, adaptive: true, gate: 0.9999 }
    }
}

/// Gauge depth predicted from an IMU state (relative to the world origin's depth).
pub fn gauge_depth(imu: &ImuState, cfg: &DepthConfig) -> f64 {
    imu.pos_w_m.z + (imu.rot * cfg.lever_b_m).z
}

/// Adaptive scalar measurement noise starting at `sigma^2`, bounded to `[1e-2, 1e4]` times that,
/// forgetting factor `alpha` (clamped into `[0, 1)`; a NaN falls back to 0.98). Shared by the
/// depth and sonar updates.
pub(crate) fn scalar_noise(sigma: f64, alpha: f64) -> AdaptiveNoise<f64, 1> {
    let r0 = sigma * sigma;
    AdaptiveNoise::new(Matrix1::new(r0), alpha.clamp(0.0, 0.999_999), r0 * 1e-2, r0 * 1e4).unwrap_or(AdaptiveNoise {
        r: Matrix1::new(r0),
        alpha: 0.98,
        r_min: r0 * 1e-2,
        r_max: r0 * 1e4,
        steps: 0,
    })
}

/// What [`scalar_adaptive_update`] did with a residual.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ScalarOutcome {
    Used,
    /// Outside the chi-square gate; the state is unchanged.
    Gated,
    /// The EKF update failed (non-finite or singular innovation); the state is unchanged.
    Failed,
}

/// One gated scalar EKF update with adaptive noise, shared by the depth and sonar updates:
/// residual `r`, Jacobian row `h` (1 x n), noise `noise.r`. The gate is chi-square with 1 dof at
/// probability `gate` on `r^2 / (h P h^T + R)`. With `adaptive`, the noise steps on the
/// post-update residual `r - h dx` and the posterior `h P h^T`; a gated residual still steps it,
/// clipped to the gate, so a sensor whose noise grew is not locked out for good.
pub(crate) fn scalar_adaptive_update(
    st: &mut FilterState,
    noise: &mut AdaptiveNoise<f64, 1>,
    adaptive: bool,
    gate: f64,
    r: f64,
    h: &DMatrix<f64>,
) -> ScalarOutcome {
    let rr = noise.r[(0, 0)];
    let hph = (h * &st.cov * h.transpose())[(0, 0)];
    let s = hph + rr;
    let limit = subnav_base::chi2::chi2_quantile(1, gate).unwrap_or(f64::INFINITY);
    if r * r / s > limit {
        if adaptive {
            let clipped = r.signum() * (limit * s).sqrt();
            let _ = noise.step(&Vector1::new(clipped), &Matrix1::new(hph));
        }
        return ScalarOutcome::Gated;
    }
    let Some(dx) = st.ekf_update(&DVector::from_element(1, r), h, &DMatrix::from_element(1, 1, rr)) else {
        return ScalarOutcome::Failed;
    };
    if adaptive {
        let mu = r - (h * dx)[(0, 0)];
        let hph_post = (h * &st.cov * h.transpose())[(0, 0)];
        let _ = noise.step(&Vector1::new(mu), &Matrix1::new(hph_post));
    }
    ScalarOutcome::Used
}

/// A reference depth from still readings: the median, then the mean of the readings within
/// `5 x 1.4826 MAD` of it (the MAD floored at `sigma_floor_m`), and the variance of that mean
/// (sample variance of the kept readings over their count, floored at `sigma_floor_m^2 / count`;
/// a single reading gets `sigma_fallback_m^2`). `None` without finite readings.
pub fn robust_reference(readings: &[f64], sigma_floor_m: f64, sigma_fallback_m: f64) -> Option<(f64, f64)> {
    let mut v: Vec<f64> = readings.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    if v.len() == 1 {
        return Some((v[0], sigma_fallback_m * sigma_fallback_m));
    }
    v.sort_by(f64::total_cmp);
    let median = |s: &[f64]| if s.len() % 2 == 1 { s[s.len() / 2] } else { 0.5 * (s[s.len() / 2 - 1] + s[s.len() / 2]) };
    let med = median(&v);
    let mut dev: Vec<f64> = v.iter().map(|x| (x - med).abs()).collect();
    dev.sort_by(f64::total_cmp);
    let mad = (1.4826 * median(&dev)).max(sigma_floor_m);
    let kept: Vec<f64> = v.iter().copied().filter(|x| (x - med).abs() <= 5.0 * mad).collect();
    let n = kept.len() as f64;
    let mean = kept.iter().sum::<f64>() / n;
    let var = if kept.len() > 1 { kept.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0) } else { sigma_fallback_m.powi(2) };
    Some((mean, var.max(sigma_floor_m * sigma_floor_m) / n))
}

pub struct DepthUpdater {
    pub cfg: DepthConfig,
    /// Reading minus predicted gauge depth at initialization.
    reference: Option<f64>,
    pub noise: AdaptiveNoise<f64, 1>,
    pub used: usize,
    pub gated: usize,
}

impl DepthUpdater {
    pub fn new(cfg: DepthConfig) -> Self {
        let noise = scalar_noise(cfg.sigma_m, cfg.alpha);
        Self { cfg, reference: None, noise, used: 0, gated: 0 }
    }

    /// Set the reference from a reading at the initialization time.
    pub fn set_reference(&mut self, depth_m: f64, imu: &ImuState) {
        self.reference = Some(depth_m - gauge_depth(imu, &self.cfg));
    }

    pub fn has_reference(&self) -> bool {
        self.reference.is_some()
    }

    /// Update with a reading at `t_d`, the filter being at `t_i+1 >= t_d` and `prev` the IMU
    /// state at the previous sample `t_i`.
    pub fn update(&mut self, st: &mut FilterState, prev: &ImuState, t_d: f64, depth_m: f64) {
        let Some(reference) = self.reference else { return };
        if !depth_m.is_finite() {
            return;
        }
        let (g0, g1) = (gauge_depth(prev, &self.cfg), gauge_depth(&st.imu, &self.cfg));
        let pred = match interpolate_at(prev.t_s, g0, st.imu.t_s, g1, t_d) {
            Ok(p) => p,
            Err(_) => g1,
        };
        let r = depth_m - reference - (pred - st.imu.depth_ref_err_m);
        let n = st.dim();
        let mut h = DMatrix::zeros(1, n);
        h[(0, POS + 2)] = 1.0;
        h[(0, DEPTH_REF)] = -1.0;
        // d(R l)_z / d(dtheta) = -(R [l]x)_z row.
        // At the first estimate of the attitude (FEJ, see `state`).
        let d = -(st.imu_lin().rot * hat(&self.cfg.lever_b_m));
        for k in 0..3 {
            h[(0, TH + k)] = d[(2, k)];
        }
        match scalar_adaptive_update(st, &mut self.noise, self.cfg.adaptive, self.cfg.gate, r, &h) {
            ScalarOutcome::Used => self.used += 1,
            ScalarOutcome::Gated => self.gated += 1,
            ScalarOutcome::Failed => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::robust_reference;

    #[test]
    fn robust_reference_drops_a_spike_and_reports_the_mean_variance() {
        let clean: Vec<f64> = (0..19).map(|i| 10.0 + 0.01 * ((i % 3) as f64 - 1.0)).collect();
        let mut r = clean.clone();
        r.insert(7, 10.5);
        let (m, var) = robust_reference(&r, 0.002, 0.05).unwrap();
        let n = clean.len() as f64;
        let mean = clean.iter().sum::<f64>() / n;
        let s2 = clean.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
        assert!((m - mean).abs() < 1e-12, "{m} vs {mean}");
        assert!((var - s2 / n).abs() < 1e-15, "{var} vs {}", s2 / n);
        // A plain mean would be 2.5 cm off.
        assert!((r.iter().sum::<f64>() / r.len() as f64 - mean).abs() > 0.02);
        // Identical readings: the variance floor; one reading: the fallback sigma; none: None.
        let (_, v) = robust_reference(&[5.0; 4], 0.002, 0.05).unwrap();
        assert!((v - 0.002f64.powi(2) / 4.0).abs() < 1e-18);
        let (m1, v1) = robust_reference(&[5.0, f64::NAN], 0.002, 0.05).unwrap();
        assert!(m1 == 5.0 && (v1 - 0.0025).abs() < 1e-15);
        assert_eq!(robust_reference(&[f64::NAN], 0.002, 0.05), None);
    }
}
