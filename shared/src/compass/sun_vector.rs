//! Sun vector from the units' e-vectors.
//!
//! Under single scattering the e-vector `e_i` of every viewing direction is perpendicular to the
//! scattering plane, which contains the (refracted) sun direction `s`: `e_i . s = 0`. The sun is
//! the eigenvector of `M = sum_i w_i e_i e_i^T` with the smallest eigenvalue.
//!
//! Weights: an AoP error `da` turns `e_i` about the viewing direction `d_i`, giving a residual
//! `da (d_i x e_i) . s`, so the residual 1-sigma is `sigma_r = sigma_aop * |(d_i x e_i) . s|`
//! (floored). `sigma_aop` comes from the noise model and falls as 1 / DoLP: this is the DoLP
//! weighting. The first solve uses `1 / sigma_aop^2`; then iteratively reweighted least squares
//! with a Huber weight on the normalised residual rejects outlier units (the spec's robust L1
//! start followed by least squares; Huber-IRLS is our equivalent choice).
//!
//! The sign is fixed by the sun being above the horizon (`s . up > 0`). The covariance of `s` on
//! its tangent plane is the inverse Fisher information `(T^T M T)^-1`, inflated by the residual
//! chi-square per degree of freedom when that exceeds 1 (model errors the noise model misses).

use nalgebra::{Matrix2, Matrix3, SymmetricEigen, Vector3};

use super::NoFix;
use super::unit::UnitObservation;

/// Settings of the robust solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolverConfig {
    /// Huber threshold on the normalised residual.
    pub huber_k: f32,
    /// IRLS iterations after the first solve.
    pub irls_iterations: u8,
    /// Floor of the AoP 1-sigma (rad): calibration residuals the noise model does not include.
    pub sigma_aop_floor_rad: f32,
    /// Floor of `|(d x e) . s|` (units looking nearly at the sun or the anti-sun).
    pub lever_floor: f32,
    /// Minimum of the middle eigenvalue over the trace: below it the geometry leaves the sun
    /// vector undetermined in a plane.
    pub min_eigen_gap: f32,
    /// A unit whose normalised residual exceeds this after IRLS counts as an outlier.
    pub outlier_sigma: f32,
    /// Minimum number of units (after outliers) for a fix.
    pub min_units: u8,
    /// Maximum residual chi-square per degree of freedom for a fix.
    pub max_chi2_dof: f32,
}

impl Default for SolverConfig {
    fn default() -> Self {
        SolverConfig {
            huber_k: 1.5,
            irls_iterations: 4,
            sigma_aop_floor_rad: 2e-4,
            lever_floor: 0.2,
            min_eigen_gap: 0.02,
            outlier_sigma: 5.0,
            min_units: 3,
            max_chi2_dof: 400.0,
        }
    }
}

/// Result of the sun-vector solve (body frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SunVector {
    /// Unit vector toward the (refracted) sun, body FRD.
    pub s_body: Vector3<f32>,
    /// Covariance of `s_body` on its tangent plane, in the basis `tangent`.
    pub cov_tangent: Matrix2<f32>,
    /// Tangent basis: [0] horizontal (toward increasing azimuth), [1] toward increasing elevation.
    pub tangent: [Vector3<f32>; 2],
    pub units_used: u8,
    pub outliers: u8,
    /// Residual chi-square per degree of freedom (1 when the noise model is right).
    pub chi2_dof: f32,
}

fn smallest_eigen(m: Matrix3<f32>) -> Result<(Vector3<f32>, [f32; 3]), NoFix> {
    let eig = SymmetricEigen::try_new(m, 1e-7, 64).ok_or(NoFix::NoConvergence)?;
    let mut idx = [0usize, 1, 2];
    idx.sort_unstable_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    let [i0, i1, i2] = idx;
    let v = eig.eigenvectors.column(i0).into_owned();
    Ok((v, [eig.eigenvalues[i0], eig.eigenvalues[i1], eig.eigenvalues[i2]]))
}

/// Robust weighted sun vector from the good units. `up_body` is a unit vector toward the sky.
pub fn solve(obs: &[UnitObservation], up_body: &Vector3<f32>, cfg: &SolverConfig) -> Result<SunVector, NoFix> {
    let n = obs.len();
    if n < cfg.min_units.max(2) as usize {
        return Err(NoFix::TooFewUnits);
    }
    let sigma_aop = |o: &UnitObservation| o.sigma_aop_rad.max(cfg.sigma_aop_floor_rad);
    // First solve: DoLP (inverse AoP variance) weights.
    let mut m = Matrix3::zeros();
    let mut trace = 0.0;
    for o in obs {
        let w = 1.0 / (sigma_aop(o) * sigma_aop(o));
        m += o.e_body * o.e_body.transpose() * w;
        trace += w;
    }
    let (mut s, mut ev) = smallest_eigen(m)?;
    if ev[1] < cfg.min_eigen_gap * trace {
        return Err(NoFix::Degenerate);
    }
    let sigma_r = |o: &UnitObservation, s: &Vector3<f32>| {
        sigma_aop(o) * o.view_body.cross(&o.e_body).dot(s).abs().max(cfg.lever_floor)
    };
    for _ in 0..cfg.irls_iterations {
        m = Matrix3::zeros();
        trace = 0.0;
        for o in obs {
            let sr = sigma_r(o, &s);
            let r = o.e_body.dot(&s) / sr;
            let huber = if r.abs() <= cfg.huber_k { 1.0 } else { cfg.huber_k / r.abs() };
            let w = huber / (sr * sr);
            m += o.e_body * o.e_body.transpose() * w;
            trace += w;
        }
        let (s_new, ev_new) = smallest_eigen(m)?;
        s = if s_new.dot(&s) < 0.0 { -s_new } else { s_new };
        ev = ev_new;
    }
    if ev[1] < cfg.min_eigen_gap * trace {
        return Err(NoFix::Degenerate);
    }
    if s.dot(up_body) < 0.0 {
        s = -s;
    }
    // Residuals, outliers, chi-square and the Fisher information with unit-Huber weights.
    let mut info = Matrix3::zeros();
    let (mut chi2, mut used, mut outliers) = (0.0f32, 0u8, 0u8);
    for o in obs {
        let sr = sigma_r(o, &s);
        let r = o.e_body.dot(&s) / sr;
        if r.abs() > cfg.outlier_sigma {
            outliers = outliers.saturating_add(1);
            continue;
        }
        used = used.saturating_add(1);
        chi2 += r * r;
        info += o.e_body * o.e_body.transpose() / (sr * sr);
    }
    if used < cfg.min_units.max(2) {
        return Err(NoFix::TooFewUnits);
    }
    let dof = (used as f32 - 2.0).max(1.0);
    let chi2_dof = chi2 / dof;
    if !(chi2_dof <= cfg.max_chi2_dof) {
        return Err(NoFix::Inconsistent);
    }
    // Tangent basis at s: horizontal (azimuth) and elevation directions.
    let h = s.cross(up_body);
    let hn = h.norm();
    if !(hn > 1e-4) {
        return Err(NoFix::SunNearZenith);
    }
    let t0 = h / hn;
    let t1 = t0.cross(&s);
    let j = Matrix2::new(t0.dot(&(info * t0)), t0.dot(&(info * t1)), t1.dot(&(info * t0)), t1.dot(&(info * t1)));
    let mut cov = j.try_inverse().ok_or(NoFix::Degenerate)?;
    cov *= chi2_dof.max(1.0);
    cov = (cov + cov.transpose()) * 0.5;
    if !(cov[(0, 0)] > 0.0 && cov[(1, 1)] > 0.0 && s.iter().all(|x| x.is_finite())) {
        return Err(NoFix::Degenerate);
    }
    Ok(SunVector { s_body: s, cov_tangent: cov, tangent: [t0, t1], units_used: used, outliers, chi2_dof })
}
