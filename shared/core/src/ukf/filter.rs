//! The filter: state `x`, covariance `P`, predict and update.
//!
//! Sigma points are drawn from the current `(x, P)` at every predict and update (as FilterPy
//! does: its predict re-draws `sigmas_f` from the prior), so updates of different sizes and rates
//! can follow each other in any order. `P` is stored with its Cholesky factor; every write goes
//! through [`super::pd::finalize`] (symmetrize, factor, repair and count if needed), and the
//! factor is reused for the next sigma-point draw.
//!
//! A refused step changes nothing: every predict and update computes its results (state, `P`
//! and its factor, the Sage-Husa `Q`/`q` step, the fading factor's statistics) in locals and
//! writes them only once nothing can fail any more. After a refusal (non-finite input or model
//! output, innovation covariance not PD, a `P` the eigenvalue repair cannot make PD) the state,
//! `P`, `Q`, the caller's `R` and every adaptive accumulator are bit for bit what they were;
//! only the health counters move. A gate rejection leaves the state, `P`, `Q` and the
//! accumulators bit for bit too; it moves the gate's count and, with Sage-Husa R on, feeds R
//! the clipped innovation (adapt module doc: the measured reason) — nothing else
//! (`refusal_tests.rs` checks each path).

use core::marker::PhantomData;

use nalgebra::linalg::Cholesky;
use nalgebra::{RealField, SMatrix, SVector};

use super::adapt::{AdaptConfig, FadingStats, MeasNoise, sage_husa_cov, sage_husa_d};
use super::gate::{gating_cov, nis};
use super::pd::{add_outer_lower, all_finite, finalize, finalize_in_place, mirror_lower};
use super::space::{Euclidean, Space};
use super::weights::{CompactWeights, SigmaWeights};

/// Measurement statistics of an update: `(z^ without r, z^, P_zz, P_xz)`.
type MeasStats<T, const N: usize, const M: usize> = (SVector<T, M>, SVector<T, M>, SMatrix<T, M, M>, SMatrix<T, N, M>);

/// Tuning of a [`Ukf`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UkfConfig<T> {
    /// Sigma-point spread.
    pub alpha: T,
    /// Prior knowledge of the distribution (2 is optimal for Gaussians).
    pub beta: T,
    /// Secondary scaling.
    pub kappa: T,
    /// Adaptive layer switches ([`AdaptConfig::plain`] = plain UKF).
    pub adapt: AdaptConfig<T>,
    /// Absolute eigenvalue floor applied when `P` must be repaired.
    pub p_floor: T,
    /// Relative eigenvalue floor (times the largest eigenvalue) for `P` repairs.
    pub p_rel_floor: T,
    /// Eigenvalue floor of an adapted `Q`.
    pub q_floor: T,
}

impl<T: RealField + Copy> UkfConfig<T> {
    /// Plain UKF with the given unscented-transform parameters.
    pub fn plain(alpha: T, beta: T, kappa: T) -> Self {
        Self { alpha, beta, kappa, adapt: AdaptConfig::plain(), p_floor: T::zero(), p_rel_floor: T::zero(), q_floor: T::zero() }
    }
}

/// Counters and latest values for telemetry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UkfHealth<T> {
    pub predicts: u32,
    pub updates_accepted: u32,
    /// Covariance repairs of `P` (eigenvalue floor after symmetrization did not make it PD).
    pub pd_repairs: u32,
    /// Sage-Husa Q/R candidates that were not PD and were replaced by the biased form + floor.
    pub adapt_fallbacks: u32,
    /// Inputs or model outputs that were not finite (the step was not applied).
    pub nonfinite_rejects: u32,
    /// Steps refused because the new `P` could not be made PD by the eigenvalue repair
    /// ([`UkfError::CovarianceUnrepairable`]; the step was not applied).
    pub unrepairable_rejects: u32,
    /// Measurements rejected by the innovation gate.
    pub gate_rejects: u32,
    /// Times the fading factor fired.
    pub fading_events: u32,
    /// Fading factor of the latest accepted update (1 = none).
    pub last_lambda: T,
}

impl<T: RealField + Copy> UkfHealth<T> {
    /// All counters zero (one repair if the initial `P` needed it).
    fn fresh(repaired: bool) -> Self {
        Self {
            predicts: 0,
            updates_accepted: 0,
            pd_repairs: u32::from(repaired),
            adapt_fallbacks: 0,
            nonfinite_rejects: 0,
            unrepairable_rejects: 0,
            gate_rejects: 0,
            fading_events: 0,
            last_lambda: T::one(),
        }
    }
}

/// Why a step was not applied. The filter state is unchanged after any of them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UkfError {
    /// A measurement, noise matrix or scale was NaN or infinite.
    NonFiniteInput,
    /// The process or measurement model returned a non-finite value, or the result was not finite.
    NonFiniteResult,
    /// The innovation covariance could not be factored.
    NotPositiveDefinite,
    /// The new state covariance was finite but not PD, and the eigenvalue repair could not make
    /// it PD (e.g. a zero floor on a singular `P`, or the eigen-sweeps did not converge).
    CovarianceUnrepairable,
    /// Weights could not be built (S != 2N+1, or N + lambda <= 0) or the adaptive config is out
    /// of range.
    BadConfig,
}

impl core::fmt::Display for UkfError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            UkfError::NonFiniteInput => "UKF input (measurement, noise matrix or scale) is NaN or infinite",
            UkfError::NonFiniteResult => "UKF model output or result is NaN or infinite",
            UkfError::NotPositiveDefinite => "UKF innovation covariance is not positive definite",
            UkfError::CovarianceUnrepairable => {
                "UKF state covariance is not positive definite and the eigenvalue repair could not make it so"
            }
            UkfError::BadConfig => "UKF configuration out of range (sigma-point weights or adaptive settings)",
        })
    }
}

impl core::error::Error for UkfError {}

/// What an update did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UpdateReport<T> {
    /// Whether the measurement was applied (false = rejected by the gate).
    pub accepted: bool,
    /// NIS against the full predicted innovation covariance `P_zz + R`.
    pub nis: T,
    /// NIS against the gating covariance (the value compared with the gate).
    pub nis_gate: T,
    /// Fading factor applied (1 = none).
    pub lambda: T,
}

/// Unscented Kalman filter with `N` states and `S = 2N + 1` sigma points, state space `X`.
#[derive(Debug, Clone)]
pub struct Ukf<T: RealField + Copy, const N: usize, const S: usize, X = Euclidean> {
    x: SVector<T, N>,
    p: SMatrix<T, N, N>,
    l: SMatrix<T, N, N>,
    /// Process noise per predict (adapted when `q_cov` is on).
    q: SMatrix<T, N, N>,
    /// Process noise mean (adapted when `q_mean` is on).
    q_mean: SVector<T, N>,
    cfg: UkfConfig<T>,
    /// The sigma-point weights, compact (`weights()` expands them).
    w: CompactWeights<T>,
    q_k: u32,
    /// Two symmetric matrices of the Sage-Husa Q step in one (RAM on the M4F: 840 B per filter,
    /// which the boot path holds twice): the previous predict's spread `sum Wc r r^T` on and
    /// below the diagonal, the strictly lower part of `sum dx dx^T` over the updates since
    /// then above it (transposed); its diagonal in `acc_keek_diag`.
    spread_keek: SMatrix<T, N, N>,
    acc_ke: SVector<T, N>,
    acc_keek_diag: SVector<T, N>,
    acc_n: u32,
    health: UkfHealth<T>,
    _space: PhantomData<X>,
}

impl<T: RealField + Copy, const N: usize, const S: usize, X: Space<T, N>> Ukf<T, N, S, X> {
    /// A filter at `x0` with covariance `p0` and process noise `q`.
    pub fn new(cfg: UkfConfig<T>, x0: SVector<T, N>, p0: SMatrix<T, N, N>, q: SMatrix<T, N, N>) -> Result<Self, UkfError> {
        let w = SigmaWeights::<T, S>::merwe(N, cfg.alpha, cfg.beta, cfg.kappa).map_err(|_| UkfError::BadConfig)?;
        if !cfg.adapt.is_valid() {
            return Err(UkfError::BadConfig);
        }
        if !all_finite(&x0) || !all_finite(&p0) || !all_finite(&q) {
            return Err(UkfError::NonFiniteInput);
        }
        let f = finalize(p0, cfg.p_floor, cfg.p_rel_floor).ok_or(UkfError::NotPositiveDefinite)?;
        let health = UkfHealth::fresh(f.repaired);
        Ok(Self {
            x: x0,
            p: f.p,
            l: f.l,
            q,
            q_mean: SVector::zeros(),
            q_k: cfg.adapt.k0,
            cfg,
            w: CompactWeights::of(&w),
            spread_keek: SMatrix::zeros(),
            acc_ke: SVector::zeros(),
            acc_keek_diag: SVector::zeros(),
            acc_n: 0,
            health,
            _space: PhantomData,
        })
    }

    /// Re-initialise in place, as [`Ukf::new`] would build it (on failure the filter is left
    /// unchanged). In place so a microcontroller does not need a second filter on its stack.
    pub fn reinit(&mut self, cfg: UkfConfig<T>, x0: SVector<T, N>, p0: SMatrix<T, N, N>, q: SMatrix<T, N, N>) -> Result<(), UkfError> {
        let w = SigmaWeights::<T, S>::merwe(N, cfg.alpha, cfg.beta, cfg.kappa).map_err(|_| UkfError::BadConfig)?;
        if !cfg.adapt.is_valid() {
            return Err(UkfError::BadConfig);
        }
        if !all_finite(&x0) || !all_finite(&p0) || !all_finite(&q) {
            return Err(UkfError::NonFiniteInput);
        }
        let f = finalize(p0, cfg.p_floor, cfg.p_rel_floor).ok_or(UkfError::NotPositiveDefinite)?;
        self.health = UkfHealth::fresh(f.repaired);
        self.x = x0;
        self.p = f.p;
        self.l = f.l;
        self.q = q;
        self.q_mean = SVector::zeros();
        self.q_k = cfg.adapt.k0;
        self.cfg = cfg;
        self.w = CompactWeights::of(&w);
        self.spread_keek = SMatrix::zeros();
        self.acc_ke = SVector::zeros();
        self.acc_keek_diag = SVector::zeros();
        self.acc_n = 0;
        Ok(())
    }

    pub fn x(&self) -> &SVector<T, N> {
        &self.x
    }
    pub fn p(&self) -> &SMatrix<T, N, N> {
        &self.p
    }
    pub fn q(&self) -> &SMatrix<T, N, N> {
        &self.q
    }
    pub fn health(&self) -> &UkfHealth<T> {
        &self.health
    }
    pub fn config(&self) -> &UkfConfig<T> {
        &self.cfg
    }
    pub fn weights(&self) -> SigmaWeights<T, S> {
        self.w.expand()
    }

    /// Replace the state (e.g. reset an error state to zero after injecting it).
    pub fn set_x(&mut self, x: SVector<T, N>) -> Result<(), UkfError> {
        if !all_finite(&x) {
            self.health.nonfinite_rejects += 1;
            return Err(UkfError::NonFiniteInput);
        }
        self.x = x;
        Ok(())
    }

    /// Replace the covariance (symmetrized and checked; a repair is counted).
    pub fn set_p(&mut self, p: SMatrix<T, N, N>) -> Result<(), UkfError> {
        if !all_finite(&p) {
            self.health.nonfinite_rejects += 1;
            return Err(UkfError::NonFiniteInput);
        }
        self.commit_p(p)
    }

    /// Replace one diagonal entry of the process noise (`v` finite and >= 0; else refused,
    /// counted, nothing changes). No `N x N` temporary: for a scaled `Q` on the sensor head.
    pub fn set_q_diag(&mut self, i: usize, v: T) -> Result<(), UkfError> {
        if !(v.is_finite() && v >= T::zero()) || i >= N {
            self.health.nonfinite_rejects += 1;
            return Err(UkfError::NonFiniteInput);
        }
        self.q[(i, i)] = v;
        Ok(())
    }

    /// Replace the process noise.
    pub fn set_q(&mut self, q: SMatrix<T, N, N>) -> Result<(), UkfError> {
        if !all_finite(&q) {
            self.health.nonfinite_rejects += 1;
            return Err(UkfError::NonFiniteInput);
        }
        self.q = q;
        Ok(())
    }

    /// Symmetrize, factor and if needed repair a candidate `P` into `p` and `l`, without touching
    /// the filter: `Ok(repaired)`, or the refusal (counted) if it is not finite or cannot be
    /// made PD.
    fn factor(&mut self, p: &mut SMatrix<T, N, N>, l: &mut SMatrix<T, N, N>) -> Result<bool, UkfError> {
        if !all_finite(p) {
            self.health.nonfinite_rejects = self.health.nonfinite_rejects.wrapping_add(1);
            return Err(UkfError::NonFiniteResult);
        }
        match finalize_in_place(p, l, self.cfg.p_floor, self.cfg.p_rel_floor) {
            Some(repaired) => Ok(repaired),
            None => {
                self.health.unrepairable_rejects = self.health.unrepairable_rejects.wrapping_add(1);
                Err(UkfError::CovarianceUnrepairable)
            }
        }
    }

    fn commit_p(&mut self, mut p: SMatrix<T, N, N>) -> Result<(), UkfError> {
        // In place (`pd` module doc: stack on the sensor head); on failure `self.p` and `self.l`
        // are unchanged.
        let mut l = SMatrix::<T, N, N>::zeros();
        let repaired = self.factor(&mut p, &mut l)?;
        if repaired {
            self.health.pd_repairs = self.health.pd_repairs.wrapping_add(1);
        }
        self.p = p;
        self.l = l;
        Ok(())
    }

    /// The `2N+1` sigma points of the current `(x, P)`.
    pub fn sigma_points(&self) -> [SVector<T, N>; S] {
        let mut pts = [self.x; S];
        for i in 0..N {
            let d: SVector<T, N> = self.l.column(i) * self.w.gamma;
            if let Some(p) = pts.get_mut(1 + i) {
                *p = X::add(&self.x, &d);
            }
            if let Some(p) = pts.get_mut(1 + N + i) {
                *p = X::add(&self.x, &(-d));
            }
        }
        pts
    }

    /// Sage-Husa Q/q step from the updates since the previous predict, into `q` (which holds the
    /// current `Q` on entry); returns the new `(q_mean, q_k, fallbacks)`. Nothing in the filter
    /// changes: the predict commits the result only if it succeeds.
    fn adapted_q(&self, q: &mut SMatrix<T, N, N>) -> (SVector<T, N>, u32, u32) {
        let a = self.cfg.adapt;
        if self.acc_n == 0 || !(a.q_cov || a.q_mean) {
            return (self.q_mean, self.q_k, 0);
        }
        let d = sage_husa_d(a.b, self.q_k);
        let q_mean = if a.q_mean { self.q_mean * (T::one() - d) + self.acc_ke * d } else { self.q_mean };
        let mut fallbacks = 0;
        if a.q_cov {
            // Unpacked (`spread_keek`): `P - spread` and `sum dx dx^T`.
            let mut delta = self.p;
            let mut keek = SMatrix::<T, N, N>::from_diagonal(&self.acc_keek_diag);
            for j in 0..N {
                delta[(j, j)] -= self.spread_keek[(j, j)];
                for i in (j + 1)..N {
                    delta[(i, j)] -= self.spread_keek[(i, j)];
                    delta[(j, i)] -= self.spread_keek[(i, j)];
                    keek[(i, j)] = self.spread_keek[(j, i)];
                    keek[(j, i)] = self.spread_keek[(j, i)];
                }
            }
            match sage_husa_cov(q, d, &keek, &delta, self.cfg.q_floor) {
                Some(ad) => {
                    fallbacks += u32::from(ad.fallback);
                    *q = ad.cov;
                }
                None => fallbacks += 1, // keep the old Q
            }
        }
        (q_mean, self.q_k.saturating_add(1), fallbacks)
    }

    /// Time update: `x_i <- f(sigma_i)`, `P <- sum Wc r r^T + q_scale * Q` (with the Sage-Husa
    /// `Q`/`q` step first when it is on). Refused (nothing changed, see the module doc) if
    /// `q_scale` or a model output is not finite, or the new `P` cannot be made PD.
    pub fn predict<F>(&mut self, q_scale: T, f: F) -> Result<(), UkfError>
    where
        F: FnMut(&SVector<T, N>) -> SVector<T, N>,
    {
        self.predict_dep(q_scale, N, f)
    }

    /// [`Self::predict`] for a model `f` that is affine along the states `lin_from..N` at `x`
    /// (the caller's promise: `f(x + d) - f(x) = f(x) - f(x - d)` for every `d` that is zero
    /// in the states `0..lin_from`). Exact, and cheaper for `lin_from < N`: the sigma points of
    /// the Cholesky columns `lin_from..N` are such `x +- d` pairs (the factor is lower
    /// triangular), so `f(x - d)` is `f(x) - (f(x + d) - f(x))` without evaluating `f`, and the
    /// pair's share of the spread, `wc (r+ r+^T + r- r-^T)` with `r+- = c +- a`, is
    /// `2 wc (a a^T + c c^T)`, where `c = f(x) - mean` is common to every such pair: one outer
    /// product per pair instead of two. `lin_from = N` is the plain predict. E.g. the INS
    /// error transition without an attitude error is linear in the other 12 (or 15) states.
    pub fn predict_dep<F>(&mut self, q_scale: T, lin_from: usize, mut f: F) -> Result<(), UkfError>
    where
        F: FnMut(&SVector<T, N>) -> SVector<T, N>,
    {
        if !q_scale.is_finite() || q_scale < T::zero() {
            self.health.nonfinite_rejects += 1;
            return Err(UkfError::NonFiniteInput);
        }
        let lin_from = lin_from.min(N);
        // Point k >= 1 comes from column (k - 1) % N, `+` for k <= N; columns >= lin_from pair.
        let paired = |k: usize| k > 0 && (k - 1) % N >= lin_from;
        // Propagated in place: one array of 2N+1 points on the stack, not two.
        let mut prop = self.sigma_points();
        for (k, o) in prop.iter_mut().enumerate() {
            if paired(k) && k > N {
                continue;
            }
            *o = f(o);
            if !all_finite(o) {
                self.health.nonfinite_rejects += 1;
                return Err(UkfError::NonFiniteResult);
            }
        }
        let f0 = prop.first().copied().unwrap_or(self.x);
        for i in lin_from..N {
            let a = prop.get(1 + i).map(|p| X::residual(p, &f0)).unwrap_or_else(SVector::zeros);
            if let Some(p) = prop.get_mut(1 + N + i) {
                *p = X::add(&f0, &(-a));
            }
        }
        // Q adapted (Sage-Husa) or the stored one; only the adaptation needs the spread kept.
        let adapt_q = self.cfg.adapt.q_cov || self.cfg.adapt.q_mean;
        let mut q_new = SMatrix::<T, N, N>::zeros();
        let (q_mean, q_k, fallbacks) = if adapt_q {
            q_new = self.q;
            self.adapted_q(&mut q_new)
        } else {
            (self.q_mean, self.q_k, 0)
        };
        let w = self.weights();
        let xm = X::mean(&prop, &w.wm);
        let mut spread = SMatrix::<T, N, N>::zeros();
        let two = T::one() + T::one();
        for (k, (c, wc)) in prop.iter().zip(w.wc.iter()).enumerate() {
            if !paired(k) {
                let r = X::residual(c, &xm);
                add_outer_lower(&mut spread, *wc, &r);
            } else if k <= N {
                let a = X::residual(c, &f0);
                add_outer_lower(&mut spread, two * *wc, &a);
            }
        }
        if lin_from < N {
            // The common part `c` of the paired points: 2 (N - lin_from) of them, weight wc each.
            let wc = self.w.wi;
            let c = X::residual(&f0, &xm);
            add_outer_lower(&mut spread, two * T::from_subset(&((N - lin_from) as f64)) * wc, &c);
        }
        let x_new = if self.cfg.adapt.q_mean { X::add(&xm, &q_mean) } else { xm };
        if !all_finite(&x_new) {
            self.health.nonfinite_rejects += 1;
            return Err(UkfError::NonFiniteResult);
        }
        // P = spread + q_scale Q on the lower triangle, mirrored (Q is symmetric).
        let q = if adapt_q { &q_new } else { &self.q };
        let mut p = spread;
        for j in 0..N {
            for i in j..N {
                p[(i, j)] += q[(i, j)] * q_scale;
            }
        }
        mirror_lower(&mut p);
        let mut l = SMatrix::<T, N, N>::zeros();
        let repaired = self.factor(&mut p, &mut l)?;
        // Nothing can fail from here on.
        self.health.pd_repairs = self.health.pd_repairs.wrapping_add(u32::from(repaired));
        self.health.adapt_fallbacks = self.health.adapt_fallbacks.wrapping_add(fallbacks);
        self.p = p;
        self.l = l;
        self.x = x_new;
        if adapt_q {
            self.q = q_new;
            self.q_mean = q_mean;
            self.q_k = q_k;
            // The spread on and below the diagonal, no updates' sum above it yet.
            for j in 0..N {
                for i in 0..j {
                    spread[(i, j)] = T::zero();
                }
            }
            self.spread_keek = spread;
            self.acc_ke = SVector::zeros();
            self.acc_keek_diag = SVector::zeros();
            self.acc_n = 0;
        }
        self.health.predicts = self.health.predicts.wrapping_add(1);
        Ok(())
    }

    /// Measurement update with `z` (space `Z`), noise statistics `noise` and model `h`.
    ///
    /// A rejected (gated) measurement returns `Ok` with `accepted = false`: `x`, `P`, `Q` and the
    /// accumulators are unchanged, the counters move (`noise.consecutive_rejects`,
    /// `gate_rejects`) and, with Sage-Husa R on for this measurement, its innovation clipped to
    /// the gate updates `R`/`r` and their counter (adapt module doc). Any other refusal returns
    /// an error and changes nothing but a health counter. Only an accepted update writes `x`,
    /// `P`, the Q accumulators and the fading statistics.
    pub fn update<const M: usize, Z, H>(
        &mut self,
        z: &SVector<T, M>,
        noise: &mut MeasNoise<T, M>,
        h: H,
    ) -> Result<UpdateReport<T>, UkfError>
    where
        Z: Space<T, M>,
        H: FnMut(&SVector<T, N>) -> SVector<T, M>,
    {
        self.update_dep::<M, Z, H>(z, noise, N, h)
    }

    /// [`Self::update`] for a model `h` that reads only the states `0..dep` (the caller's
    /// promise). Exact, and cheaper for `dep < N`: the sigma points of the Cholesky columns
    /// `dep..N` differ from `x` only in states `dep..` (the factor is lower triangular), so their
    /// predicted measurement is `h(x)` without evaluating `h`, and each such pair's share of
    /// `P_xz` is `wc (z(x) - z^) (d - d) = 0`, which is skipped. `dep = N` is the plain update.
    /// E.g. the compass heading reads only the attitude error (3 of 15 states): 7 evaluations of
    /// `h` instead of 31.
    pub fn update_dep<const M: usize, Z, H>(
        &mut self,
        z: &SVector<T, M>,
        noise: &mut MeasNoise<T, M>,
        dep: usize,
        mut h: H,
    ) -> Result<UpdateReport<T>, UkfError>
    where
        Z: Space<T, M>,
        H: FnMut(&SVector<T, N>) -> SVector<T, M>,
    {
        self.update_with::<M, Z>(z, noise, &mut |ukf, noise, l| ukf.measurement_stats::<M, Z, H>(l.unwrap_or(&ukf.l), noise, &mut h, dep))
    }

    /// Exact Kalman update for a measurement linear in the state, `z = h(x) + H (x' - x)`: the
    /// sigma-point statistics of a linear model are `z^ = h(x)`, `P_zz = H P H^T`,
    /// `P_xz = P H^T` exactly (the unscented transform is exact to second order, and a linear
    /// model has no higher one), so they are computed in closed form instead of from `2N + 1`
    /// evaluations. Everything after the statistics (gate, fading factor, gain, covariance
    /// `P - K S K^T`, symmetrised and factored, the Sage-Husa R step, refusals) is the code of
    /// [`Self::update`]; `h` is evaluated once, at `x`. Euclidean measurement space.
    pub fn update_linear<const M: usize, H>(
        &mut self,
        z: &SVector<T, M>,
        noise: &mut MeasNoise<T, M>,
        hm: &SMatrix<T, M, N>,
        h: H,
    ) -> Result<UpdateReport<T>, UkfError>
    where
        H: Fn(&SVector<T, N>) -> SVector<T, M>,
    {
        let zhat0 = h(&self.x);
        if !all_finite(&zhat0) {
            self.health.nonfinite_rejects += 1;
            return Err(UkfError::NonFiniteResult);
        }
        self.update_with::<M, Euclidean>(z, noise, &mut |ukf, noise, l| {
            // P itself, or the fading factor's scaled prior `L_f L_f^T`.
            let scaled;
            let p = match l {
                None => &ukf.p,
                Some(l) => {
                    scaled = l * l.transpose();
                    &scaled
                }
            };
            let pxz: SMatrix<T, N, M> = p * hm.transpose();
            let mut pzz: SMatrix<T, M, M> = hm * pxz;
            // Exactly symmetric, as the sigma-point sum is.
            for i in 0..M {
                for j in (i + 1)..M {
                    let v = (pzz[(i, j)] + pzz[(j, i)]) * T::from_subset(&0.5);
                    pzz[(i, j)] = v;
                    pzz[(j, i)] = v;
                }
            }
            let zhat = if ukf.cfg.adapt.r_mean { zhat0 + noise.r_mean } else { zhat0 };
            Some((zhat0, zhat, pzz, pxz))
        })
    }

    /// The update after the measurement statistics: `stats(self, noise, L)` gives
    /// `(z^ without r, z^, P_zz, P_xz)` for the prior with factor `L` (`None`: the stored `P`
    /// and its factor; `Some`: the fading factor's scaled factor), `None` if a model output is
    /// not finite.
    /// `stats` is a trait object so the update's code exists once per measurement size and space
    /// (flash on the M4F), not once per model.
    #[allow(clippy::type_complexity)]
    fn update_with<const M: usize, Z>(
        &mut self,
        z: &SVector<T, M>,
        noise: &mut MeasNoise<T, M>,
        stats: &mut dyn FnMut(&Self, &MeasNoise<T, M>, Option<&SMatrix<T, N, N>>) -> Option<MeasStats<T, N, M>>,
    ) -> Result<UpdateReport<T>, UkfError>
    where
        Z: Space<T, M>,
    {
        if !all_finite(z) || !all_finite(&noise.r) || !all_finite(&noise.r_mean) {
            self.health.nonfinite_rejects += 1;
            return Err(UkfError::NonFiniteInput);
        }
        let a = self.cfg.adapt;
        let Some((mut zhat0, mut zhat, mut pzz, mut pxz)) = stats(self, noise, None) else {
            self.health.nonfinite_rejects += 1;
            return Err(UkfError::NonFiniteResult);
        };
        let e = Z::residual(z, &zhat);
        let mut s = pzz + noise.r;
        let Some(chol_prior) = Cholesky::new(s) else {
            self.health.nonfinite_rejects += 1;
            return Err(UkfError::NotPositiveDefinite);
        };
        let nis_full = e.dot(&chol_prior.solve(&e));
        if !nis_full.is_finite() {
            self.health.nonfinite_rejects += 1;
            return Err(UkfError::NotPositiveDefinite);
        }
        let release = noise.gate_release_after > 0 && noise.consecutive_rejects >= noise.gate_release_after;
        let s_gate = if release { s } else { gating_cov(&pzz, &noise.r, noise.gate_state_max) };
        let nis_gate = nis(&e, &s_gate).ok_or(UkfError::NotPositiveDefinite)?;

        if !(nis_gate <= noise.gate) {
            noise.consecutive_rejects = noise.consecutive_rejects.saturating_add(1);
            self.health.gate_rejects = self.health.gate_rejects.wrapping_add(1);
            // The one thing a rejected measurement may change besides the counts: with Sage-Husa
            // R on, its innovation clipped to the gate informs R (adapt module doc: without
            // it, a sensor whose noise jumps past the gate never teaches R).
            let clip = (noise.gate / nis_gate).sqrt();
            self.adapt_r(noise, &(e * clip), z, &zhat0, &pzz);
            return Ok(UpdateReport { accepted: false, nis: nis_full, nis_gate, lambda: T::one() });
        }

        // Fading factor (adapt module doc): its statistics are computed here and stored with the
        // rest of the step. P_{k|k-1} <- Lambda^1/2 P Lambda^1/2, Lambda = lambda on the states
        // of `noise.fading_mask` (all states when 0), 1 elsewhere. The scaled factor is
        // Lambda^1/2 L, so the sigma points are re-drawn without a new factorization and the
        // measurement statistics recomputed exactly.
        let mut lambda = T::one();
        let mut p_prior = self.p;
        let mut e = e;
        let mut fading = FadingStats::of(noise);
        if a.fading {
            fading.observe(&a, &e, &chol_prior);
            let tr_m = pzz.trace();
            if e.dot(&e) > a.fading_s * s.trace() && tr_m > T::zero() && fading.persistent(&a) {
                let ratio = (fading.v - noise.r).trace() / tr_m;
                let mut l = if ratio > a.lambda0 { ratio } else { a.lambda0 };
                if !(l <= a.lambda_max) {
                    l = a.lambda_max;
                }
                if l > T::one() {
                    let sq = l.sqrt();
                    let scale = SVector::<T, N>::from_fn(|i, _| {
                        if noise.fading_mask == 0 || (i < 64 && noise.fading_mask & (1u64 << i) != 0) { sq } else { T::one() }
                    });
                    let l_f = SMatrix::<T, N, N>::from_diagonal(&scale) * self.l;
                    if let Some(st) = stats(self, noise, Some(&l_f)) {
                        (zhat0, zhat, pzz, pxz) = st;
                        e = Z::residual(z, &zhat);
                        p_prior = l_f * l_f.transpose();
                        s = pzz + noise.r;
                        lambda = l;
                    }
                }
            }
        }

        // Gain K = Pxz S^-1 via Cholesky: K^T = S^-1 Pxz^T.
        let Some(chol) = Cholesky::new(s) else {
            self.health.nonfinite_rejects += 1;
            return Err(UkfError::NotPositiveDefinite);
        };
        let k: SMatrix<T, N, M> = chol.solve(&pxz.transpose()).transpose();
        let dx = k * e;
        let x_new = X::add(&self.x, &dx);
        // P - K S K^T on the lower triangle (then mirrored): half of a general product.
        let ks: SMatrix<T, N, M> = k * s;
        let mut p_new = p_prior;
        for j in 0..N {
            for i in j..N {
                let mut acc = T::zero();
                for m in 0..M {
                    acc += ks[(i, m)] * k[(j, m)];
                }
                p_new[(i, j)] -= acc;
            }
        }
        mirror_lower(&mut p_new);
        if !all_finite(&x_new) {
            self.health.nonfinite_rejects += 1;
            return Err(UkfError::NonFiniteResult);
        }
        let mut l_new = SMatrix::<T, N, N>::zeros();
        let repaired = self.factor(&mut p_new, &mut l_new)?;
        // Nothing can fail from here on.
        self.health.pd_repairs = self.health.pd_repairs.wrapping_add(u32::from(repaired));
        self.p = p_new;
        self.l = l_new;
        self.x = x_new;
        if a.fading {
            fading.store(noise);
        }
        if lambda > T::one() {
            self.health.fading_events = self.health.fading_events.wrapping_add(1);
        }
        noise.consecutive_rejects = 0;
        self.health.last_lambda = lambda;
        self.health.updates_accepted = self.health.updates_accepted.wrapping_add(1);
        if a.q_cov || a.q_mean {
            self.acc_ke += dx;
            // `sum dx dx^T`: strictly lower part above the diagonal of `spread_keek`.
            for j in 0..N {
                self.acc_keek_diag[j] += dx[j] * dx[j];
                for i in (j + 1)..N {
                    self.spread_keek[(j, i)] += dx[i] * dx[j];
                }
            }
            self.acc_n = self.acc_n.saturating_add(1);
        }
        self.adapt_r(noise, &e, z, &zhat0, &pzz);
        Ok(UpdateReport { accepted: true, nis: nis_full, nis_gate, lambda })
    }

    /// Sigma points of `(x, L L^T)` through `h`: `(z^ without r, z^, P_zz, P_xz)`; `None` if a
    /// model output is not finite.
    #[allow(clippy::type_complexity)]
    fn measurement_stats<const M: usize, Z, H>(
        &self,
        l: &SMatrix<T, N, N>,
        noise: &MeasNoise<T, M>,
        h: &mut H,
        dep: usize,
    ) -> Option<MeasStats<T, N, M>>
    where
        Z: Space<T, M>,
        H: FnMut(&SVector<T, N>) -> SVector<T, M>,
    {
        let mut pts = [self.x; S];
        for i in 0..N {
            let d: SVector<T, N> = l.column(i) * self.w.gamma;
            if let Some(p) = pts.get_mut(1 + i) {
                *p = X::add(&self.x, &d);
            }
            if let Some(p) = pts.get_mut(1 + N + i) {
                *p = X::add(&self.x, &(-d));
            }
        }
        // Point k >= 1 comes from column (k - 1) % N; columns >= dep leave h at h(x).
        let moves = |k: usize| k == 0 || (k - 1) % N < dep;
        let mut zs = [SVector::<T, M>::zeros(); S];
        for (k, (o, xi)) in zs.iter_mut().zip(pts.iter()).enumerate() {
            if !moves(k) {
                continue;
            }
            *o = h(xi);
            if !all_finite(o) {
                return None;
            }
        }
        let z0 = zs[0];
        for (k, o) in zs.iter_mut().enumerate() {
            if !moves(k) {
                *o = z0;
            }
        }
        let w = self.weights();
        let zhat0 = Z::mean(&zs, &w.wm);
        let zhat = if self.cfg.adapt.r_mean { Z::add(&zhat0, &noise.r_mean) } else { zhat0 };
        let mut pzz = SMatrix::<T, M, M>::zeros();
        let mut pxz = SMatrix::<T, N, M>::zeros();
        for (k, ((zi, xi), wc)) in zs.iter().zip(pts.iter()).zip(w.wc.iter()).enumerate() {
            let rz = Z::residual(zi, &zhat);
            for m in 0..M {
                let wr = *wc * rz[m];
                for j in 0..M {
                    pzz[(j, m)] += wr * rz[j];
                }
            }
            if !moves(k) {
                continue;
            }
            let rx = X::residual(xi, &self.x);
            for m in 0..M {
                let wr = *wc * rz[m];
                for i in 0..N {
                    pxz[(i, m)] += wr * rx[i];
                }
            }
        }
        Some((zhat0, zhat, pzz, pxz))
    }

    /// Sage-Husa r/R step (spec A5) with the PD safeguard.
    fn adapt_r<const M: usize>(
        &mut self,
        noise: &mut MeasNoise<T, M>,
        e: &SVector<T, M>,
        z: &SVector<T, M>,
        zhat0: &SVector<T, M>,
        pzz: &SMatrix<T, M, M>,
    ) {
        let a = self.cfg.adapt;
        if !(a.r_cov || a.r_mean) || !noise.adapt {
            return;
        }
        let d = sage_husa_d(a.b, noise.k);
        noise.k = noise.k.saturating_add(1);
        if a.r_mean {
            noise.r_mean = noise.r_mean * (T::one() - d) + (z - zhat0) * d;
        }
        if a.r_cov {
            let eet = e * e.transpose();
            match sage_husa_cov(&noise.r, d, &eet, &(-pzz), noise.r_floor) {
                Some(ad) => {
                    if ad.fallback {
                        self.health.adapt_fallbacks = self.health.adapt_fallbacks.wrapping_add(1);
                    }
                    noise.r = ad.cov;
                }
                None => self.health.adapt_fallbacks = self.health.adapt_fallbacks.wrapping_add(1),
            }
        }
    }
}

#[cfg(test)]
impl<T: RealField + Copy, const N: usize, const S: usize, X> Ukf<T, N, S, X> {
    /// Zero the health counters (tests compare everything else bit for bit).
    pub(crate) fn clear_counters(&mut self) {
        self.health = UkfHealth::fresh(false);
    }
}

#[cfg(test)]
#[path = "refusal_tests.rs"]
mod refusal_tests;

#[cfg(test)]
#[path = "shortcut_tests.rs"]
mod shortcut_tests;
