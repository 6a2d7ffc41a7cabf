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
//! This module runs the procedure on a target (the rig's sequence, recording, writing and
//! reading back the records, the comparison dives); the estimators themselves, pure maths on
//! a recording, are [`fit`] (re-exported here), so they can be read and tested without a head.

use std::path::Path;

use anyhow::{Context, Result, bail};
use nalgebra::Vector3;
use serde::Serialize;
use subnav_base::trajectory::{RigMotion, RigStep, Trajectory};
use subnav_wire::{Command, Downlink, ImuSample, PolarizationSample, RawSample, Record, RecordKey, Uplink};

use crate::chips::w25q::SharedFlash;
use crate::head::{Scenario, SimHead};
use crate::run::{HeadRun, RunOutput};

pub mod fit;
#[cfg(test)]
use fit::fit_unit;
pub use fit::{
    ImuAffine, RecoveryErrors, fit_all, fit_imu, fit_polarization, imu_affine, imu_record, max_aop_error_deg, model_counts, recovery_errors,
};

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

/// Which head a session runs on (the run builder's targets).
pub use crate::run::Target;

/// Run a session of `sc` on `head` and return its telemetry (every message).
pub fn run_session(target: &Target, sc: &Scenario, head: SimHead) -> Result<Vec<Uplink>> {
    Ok(HeadRun::on(sc, target.clone()).on_head(head).keep_all().run()?.messages)
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
    /// The figures of a run of `sc`.
    pub fn of(sc: &Scenario, run: &RunOutput) -> Result<Self> {
        let r = run.score(sc)?;
        let msgs = &run.messages;
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
        Ok(HeadFigures {
            compass_rmse_deg: r.compass_rmse_deg,
            compass_fixes: r.compass_fixes,
            compass_no_fix: r.compass_no_fix,
            compass_median_abs_deg: err.get(err.len() / 2).copied().unwrap_or(f64::NAN),
            compass_outliers: err.len() - inliers.len(),
            compass_rmse_inliers_deg: rms(&inliers),
            heading_rmse_deg: r.score.heading_rmse_deg,
            horizontal_rms_err_m: r.score.horizontal_rms_err_m,
        })
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
    let ideal = HeadRun::native(&ideal_sc).run()?;
    let uncalibrated = HeadRun::native(&built_sc).run()?;
    let flash = SharedFlash::default();
    let cal = calibrate(&Target::Native, Some(build_seed), session_seed(build_seed), &flash)?;
    let calibrated = HeadRun::native(&built_sc).on_head(SimHead::new(&built_sc).with_flash_chip(flash)).run()?;
    Ok(Comparison {
        build_seed,
        uncalibrated: HeadFigures::of(&built_sc, &uncalibrated)?,
        calibrated: HeadFigures::of(&built_sc, &calibrated)?,
        ideal: HeadFigures::of(&ideal_sc, &ideal)?,
        recovery: recovery_errors(&cal.records, build_seed),
    })
}
