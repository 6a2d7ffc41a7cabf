//! `subnav calibrate`: record a calibration sequence from a (simulated) sensor head, estimate its
//! calibrations from the raw samples, write them to the head over the downlink (`SetRecord`),
//! read them back (`ReadRecord`) and check they are what was sent.
//!
//! The sequence ([`Procedure::standard`]) runs on a rig at a known place, time and depth: the
//! head held level, turned a full circle about each body axis at 30 deg/s, held still in six
//! positions (each axis down and up), then turned a full circle about the vertical under the
//! sky in 36 stops of 10 deg, held still 3 s at each (a turntable or a vehicle holding
//! heading), and twice more in 12 stops tilted 40 deg about x, then about y. Level, a unit
//! looking 15 deg up sees angles of polarization within about +-40 deg only, which leaves its
//! channels poorly determined (measured: 0.22 deg of angle error after the level turn alone,
//! 0.02 deg with the tilted turns; the tilts widen the range to about +-80 deg). The estimators use only what a real procedure has: the raw samples the head
//! streams, the rig's commanded motion, the sun from the ephemeris and the sky's polarization
//! model (`subnav_base::sky`), never the simulator's errors.
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

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use nalgebra::{Matrix2, Matrix3, Matrix4, Rotation3, UnitQuaternion, Vector2, Vector3, Vector4};
use serde::Serialize;
use subnav_base::sky::{self, Water};
use subnav_base::trajectory::{RigMotion, RigStep, Trajectory};
use subnav_core::head;
use subnav_wire::{
    Command, Downlink, ImuCalibration, ImuSample, PolarizationCalibration, PolarizationSample, RawSample, Record, RecordKey, Uplink,
};

use crate::chips::w25q::SharedFlash;
use crate::head::{Scenario, SimHead};

const DEG: f64 = std::f64::consts::PI / 180.0;
/// Depth of the rig, m.
pub const RIG_DEPTH_M: f64 = 3.0;
const TURN_RATE_RADPS: f64 = 30.0 * DEG;
/// The turns under the sky: stops, held still at each (so that when each channel was converted
/// within the head's 8-ms scan does not matter: measured, a 3 deg/s spin without stops left
/// 0.14 deg of angle error, 11 ms of scan lead moving it by 0.08 deg).
const SPIN_RATE_RADPS: f64 = 10.0 * DEG;
const SKY_STOPS: usize = 36;
const SKY_HOLD_S: f64 = 3.0;
const SKY_TILTED_STOPS: usize = 12;
const SKY_TILT_RAD: f64 = 40.0 * DEG;
const STATIC_S: f64 = 8.0;
/// Samples this close to a phase's ends are not used (the rig settling; the sensors' filters).
const SETTLE_S: f64 = 0.5;

/// What the rig does in one phase of the sequence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PhaseKind {
    /// Not used by the estimators (pre-roll).
    Idle,
    /// Held still: the body specific force is known.
    Static { f_body_mps2: Vector3<f64> },
    /// Turning at a known body rate.
    Turn { rate_body_radps: Vector3<f64> },
    /// Held still at one of the stops of the turn about the vertical under the sky.
    SkyHold,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Phase {
    pub t0_s: f64,
    pub t1_s: f64,
    pub kind: PhaseKind,
}

impl Phase {
    fn contains(&self, t_us: u64) -> bool {
        let t = t_us as f64 * 1e-6;
        t >= self.t0_s + SETTLE_S && t <= self.t1_s - SETTLE_S
    }
}

/// A calibration sequence: the rig's commanded motion and what each phase is for.
#[derive(Debug, Clone, PartialEq)]
pub struct Procedure {
    pub motion: RigMotion,
    pub phases: Vec<Phase>,
}

impl Procedure {
    /// The sequence of the module doc (415 s).
    pub fn standard() -> Self {
        Self::build(true)
    }

    /// The IMU part alone (the static positions and turns; 126 s), for the further power-ups.
    pub fn imu_only() -> Self {
        Self::build(false)
    }

    fn build(sky: bool) -> Self {
        let mut motion = RigMotion { depth_m: RIG_DEPTH_M, heading0_rad: 0.0, steps: Vec::new() };
        let mut marks = Vec::new();
        let (x, y, z) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]);
        let mut push = |duration_s: f64, axis_body: [f64; 3], rate_radps: f64, use_it: u8| {
            motion.steps.push(RigStep { duration_s, axis_body, rate_radps });
            marks.push(use_it);
        };
        const IDLE: u8 = 0;
        const STILL: u8 = 1;
        const TURN: u8 = 2;
        const SKY: u8 = 3;
        let quarter = 90.0 * DEG / TURN_RATE_RADPS;
        push(2.0, z, 0.0, IDLE);
        push(10.0, z, 0.0, STILL);
        push(4.0 * quarter, z, TURN_RATE_RADPS, TURN);
        push(4.0 * quarter, z, -TURN_RATE_RADPS, TURN);
        push(STATIC_S, z, 0.0, STILL);
        for _ in 0..4 {
            push(quarter, x, TURN_RATE_RADPS, TURN);
            push(STATIC_S, z, 0.0, STILL);
        }
        push(quarter, y, TURN_RATE_RADPS, TURN);
        push(STATIC_S, z, 0.0, STILL);
        push(2.0 * quarter, y, TURN_RATE_RADPS, TURN);
        push(STATIC_S, z, 0.0, STILL);
        push(quarter, y, TURN_RATE_RADPS, TURN);
        push(4.0, z, 0.0, STILL);
        for _ in 0..if sky { SKY_STOPS } else { 0 } {
            push(360.0 * DEG / SKY_STOPS as f64 / SPIN_RATE_RADPS, z, SPIN_RATE_RADPS, IDLE);
            push(SKY_HOLD_S, z, 0.0, SKY);
        }
        // The same turn tilted about x, then about y, so that every unit sees a wider range
        // of polarization angles: turning about the vertical, which in the tilted body is
        // (0, sin, cos) / (-sin, 0, cos).
        let (st, ct) = (SKY_TILT_RAD.sin(), SKY_TILT_RAD.cos());
        for (tilt_axis, vertical) in [(x, [0.0, st, ct]), (y, [-st, 0.0, ct])].into_iter().filter(|_| sky) {
            push(SKY_TILT_RAD / TURN_RATE_RADPS, tilt_axis, TURN_RATE_RADPS, IDLE);
            for _ in 0..SKY_TILTED_STOPS {
                push(360.0 * DEG / SKY_TILTED_STOPS as f64 / SPIN_RATE_RADPS, vertical, SPIN_RATE_RADPS, IDLE);
                push(SKY_HOLD_S, z, 0.0, SKY);
            }
            push(SKY_TILT_RAD / TURN_RATE_RADPS, tilt_axis, -TURN_RATE_RADPS, IDLE);
        }
        push(2.0, z, 0.0, IDLE);
        let traj = Trajectory::rig(&motion);
        let mut t = 0.0;
        let phases = motion
            .steps
            .iter()
            .zip(marks)
            .map(|(s, m)| {
                let (t0, t1) = (t, t + s.duration_s);
                t = t1;
                let kind = match m {
                    STILL => PhaseKind::Static { f_body_mps2: traj.at(0.5 * (t0 + t1)).specific_force_mps2 },
                    TURN => PhaseKind::Turn { rate_body_radps: Vector3::from(s.axis_body) * s.rate_radps },
                    SKY => PhaseKind::SkyHold,
                    _ => PhaseKind::Idle,
                };
                Phase { t0_s: t0, t1_s: t1, kind }
            })
            .collect();
        Procedure { motion, phases }
    }

    pub fn duration_s(&self) -> f64 {
        self.motion.duration_s()
    }

    /// The scenario of a calibration session of the head built with `build_seed` (None: an
    /// ideal head), power-up `run_seed`, at the default scenario's place and time, at
    /// [`RIG_DEPTH_M`]: the rig, no DVL, no fixes, no camera.
    pub fn scenario(&self, build_seed: Option<u64>, run_seed: u64) -> Scenario {
        Scenario {
            seed: run_seed,
            duration_s: self.duration_s(),
            position_fixes: None,
            dvl: None,
            camera: None,
            build_seed,
            rig: Some(self.motion.clone()),
            ..Scenario::default()
        }
    }
}

/// The raw samples of a calibration session.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    pub imu: Vec<ImuSample>,
    pub polarization: Vec<PolarizationSample>,
    pub boot_seen: bool,
}

impl Recording {
    pub fn from_messages(msgs: &[Uplink]) -> Self {
        let mut r = Recording::default();
        for m in msgs {
            match m {
                Uplink::Raw(RawSample::Imu(s)) => r.imu.push(*s),
                Uplink::Raw(RawSample::Polarization(s)) => r.polarization.push(*s),
                Uplink::Boot(_) => r.boot_seen = true,
                _ => {}
            }
        }
        r
    }
}

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

/// Where and when a session ran (what the procedure knows of its setup).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Site {
    pub start_utc_unix_us: i64,
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub depth_m: f64,
}

impl Site {
    pub fn of(sc: &Scenario) -> Self {
        Site {
            start_utc_unix_us: sc.start_utc_unix_us,
            lat_deg: sc.lat_deg,
            lon_deg: sc.lon_deg,
            depth_m: sc.rig.as_ref().map_or(RIG_DEPTH_M, |r| r.depth_m),
        }
    }
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
fn fit_unit(unit: u8, samples: &[([f64; 4], f64)]) -> Result<PolarizationCalibration> {
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

/// Which head a session runs on.
#[derive(Debug, Clone)]
pub enum Target {
    /// The firmware's application core natively (software in the loop).
    Native,
    /// The QEMU board firmware.
    Qemu { elf: PathBuf, timeout: Duration },
}

/// Run a session of `sc` on `head` and return its telemetry.
pub fn run_session(target: &Target, sc: &Scenario, head: SimHead) -> Result<Vec<Uplink>> {
    match target {
        Target::Native => Ok(crate::sil::run_native_with_head(sc, head, true).messages),
        Target::Qemu { elf, timeout } => {
            use subnav_link::LinkEvent;
            use subnav_link::qemu::{QemuConfig, QemuEvent, run_with_bus};
            if !elf.is_file() {
                bail!("firmware ELF {}: no such file (`cargo xtask build --board qemu` builds it)", elf.display());
            }
            let mut cfg = QemuConfig::new(elf);
            cfg.run_ms = Some((sc.duration_s * 1000.0).round() as u64);
            cfg.timeout = *timeout;
            cfg.board_args = sc.board_args();
            let mut msgs = Vec::new();
            let (outcome, _) = run_with_bus(&cfg, Box::new(head), |e, _| {
                if let QemuEvent::Link(LinkEvent::Message(m)) = e {
                    msgs.push(m);
                }
            })
            .with_context(|| format!("running {} under QEMU", elf.display()))?;
            if outcome.timed_out {
                bail!("the QEMU head ({}) did not finish its session within {} s", elf.display(), timeout.as_secs());
            }
            Ok(msgs)
        }
    }
}

/// Record the calibration sequence on the head whose store is `flash`.
pub fn record(target: &Target, sc: &Scenario, flash: &SharedFlash) -> Result<Recording> {
    let head = SimHead::new(sc).with_flash_chip(flash.clone());
    let rec = Recording::from_messages(&run_session(target, sc, head)?);
    if !rec.boot_seen {
        bail!("no head answered: the calibration session's telemetry has no Boot message");
    }
    if rec.imu.is_empty() || rec.polarization.is_empty() {
        bail!("the head streamed no raw samples (IMU {}, polarization {}): is its raw stream off?", rec.imu.len(), rec.polarization.len());
    }
    Ok(rec)
}

fn frame(seq: u16, command: Command) -> Result<Vec<u8>> {
    let mut buf = [0u8; subnav_wire::MAX_DOWNLINK_FRAME];
    Ok(subnav_wire::encode(&Downlink { seq, command }, &mut buf).context("encoding a downlink command")?.to_vec())
}

/// Write `records` to the head (one `SetRecord` each), read each back and check it is what was
/// sent. Errors name the record and the head's reason.
pub fn write_and_verify(target: &Target, sc_still: &Scenario, flash: &SharedFlash, records: &[Record]) -> Result<()> {
    const FIRST_US: u64 = 500_000;
    const STEP_US: u64 = 100_000;
    let n = records.len() as u64;
    let mut frames = Vec::new();
    for (k, r) in records.iter().enumerate() {
        frames.push((FIRST_US + k as u64 * STEP_US, frame(1 + k as u16, Command::SetRecord(*r))?));
        frames.push((FIRST_US + (n + k as u64) * STEP_US, frame(1001 + k as u16, Command::ReadRecord(r.key()))?));
    }
    let mut sc = sc_still.clone();
    sc.duration_s = (FIRST_US + 2 * n * STEP_US) as f64 * 1e-6 + 1.0;
    let head = SimHead::build_with_commands(&sc, None, None, frames).with_flash_chip(flash.clone());
    let msgs = run_session(target, &sc, head)?;
    if !msgs.iter().any(|m| matches!(m, Uplink::Boot(_))) {
        bail!("no head answered: the write session's telemetry has no Boot message");
    }
    let ack = |seq: u16| msgs.iter().find_map(|m| if let Uplink::Ack(a) = m { (a.seq == seq).then_some(a.result) } else { None });
    for (k, r) in records.iter().enumerate() {
        match ack(1 + k as u16) {
            Some(Ok(())) => {}
            Some(Err(e)) => bail!("the head refused the {}: {e}", r.key()),
            None => bail!("the head did not acknowledge the {} (no answer to SetRecord)", r.key()),
        }
    }
    for (k, r) in records.iter().enumerate() {
        if let Some(Err(e)) = ack(1001 + k as u16) {
            bail!("the head refused to read back the {}: {e}", r.key());
        }
        let key: RecordKey = r.key();
        let back = msgs.iter().rev().find_map(|m| if let Uplink::Record(rep) = m { (rep.key == key).then_some(rep.stored) } else { None });
        match back {
            Some(Some(b)) if b == *r => {}
            Some(Some(b)) => bail!("read-back of the {key} differs from what was written: wrote {r:?}, read {b:?}"),
            Some(None) => bail!("read-back of the {key}: the head has no valid record stored"),
            None => bail!("the head sent no read-back of the {key}"),
        }
    }
    Ok(())
}

/// Power-ups the IMU part of the procedure is run in (the first with the sky turns). The
/// accelerometer's turn-on bias differs at every power-up (ICM-42688-P grade: 0.02 m/s^2,
/// 1-sigma, `subnav_core::head`): the stored bias is the repeatable part plus the sessions'
/// mean turn-on bias, so a dive's tilt error from it is `sqrt(1 + 1/n)` times an ideal head's
/// (which carries only its own): 1.41 with one power-up, 1.06 with eight. Measured: with
/// one power-up, the calibrated compass's median error was 2.6x the ideal head's; calibrated
/// and dived in the same power-up, 0.35-0.7x (seeds 3 and 8, 90-s dives).
pub const IMU_POWER_UPS: u64 = 8;

/// What a calibration did.
#[derive(Debug, Clone)]
pub struct Calibrated {
    pub records: Vec<Record>,
    pub recording: Recording,
}

/// The whole procedure on one head: record, fit, write, verify. `run_seed` is the first
/// session's power-up (its turn-on biases and noise); the IMU part runs in [`IMU_POWER_UPS`].
pub fn calibrate(target: &Target, build_seed: Option<u64>, run_seed: u64, flash: &SharedFlash) -> Result<Calibrated> {
    calibrate_with(target, build_seed, run_seed, IMU_POWER_UPS, flash)
}

/// As [`calibrate`] with the IMU part in `power_ups` power-ups (at least 1).
pub fn calibrate_with(target: &Target, build_seed: Option<u64>, run_seed: u64, power_ups: u64, flash: &SharedFlash) -> Result<Calibrated> {
    let proc = Procedure::standard();
    let sc = proc.scenario(build_seed, run_seed);
    let recording = record(target, &sc, flash)?;
    let mut records: Vec<Record> = fit_polarization(&recording, &proc, &Site::of(&sc))?.into_iter().map(Record::Polarization).collect();
    let mut imu = vec![imu_affine(&recording, &proc)?];
    let imu_proc = Procedure::imu_only();
    for k in 1..power_ups.max(1) {
        let sc = imu_proc.scenario(build_seed, run_seed.wrapping_add(7919 * k));
        imu.push(imu_affine(&record(target, &sc, flash)?, &imu_proc)?);
    }
    records.push(Record::Imu(imu_record(&imu)?));
    let still = Scenario { rig: Some(RigMotion { steps: Vec::new(), ..proc.motion.clone() }), ..sc };
    write_and_verify(target, &still, flash, &records)?;
    Ok(Calibrated { records, recording })
}

/// A flash image file as a shared chip (created erased when missing; `new`: a new erased image
/// replacing the file there). A file that is not an image is refused, untouched.
pub fn flash_file(path: &Path, new: bool) -> Result<SharedFlash> {
    use crate::chips::w25q::W25qModel;
    let chip = if new { W25qModel::new_file(path)? } else { W25qModel::with_file(path)? };
    Ok(SharedFlash(std::sync::Arc::new(std::sync::Mutex::new(chip))))
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

#[cfg(test)]
mod tests;

/// One head's figures in a dive.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct HeadFigures {
    /// Compass heading fixes against the true heading (NaN: no fix at all).
    pub compass_rmse_deg: f64,
    pub compass_fixes: usize,
    /// Solves without a heading.
    pub compass_no_fix: usize,
    /// Median absolute error of the fixes, deg.
    pub compass_median_abs_deg: f64,
    /// Fixes more than [`OUTLIER_DEG`] off, and the RMSE of the others.
    pub compass_outliers: usize,
    pub compass_rmse_inliers_deg: f64,
    /// The navigation solution's heading (converged samples).
    pub heading_rmse_deg: f64,
    pub horizontal_rms_err_m: f64,
}

/// A compass fix this far from the truth counts as an outlier in [`HeadFigures`], deg.
pub const OUTLIER_DEG: f64 = 10.0;

impl HeadFigures {
    /// The figures of a dive's telemetry (`msgs` must hold its Nav and Compass messages).
    pub fn of(sc: &Scenario, msgs: &[Uplink]) -> Self {
        let r = crate::dive::evaluate(sc, msgs, Some(0), 0, 0);
        let traj = sc.trajectory();
        let mut err: Vec<f64> = msgs
            .iter()
            .filter_map(|m| if let Uplink::Compass(c) = m { c.heading_rad.map(|h| (c.t_us, h)) } else { None })
            .map(|(t, h)| {
                let d = f64::from(h).to_degrees() - traj.at(t as f64 * 1e-6).yaw_rad.to_degrees();
                subnav_base::wrap_deg(d).abs()
            })
            .collect();
        err.sort_by(f64::total_cmp);
        let inliers: Vec<f64> = err.iter().copied().filter(|e| *e <= OUTLIER_DEG).collect();
        let rms = |v: &[f64]| if v.is_empty() { f64::NAN } else { (v.iter().map(|e| e * e).sum::<f64>() / v.len() as f64).sqrt() };
        HeadFigures {
            compass_rmse_deg: r.compass_rmse_deg,
            compass_fixes: r.compass_fixes,
            compass_no_fix: r.compass_no_fix,
            compass_median_abs_deg: err.get(err.len() / 2).copied().unwrap_or(f64::NAN),
            compass_outliers: err.len() - inliers.len(),
            compass_rmse_inliers_deg: rms(&inliers),
            heading_rmse_deg: r.heading_rmse_deg,
            horizontal_rms_err_m: r.horizontal_rms_err_m,
        }
    }
}

/// A mis-built head uncalibrated, calibrated by [`calibrate`] and the ideal head, in the same dive.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Comparison {
    pub build_seed: u64,
    pub uncalibrated: HeadFigures,
    pub calibrated: HeadFigures,
    pub ideal: HeadFigures,
    pub recovery: RecoveryErrors,
}

/// Power-up seed of a head's calibration session (not the dive's: another power-up, other
/// turn-on biases).
pub fn session_seed(build_seed: u64) -> u64 {
    build_seed.wrapping_add(1_000_000)
}

/// Run `dive` (its seed replaced by `build_seed`, so the three heads see the same dive, noise
/// and turn-on biases) natively on the head built with `build_seed` uncalibrated, on the same
/// head after [`calibrate`] and on the ideal head.
pub fn compare(build_seed: u64, dive: &Scenario) -> Result<Comparison> {
    if dive.camera.is_some() {
        bail!("the comparison dive must have no camera (the map in the loop is not run)");
    }
    let ideal_sc = Scenario { seed: build_seed, build_seed: None, rig: None, ..dive.clone() };
    let built_sc = Scenario { build_seed: Some(build_seed), ..ideal_sc.clone() };
    let ideal = crate::sil::run_native_scored(&ideal_sc, None).messages;
    let uncalibrated = crate::sil::run_native_scored(&built_sc, None).messages;
    let flash = SharedFlash::default();
    let cal = calibrate(&Target::Native, Some(build_seed), session_seed(build_seed), &flash)?;
    let calibrated = crate::sil::run_native_with_head(&built_sc, SimHead::new(&built_sc).with_flash_chip(flash), false).messages;
    Ok(Comparison {
        build_seed,
        uncalibrated: HeadFigures::of(&built_sc, &uncalibrated),
        calibrated: HeadFigures::of(&built_sc, &calibrated),
        ideal: HeadFigures::of(&ideal_sc, &ideal),
        recovery: recovery_errors(&cal.records, build_seed),
    })
}
