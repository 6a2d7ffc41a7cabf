//! Abnormal-observation test (spec B4): Mahalanobis distance of a DVL/USBL residual,
//! `gamma = r^T (H P H^T + R)^-1 r` with `P` the marginal covariance of the node before the
//! observation is added, against the chi-square quantile of the residual dimension. Normal: keep
//! `R`. Abnormal: `kappa = gamma / threshold` and the factor enters the graph with `kappa R`.
//! Every decision is recorded in a [`GateLog`] (countable, printable).

use nalgebra::{DMatrix, DVector};

use super::FgoError;
use super::solver::Matrix15;

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GatingConfig {
    pub enabled: bool,
    /// Confidence of the chi-square gate, e.g. 0.99.
    pub confidence: f64,
}

impl Default for GatingConfig {
    fn default() -> Self {
        Self { enabled: true, confidence: 0.99 }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Sensor {
    Dvl,
    Usbl,
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
}

/// Regularised lower incomplete gamma P(a, x) by its series (converges for all x > 0 used here).
fn gamma_p(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x > a + 1.0 {
        return 1.0 - gamma_q_cf(a, x);
    }
    let mut sum = 1.0 / a;
    let mut term = sum;
    let mut n = a;
    for _ in 0..500 {
        n += 1.0;
        term *= x / n;
        sum += term;
        if term.abs() < sum.abs() * 1e-16 {
            break;
        }
    }
    sum * (-x + a * x.ln() - ln_gamma(a)).exp()
}

/// Continued fraction for Q(a, x) (Lentz), x > a + 1.
fn gamma_q_cf(a: f64, x: f64) -> f64 {
    let tiny = 1e-300;
    let mut b = x + 1.0 - a;
    let mut c = 1.0 / tiny;
    let mut d = 1.0 / b;
    let mut h = d;
    for i in 1..500 {
        let an = -(i as f64) * (i as f64 - a);
        b += 2.0;
        d = an * d + b;
        if d.abs() < tiny {
            d = tiny;
        }
        c = b + an / c;
        if c.abs() < tiny {
            c = tiny;
        }
        d = 1.0 / d;
        let del = d * c;
        h *= del;
        if (del - 1.0).abs() < 1e-16 {
            break;
        }
    }
    (-x + a * x.ln() - ln_gamma(a)).exp() * h
}

/// ln Gamma for half-integers and integers (the chi-square case), exact recursions.
fn ln_gamma(a: f64) -> f64 {
    // a = k/2; Gamma(1) = 1, Gamma(1/2) = sqrt(pi), Gamma(a + 1) = a Gamma(a)
    let mut x = a;
    let mut acc = 0.0;
    while x > 1.0 + 1e-12 {
        x -= 1.0;
        acc += x.ln();
    }
    if (x - 0.5).abs() < 1e-12 { acc + 0.5 * std::f64::consts::PI.ln() } else { acc }
}

/// Chi-square CDF with `dof` degrees of freedom.
pub fn chi2_cdf(dof: usize, x: f64) -> f64 {
    gamma_p(dof as f64 / 2.0, x / 2.0)
}

/// Chi-square quantile by bisection on the CDF.
pub fn chi2_quantile(dof: usize, p: f64) -> Result<f64, FgoError> {
    if dof == 0 || !(p > 0.0 && p < 1.0) {
        return Err(FgoError::Input(format!("chi-square quantile needs dof > 0 and 0 < p < 1 (dof {dof}, p {p})")));
    }
    let (mut lo, mut hi) = (0.0, 1.0);
    while chi2_cdf(dof, hi) < p {
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if chi2_cdf(dof, mid) < p { lo = mid } else { hi = mid }
    }
    Ok(0.5 * (lo + hi))
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
    let abnormal = cfg.enabled && gamma > threshold;
    let kappa = if abnormal { gamma / threshold } else { 1.0 };
    Ok(Decision { t_s, sensor, gamma, threshold, kappa, abnormal })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chi2_quantiles_match_tables() {
        // published table values
        assert!((chi2_quantile(3, 0.99).unwrap() - 11.344_866_7).abs() < 1e-6);
        assert!((chi2_quantile(3, 0.99).unwrap() - 11.344_866_730_144_373).abs() < 1e-9);
        assert!((chi2_quantile(3, 0.95).unwrap() - 7.814_727_9).abs() < 1e-6);
        assert!((chi2_quantile(1, 0.95).unwrap() - 3.841_458_8).abs() < 1e-6);
        assert!((chi2_quantile(6, 0.999).unwrap() - 22.457_744).abs() < 1e-5);
        assert!(chi2_quantile(3, 1.0).is_err());
    }

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
