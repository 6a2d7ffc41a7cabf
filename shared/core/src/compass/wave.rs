//! Online estimate of the heading error the waves add (no heap, f32).
//!
//! A moving sea tilts the refracted sunbeam: every unit's e-vector moves, together over the
//! long waves, so the sun vector jitters by more than the photodiode noise the solver's sigma
//! describes, and the jitter is correlated over a wave period. Across units the residuals see
//! only part of it (the units' footprints share the long waves), so the estimate is temporal:
//! the heading fixes are compared with a heading reference carried between fixes by the gyro
//! (`rotate`: the body's turn about the vertical), `r_k = wrap(fix_k - ref_k)`. The slow part
//! of `r` (the reference's offset and the gyro's residual bias) is removed by an exponential
//! mean with time constant [`WaveSigmaConfig::tau_mean_s`] (longer than a wave period);
//! the variance of the rest, over [`WaveSigmaConfig::tau_var_s`], is the fixes' error variance.
//! Its excess over the solver's own variance is the wave part, reported in every fix's sigma:
//! `sigma^2 = sigma_solver^2 + max(0, var_r - mean(sigma_solver^2))`.
//!
//! The lag-1 autocorrelation `rho` of the deviations gives the fixes' correlation; a filter
//! that takes every fix as independent should use [`WaveSigma::sigma_for_filter_rad`], the
//! wave part inflated by `(1 + rho) / (1 - rho)` (the variance of the mean of an AR(1)
//! sequence), the usual treatment of correlated measurement noise without a state for it.
//!
//! Until [`WaveSigmaConfig::min_fixes`] fixes have been seen (after a start or a gap longer
//! than [`WaveSigmaConfig::max_gap_s`]) the wave part is unknown and taken as
//! [`WaveSigmaConfig::prior_sigma_rad`] (conservative).

use crate::ukf::wrap_pi;

/// Settings of the tracker.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WaveSigmaConfig {
    pub tau_mean_s: f32,
    pub tau_var_s: f32,
    /// A gap longer than this restarts the statistics (s).
    pub max_gap_s: f32,
    pub min_fixes: u16,
    /// Wave part assumed before the statistics are ready (rad).
    pub prior_sigma_rad: f32,
    /// Largest inflation of the wave variance for correlation.
    pub max_corr_inflation: f32,
}

impl Default for WaveSigmaConfig {
    fn default() -> Self {
        WaveSigmaConfig {
            tau_mean_s: 30.0,
            tau_var_s: 30.0,
            max_gap_s: 5.0,
            min_fixes: 20,
            prior_sigma_rad: 2.0 * core::f32::consts::PI / 180.0,
            max_corr_inflation: 60.0,
        }
    }
}

/// The tracker (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WaveSigma {
    cfg: WaveSigmaConfig,
    last_t_us: Option<u64>,
    /// Heading reference (rad): the first fix, then carried by the gyro.
    ref_rad: f32,
    mean_r: f32,
    var_r: f32,
    /// Lag-1 covariance of the deviations and the previous deviation.
    cov1: f32,
    last_dev: f32,
    mean_solver_var: f32,
    n: u16,
}

impl Default for WaveSigma {
    fn default() -> Self {
        Self::new(WaveSigmaConfig::default())
    }
}

impl WaveSigma {
    pub fn new(cfg: WaveSigmaConfig) -> Self {
        WaveSigma { cfg, last_t_us: None, ref_rad: 0.0, mean_r: 0.0, var_r: 0.0, cov1: 0.0, last_dev: 0.0, mean_solver_var: 0.0, n: 0 }
    }

    /// Forget the statistics (e.g. after a heading reset).
    pub fn reset(&mut self) {
        *self = Self::new(self.cfg);
    }

    /// The body turned by `d_heading_rad` (clockwise about the vertical) since the last call.
    pub fn rotate(&mut self, d_heading_rad: f32) {
        if d_heading_rad.is_finite() {
            self.ref_rad = wrap_pi(self.ref_rad + d_heading_rad);
        }
    }

    /// A heading fix at `t_us` with the solver's 1-sigma: updates the statistics and returns the
    /// fix's 1-sigma including the wave part. Non-finite input changes nothing and returns NaN.
    pub fn update(&mut self, t_us: u64, heading_rad: f32, solver_sigma_rad: f32) -> f32 {
        if !(heading_rad.is_finite() && solver_sigma_rad.is_finite() && solver_sigma_rad >= 0.0) {
            return f32::NAN;
        }
        let dt_s = match self.last_t_us {
            Some(t0) if t_us > t0 => (t_us - t0) as f32 * 1e-6,
            Some(_) => 0.0,
            None => f32::INFINITY,
        };
        if dt_s > self.cfg.max_gap_s {
            self.reset();
            self.ref_rad = wrap_pi(heading_rad);
        }
        self.last_t_us = Some(t_us);
        let s2 = solver_sigma_rad * solver_sigma_rad;
        let r = wrap_pi(heading_rad - self.ref_rad);
        if self.n == 0 {
            self.mean_r = r;
            self.var_r = 0.0;
            self.cov1 = 0.0;
            self.last_dev = 0.0;
            self.mean_solver_var = s2;
            self.n = 1;
            return self.sigma_rad(solver_sigma_rad);
        }
        // Exponential weights, at least 1/n while the window fills.
        let n1 = (self.n as f32 + 1.0).max(1.0);
        let a_m = (dt_s / self.cfg.tau_mean_s.max(1e-3)).max(1.0 / n1).min(1.0);
        let a_v = (dt_s / self.cfg.tau_var_s.max(1e-3)).max(1.0 / n1).min(1.0);
        let dev = wrap_pi(r - self.mean_r);
        self.mean_r = wrap_pi(self.mean_r + a_m * dev);
        self.var_r += a_v * (dev * dev - self.var_r);
        self.cov1 += a_v * (dev * self.last_dev - self.cov1);
        self.mean_solver_var += a_v * (s2 - self.mean_solver_var);
        self.last_dev = dev;
        self.n = self.n.saturating_add(1);
        self.sigma_rad(solver_sigma_rad)
    }

    /// The wave part's variance (rad^2): the prior until the statistics are ready.
    pub fn wave_var_rad2(&self) -> f32 {
        if self.n < self.cfg.min_fixes {
            return self.cfg.prior_sigma_rad * self.cfg.prior_sigma_rad;
        }
        (self.var_r - self.mean_solver_var).max(0.0)
    }

    /// The wave part's 1-sigma (rad).
    pub fn wave_sigma_rad(&self) -> f32 {
        libm::sqrtf(self.wave_var_rad2())
    }

    /// Lag-1 correlation of successive fixes' errors (0 until known).
    pub fn correlation(&self) -> f32 {
        if self.n < self.cfg.min_fixes || !(self.var_r > 0.0) {
            return 0.0;
        }
        (self.cov1 / self.var_r).clamp(0.0, 0.999)
    }

    /// 1-sigma of one fix: the solver's and the wave part.
    pub fn sigma_rad(&self, solver_sigma_rad: f32) -> f32 {
        libm::sqrtf(solver_sigma_rad * solver_sigma_rad + self.wave_var_rad2())
    }

    /// The wave part's variance inflated for its correlation (rad^2, module doc).
    pub fn filter_wave_var_rad2(&self) -> f32 {
        let rho = self.correlation();
        let infl = ((1.0 + rho) / (1.0 - rho)).min(self.cfg.max_corr_inflation);
        self.wave_var_rad2() * infl
    }

    /// 1-sigma for a filter that takes every fix as independent: the wave part inflated for
    /// its correlation (module doc).
    pub fn sigma_for_filter_rad(&self, solver_sigma_rad: f32) -> f32 {
        libm::sqrtf(solver_sigma_rad * solver_sigma_rad + self.filter_wave_var_rad2())
    }

    pub fn fixes(&self) -> u16 {
        self.n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic Gaussian-ish noise (sum of 12 uniforms from an LCG), no dependency.
    struct Lcg(u64);
    impl Lcg {
        fn normal(&mut self) -> f32 {
            let mut s = 0.0;
            for _ in 0..12 {
                self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                s += (self.0 >> 40) as f32 / (1u64 << 24) as f32;
            }
            s - 6.0
        }
    }

    const DEG: f32 = core::f32::consts::PI / 180.0;

    /// AR(1) wave error (correlation time 3 s at 10 Hz) of 1 deg plus 0.1 deg white noise, on a
    /// vehicle turning at 5 deg/s whose turn the gyro reports: the reported sigma finds the
    /// 1 deg (within 25 %), the correlation is seen, and the sigma follows a change of sea state.
    #[test]
    fn finds_the_wave_part_and_follows_a_change() {
        let mut w = WaveSigma::default();
        let mut g = Lcg(7);
        let rho = libm::expf(-0.1 / 3.0);
        let mut wave = 0.0f32;
        let mut yaw = 0.3f32;
        let mut run = |w: &mut WaveSigma, wave_sigma: f32, secs: u32, t0: u32| {
            let mut last = 0.0;
            for k in 0..secs * 10 {
                wave = rho * wave + libm::sqrtf(1.0 - rho * rho) * wave_sigma * g.normal();
                let d = 0.5 * DEG;
                yaw = wrap_pi(yaw + d);
                w.rotate(d);
                let fix = wrap_pi(yaw + wave + 0.1 * DEG * g.normal());
                last = w.update(((t0 * 10 + k) as u64) * 100_000, fix, 0.1 * DEG);
            }
            last
        };
        let prior = run(&mut w, 1.0 * DEG, 1, 0);
        assert!(prior >= 2.0 * DEG, "conservative before the statistics are ready: {prior}");
        let s1 = run(&mut w, 1.0 * DEG, 120, 1);
        assert!((s1 / DEG - 1.0).abs() < 0.25, "1 deg sea: {}", s1 / DEG);
        assert!(w.correlation() > 0.8, "{}", w.correlation());
        assert!(w.sigma_for_filter_rad(0.1 * DEG) > 3.0 * s1);
        let s3 = run(&mut w, 3.0 * DEG, 90, 121);
        assert!((s3 / DEG - 3.0).abs() < 0.75, "rougher sea: {}", s3 / DEG);
        let s0 = run(&mut w, 0.0, 150, 211);
        assert!(s0 < 0.4 * DEG, "calm again: {}", s0 / DEG);
    }

    /// Bad input changes nothing; a long gap restarts from the prior; turning without waves
    /// (the gyro's turn removed) reports the solver's noise only.
    #[test]
    fn bad_input_gaps_and_turns() {
        let mut w = WaveSigma::default();
        let mut g = Lcg(3);
        let mut yaw = 0.0f32;
        for k in 0..400u64 {
            let d = 2.0 * DEG;
            yaw = wrap_pi(yaw + d);
            w.rotate(d);
            w.update(k * 100_000, wrap_pi(yaw + 0.2 * DEG * g.normal()), 0.2 * DEG);
        }
        let calm = w.sigma_rad(0.2 * DEG);
        assert!(calm < 0.3 * DEG, "{}", calm / DEG);
        let before = w;
        assert!(w.update(40_000_000, f32::NAN, 0.1).is_nan());
        assert!(w.update(40_000_000, 0.1, f32::INFINITY).is_nan());
        w.rotate(f32::NAN);
        assert_eq!(w, before);
        let after_gap = w.update(60_000_000, 0.1, 0.2 * DEG);
        assert!(after_gap >= 2.0 * DEG, "a gap restarts from the prior");
        assert_eq!(w.fixes(), 1);
        // Time going backwards does not divide by zero.
        let s = w.update(10, 0.1, 0.2 * DEG);
        assert!(s.is_finite());
    }
}
