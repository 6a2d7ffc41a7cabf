//! The chi-square distribution for the host's gates: CDF by the regularised incomplete gamma
//! function and the quantile by bisection on it (exact to 1e-9 for the degrees of freedom the
//! gates use). The firmware's gates use the p = 0.999 table in `subnav_core::ukf::gate`,
//! which a test here checks against this quantile.

/// A chi-square quantile was asked for outside its domain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Chi2Error {
    pub dof: usize,
    pub p: f64,
}

impl core::fmt::Display for Chi2Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "chi-square quantile needs dof > 0 and 0 < p < 1 (dof {}, p {})", self.dof, self.p)
    }
}

impl core::error::Error for Chi2Error {}

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
pub fn chi2_quantile(dof: usize, p: f64) -> Result<f64, Chi2Error> {
    if dof == 0 || !(p > 0.0 && p < 1.0) {
        return Err(Chi2Error { dof, p });
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

/// The 99 % quantile for 2 degrees of freedom (9.2103): the gate of the 2-D position checks.
pub fn chi2_2_99() -> f64 {
    static Q: std::sync::OnceLock<f64> = std::sync::OnceLock::new();
    // -2 ln(0.01) in closed form if the bisection were ever refused (it is not: dof 2, p 0.99).
    *Q.get_or_init(|| chi2_quantile(2, 0.99).unwrap_or(9.210_340_371_976_184))
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
        // 2 dof has the closed form -2 ln(1 - p)
        assert!((chi2_2_99() - -2.0 * 0.01f64.ln()).abs() < 1e-9);
    }

    #[test]
    fn firmware_table_matches_the_quantile() {
        for dof in 1..=18 {
            let table = subnav_core::ukf::gate::chi2_999::<f64>(dof);
            let q = chi2_quantile(dof, 0.999).unwrap();
            assert!((table - q).abs() < 1e-3 * q, "dof {dof}: table {table}, quantile {q}");
        }
    }
}
