//! The adaptive layer (spec A5): Sage-Husa decaying-memory noise statistics and the fading
//! factor. Every part has its own switch; with all of them off the filter is a plain UKF and
//! runs exactly the same code path otherwise.
//!
//! Sage-Husa, with forgetting factor `b` and `d_k = (1 - b) / (1 - b^(k+1))`:
//! - `q_k = (1-d_k) q_{k-1} + d_k (x_k - sum_i Wm_i f(chi_i))` (sum of the `K e` of the updates
//!   since the last predict),
//! - `Q_k = (1-d_k) Q_{k-1} + d_k (sum K e e^T K^T + P_k - sum_i Wc_i (chi_i - x^-)(chi_i - x^-)^T)`,
//! - `r_k = (1-d_k) r_{k-1} + d_k (z_k - sum_i Wm_i z_i)`,
//! - `R_k = (1-d_k) R_{k-1} + d_k (e e^T - sum_i Wc_i (z_i - z^)(z_i - z^)^T)`.
//!
//! Safeguard (ours, counted in the health): the unbiased recursions above subtract a covariance
//! and can lose positive definiteness. When the candidate is not PD (Cholesky fails, or an
//! eigenvalue would fall under the configured floor), the biased form is used instead, which drops
//! the subtracted term (`Q_k = (1-d_k) Q_{k-1} + d_k sum K e e^T K^T`, `R_k = (1-d_k) R_{k-1} +
//! d_k e e^T`, both PD because `Q_{k-1}`/`R_{k-1}` are), and its eigenvalues are floored.
//!
//! Gated-out measurements (ours): the innovation fed to the R recursion is clipped to the gate
//! boundary (Huber-style), and a gated-out measurement does feed it (clipped), though it changes
//! nothing else (not the state, P, Q, the Q accumulators or the fading statistics). Without that,
//! a sensor whose noise suddenly grows has its measurements rejected by the gate and R can never
//! learn the new level; with it, one outlier moves R by at most `d_k * gate * S`. Measured on the
//! 40 dives of seeds 0..40 (`subnav filter monte-carlo --seeds 0..40 --no-fading`, release):
//! R left alone by a rejection gave 6 / 40 divergences (worst horizontal error 39.5 m), the
//! clipped step 0 / 40 (worst 3.4 m).
//!
//! Fading factor (strong tracking, spec A5): innovation covariance with forgetting `rho`:
//! `V_0 = e e^T`, `V_k = (rho V_{k-1} + e e^T) / (1 + rho)`. Divergence test
//! `e^T e > S_test * tr(E[e e^T])` with `E[e e^T] = P_zz + R` from the sigma points. When it fires,
//! `lambda_k = max(lambda_0, tr(N_k) / tr(M_k))` with `N_k = V_k - R_k` and `M_k = P_zz` (the part
//! of the predicted innovation covariance that comes from `P_{k|k-1}`), capped at `lambda_max`,
//! and `P_{k|k-1} <- lambda_k P_{k|k-1}`; `P_zz` and `P_xz` are scaled by the same factor (exact for
//! a measurement linear in the state, the usual strong-tracking approximation otherwise).
//!
//! Persistence test (ours; `fading_persist > 0`): the seed's test reads any innovation larger
//! than expected as state divergence, so a sensor whose noise grows (which Sage-Husa R is there
//! to absorb) also inflates P, the filter then follows the noisy measurements, and the two
//! adaptations work against each other (measured: 2 / 500 divergences with the seed's test
//! alone, 0 / 500 with the fading factor off; docs/PERFORMANCE.md). The two causes differ in the
//! innovations' mean, not their size: more sensor noise keeps the innovations zero-mean and
//! white, a state that diverges gives a persistent, one-signed innovation. So the fading factor
//! fires only when the seed's test fires *and* the decaying mean (forgetting `rho`) of the
//! whitened innovation `w = L_S^-1 e` (`S = L_S L_S^T = P_zz + R`) is significant against the
//! innovations' own power: `|m_k|^2 / (c_k p_k) > fading_persist * chi2_0.999(M)` with
//! `m_k = rho m_{k-1} + (1 - rho) w`, `p_k` the bias-corrected decaying mean of `|w|^2 / M` and
//! `c_k = (1 - rho) / (1 + rho) (1 - rho^2k)` the variance factor of `m_k` for white `w`. The
//! statistic is scale-free: white innovations of any variance give about `chi2(M)`, a constant
//! bias `b` against noise `sigma` tends to `|b|^2 / (c (|b|^2 / M + sigma^2))` (up to `M / c`,
//! 39 M at `rho = 0.95`). The statistics move only with accepted updates.

use nalgebra::linalg::Cholesky;
use nalgebra::{Const, RealField, SMatrix, SVector};

use super::gate::chi2_999;
use super::pd;

/// Switches and tuning of the adaptive layer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdaptConfig<T> {
    /// Sage-Husa forgetting factor `b` (0 < b < 1, typically 0.95..0.995).
    pub b: T,
    /// Initial value of the step counter `k` used in `d_k`: 0 is the spec's recursion (the first
    /// sample replaces the prior); a larger `k0` lets the configured Q/R count as
    /// about `k0` earlier samples.
    pub k0: u32,
    /// Estimate the process-noise mean `q`.
    pub q_mean: bool,
    /// Estimate the process-noise covariance `Q`.
    pub q_cov: bool,
    /// Estimate the measurement-noise mean `r`.
    pub r_mean: bool,
    /// Estimate the measurement-noise covariance `R`.
    pub r_cov: bool,
    /// Apply the fading factor.
    pub fading: bool,
    /// Divergence test multiplier `S >= 1`.
    pub fading_s: T,
    /// Lower bound `lambda_0` of the fading factor (>= 1).
    pub lambda0: T,
    /// Upper bound of the fading factor (ours: a safety cap).
    pub lambda_max: T,
    /// Forgetting factor `rho` of the innovation covariance estimate `V_k` (and of the
    /// persistence statistics).
    pub rho: T,
    /// Persistence test of the fading factor (ours, module doc): the fading factor fires only
    /// when the whitened innovation mean is significant against the innovations' own spread,
    /// beyond `fading_persist` times the chi-square 99.9 % quantile; 0 = off (the seed's test
    /// alone).
    pub fading_persist: T,
}

impl<T: RealField + Copy> AdaptConfig<T> {
    /// Everything off: a plain UKF.
    pub fn plain() -> Self {
        Self {
            b: T::from_subset(&0.98),
            k0: 0,
            q_mean: false,
            q_cov: false,
            r_mean: false,
            r_cov: false,
            fading: false,
            fading_s: T::from_subset(&4.0),
            lambda0: T::one(),
            lambda_max: T::from_subset(&10.0),
            rho: T::from_subset(&0.95),
            fading_persist: T::zero(),
        }
    }

    /// Whether any adaptive part is switched on.
    pub fn any(&self) -> bool {
        self.q_mean || self.q_cov || self.r_mean || self.r_cov || self.fading
    }

    /// Range check; `false` means refuse the configuration.
    pub fn is_valid(&self) -> bool {
        self.b > T::zero()
            && self.b < T::one()
            && self.fading_s >= T::one()
            && self.lambda0 >= T::one()
            && self.lambda_max >= self.lambda0
            && self.rho > T::zero()
            && self.rho < T::one()
            && self.lambda_max.is_finite()
            && self.fading_persist >= T::zero()
            && self.fading_persist.is_finite()
    }
}

/// Tuning of [`NisQScale`]: the process-noise scale matched to the innovations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QScaleConfig<T> {
    /// Adapt at all (off: the scale stays 1).
    pub on: bool,
    /// Forgetting factor of the mean normalised NIS (`nis / M`), per measurement.
    pub b: T,
    /// Dead band of that mean: the scale moves only while it is above `hi` or below `lo`.
    pub hi: T,
    pub lo: T,
    /// Exponent of a step: `scale *= mean^gain` per measurement outside the dead band.
    pub gain: T,
    /// One measurement's `nis / M` counts at most this much (an outlier moves the mean by at
    /// most `(1 - b) * clip`).
    pub clip: T,
    /// Bounds of the scale (variance ratio against the configured process noise).
    pub min: T,
    pub max: T,
}

impl<T: RealField + Copy> QScaleConfig<T> {
    /// Off: the configured process noise, always.
    pub fn off() -> Self {
        Self {
            on: false,
            b: T::from_subset(&0.8),
            hi: T::from_subset(&2.0),
            lo: T::from_subset(&0.5),
            gain: T::from_subset(&0.3),
            clip: T::from_subset(&5.0),
            min: T::one(),
            max: T::from_subset(&1.0e5),
        }
    }

    /// On, with the defaults of [`QScaleConfig::off`].
    pub fn on() -> Self {
        Self { on: true, ..Self::off() }
    }

    /// Range check; `false` means refuse the configuration.
    pub fn is_valid(&self) -> bool {
        self.b > T::zero()
            && self.b < T::one()
            && self.lo > T::zero()
            && self.hi > self.lo
            && self.gain > T::zero()
            && self.gain <= T::one()
            && self.clip >= self.hi
            && self.min > T::zero()
            && self.max >= self.min
            && self.max.is_finite()
    }
}

/// The process-noise scale by covariance matching on the NIS (ours; the seed's Sage-Husa `Q`
/// recursion, constrained to one degree of freedom).
///
/// Why: the full Sage-Husa `Q` of 15 error states is not observable from 1-3-dimensional aiding
/// measurements (hence off in [`AdaptConfig`]), and the filter's own statistics move only with
/// accepted updates. An IMU noisier than configured makes the aiding innovations larger than the
/// filter predicts; the gate refuses them, the refused ones teach nothing, `P` stays small, and
/// the filter coasts free-inertial for good (measured: IMU noise x20 with a working DVL, 9.8 km
/// horizontal RMS). Here the evidence comes from every measurement of the sources fed to it,
/// refused ones included: the decaying mean `m` of `min(NIS / M, clip)` (forgetting `b`), where
/// `NIS` is taken against the filter's full prior innovation covariance `S = P_zz + R` (not the
/// gate's capped one). While `m > hi` the scale `s` of the IMU's part of the process noise
/// grows by `m^gain` per measurement; while `m < lo` it shrinks by the same law, within
/// `[min, max]`.
///
/// Why it cannot spiral: one scalar, bounded on both sides, moved by multiplicative steps of at
/// most `clip^gain` (1.6 by default) per measurement. Its only effect is to make `P`, hence
/// `S`, larger when it grows, so the statistic that drives it falls: a monotone negative
/// feedback whose fixed point is `E[NIS] = M` (a consistent filter), with the dead band
/// `[lo, hi]` around it so that a consistent filter's scatter (the mean of a few `chi2(M) / M`
/// samples) does not move it. Widening `Q` never makes a gate refuse more (it widens `S`), so it
/// cannot starve the filter; a clipped outlier moves `m` by at most `(1 - b) clip` (1.0 by
/// default: from a consistent filter's 1 to 1.8, inside the dead band, so it moves nothing). What it cannot tell apart: an aiding sensor noisier than its `R` also
/// raises the NIS; the scale then widens `Q` too, which costs some accuracy but keeps the
/// filter consistent (the R adaptation, when on, takes its own share first).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NisQScale<T> {
    scale: T,
    mean: T,
}

impl<T: RealField + Copy> Default for NisQScale<T> {
    fn default() -> Self {
        Self { scale: T::one(), mean: T::one() }
    }
}

impl<T: RealField + Copy> NisQScale<T> {
    /// The current scale (variance ratio).
    pub fn scale(&self) -> T {
        self.scale
    }

    /// The decaying mean of `NIS / M`.
    pub fn mean_nis_ratio(&self) -> T {
        self.mean
    }

    /// Start at `scale`, clamped to the bounds (other evidence of the process noise, e.g. the
    /// IMU's noise measured at rest); a non-finite value is ignored.
    pub fn seed(&mut self, cfg: &QScaleConfig<T>, scale: T) {
        if scale.is_finite() {
            self.scale = if scale > cfg.max {
                cfg.max
            } else if scale < cfg.min {
                cfg.min
            } else {
                scale
            };
        }
    }

    /// One measurement's NIS (against the full prior innovation covariance) of dimension `m`,
    /// accepted or refused by the gate. A non-finite NIS is ignored.
    pub fn observe(&mut self, cfg: &QScaleConfig<T>, nis: T, m: usize) {
        if !cfg.on || !nis.is_finite() || nis < T::zero() || m == 0 {
            return;
        }
        let r = nis / T::from_subset(&(m as f64));
        let r = if r > cfg.clip { cfg.clip } else { r };
        self.mean = self.mean * cfg.b + r * (T::one() - cfg.b);
        if self.mean > cfg.hi || self.mean < cfg.lo {
            let s = self.scale * self.mean.powf(cfg.gain);
            self.scale = if s > cfg.max {
                cfg.max
            } else if s < cfg.min {
                cfg.min
            } else {
                s
            };
        }
    }
}

/// Sage-Husa weight `d_k = (1 - b) / (1 - b^(k+1))`.
pub fn sage_husa_d<T: RealField + Copy>(b: T, k: u32) -> T {
    // b^(k+1) underflows to 0 for large k, which gives the correct limit 1 - b.
    let bk = b.powi(k.saturating_add(1).min(i32::MAX as u32) as i32);
    (T::one() - b) / (T::one() - bk)
}

/// Per-measurement noise statistics: the (adapted) `R`, its mean `r`, the counters of the
/// Sage-Husa recursion and of the fading factor's innovation estimate, and the gate tuning.
/// Each sensor owns one of these and passes it to [`super::Ukf::update`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasNoise<T: RealField + Copy, const M: usize> {
    /// Measurement noise covariance (the configured value, adapted when `r_cov` is on).
    pub r: SMatrix<T, M, M>,
    /// Measurement noise mean (zero unless `r_mean` is on).
    pub r_mean: SVector<T, M>,
    /// Eigenvalue floor of an adapted `R`.
    pub r_floor: T,
    /// Sage-Husa step counter.
    pub k: u32,
    /// Fading factor's innovation covariance estimate `V_k` and its counter.
    pub v: SMatrix<T, M, M>,
    pub v_k: u32,
    /// Fading factor's persistence statistics: decaying means (forgetting `rho`) of the
    /// whitened innovation `L_S^-1 e` and of its power per axis, and their sample count.
    pub inn_mean: SVector<T, M>,
    pub inn_pow: T,
    pub inn_k: u32,
    /// Gate: chi-square threshold on the NIS (e.g. [`super::gate::chi2_999`]); infinite = off.
    pub gate: T,
    /// Gate floor: on every axis the state part of the gating covariance is capped at
    /// `gate_state_max` times the measurement noise, so the gate can still reject when `P` is
    /// huge.
    pub gate_state_max: T,
    /// After this many consecutive rejections the cap is lifted for the next measurement
    /// (re-acquisition after an outage); 0 = never.
    pub gate_release_after: u32,
    /// Consecutive rejections so far.
    pub consecutive_rejects: u32,
    /// Whether the Sage-Husa r/R recursion runs for this measurement (when switched on in the
    /// filter's [`AdaptConfig`]); off for measurements that bring their own covariance.
    pub adapt: bool,
    /// States the fading factor scales for this measurement (bit i = state i; 0 = all). Scaling
    /// states the measurement does not observe (e.g. position, by a heading) would inflate their
    /// variance without bound.
    pub fading_mask: u64,
}

impl<T: RealField + Copy, const M: usize> MeasNoise<T, M> {
    /// Noise `r`, no gate, no adaptation state.
    pub fn new(r: SMatrix<T, M, M>) -> Self {
        Self {
            r,
            r_mean: SVector::zeros(),
            r_floor: T::zero(),
            k: 0,
            v: SMatrix::zeros(),
            v_k: 0,
            inn_mean: SVector::zeros(),
            inn_pow: T::zero(),
            inn_k: 0,
            gate: T::max_value().unwrap_or(T::one() / T::default_epsilon()),
            gate_state_max: T::max_value().unwrap_or(T::one() / T::default_epsilon()),
            gate_release_after: 0,
            consecutive_rejects: 0,
            adapt: true,
            fading_mask: 0,
        }
    }

    /// With a chi-square gate and its floor.
    pub fn with_gate(mut self, gate: T, gate_state_max: T, release_after: u32) -> Self {
        self.gate = gate;
        self.gate_state_max = gate_state_max;
        self.gate_release_after = release_after;
        self
    }

    /// With the Sage-Husa step counter started at `k` (the forgetting factor's warm-up).
    pub fn with_k(mut self, k: u32) -> Self {
        self.k = k;
        self
    }

    /// With an eigenvalue floor for the adapted R.
    pub fn with_floor(mut self, r_floor: T) -> Self {
        self.r_floor = r_floor;
        self
    }

    /// Start the Sage-Husa counter at `k0`.
    pub fn with_k0(mut self, k0: u32) -> Self {
        self.k = k0;
        self
    }
}

/// The fading factor's statistics of one measurement, updated by a step in a copy and written
/// back to the [`MeasNoise`] only when the step is committed.
pub(crate) struct FadingStats<T: RealField + Copy, const M: usize> {
    pub v: SMatrix<T, M, M>,
    v_k: u32,
    mean: SVector<T, M>,
    pow: T,
    k: u32,
}

impl<T: RealField + Copy, const M: usize> FadingStats<T, M> {
    pub fn of(n: &MeasNoise<T, M>) -> Self {
        Self { v: n.v, v_k: n.v_k, mean: n.inn_mean, pow: n.inn_pow, k: n.inn_k }
    }

    /// Add the innovation `e` (prior innovation covariance `S = chol_s L L^T`).
    pub fn observe(&mut self, a: &AdaptConfig<T>, e: &SVector<T, M>, chol_s: &Cholesky<T, Const<M>>) {
        let eet = e * e.transpose();
        self.v = if self.v_k == 0 { eet } else { (self.v * a.rho + eet) / (T::one() + a.rho) };
        self.v_k = self.v_k.saturating_add(1);
        if a.fading_persist > T::zero() {
            if let Some(w) = chol_s.l().solve_lower_triangular(e) {
                let g = T::one() - a.rho;
                self.mean = self.mean * a.rho + w * g;
                self.pow = self.pow * a.rho + w.norm_squared() * g / T::from_subset(&(M as f64));
                self.k = self.k.saturating_add(1);
            }
        }
    }

    /// The persistence test (module doc); `true` when it is off.
    pub fn persistent(&self, a: &AdaptConfig<T>) -> bool {
        if !(a.fading_persist > T::zero()) {
            return true;
        }
        // Of the zero-initialised decaying means after k samples: E|mean|^2 = M s2 c_k with
        // c_k = (1-rho)/(1+rho) (1 - rho^2k), and E[pow] = s2 (1 - rho^k), for white innovations
        // of any per-axis variance s2.
        let rk = a.rho.powi(self.k.min(i32::MAX as u32) as i32);
        let c = (T::one() - a.rho) / (T::one() + a.rho) * (T::one() - rk * rk);
        let s2 = self.pow / (T::one() - rk);
        if !(c > T::zero() && s2 > T::zero()) {
            return false;
        }
        self.mean.norm_squared() / (c * s2) > a.fading_persist * chi2_999::<T>(M)
    }

    pub fn store(self, n: &mut MeasNoise<T, M>) {
        n.v = self.v;
        n.v_k = self.v_k;
        n.inn_mean = self.mean;
        n.inn_pow = self.pow;
        n.inn_k = self.k;
    }
}

/// Outcome of one adaptive covariance recursion.
pub(crate) struct Adapted<T: RealField + Copy, const D: usize> {
    pub cov: SMatrix<T, D, D>,
    /// The biased fallback (and/or eigenvalue floor) had to be used.
    pub fallback: bool,
}

/// One Sage-Husa covariance step with the PD safeguard:
/// candidate `(1-d) old + d (pos + delta)`, fallback `(1-d) old + d pos`, then floor.
/// `pos` is the PSD part (`e e^T`, `K e e^T K^T`), `delta` the correction that may break PD.
pub(crate) fn sage_husa_cov<T: RealField + Copy, const D: usize>(
    old: &SMatrix<T, D, D>,
    d: T,
    pos: &SMatrix<T, D, D>,
    delta: &SMatrix<T, D, D>,
    floor: T,
) -> Option<Adapted<T, D>> {
    // Built entry by entry and factored in place (`pd` module doc: stack on the sensor head).
    let one_d = T::one() - d;
    let mut cand = SMatrix::<T, D, D>::from_fn(|i, j| old[(i, j)] * one_d + (pos[(i, j)] + delta[(i, j)]) * d);
    pd::symmetrize(&mut cand);
    if pd::all_finite(&cand) && min_diag(&cand) > floor {
        let mut l = SMatrix::<T, D, D>::zeros();
        if pd::cholesky_into(&cand, &mut l) && (0..D).all(|i| l[(i, i)] * l[(i, i)] > floor) {
            return Some(Adapted { cov: cand, fallback: false });
        }
    }
    // The biased fallback, reusing the candidate's storage.
    for i in 0..D {
        for j in 0..D {
            cand[(i, j)] = old[(i, j)] * one_d + pos[(i, j)] * d;
        }
    }
    pd::symmetrize(&mut cand);
    let tiny = T::default_epsilon();
    let fl = if floor > tiny { floor } else { tiny };
    pd::repair_in_place(&mut cand, fl, T::zero()).then_some(Adapted { cov: cand, fallback: true })
}

fn min_diag<T: RealField + Copy, const D: usize>(m: &SMatrix<T, D, D>) -> T {
    (0..D).fold(T::max_value().unwrap_or(T::one()), |a, i| if m[(i, i)] < a { m[(i, i)] } else { a })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix2;

    /// A filter told the truth gives `NIS / M` of mean 1: the scale stays at 1. Innovations 30x
    /// larger than predicted (a noisier IMU) raise it until the statistic is back in its dead
    /// band, within a bounded number of steps; an isolated outlier moves it by a few percent.
    #[test]
    fn the_q_scale_follows_the_evidence_and_stays_bounded() {
        let cfg = QScaleConfig::<f64>::on();
        let mut a = NisQScale::default();
        // chi2(3)-like sequence with mean 3.
        let seq = [1.2, 4.5, 2.0, 0.4, 6.1, 3.3, 1.9, 2.6, 5.0, 3.0];
        for k in 0..1000 {
            a.observe(&cfg, seq[k % seq.len()], 3);
        }
        assert_eq!(a.scale(), 1.0, "consistent innovations leave the tuning alone");
        a.observe(&cfg, 1e6, 3);
        a.observe(&cfg, 3.0, 3);
        assert_eq!(a.scale(), 1.0, "one outlier among consistent innovations moves nothing");
        // The truth's process noise is 900x the filter's: the NIS (in a filter whose innovation
        // covariance is dominated by the process noise) falls as the scale grows.
        let mut b = NisQScale::default();
        let mut steps = 0;
        for k in 0..2000 {
            let nis = seq[k % seq.len()] * 900.0 / b.scale();
            b.observe(&cfg, nis, 3);
            if (b.scale() - 900.0).abs() < 0.5 * 900.0 && steps == 0 {
                steps = k;
            }
        }
        assert!(steps > 0 && steps < 200, "reached the truth's scale after {steps} measurements");
        assert!(b.scale() > 250.0 && b.scale() < 3000.0, "settles near the truth: {}", b.scale());
        // Bounded, and a NaN changes nothing.
        let mut c = NisQScale::default();
        for _ in 0..100_000 {
            c.observe(&cfg, 1e30, 3);
        }
        assert_eq!(c.scale(), cfg.max);
        let before = c;
        c.observe(&cfg, f64::NAN, 3);
        assert_eq!(c, before);
        let mut off = NisQScale::default();
        off.observe(&QScaleConfig::off(), 1e9, 3);
        assert_eq!(off.scale(), 1.0);
    }

    #[test]
    fn d_k_matches_the_formula() {
        let b = 0.96f64;
        assert!((sage_husa_d(b, 0) - 1.0).abs() < 1e-12);
        assert!((sage_husa_d(b, 1) - (1.0 - b) / (1.0 - b * b)).abs() < 1e-12);
        assert!((sage_husa_d(b, 1_000_000) - (1.0 - b)).abs() < 1e-12);
    }

    #[test]
    fn unbiased_step_losing_pd_falls_back() {
        let old = Matrix2::<f64>::identity();
        let pos = Matrix2::<f64>::zeros();
        let neg = Matrix2::<f64>::identity() * -5.0;
        let a = sage_husa_cov(&old, 0.5, &pos, &neg, 1e-6).unwrap();
        assert!(a.fallback);
        assert!((a.cov[(0, 0)] - 0.5).abs() < 1e-9);
        let b = sage_husa_cov(&old, 0.5, &(Matrix2::identity() * 3.0), &(Matrix2::identity() * -1.0), 1e-6).unwrap();
        assert!(!b.fallback);
        assert!((b.cov[(1, 1)] - 1.5).abs() < 1e-12);
    }
}
