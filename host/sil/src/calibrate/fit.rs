//! The calibration estimators: pure maths from a session's [`Recording`] (and the rig's
//! [`Procedure`] and [`Site`]) to the records, and the recovery errors against a mis-built
//! head's truth. Nothing here runs a head; `crate::calibrate` records the sessions and writes
//! the records.
//!
//! - IMU (six-position static + rotations): each static position gives the mean specific force
//!   `raw = K f_body + b` with `f_body` known from the rig's attitude; each turn gives the mean
//!   rate `raw = K_g w_body + b_g`. Both are linear least squares (per output axis). The body
//!   from raw correction `K^-1` is factored `R U` (QR; `R` the mounting rotation, `U` upper
//!   triangular with a positive diagonal), the form of `ImuCalibration`; the gyro's `U_g` is
//!   `R^T K_g^-1` (its lower triangle, zero up to noise, is dropped).
//! - Polarization (sky stops): per sample the sky model gives the angle of polarization `chi` of
//!   the light each unit sees (it depends on the geometry only: the water's turbidity changes
//!   the intensity and the degree of polarization, not the angle). Channel `k` reads
//!   `o_k + g_k I + P (B_k cos 2chi + C_k sin 2chi)` with the intensity `I` and polarized
//!   intensity `P` of each sample unknown: alternating least squares over the samples' (I, P)
//!   and the channels' (o, g, B, C); then `th_k = atan2(C_k, B_k) / 2`, `eta_k = |(B, C)| / g_k`.
//!   Not observable from the sky, and harmless to the angle: a common scale of the gains (set to
//!   a mean gain of nominal), of the polarized part (set to the best channel at the nominal
//!   extinction ratio), an offset along the gains (set to a mean offset of nominal; a dark
//!   frame would find it) and a part of the gains added to the polarized responses (`B - a g`,
//!   `C - b g`: which response is "unpolarized" needs the DoLP, which the sky model does not
//!   know without the water; set so that the channels' extinction ratios come out as nearly
//!   equal as they can, [`circle_centre`]). Each moves only S0 and the DoLP, not
//!   the angle, so the fitted polarizer angles and extinction ratios are not the unit's own
//!   but give its angle of polarization ([`recovery_errors`] measures that).

use anyhow::{Context, Result, bail};
use nalgebra::{Matrix2, Matrix3, Matrix4, Rotation3, UnitQuaternion, Vector2, Vector3, Vector4};
use serde::Serialize;
use subnav_base::sky::{self, Water};
use subnav_base::trajectory::Trajectory;
use subnav_core::head;
use subnav_wire::{ImuCalibration, PolarizationCalibration, Record};

use super::{Phase, PhaseKind, Procedure, Recording, Site};
use crate::scenario::Scenario;

/// Least squares `A x = b` by the normal equations (small, well-conditioned systems).
fn lsq4(rows: &[(Vector4<f64>, f64)]) -> Option<Vector4<f64>> {
    let (mut ata, mut atb) = (Matrix4::zeros(), Vector4::zeros());
    for (a, b) in rows {
        ata += a * a.transpose();
        atb += a * *b;
    }
    ata.cholesky().map(|c| c.solve(&atb))
}

/// `raw = K x + b` per output axis from `(x, mean raw)` pairs: `(K, b)`.
fn affine_fit(pairs: &[(Vector3<f64>, Vector3<f64>)]) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let mut k = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for r in 0..3 {
        let rows: Vec<_> = pairs.iter().map(|(x, y)| (Vector4::new(x.x, x.y, x.z, 1.0), y[r])).collect();
        let sol = lsq4(&rows)?;
        k.set_row(r, &sol.fixed_rows::<3>(0).transpose());
        b[r] = sol[3];
    }
    Some((k, b))
}

fn upper(m: &Matrix3<f64>) -> [f32; 6] {
    [m[(0, 0)], m[(0, 1)], m[(0, 2)], m[(1, 1)], m[(1, 2)], m[(2, 2)]].map(|v| v as f32)
}

fn mean3(v: impl Iterator<Item = [f32; 3]>) -> Option<Vector3<f64>> {
    let (mut s, mut n) = (Vector3::zeros(), 0usize);
    for x in v {
        s += Vector3::new(f64::from(x[0]), f64::from(x[1]), f64::from(x[2]));
        n += 1;
    }
    (n >= 50).then(|| s / n as f64)
}

/// The IMU calibration from the static positions and turns of `proc`.
pub fn fit_imu(rec: &Recording, proc: &Procedure) -> Result<ImuCalibration> {
    imu_record(&[imu_affine(rec, proc)?])
}

/// One session's IMU estimate: `raw = K f + b` for the accelerometer and the gyro.
#[derive(Debug, Clone, Copy)]
pub struct ImuAffine {
    pub accel: (Matrix3<f64>, Vector3<f64>),
    pub gyro: (Matrix3<f64>, Vector3<f64>),
}

/// The session's IMU estimate from the static positions and turns of `proc`.
pub fn imu_affine(rec: &Recording, proc: &Procedure) -> Result<ImuAffine> {
    let (mut acc, mut gyro) = (Vec::new(), Vec::new());
    for (i, ph) in proc.phases.iter().enumerate() {
        let samples = || rec.imu.iter().filter(|s| ph.contains(s.t_us));
        match ph.kind {
            PhaseKind::Static { f_body_mps2 } => {
                let (Some(a), Some(g)) = (mean3(samples().map(|s| s.accel_mps2)), mean3(samples().map(|s| s.gyro_radps))) else {
                    bail!("IMU calibration: too few IMU samples in static position {i} ({:.1}..{:.1} s)", ph.t0_s, ph.t1_s);
                };
                acc.push((f_body_mps2, a));
                gyro.push((Vector3::zeros(), g));
            }
            PhaseKind::Turn { rate_body_radps } => {
                let Some(g) = mean3(samples().map(|s| s.gyro_radps)) else {
                    bail!("IMU calibration: too few IMU samples in turn {i} ({:.1}..{:.1} s)", ph.t0_s, ph.t1_s);
                };
                gyro.push((rate_body_radps, g));
            }
            _ => {}
        }
    }
    let accel = affine_fit(&acc).context("IMU calibration: the static positions do not determine the accelerometer")?;
    let gyro = affine_fit(&gyro).context("IMU calibration: the turns do not determine the gyro")?;
    Ok(ImuAffine { accel, gyro })
}

/// The IMU calibration of the mean of several sessions' estimates (power-ups: their turn-on
/// biases average out of the stored bias).
pub fn imu_record(sessions: &[ImuAffine]) -> Result<ImuCalibration> {
    if sessions.is_empty() {
        bail!("IMU calibration: no session");
    }
    let n = sessions.len() as f64;
    let ka: Matrix3<f64> = sessions.iter().map(|s| s.accel.0).sum::<Matrix3<f64>>() / n;
    let ba: Vector3<f64> = sessions.iter().map(|s| s.accel.1).sum::<Vector3<f64>>() / n;
    let kg: Matrix3<f64> = sessions.iter().map(|s| s.gyro.0).sum::<Matrix3<f64>>() / n;
    let bg: Vector3<f64> = sessions.iter().map(|s| s.gyro.1).sum::<Vector3<f64>>() / n;
    let ka_inv = ka.try_inverse().context("IMU calibration: singular accelerometer matrix")?;
    let kg_inv = kg.try_inverse().context("IMU calibration: singular gyro matrix")?;
    // K_a^-1 = R U: QR with the signs chosen so that U's diagonal is positive.
    let qr = ka_inv.qr();
    let (mut q, mut u) = (qr.q(), qr.r());
    for i in 0..3 {
        if u[(i, i)] < 0.0 {
            q.set_column(i, &(-q.column(i)));
            u.set_row(i, &(-u.row(i)));
        }
    }
    if q.determinant() < 0.0 {
        bail!("IMU calibration: the accelerometer's axes are left-handed (the sequence does not match the head)");
    }
    let r = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(q));
    let ug = q.transpose() * kg_inv;
    let f = |v: Vector3<f64>| [v.x as f32, v.y as f32, v.z as f32];
    Ok(ImuCalibration {
        gyro_bias_radps: f(bg),
        accel_bias_mps2: f(ba),
        gyro_correction: upper(&ug),
        accel_correction: upper(&u),
        body_from_imu_wxyz: [r.w, r.i, r.j, r.k].map(|v| v as f32),
    })
}

/// Angle of polarization (rad, in each unit's frame) the sky model predicts at `t_s` of the
/// sequence for every unit: the simulator's mean field at the site (a flat sea, a clear sky,
/// single scattering with the OSOAA radiative-transfer departure, `SeaField::calm_clear`), as a
/// real procedure would predict its site's sky with a radiative-transfer run. The SIL's rig
/// sky is that same field, so the calibration is checked in a sky it models exactly; its
/// error against a real sky is not measured here.
fn predicted_aop(site: &Site, traj: &Trajectory, t_s: f64) -> Vec<f64> {
    let sc = Scenario { start_utc_unix_us: site.start_utc_unix_us, lat_deg: site.lat_deg, lon_deg: site.lon_deg, ..Scenario::default() };
    let field = sky::SeaField::calm_clear(sc.sun_ned(t_s), Water::clear(), site.depth_m);
    let r_nb = traj.at(t_s).att_nb.to_rotation_matrix();
    let v3 = |x: [f32; 3]| Vector3::new(f64::from(x[0]), f64::from(x[1]), f64::from(x[2]));
    head::polarization_units()
        .iter()
        .map(|u| match u {
            Some(u) => {
                let d = r_nb * v3(u.view_body);
                let a = r_nb * v3(u.axis0_body);
                let s = sky::stokes(&sky::LightField::radiance(&field, d), &a, &d.cross(&a));
                0.5 * s[2].atan2(s[1])
            }
            None => 0.0,
        })
        .collect()
}

/// One unit's channels as the fit carries them: counts = o + g I + P (B cos 2chi + C sin 2chi).
#[derive(Debug, Clone, Copy)]
struct Channels {
    o: [f64; 4],
    g: [f64; 4],
    b: [f64; 4],
    c: [f64; 4],
}

fn eta_of(er: f64) -> f64 {
    (er - 1.0) / (er + 1.0)
}

/// The channels in closed form (the start of the least squares): the samples lie in a 3-D
/// affine subspace of the 4 channels (`o + span(g, B, C)`; its plane by principal components,
/// coordinates `z`). In it, `z - z0` is in the plane of `G` and `cos 2chi b + sin 2chi c`, so
/// with `u = G x b`, `v = G x c`: `cos 2chi (z.u - z0.u) + sin 2chi (z.v - z0.v) = 0`, linear
/// and homogeneous in `(u, v, z0.u, z0.v)`: the smallest eigenvector of its normal matrix.
/// Then `G ~ u x v`, `b = u x G / |G|^2`, `c = v x G / |G|^2`, up to the gauges of the module doc.
fn closed_form(samples: &[([f64; 4], f64)]) -> Option<Channels> {
    let n = samples.len() as f64;
    let mean: Vector4<f64> = samples.iter().map(|(y, _)| Vector4::from(*y)).sum::<Vector4<f64>>() / n;
    let cov: Matrix4<f64> = samples.iter().map(|(y, _)| (Vector4::from(*y) - mean) * (Vector4::from(*y) - mean).transpose()).sum();
    let eig = cov.symmetric_eigen();
    let mut order = [0usize, 1, 2, 3];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let q = nalgebra::Matrix4x3::from_columns(&[
        eig.eigenvectors.column(order[1]),
        eig.eigenvectors.column(order[2]),
        eig.eigenvectors.column(order[3]),
    ]);
    let mut m = nalgebra::SMatrix::<f64, 8, 8>::zeros();
    for (y, chi) in samples {
        let z = q.transpose() * (Vector4::from(*y) - mean);
        let (c, s) = ((2.0 * chi).cos(), (2.0 * chi).sin());
        let r = nalgebra::SVector::<f64, 8>::from_column_slice(&[c * z.x, c * z.y, c * z.z, s * z.x, s * z.y, s * z.z, -c, -s]);
        m += r * r.transpose();
    }
    let e = m.symmetric_eigen();
    let k = (0..8).min_by(|&a, &b| e.eigenvalues[a].total_cmp(&e.eigenvalues[b]))?;
    let x = e.eigenvectors.column(k);
    let (u, v) = (Vector3::new(x[0], x[1], x[2]), Vector3::new(x[3], x[4], x[5]));
    let gg = u.cross(&v);
    let g2 = gg.norm_squared();
    if !(g2 > 0.0) {
        return None;
    }
    let (b, c) = (u.cross(&gg) / g2, v.cross(&gg) / g2);
    let z0 = Matrix3::from_rows(&[u.transpose(), v.transpose(), gg.transpose()]).try_inverse()? * Vector3::new(x[6], x[7], 0.0);
    let (g, bb, cc, o) = (q * gg, q * b, q * c, mean + q * z0);
    let sign = if g.sum() < 0.0 { -1.0 } else { 1.0 };
    Some(Channels { o: o.into(), g: (g * sign).into(), b: bb.into(), c: cc.into() })
}

/// The centre of the circle nearest the points `(B_k, C_k) / g_k` (Kasa's algebraic fit: `x^2
/// + y^2 + D x + E y + F = 0` by least squares). For channels with equal extinction ratios the
/// points lie on a circle about the true zero of polarization, so removing the centre picks
/// the gauge (`B - a g`, `C - b g`, module doc) that gives the most nearly equal ratios.
fn circle_centre(ch: &Channels) -> (f64, f64) {
    let (mut m, mut v) = (Matrix3::zeros(), Vector3::zeros());
    for k in 0..4 {
        let (x, y) = (ch.b[k] / ch.g[k], ch.c[k] / ch.g[k]);
        let a = Vector3::new(x, y, 1.0);
        m += a * a.transpose();
        v -= a * (x * x + y * y);
    }
    match m.try_inverse() {
        Some(mi) => {
            let d = mi * v;
            (-0.5 * d[0], -0.5 * d[1])
        }
        None => (0.0, 0.0),
    }
}

/// A unit's calibration from `(counts, chi)` samples.
pub(super) fn fit_unit(unit: u8, samples: &[([f64; 4], f64)]) -> Result<PolarizationCalibration> {
    if samples.len() < 100 {
        bail!("polarization unit {unit}: {} samples in the sky spin, at least 100 needed", samples.len());
    }
    let nominal = head::polarization_units()
        .get(usize::from(unit))
        .copied()
        .flatten()
        .with_context(|| format!("polarization unit {unit} is not on this head"))?;
    let eta0 = eta_of(f64::from(head::POLARIZER_EXTINCTION_RATIO));
    let mut ch = Channels { o: [0.0; 4], g: [0.0; 4], b: [0.0; 4], c: [0.0; 4] };
    for (k, n) in nominal.channels.iter().enumerate() {
        let th = 2.0 * f64::from(n.polarizer_rad);
        ch.o[k] = f64::from(n.offset_counts);
        ch.g[k] = f64::from(n.gain);
        ch.b[k] = eta_of(f64::from(n.extinction_ratio)) * th.cos();
        ch.c[k] = eta_of(f64::from(n.extinction_ratio)) * th.sin();
    }
    if let Some(mut cf) = closed_form(samples) {
        // The polarizers' order: the one closest to the nominal axes (else every axis is 90
        // deg off and the fit's polarized intensity negative).
        let score: f64 = (0..4).map(|k| cf.b[k] * ch.b[k] + cf.c[k] * ch.c[k]).sum();
        if score < 0.0 {
            cf.b = cf.b.map(|v| -v);
            cf.c = cf.c.map(|v| -v);
        }
        ch = cf;
    }
    let trig: Vec<(f64, f64)> = samples.iter().map(|(_, chi)| ((2.0 * chi).cos(), (2.0 * chi).sin())).collect();
    let mut ip = vec![(0.0, 0.0); samples.len()];
    let mut rms = f64::INFINITY;
    for _ in 0..400 {
        // Each sample's intensity and polarized intensity, given the channels.
        for (((y, _), (cs, sn)), out) in samples.iter().zip(&trig).zip(ip.iter_mut()) {
            let (mut m, mut v) = (Matrix2::zeros(), Vector2::zeros());
            for k in 0..4 {
                let a = Vector2::new(ch.g[k], ch.b[k] * cs + ch.c[k] * sn);
                m += a * a.transpose();
                v += a * (y[k] - ch.o[k]);
            }
            if let Some(x) = m.try_inverse().map(|mi| mi * v) {
                *out = (x[0], x[1]);
            }
        }
        // Each channel, given the samples.
        let mut sq = 0.0;
        for k in 0..4 {
            let rows: Vec<_> = samples
                .iter()
                .zip(&trig)
                .zip(&ip)
                .map(|(((y, _), (cs, sn)), (i, p))| (Vector4::new(1.0, *i, p * cs, p * sn), y[k]))
                .collect();
            let x = lsq4(&rows).with_context(|| format!("polarization unit {unit}: the sky spin does not determine channel {k}"))?;
            (ch.o[k], ch.g[k], ch.b[k], ch.c[k]) = (x[0], x[1], x[2], x[3]);
            sq += rows.iter().map(|(a, y)| (a.dot(&x) - y).powi(2)).sum::<f64>();
        }
        // The gauges (module doc): the channels' polarized responses per gain as close to a
        // circle about the origin as they go (equal extinction ratios), mean gain nominal,
        // best channel at the nominal extinction ratio, mean offset nominal.
        let (alpha, beta) = circle_centre(&ch);
        for k in 0..4 {
            ch.b[k] -= alpha * ch.g[k];
            ch.c[k] -= beta * ch.g[k];
        }
        let lambda = ch.g.iter().sum::<f64>() / 4.0 / f64::from(head::POLARIZATION_GAIN_COUNTS);
        let eta_max = (0..4).map(|k| (ch.b[k].hypot(ch.c[k])) / ch.g[k]).fold(0.0, f64::max);
        if !(lambda > 0.0 && eta_max > 0.0) {
            bail!("polarization unit {unit}: the fit diverged (gain scale {lambda}, polarized part {eta_max})");
        }
        let mu = eta0 / eta_max;
        let shift = (ch.o.iter().sum::<f64>() / 4.0 - f64::from(head::POLARIZATION_OFFSET_COUNTS)) / (ch.g.iter().sum::<f64>() / 4.0);
        for k in 0..4 {
            ch.o[k] -= shift * ch.g[k];
            ch.g[k] /= lambda;
            ch.b[k] *= mu / lambda;
            ch.c[k] *= mu / lambda;
        }
        let new_rms = (sq / (4 * samples.len()) as f64).sqrt();
        let done = (rms - new_rms).abs() < 1e-9 * new_rms.max(1.0);
        rms = new_rms;
        if done {
            break;
        }
    }
    if !(rms < 50.0) {
        bail!("polarization unit {unit}: the channel model does not fit the sky spin (residual {rms:.1} counts RMS)");
    }
    let mut cal =
        PolarizationCalibration { unit, gain: [0.0; 4], offset_counts: [0.0; 4], polarizer_rad: [0.0; 4], extinction_ratio: [0.0; 4] };
    for k in 0..4 {
        let eta = ch.b[k].hypot(ch.c[k]) / ch.g[k];
        let mut th = 0.5 * ch.c[k].atan2(ch.b[k]);
        // The same axis as the nominal one, modulo 180 deg.
        let nominal_rad = f64::from(nominal.channels[k].polarizer_rad);
        th = nominal_rad + (th - nominal_rad + 0.5 * std::f64::consts::PI).rem_euclid(std::f64::consts::PI) - 0.5 * std::f64::consts::PI;
        cal.gain[k] = ch.g[k] as f32;
        cal.offset_counts[k] = ch.o[k] as f32;
        cal.polarizer_rad[k] = th as f32;
        cal.extinction_ratio[k] = ((1.0 + eta) / (1.0 - eta).max(1e-5)).min(1e5) as f32;
    }
    Ok(cal)
}

/// The calibration of every polarization unit from the sky stops of `proc` at `site`.
pub fn fit_polarization(rec: &Recording, proc: &Procedure, site: &Site) -> Result<Vec<PolarizationCalibration>> {
    let traj = Trajectory::rig(&proc.motion);
    let spin: Vec<&Phase> = proc.phases.iter().filter(|p| p.kind == PhaseKind::SkyHold).collect();
    let mut per_unit: Vec<Vec<([f64; 4], f64)>> = vec![Vec::new(); head::POLARIZATION_UNITS];
    let mut chi_at: Option<(u64, Vec<f64>)> = None;
    for s in rec.polarization.iter().filter(|s| spin.iter().any(|p| p.contains(s.t_us))) {
        if chi_at.as_ref().is_none_or(|(t, _)| *t != s.t_us) {
            chi_at = Some((s.t_us, predicted_aop(site, &traj, s.t_us as f64 * 1e-6)));
        }
        let (Some((_, chi)), Some(list)) = (chi_at.as_ref(), per_unit.get_mut(usize::from(s.unit))) else { continue };
        if let Some(&c) = chi.get(usize::from(s.unit)) {
            list.push((s.counts.map(f64::from), c));
        }
    }
    per_unit.iter().enumerate().map(|(u, samples)| fit_unit(u as u8, samples)).collect()
}

/// Every record the procedure computes from a session's recording.
pub fn fit_all(rec: &Recording, proc: &Procedure, site: &Site) -> Result<Vec<Record>> {
    if !rec.boot_seen && rec.imu.is_empty() {
        bail!("no head answered: the session's telemetry has no Boot message and no samples");
    }
    let mut out: Vec<Record> = fit_polarization(rec, proc, site)?.into_iter().map(Record::Polarization).collect();
    out.push(Record::Imu(fit_imu(rec, proc)?));
    Ok(out)
}

/// How far the records are from a mis-built head's true errors (evaluation only).
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct RecoveryErrors {
    pub max_gain_rel: f64,
    /// Largest angle-of-polarization error of a calibrated unit on its true channels (noise
    /// free, DoLP 0.3, every 5 deg of angle), deg.
    pub max_aop_deg: f64,
    /// Angle between the calibrated and the true mounting rotation, deg.
    pub mounting_deg: f64,
    pub max_accel_scale_rel: f64,
}

/// The channel model's counts (f64) for Stokes `s` (counts of S0, S1, S2).
pub fn model_counts(channels: &[subnav_core::compass::ChannelCal; 4], s: [f64; 3]) -> [f64; 4] {
    channels.map(|c| {
        let eta = eta_of(f64::from(c.extinction_ratio));
        let th = 2.0 * f64::from(c.polarizer_rad);
        f64::from(c.offset_counts) + f64::from(c.gain) * 0.5 * (s[0] + eta * (s[1] * th.cos() + s[2] * th.sin()))
    })
}

/// Largest angle-of-polarization error (deg) of calibration `p` applied to counts from the
/// true channels `truth` (S0 20,000 counts, DoLP 0.3, angles every 5 deg; no noise, no
/// rounding), with the compass's least-squares Stokes inverse in f64.
pub fn max_aop_error_deg(p: &PolarizationCalibration, truth: &[subnav_core::compass::ChannelCal; 4]) -> f64 {
    let rows: Vec<Vector3<f64>> = (0..4)
        .map(|k| {
            let eta = eta_of(f64::from(p.extinction_ratio[k]));
            let th = 2.0 * f64::from(p.polarizer_rad[k]);
            Vector3::new(0.5, 0.5 * eta * th.cos(), 0.5 * eta * th.sin()) * f64::from(p.gain[k])
        })
        .collect();
    let ata: Matrix3<f64> = rows.iter().map(|r| r * r.transpose()).sum();
    let Some(inv) = ata.try_inverse() else { return f64::INFINITY };
    (0..36)
        .map(|i| {
            let chi = (i as f64 * 5.0 - 90.0).to_radians();
            let y = model_counts(truth, [20_000.0, 6_000.0 * (2.0 * chi).cos(), 6_000.0 * (2.0 * chi).sin()]);
            let atb: Vector3<f64> = rows.iter().enumerate().map(|(k, r)| r * (y[k] - f64::from(p.offset_counts[k]))).sum();
            let est = inv * atb;
            let d = 0.5 * est[2].atan2(est[1]) - chi;
            ((d + 0.5 * std::f64::consts::PI).rem_euclid(std::f64::consts::PI) - 0.5 * std::f64::consts::PI).abs().to_degrees()
        })
        .fold(0.0, f64::max)
}

/// Compare `records` with the true build of `build_seed`. Gains are compared after removing the
/// unobservable common scale (module doc).
pub fn recovery_errors(records: &[Record], build_seed: u64) -> RecoveryErrors {
    let b = crate::manufacturing::BuildErrors::draw(build_seed);
    let mut e = RecoveryErrors::default();
    for r in records {
        match r {
            Record::Polarization(p) => {
                let Some(truth) = b.polarization.get(usize::from(p.unit)) else { continue };
                let mean_true = truth.iter().map(|c| f64::from(c.gain)).sum::<f64>() / 4.0;
                let mean_fit = p.gain.iter().map(|g| f64::from(*g)).sum::<f64>() / 4.0;
                for (k, t) in truth.iter().enumerate() {
                    let g = f64::from(p.gain[k]) / mean_fit;
                    e.max_gain_rel = e.max_gain_rel.max((g / (f64::from(t.gain) / mean_true) - 1.0).abs());
                }
                e.max_aop_deg = e.max_aop_deg.max(max_aop_error_deg(p, truth));
            }
            Record::Imu(c) => {
                let [w, x, y, z] = c.body_from_imu_wxyz.map(f64::from);
                let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
                let truth = UnitQuaternion::from_rotation_matrix(&b.imu_from_body.inverse());
                e.mounting_deg = q.angle_to(&truth).to_degrees();
                let u = c.accel_correction;
                for (k, d) in [u[0], u[3], u[5]].iter().enumerate() {
                    e.max_accel_scale_rel = e.max_accel_scale_rel.max((1.0 / f64::from(*d) / b.accel.n[(k, k)] - 1.0).abs());
                }
            }
            _ => {}
        }
    }
    e
}
