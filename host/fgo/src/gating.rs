//! Abnormal-observation test (spec B4): Mahalanobis distance of a DVL/USBL residual,
//! `gamma = r^T (H P H^T + R)^-1 r` with `P` the marginal covariance of the node before the
//! observation is added, against the chi-square quantile of the residual dimension. Normal: keep
//! `R`. Abnormal: `kappa = gamma / threshold` and the factor enters the graph with `kappa R`.
//! Every decision is recorded in a [`GateLog`] (countable, printable).
//!
//! Adaptive form (the default, issue 36): `gamma` is first divided by a robust scale of the
//! sensor's recent innovations, `s = max(1, median(gamma of the last ADAPT_WINDOW decisions) /
//! median(chi2(dim)))`, so that a model whose predicted covariance is too tight for the data (a
//! MEMS IMU noise model on KITTI: the seed's gate inflated 27 of 47 clean fixes) does not make
//! every clean observation abnormal, while a jump that stands out of the sensor's own recent
//! innovations still does (the median ignores up to half of them being abnormal). Abnormal:
//! `kappa = gamma / (s threshold)`. `s` never goes below 1: the test is never tighter than the
//! seed's.

use nalgebra::{DMatrix, DVector};

use super::FgoError;
use super::solver::Matrix15;
use subnav_base::chi2::chi2_quantile;

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GatingConfig {
    pub enabled: bool,
    /// Confidence of the chi-square gate, e.g. 0.99.
    pub confidence: f64,
    /// Divide gamma by the robust scale of the recent innovations (see the module doc); false is
    /// the seed's fixed test.
    pub adaptive: bool,
}

impl Default for GatingConfig {
    fn default() -> Self {
        Self { enabled: true, confidence: 0.99, adaptive: true }
    }
}

/// Decisions (per sensor) whose gammas make the adaptive scale.
pub const ADAPT_WINDOW: usize = 30;
/// Fewer decisions than this: no adaptive scale yet (s = 1).
pub const ADAPT_MIN: usize = 5;

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Sensor {
    Dvl,
    Usbl,
    /// LBL / single-beacon range.
    Range,
}

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Decision {
    pub t_s: f64,
    pub sensor: Sensor,
    pub gamma: f64,
    pub threshold: f64,
    /// Covariance scale applied (1 when normal or gating disabled).
    pub kappa: f64,
    pub abnormal: bool,
    /// Robust innovation scale gamma was divided by (1: none).
    #[serde(default = "one")]
    pub scale: f64,
}

fn one() -> f64 {
    1.0
}

#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GateLog {
    pub decisions: Vec<Decision>,
    /// Observations dropped because their valid time was older than the smoother window.
    pub dropped_too_old: usize,
}

impl GateLog {
    pub fn count(&self, sensor: Sensor, abnormal: bool) -> usize {
        self.decisions.iter().filter(|d| d.sensor == sensor && d.abnormal == abnormal).count()
    }

    /// The adaptive scale for the next decision of `sensor` with residual dimension `dim`.
    pub fn adaptive_scale(&self, sensor: Sensor, dim: usize) -> Result<f64, FgoError> {
        let mut g: Vec<f64> = self.decisions.iter().rev().filter(|d| d.sensor == sensor).take(ADAPT_WINDOW).map(|d| d.gamma).collect();
        if g.len() < ADAPT_MIN {
            return Ok(1.0);
        }
        g.sort_by(|a, b| a.total_cmp(b));
        let n = g.len();
        let med = if n % 2 == 1 { g[n / 2] } else { 0.5 * (g[n / 2 - 1] + g[n / 2]) };
        Ok((med / chi2_quantile(dim, 0.5)?).max(1.0))
    }
}

/// Run the test on residual `r` with measurement Jacobian `h` (dim x 15), node covariance `p`
/// and observation covariance `r_cov`.
pub fn gate(
    t_s: f64,
    sensor: Sensor,
    r: &DVector<f64>,
    h: &DMatrix<f64>,
    p: &Matrix15,
    r_cov: &DMatrix<f64>,
    cfg: &GatingConfig,
) -> Result<Decision, FgoError> {
    gate_scaled(t_s, sensor, r, h, p, r_cov, cfg, 1.0)
}

/// [`gate`] with gamma divided by `scale` (>= 1; see [`GateLog::adaptive_scale`]).
#[allow(clippy::too_many_arguments)]
pub fn gate_scaled(
    t_s: f64,
    sensor: Sensor,
    r: &DVector<f64>,
    h: &DMatrix<f64>,
    p: &Matrix15,
    r_cov: &DMatrix<f64>,
    cfg: &GatingConfig,
    scale: f64,
) -> Result<Decision, FgoError> {
    if !(scale >= 1.0 && scale.is_finite()) {
        return Err(FgoError::Numeric(format!("gate scale {scale} at t={t_s} must be >= 1")));
    }
    let dim = r.len();
    if !r.iter().all(|x| x.is_finite()) {
        return Err(FgoError::Input(format!("{sensor:?} residual at t={t_s} is not finite")));
    }
    let p_dyn = DMatrix::from_iterator(15, 15, p.iter().copied());
    let s = h * p_dyn * h.transpose() + r_cov;
    let s = (&s + s.transpose()) * 0.5;
    let chol = s
        .cholesky()
        .ok_or_else(|| FgoError::Numeric(format!("innovation covariance of {sensor:?} at t={t_s} is not positive definite")))?;
    let gamma = r.dot(&chol.solve(r));
    let threshold = match (dim, cfg.confidence) {
        // the common case, cached: chi2(3) at 0.99
        (3, c) if c == 0.99 => 11.344_866_730_144_373,
        _ => chi2_quantile(dim, cfg.confidence)?,
    };
    let abnormal = cfg.enabled && gamma / scale > threshold;
    let kappa = if abnormal { gamma / (scale * threshold) } else { 1.0 };
    Ok(Decision { t_s, sensor, gamma, threshold, kappa, abnormal, scale })
}

/// Batch re-decision of the USBL fixes (adaptive mode): the smoother's real-time inflations are
/// undone and each fix is tested on its *posterior* residual, i.e. against the solved
/// trajectory that all the other observations shape, not against a prediction from the past:
/// `gamma = r^T R^-1 r` at the batch optimum, divided by the robust scale `s = max(1,
/// median(gamma) / median(chi2(3)))` of all fixes; abnormal fixes get `kappa = gamma / (s
/// threshold)` and the batch is solved again, once (see the comment in the body).
/// Returns the LM report of both solves together (the final problem's cost at the given nodes
/// and at the optimum) and the number of fixes inflated.
pub fn robust_batch(
    nodes: &mut [crate::state::NodeState],
    factors: &mut [crate::factors::Factor],
    cfg: &GatingConfig,
    opts: &crate::solver::LmOptions,
) -> Result<(crate::solver::LmReport, usize), FgoError> {
    use crate::factors::Factor;
    let thr = chi2_quantile(3, cfg.confidence)?;
    let median3 = chi2_quantile(3, 0.5)?;
    for f in factors.iter_mut() {
        if let Factor::Usbl(u) = f {
            u.noise = u.noise.scaled(1.0 / u.kappa);
            u.kappa = 1.0;
        }
    }
    let nominal: Vec<Option<DMatrix<f64>>> =
        factors.iter().map(|f| if let Factor::Usbl(u) = f { Some(u.noise.whitener.clone()) } else { None }).collect();
    let initial = nodes.to_vec();
    let mut report = crate::solver::solve_lm(nodes, factors, opts)?;
    // One decision round. Iterating (re-test at the re-solved optimum) runs away on KITTI: an
    // inflated fix lets the trajectory move off it, its residual grows, more fixes are inflated
    // (clean run: largest gamma 127 -> 456 -> 1524 -> 2268 over four rounds; 3.75 m held-out
    // RMSE instead of 2.02 m with one round).
    let mut gammas = Vec::new();
    for (f, w) in factors.iter().zip(&nominal) {
        if let (Factor::Usbl(u), Some(w)) = (f, w) {
            let x = nodes.get(u.node).ok_or_else(|| FgoError::Input(format!("USBL factor on missing node {}", u.node)))?;
            gammas.push((w * u.evaluate(x).residual).norm_squared());
        }
    }
    if gammas.is_empty() {
        return Ok((report, 0));
    }
    let mut sorted = gammas.clone();
    sorted.sort_by(|a, b| a.total_cmp(b));
    let n = sorted.len();
    let med = if n % 2 == 1 { sorted[n / 2] } else { 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]) };
    let s = (med / median3).max(1.0);
    let kappas: Vec<f64> = gammas.iter().map(|g| if g / s > thr { g / (s * thr) } else { 1.0 }).collect();
    let inflated = kappas.iter().filter(|k| **k > 1.0).count();
    if inflated > 0 {
        let mut it = kappas.iter();
        for f in factors.iter_mut() {
            if let Factor::Usbl(u) = f {
                let k = *it.next().ok_or_else(|| FgoError::Numeric("fix count changed".into()))?;
                u.noise = u.noise.scaled(k);
                u.kappa = k;
            }
        }
        let second = crate::solver::solve_lm(nodes, factors, opts)?;
        // one report for both solves: the final problem's cost at the batch's initial values,
        // and at its optimum
        report = crate::solver::LmReport {
            iterations: report.iterations + second.iterations,
            initial_cost: crate::solver::total_cost(&initial, factors)?,
            final_cost: second.final_cost,
            converged: second.converged,
        };
    }
    Ok((report, inflated))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gate_can_fail_and_pass() {
        let h = DMatrix::zeros(3, 15);
        let p = Matrix15::identity();
        let rc = DMatrix::identity(3, 3);
        let cfg = GatingConfig::default();
        let ok = gate(0.0, Sensor::Usbl, &DVector::from_vec(vec![0.5, -0.5, 1.0]), &h, &p, &rc, &cfg).unwrap();
        assert!(!ok.abnormal && ok.kappa == 1.0);
        let bad = gate(0.0, Sensor::Usbl, &DVector::from_vec(vec![20.0, 0.0, 0.0]), &h, &p, &rc, &cfg).unwrap();
        assert!(bad.abnormal && (bad.kappa - 400.0 / bad.threshold).abs() < 1e-9);
        let off = gate(0.0, Sensor::Usbl, &DVector::from_vec(vec![20.0, 0.0, 0.0]), &h, &p, &rc, &GatingConfig { enabled: false, ..cfg })
            .unwrap();
        assert!(!off.abnormal && off.kappa == 1.0);
        assert!(gate(0.0, Sensor::Dvl, &DVector::from_vec(vec![f64::NAN, 0.0, 0.0]), &h, &p, &rc, &cfg).is_err());
        let not_pd = -DMatrix::identity(3, 3);
        assert!(gate(0.0, Sensor::Dvl, &DVector::from_vec(vec![1.0, 0.0, 0.0]), &h, &Matrix15::zeros(), &not_pd, &cfg).is_err());
    }
}
