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
    /// How far the real field's AoP departs from the single-scattering e-vector, as
    /// `departure * DoLP` (rad): each unit's AoP 1-sigma gets `model_aop_dolp_rad / DoLP` in
    /// quadrature. Multiple scattering, the sky's own polarization and particle polarization
    /// add a polarized part whose orientation is not the single-scattering one; its share of
    /// the polarized light grows as DoLP falls, so the AoP departure scales as 1 / DoLP. 0
    /// trusts the single-scattering model (the synthetic tests). Measured against OSOAA
    /// (docs/PERFORMANCE.md, "The compass in an independent light field").
    pub model_aop_dolp_rad: f32,
    /// The azimuth fit's ([`solve_azimuth`]) 1-sigma is inflated by `(chi2/dof)^(power/2)`
    /// when the residual chi-square per degree of freedom exceeds 1: 1 treats the residuals as
    /// independent unit errors; the real field's leftover departure is mirror-symmetric about
    /// the solar plane and cancels in the azimuth across a ring, so the full inflation
    /// overstates the error (2-6x the RMSE on the OSOAA fields). The head's 0.5 keeps >= 99 %
    /// of fixes within 2 sigma on every OSOAA case and the map in the loop's recognition
    /// precision above its bound (0.80 with 1); chosen on those fields, so not an independent
    /// check of the sigma (docs/PERFORMANCE.md, "The compass in an independent light field").
    pub chi2_inflation_power: f32,
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
            model_aop_dolp_rad: 0.0,
            chi2_inflation_power: 1.0,
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

/// AoP shift (rad) of unit `o` caused by the partial polarization of the refracted sunbeam
/// (Fresnel transmission, T_p > T_s), relative to the pure-Rayleigh e-vector `d x s`.
/// `s`: toward the refracted sun (body), `up`: toward the sky (body).
pub fn fresnel_aop_shift(view_body: &Vector3<f32>, s: &Vector3<f32>, up: &Vector3<f32>, n_water: f32) -> Option<f32> {
    let k_t = -s; // propagation in water
    let down = -up;
    let cos_t = k_t.dot(&down);
    if !(cos_t > 0.0) {
        return None;
    }
    let sin_t2 = (1.0 - cos_t * cos_t).max(0.0);
    let sin_i2 = (n_water * n_water * sin_t2).min(1.0);
    let cos_i = libm::sqrtf(1.0 - sin_i2);
    let rs = (cos_i - n_water * cos_t) / (cos_i + n_water * cos_t);
    let rp = (n_water * cos_i - cos_t) / (n_water * cos_i + cos_t);
    let (ts, tp) = (1.0 - rs * rs, 1.0 - rp * rp);
    let sv = k_t.cross(&down);
    let sn = sv.norm();
    if !(sn > 1e-4) {
        return Some(0.0); // sun at the zenith: the beam is unpolarized
    }
    let s_hat = sv / sn;
    let p_hat = s_hat.cross(&k_t);
    let d = *view_body;
    // Projected field components (P = I - d d^T), then Stokes in a frame (a, b) on the unit.
    let ps = s_hat - d * d.dot(&s_hat);
    let pp = p_hat - d * d.dot(&p_hat);
    let e0 = d.cross(s);
    let e0n = e0.norm();
    if !(e0n > 1e-4) {
        return None;
    }
    let a = e0 / e0n; // frame axis along the pure-Rayleigh e-vector
    let b = d.cross(&a);
    let (sa, sb, pa, pb) = (ps.dot(&a), ps.dot(&b), pp.dot(&a), pp.dot(&b));
    let s1 = ts * (sa * sa - sb * sb) + tp * (pa * pa - pb * pb);
    let s2 = 2.0 * (ts * sa * sb + tp * pa * pb);
    Some(0.5 * libm::atan2f(s2, s1))
}

/// Rotates an e-vector by `-delta` about the viewing direction.
pub fn rotate_back(o: &UnitObservation, delta: f32) -> Vector3<f32> {
    let (sd, cd) = crate::ephemeris::phase::sincos_rad(delta);
    o.e_body * cd - o.view_body.cross(&o.e_body) * sd
}

/// Median of |x| over a small slice (no heap; at most [`super::MAX_UNITS`] values used).
fn median_abs(x: &[f32]) -> f32 {
    let mut buf = [0.0f32; super::MAX_UNITS];
    let n = x.len().min(super::MAX_UNITS);
    for (b, v) in buf.iter_mut().zip(x) {
        *b = v.abs();
    }
    let sl = buf.get_mut(..n).unwrap_or(&mut []);
    sl.sort_unstable_by(f32::total_cmp);
    match n {
        0 => 0.0,
        _ if n % 2 == 1 => sl.get(n / 2).copied().unwrap_or(0.0),
        _ => 0.5 * (sl.get(n / 2 - 1).copied().unwrap_or(0.0) + sl.get(n / 2).copied().unwrap_or(0.0)),
    }
}

/// AoP 1-sigma of a unit: the noise model (floored) and the model departure, in quadrature.
pub fn aop_sigma(o: &UnitObservation, cfg: &SolverConfig) -> f32 {
    let noise = o.sigma_aop_rad.max(cfg.sigma_aop_floor_rad);
    let model = cfg.model_aop_dolp_rad / o.dolp.max(1e-3);
    libm::sqrtf(noise * noise + model * model)
}

/// The sun's azimuth with its refracted elevation known (from the ephemeris and Snell).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AzimuthFit {
    /// Unit vector toward the refracted sun, body FRD.
    pub s_body: Vector3<f32>,
    /// Sun azimuth relative to the level frame's forward axis (body x projected), clockwise
    /// seen from above (rad), and its 1-sigma (inflated by the residual chi-square).
    pub rel_azimuth_rad: f32,
    pub sigma_rel_azimuth_rad: f32,
    pub chi2_dof: f32,
    pub units_used: u8,
}

/// One-parameter fit of the sun azimuth on the cone of the known refracted elevation
/// `water_elevation_rad`, starting from the unconstrained sun `s_init` (body). Why: the
/// departure of the real field from single scattering pulls the measured sun's elevation (by
/// degrees at a low sun), and in the two-parameter fit that pull leaks into the azimuth; with
/// the elevation known, only the azimuth is fitted, with one more residual degree of freedom
/// to check the model. Same weights, Huber IRLS and Fresnel correction as [`solve`]. With
/// `departure` (a table and the sun's zenith in air, rad) each unit's e-vector is also turned
/// back by the real field's expected departure at its view ([`super::departure`]), evaluated
/// at the current azimuth.
pub fn solve_azimuth(
    obs: &[UnitObservation],
    up_body: &Vector3<f32>,
    n_water: Option<f32>,
    cfg: &SolverConfig,
    water_elevation_rad: f32,
    s_init: &Vector3<f32>,
    departure: Option<(&super::departure::AopDeparture, f32)>,
) -> Result<AzimuthFit, NoFix> {
    let n = obs.len();
    if n > super::MAX_UNITS || n < cfg.min_units.max(2) as usize {
        return Err(NoFix::TooFewUnits);
    }
    // Level frame: forward = body x projected on the horizontal, right = down x forward.
    let down = -up_body;
    let xb = Vector3::new(1.0, 0.0, 0.0);
    let fwd = xb - down * xb.dot(&down);
    if !(fwd.norm() > 0.05) {
        return Err(NoFix::TiltInvalid);
    }
    let fwd = fwd.normalize();
    let right = down.cross(&fwd);
    let (se, ce) = crate::ephemeris::phase::sincos_rad(water_elevation_rad);
    let sun_at = |psi: f32| {
        let (sp, cp) = crate::ephemeris::phase::sincos_rad(psi);
        (fwd * cp + right * sp) * ce + up_body * se
    };
    let mut psi = libm::atan2f(s_init.dot(&right), s_init.dot(&fwd));
    let sigma_r =
        |o: &UnitObservation, s: &Vector3<f32>| aop_sigma(o, cfg) * o.view_body.cross(&o.e_body).dot(s).abs().max(cfg.lever_floor);
    let mut e = [Vector3::zeros(); super::MAX_UNITS];
    let mut r = [0.0f32; super::MAX_UNITS];
    let mut info = 0.0f32;
    let mut chi2 = 0.0f32;
    for it in 0..(cfg.irls_iterations as usize + 4) {
        let s = sun_at(psi);
        let (sp, cp) = crate::ephemeris::phase::sincos_rad(psi);
        let ds = (right * cp - fwd * sp) * ce;
        for (ei, o) in e.iter_mut().zip(obs) {
            let mut delta = n_water.and_then(|nw| fresnel_aop_shift(&o.view_body, &s, up_body, nw)).unwrap_or(0.0);
            if let Some((table, sun_zenith_rad)) = departure {
                let view_zenith = libm::acosf(o.view_body.dot(up_body).clamp(-1.0, 1.0));
                delta += table.at(sun_zenith_rad, view_zenith, rel_azimuth(&o.view_body, &s, up_body));
            }
            *ei = rotate_back(o, delta);
        }
        for ((ri, ei), o) in r.iter_mut().zip(e.iter()).zip(obs) {
            *ri = ei.dot(&s) / sigma_r(o, &s);
        }
        let scale = (1.482_6 * median_abs(r.get(..n).unwrap_or(&[]))).max(1.0);
        let (mut jtj, mut jtr) = (0.0f32, 0.0f32);
        chi2 = 0.0;
        for ((ei, ri), o) in e.iter().zip(r.iter()).zip(obs) {
            let sr = sigma_r(o, &s);
            let j = ei.dot(&ds) / sr;
            // Plain least squares on the first pass, Huber weights after.
            let u = ri.abs() / scale;
            let w = if it == 0 || u <= cfg.huber_k { 1.0 } else { cfg.huber_k / u };
            jtj += w * j * j;
            jtr += w * j * ri;
            chi2 += ri * ri;
        }
        if !(jtj > 0.0 && jtj.is_finite()) {
            return Err(NoFix::Degenerate);
        }
        info = jtj;
        let step = (-jtr / jtj).clamp(-0.3, 0.3);
        psi += step;
        if step.abs() < 1e-6 {
            break;
        }
    }
    let dof = (n as f32 - 1.0).max(1.0);
    let chi2_dof = chi2 / dof;
    if !(chi2_dof <= cfg.max_chi2_dof) {
        return Err(NoFix::Inconsistent);
    }
    let sigma = libm::sqrtf(libm::powf(chi2_dof.max(1.0), cfg.chi2_inflation_power) / info);
    let s = sun_at(psi);
    if !(sigma.is_finite() && psi.is_finite()) {
        return Err(NoFix::Degenerate);
    }
    let psi = libm::atan2f(libm::sinf(psi), libm::cosf(psi));
    Ok(AzimuthFit { s_body: s, rel_azimuth_rad: psi, sigma_rel_azimuth_rad: sigma, chi2_dof, units_used: n as u8 })
}

/// Robust weighted sun vector from the good units. `up_body` is a unit vector toward the sky.
/// With `n_water`, the e-vectors are corrected for the Fresnel polarization of the refracted
/// sunbeam (computed from the current sun estimate and the vertical; flat-surface model).
pub fn solve(obs: &[UnitObservation], up_body: &Vector3<f32>, n_water: Option<f32>, cfg: &SolverConfig) -> Result<SunVector, NoFix> {
    solve_with_departure(obs, up_body, n_water, cfg, None)
}

/// Relative azimuth `A_sun - A_look` (rad, clockwise seen from above) of a look direction and
/// the sun, both body vectors, `up` toward the sky.
pub fn rel_azimuth(look: &Vector3<f32>, sun: &Vector3<f32>, up: &Vector3<f32>) -> f32 {
    let lh = look - up * look.dot(up);
    let sh = sun - up * sun.dot(up);
    libm::atan2f(-lh.cross(&sh).dot(up), lh.dot(&sh))
}

/// [`solve`] with the real field's expected AoP departure (a table and the sun's zenith in air,
/// rad) subtracted from each unit at the current sun estimate, as [`solve_azimuth`] does.
pub fn solve_with_departure(
    obs: &[UnitObservation],
    up_body: &Vector3<f32>,
    n_water: Option<f32>,
    cfg: &SolverConfig,
    departure: Option<(&super::departure::AopDeparture, f32)>,
) -> Result<SunVector, NoFix> {
    let n = obs.len();
    if n > super::MAX_UNITS {
        return Err(NoFix::BadInput);
    }
    if n < cfg.min_units.max(2) as usize {
        return Err(NoFix::TooFewUnits);
    }
    let sigma_aop = |o: &UnitObservation| aop_sigma(o, cfg);
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
    if s.dot(up_body) < 0.0 {
        s = -s;
    }
    let sigma_r = |o: &UnitObservation, s: &Vector3<f32>| sigma_aop(o) * o.view_body.cross(&o.e_body).dot(s).abs().max(cfg.lever_floor);
    let mut e = [Vector3::zeros(); super::MAX_UNITS];
    let mut r = [0.0f32; super::MAX_UNITS];
    let correct = |e: &mut [Vector3<f32>; super::MAX_UNITS], s: &Vector3<f32>| {
        for (ei, o) in e.iter_mut().zip(obs) {
            let mut delta = n_water.and_then(|nw| fresnel_aop_shift(&o.view_body, s, up_body, nw)).unwrap_or(0.0);
            if let Some((table, sun_zenith_rad)) = departure {
                let view_zenith = libm::acosf(o.view_body.dot(up_body).clamp(-1.0, 1.0));
                delta += table.at(sun_zenith_rad, view_zenith, rel_azimuth(&o.view_body, s, up_body));
            }
            *ei = rotate_back(o, delta);
        }
    };
    // Normalised residuals and their robust scale (>= 1: the noise model is a floor).
    let residuals = |e: &[Vector3<f32>; super::MAX_UNITS], r: &mut [f32; super::MAX_UNITS], s: &Vector3<f32>| -> f32 {
        for ((ri, ei), o) in r.iter_mut().zip(e.iter()).zip(obs) {
            *ri = ei.dot(s) / sigma_r(o, s);
        }
        (1.482_6 * median_abs(r.get(..n).unwrap_or(&[]))).max(1.0)
    };
    for _ in 0..cfg.irls_iterations {
        correct(&mut e, &s);
        let scale = residuals(&e, &mut r, &s);
        m = Matrix3::zeros();
        trace = 0.0;
        for ((ei, ri), o) in e.iter().zip(r.iter()).zip(obs) {
            let sr = sigma_r(o, &s);
            let u = ri.abs() / scale;
            let huber = if u <= cfg.huber_k { 1.0 } else { cfg.huber_k / u };
            let w = huber / (sr * sr);
            m += ei * ei.transpose() * w;
            trace += w;
        }
        let (s_new, ev_new) = smallest_eigen(m)?;
        s = if s_new.dot(up_body) < 0.0 { -s_new } else { s_new };
        ev = ev_new;
    }
    if ev[1] < cfg.min_eigen_gap * trace {
        return Err(NoFix::Degenerate);
    }
    // Outliers (far beyond the robust scale) are dropped and the sun re-solved from the inliers
    // with plain inverse-variance weights; then chi-square and the Fisher information.
    correct(&mut e, &s);
    let scale = residuals(&e, &mut r, &s);
    let mut inlier = [false; super::MAX_UNITS];
    let mut outliers = 0u8;
    for (ok, ri) in inlier.iter_mut().zip(r.iter()).take(n) {
        *ok = ri.abs() <= cfg.outlier_sigma * scale;
        if !*ok {
            outliers = outliers.saturating_add(1);
        }
    }
    if outliers > 0 && n - (outliers as usize) >= cfg.min_units.max(2) as usize {
        m = Matrix3::zeros();
        for ((ei, ok), o) in e.iter().zip(inlier.iter()).zip(obs) {
            if *ok {
                let sr = sigma_r(o, &s);
                m += ei * ei.transpose() / (sr * sr);
            }
        }
        let (s_new, _) = smallest_eigen(m)?;
        s = if s_new.dot(up_body) < 0.0 { -s_new } else { s_new };
        correct(&mut e, &s);
        residuals(&e, &mut r, &s);
    }
    let mut info = Matrix3::zeros();
    let (mut chi2, mut used) = (0.0f32, 0u8);
    for (((ei, ri), ok), o) in e.iter().zip(r.iter()).zip(inlier.iter()).zip(obs) {
        if !*ok {
            continue;
        }
        let sr = sigma_r(o, &s);
        used = used.saturating_add(1);
        chi2 += ri * ri;
        info += ei * ei.transpose() / (sr * sr);
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
