//! Warm start: after a watchdog reset or a brown-out the head starts from its last solution
//! (a record the board keeps across the reset), not from the origin at rest.
//!
//! An AUV does not stop for a reset: a cold alignment assumes rest (wrong while moving) and puts
//! the head at the origin (its navigation is gone). Instead the running head leaves a
//! [`WarmStart`] record (its solution, sigmas and gyro bias) in memory that survives a reset,
//! written every [`WARM_RECORD_PERIOD_US`] and sealed by a CRC; after a reset the filter starts
//! from it ([`Estimator::warm_start`]), every part made uncertain enough for what the vehicle may
//! have done while the head was away:
//! - position: the record's, dead-reckoned with its velocity over the middle of the possible gap;
//!   1-sigma from the record's, its velocity's over the gap, the half-width of the gap at the
//!   recorded speed, and an acceleration of [`MAX_ACCEL_MPS2`] over the gap;
//! - velocity: the record's, 1-sigma grown by [`MAX_ACCEL_MPS2`] over the gap (the DVL pulls it in);
//! - yaw: the record's, 1-sigma grown by a turn of [`MAX_TURN_RATE_RADPS`] over the gap (the
//!   compass pulls it in), capped where the sigma points stay on one side of the circle;
//! - roll and pitch: levelled on the mean specific force of the first [`WARM_LEVEL_S`] after boot,
//!   which includes the vehicle's acceleration (not at rest): a 1-sigma of
//!   [`WARM_TILT_SIGMA_RAD`] instead of the static alignment's 1 mrad, and no tilt-to-bias
//!   correlation (the static alignment's, `aligned_covariance`, is far below this sigma);
//! - gyro bias: the recorded estimate (alignment plus filter), not re-measured (the head is not at
//!   rest), with the configured initial bias sigma.
//!
//! A record that fails the CRC, carries non-finite or implausible values, or was stale when it was
//! written is ignored: the head aligns cold as before. Nothing here panics on the record's bytes.

use super::{Estimator, YAW_UNKNOWN_SIGMA_RAD};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use subnav_core::head;
use subnav_core::nav::state::{POS, VEL, yaw_of};
use subnav_core::nav::{NavError, NavInit};

/// How often the running head leaves its record (µs): the nav solution's default period; the
/// record is at most this old when the head stops.
pub const WARM_RECORD_PERIOD_US: u64 = 100_000;
/// Bytes of an encoded record (a multiple of 4: boards keep it in words).
pub const WARM_RECORD_BYTES: usize = 116;
/// Record layout version, in the header.
const VERSION: u16 = 1;
const MAGIC: u32 = 0x5357_4E53; // "SNWS" little-endian
const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Largest acceleration an AUV's guidance asks for (m/s^2): speed changes and turns (1 m/s on a
/// 10 m radius is 0.1 m/s^2), with margin.
pub const MAX_ACCEL_MPS2: f32 = 0.5;
/// Largest turn rate of an AUV (rad/s): 10 deg/s (a 1 m/s vehicle on a 5.7 m radius).
pub const MAX_TURN_RATE_RADPS: f32 = 10.0 * core::f32::consts::PI / 180.0;
/// Tilt 1-sigma of the levelling on a moving vehicle: 0.1 m/s^2 of unmodelled acceleration is
/// 0.6 deg, pitching in waves more; 2 deg.
pub const WARM_TILT_SIGMA_RAD: f32 = 2.0 * core::f32::consts::PI / 180.0;
/// IMU samples averaged for the levelling after boot (s).
pub const WARM_LEVEL_S: f32 = 0.2;
/// A record is stale if its solution was this old when written (µs): the solution stopped being
/// updated (the board writes what the estimator gives, which follows every IMU sample).
const MAX_RECORD_AGE_US: u64 = 2_000_000;
/// Longest gap between the record and the warm start (s): past this the dead reckoning is worth
/// less than the position fixes' re-acquisition; align cold.
pub const MAX_GAP_S: f32 = 60.0;

/// Plausibility bounds of a record (beyond them it is corrupt, or the head was lost anyway).
const MAX_POS_M: f32 = 1.0e6;
const MAX_SPEED_MPS: f32 = 10.0;
const MAX_SIGMA_POS_M: f32 = 1.0e4;
const MAX_SIGMA_VEL_MPS: f32 = 10.0;
const MAX_GYRO_BIAS_RADPS: f32 = 0.2;

/// The head's solution kept across a reset. Times are the writing boot's (µs since that boot).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WarmStart {
    /// When the record was written, and the solution's time.
    pub written_us: u64,
    pub t_us: u64,
    pub pos_ned_m: [f32; 3],
    pub vel_ned_mps: [f32; 3],
    /// Body (FRD) to NED.
    pub att_nb_wxyz: [f32; 4],
    pub sigma_pos_m: [f32; 3],
    pub sigma_vel_mps: [f32; 3],
    /// Roll, pitch, yaw 1-sigma (the heading-aligned level frame of `NavSolution`).
    pub sigma_att_rad: [f32; 3],
    /// Total gyro bias (the alignment's plus the filter's estimate), body FRD.
    pub gyro_bias_radps: [f32; 3],
}

/// Why a record or a warm start was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WarmStartError {
    /// No record: wrong header (never written, cleared, power-on contents) or wrong length.
    NoRecord,
    /// The CRC does not match (corrupted, half-written).
    Corrupt,
    /// Non-finite or implausible values, or stale when written.
    Invalid,
    /// The gap since the record is negative, non-finite or longer than [`MAX_GAP_S`].
    Gap,
    /// Fewer than [`WARM_LEVEL_S`] of IMU samples since boot: call again later.
    NotYet,
    /// The filter is already running (aligned cold, or warm started).
    Running,
    /// The filter refused the initial state.
    Filter(NavError),
}

/// By name (the core's `NavError` has no defmt format).
#[cfg(feature = "defmt")]
impl defmt::Format for WarmStartError {
    fn format(&self, f: defmt::Formatter) {
        let name = match self {
            Self::NoRecord => "NoRecord",
            Self::Corrupt => "Corrupt",
            Self::Invalid => "Invalid",
            Self::Gap => "Gap",
            Self::NotYet => "NotYet",
            Self::Running => "Running",
            Self::Filter(_) => "Filter",
        };
        defmt::write!(f, "{=str}", name)
    }
}

fn finite(v: &[f32]) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn in_range(v: &[f32], lo: f32, hi: f32) -> bool {
    v.iter().all(|x| *x > lo && *x <= hi)
}

impl WarmStart {
    /// Finite, a unit quaternion, positive sigmas and values in range, not stale when written.
    pub fn is_valid(&self) -> bool {
        let all = [self.pos_ned_m, self.vel_ned_mps, self.sigma_pos_m, self.sigma_vel_mps, self.sigma_att_rad, self.gyro_bias_radps];
        if !(all.iter().all(|v| finite(v)) && finite(&self.att_nb_wxyz)) {
            return false;
        }
        let q = &self.att_nb_wxyz;
        let norm = libm::sqrtf(q.iter().map(|x| x * x).sum::<f32>());
        let speed = libm::sqrtf(self.vel_ned_mps.iter().map(|x| x * x).sum::<f32>());
        (norm - 1.0).abs() < 1e-3
            && self.pos_ned_m.iter().all(|p| p.abs() <= MAX_POS_M)
            && speed <= MAX_SPEED_MPS
            && self.gyro_bias_radps.iter().all(|b| b.abs() <= MAX_GYRO_BIAS_RADPS)
            && in_range(&self.sigma_pos_m, 0.0, MAX_SIGMA_POS_M)
            && in_range(&self.sigma_vel_mps, 0.0, MAX_SIGMA_VEL_MPS)
            && in_range(&self.sigma_att_rad, 0.0, core::f32::consts::PI)
            && self.written_us >= self.t_us
            && self.written_us - self.t_us <= MAX_RECORD_AGE_US
    }

    /// The record's bytes: header (magic, version, length), the fields little-endian, CRC-32 of
    /// everything before it.
    pub fn encode(&self) -> [u8; WARM_RECORD_BYTES] {
        let mut out = [0u8; WARM_RECORD_BYTES];
        let mut w = Writer { buf: &mut out, at: 0 };
        w.put(&MAGIC.to_le_bytes());
        w.put(&VERSION.to_le_bytes());
        w.put(&(WARM_RECORD_BYTES as u16).to_le_bytes());
        w.put(&self.written_us.to_le_bytes());
        w.put(&self.t_us.to_le_bytes());
        for v in self.floats() {
            w.put(&v.to_le_bytes());
        }
        let at = w.at;
        let crc = CRC.checksum(out.get(..at).unwrap_or(&[]));
        if let Some(tail) = out.get_mut(at..at + 4) {
            tail.copy_from_slice(&crc.to_le_bytes());
        }
        out
    }

    /// A record from its bytes, checked (header, CRC, [`WarmStart::is_valid`]).
    pub fn decode(bytes: &[u8]) -> Result<Self, WarmStartError> {
        let bytes = bytes.get(..WARM_RECORD_BYTES).ok_or(WarmStartError::NoRecord)?;
        let mut r = Reader { buf: bytes, at: 0 };
        if r.u32() != Some(MAGIC) || r.u16() != Some(VERSION) || r.u16() != Some(WARM_RECORD_BYTES as u16) {
            return Err(WarmStartError::NoRecord);
        }
        let body = WARM_RECORD_BYTES - 4;
        let stored = bytes.get(body..).and_then(|b| <[u8; 4]>::try_from(b).ok()).map(u32::from_le_bytes);
        if stored != Some(CRC.checksum(bytes.get(..body).unwrap_or(&[]))) {
            return Err(WarmStartError::Corrupt);
        }
        let (written_us, t_us) = (r.u64().ok_or(WarmStartError::Corrupt)?, r.u64().ok_or(WarmStartError::Corrupt)?);
        let mut f = [0.0f32; FLOATS];
        for x in f.iter_mut() {
            *x = r.f32().ok_or(WarmStartError::Corrupt)?;
        }
        let three = |i: usize| [f[i], f[i + 1], f[i + 2]];
        let rec = WarmStart {
            written_us,
            t_us,
            pos_ned_m: three(0),
            vel_ned_mps: three(3),
            att_nb_wxyz: [f[6], f[7], f[8], f[9]],
            sigma_pos_m: three(10),
            sigma_vel_mps: three(13),
            sigma_att_rad: three(16),
            gyro_bias_radps: three(19),
        };
        if rec.is_valid() { Ok(rec) } else { Err(WarmStartError::Invalid) }
    }

    fn floats(&self) -> [f32; FLOATS] {
        let mut f = [0.0f32; FLOATS];
        let parts: [&[f32]; 7] = [
            &self.pos_ned_m,
            &self.vel_ned_mps,
            &self.att_nb_wxyz,
            &self.sigma_pos_m,
            &self.sigma_vel_mps,
            &self.sigma_att_rad,
            &self.gyro_bias_radps,
        ];
        for (dst, src) in f.iter_mut().zip(parts.into_iter().flatten()) {
            *dst = *src;
        }
        f
    }
}

/// f32 fields of the record.
const FLOATS: usize = 22;
const _: () = assert!(4 + 2 + 2 + 8 + 8 + 4 * FLOATS + 4 == WARM_RECORD_BYTES);

struct Writer<'a> {
    buf: &'a mut [u8],
    at: usize,
}

impl Writer<'_> {
    fn put(&mut self, b: &[u8]) {
        if let Some(dst) = self.buf.get_mut(self.at..self.at + b.len()) {
            dst.copy_from_slice(b);
        }
        self.at += b.len();
    }
}

struct Reader<'a> {
    buf: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> Option<[u8; N]> {
        let b = self.buf.get(self.at..self.at + N).and_then(|b| <[u8; N]>::try_from(b).ok());
        self.at += N;
        b
    }
    fn u16(&mut self) -> Option<u16> {
        self.take().map(u16::from_le_bytes)
    }
    fn u32(&mut self) -> Option<u32> {
        self.take().map(u32::from_le_bytes)
    }
    fn u64(&mut self) -> Option<u64> {
        self.take().map(u64::from_le_bytes)
    }
    fn f32(&mut self) -> Option<f32> {
        self.take().map(f32::from_le_bytes)
    }
}

impl Estimator {
    /// The record to keep for a warm start, at `now_us`: `None` while the filter is not running
    /// (a board then clears its copy: an old record must not outlive a filter reset).
    pub fn warm_start_record(&self, now_us: u64) -> Option<WarmStart> {
        let nav = self.nav.as_ref().filter(|_| self.running)?;
        let s = nav.solution();
        let b = nav.nominal().gyro_bias_radps;
        let rec = WarmStart {
            written_us: now_us,
            t_us: s.t_us,
            pos_ned_m: s.pos_ned_m,
            vel_ned_mps: s.vel_ned_mps,
            att_nb_wxyz: s.att_nb_wxyz,
            sigma_pos_m: s.sigma_pos_m,
            sigma_vel_mps: s.sigma_vel_mps,
            sigma_att_rad: s.sigma_att_rad,
            gyro_bias_radps: [self.gyro_bias_align[0] + b.x, self.gyro_bias_align[1] + b.y, self.gyro_bias_align[2] + b.z],
        };
        rec.is_valid().then_some(rec)
    }

    /// Start the filter from `rec` instead of aligning at rest (see the module doc). `gap_s`: an
    /// upper bound of the time from the record's writing to now (the reset's duration and the time
    /// since boot); the gap is taken as anywhere in `[0, gap_s]` plus the record's own age.
    /// Needs [`WARM_LEVEL_S`] of IMU samples since boot (else `NotYet`: call again).
    #[inline(never)] // at boot only: its frame stays out of the IMU path
    pub fn warm_start(&mut self, rec: &WarmStart, gap_s: f32) -> Result<(), WarmStartError> {
        if self.running {
            return Err(WarmStartError::Running);
        }
        if !rec.is_valid() {
            return Err(WarmStartError::Invalid);
        }
        if !(gap_s >= 0.0 && gap_s <= MAX_GAP_S) {
            return Err(WarmStartError::Gap);
        }
        let (Some(start), Some(now_us)) = (self.align.start_us, self.last_imu_us) else { return Err(WarmStartError::NotYet) };
        if self.align.n == 0 || (now_us.saturating_sub(start) as f32) * 1e-6 < WARM_LEVEL_S {
            return Err(WarmStartError::NotYet);
        }
        let (roll, pitch) = head::level_from_accel(self.align.mean_accel());

        let age_s = (rec.written_us - rec.t_us) as f32 * 1e-6;
        let dt_max = age_s + gap_s;
        let dt_mid = age_s + 0.5 * gap_s;
        let v = rec.vel_ned_mps;
        let speed = libm::sqrtf(v.iter().map(|x| x * x).sum::<f32>());
        let accel_m = 0.5 * MAX_ACCEL_MPS2 * dt_max * dt_max;
        let mut pos = [0.0f32; 3];
        let mut var_pos = [0.0f32; 3];
        let mut var_vel = [0.0f32; 3];
        for k in 0..3 {
            pos[k] = rec.pos_ned_m[k] + v[k] * dt_mid;
            let sv = rec.sigma_vel_mps[k] * dt_max;
            let gap_m = speed * 0.5 * gap_s;
            var_pos[k] = rec.sigma_pos_m[k] * rec.sigma_pos_m[k] + sv * sv + gap_m * gap_m + accel_m * accel_m;
            let dv = MAX_ACCEL_MPS2 * dt_max;
            var_vel[k] = rec.sigma_vel_mps[k] * rec.sigma_vel_mps[k] + dv * dv;
        }
        // Depth: the sensor's latest reading if there is one (it is current).
        if let Some(d) = self.last_depth_m {
            pos[2] = d;
        }
        let q = UnitQuaternion::from_quaternion(Quaternion::new(
            rec.att_nb_wxyz[0],
            rec.att_nb_wxyz[1],
            rec.att_nb_wxyz[2],
            rec.att_nb_wxyz[3],
        ));
        let yaw = yaw_of(&q);
        let turn = MAX_TURN_RATE_RADPS * dt_max;
        let yaw_sigma = libm::sqrtf(rec.sigma_att_rad[2] * rec.sigma_att_rad[2] + turn * turn).min(YAW_UNKNOWN_SIGMA_RAD);

        let mut cfg = self.cfg;
        cfg.init_sigma_att_rad = [WARM_TILT_SIGMA_RAD, WARM_TILT_SIGMA_RAD, yaw_sigma];
        let init = NavInit {
            t_us: now_us,
            att_nb: head::attitude(roll, pitch, yaw),
            vel_ned_mps: Vector3::from(v),
            pos_ned_m: Vector3::from(pos),
        };
        let Some(nav) = self.nav.as_mut() else { return Err(WarmStartError::Filter(NavError::BadConfig)) };
        nav.reinit(cfg, init).map_err(WarmStartError::Filter)?;
        // Per-axis position and velocity variances (the configuration has one sigma for all
        // three); a diagonal P with positive entries: symmetric PD.
        let mut p = *nav.covariance();
        for (k, (vp, vv)) in var_pos.into_iter().zip(var_vel).enumerate() {
            if let Some(x) = p.get_mut((POS + k, POS + k)) {
                *x = vp;
            }
            if let Some(x) = p.get_mut((VEL + k, VEL + k)) {
                *x = vv;
            }
        }
        nav.set_covariance(p).map_err(WarmStartError::Filter)?;
        self.gyro_bias_align = rec.gyro_bias_radps;
        self.running = true;
        Ok(())
    }
}

/// A start in motion from a solution given from outside (the host's last solution, a GNSS
/// fix pair on the surface, a surveyed launch): position, velocity and yaw with their 1-sigmas;
/// roll and pitch come from the mean specific force since boot, the gyro bias from the
/// configuration's initial sigma.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MovingStart {
    pub pos_ned_m: [f32; 3],
    pub vel_ned_mps: [f32; 3],
    pub yaw_rad: f32,
    pub sigma_pos_m: [f32; 3],
    pub sigma_vel_mps: [f32; 3],
    pub sigma_yaw_rad: f32,
    /// 1-sigma of the levelling in motion (the vehicle's own accelerations over the levelling
    /// window tilt the mean specific force).
    pub sigma_tilt_rad: f32,
}

impl MovingStart {
    fn is_valid(&self) -> bool {
        let finite =
            self.pos_ned_m.iter().chain(&self.vel_ned_mps).chain(&self.sigma_pos_m).chain(&self.sigma_vel_mps).all(|v| v.is_finite())
                && self.yaw_rad.is_finite();
        let pos = |v: f32| v.is_finite() && v > 0.0;
        finite
            && self.sigma_pos_m.iter().chain(&self.sigma_vel_mps).all(|v| *v > 0.0)
            && pos(self.sigma_yaw_rad)
            && pos(self.sigma_tilt_rad)
    }
}

impl Estimator {
    /// Start the filter in motion from `s` (see [`MovingStart`]) instead of aligning at rest.
    /// Needs [`WARM_LEVEL_S`] of IMU samples since boot (else `NotYet`: call again); refused
    /// while running or with a non-finite or non-positive-sigma `s` (nothing changes).
    #[inline(never)]
    pub fn start_moving(&mut self, s: &MovingStart) -> Result<(), WarmStartError> {
        if self.running {
            return Err(WarmStartError::Running);
        }
        if !s.is_valid() {
            return Err(WarmStartError::Invalid);
        }
        let (Some(start), Some(now_us)) = (self.align.start_us, self.last_imu_us) else { return Err(WarmStartError::NotYet) };
        if self.align.n == 0 || (now_us.saturating_sub(start) as f32) * 1e-6 < WARM_LEVEL_S {
            return Err(WarmStartError::NotYet);
        }
        let (roll, pitch) = head::level_from_accel(self.align.mean_accel());
        let mut cfg = self.cfg;
        cfg.init_sigma_att_rad = [s.sigma_tilt_rad, s.sigma_tilt_rad, s.sigma_yaw_rad.min(YAW_UNKNOWN_SIGMA_RAD)];
        let init = NavInit {
            t_us: now_us,
            att_nb: head::attitude(roll, pitch, s.yaw_rad),
            vel_ned_mps: Vector3::from(s.vel_ned_mps),
            pos_ned_m: Vector3::from(s.pos_ned_m),
        };
        let Some(nav) = self.nav.as_mut() else { return Err(WarmStartError::Filter(NavError::BadConfig)) };
        nav.reinit(cfg, init).map_err(WarmStartError::Filter)?;
        // Diagonal with positive entries: symmetric PD.
        let mut p = *nav.covariance();
        for k in 0..3 {
            if let Some(x) = p.get_mut((POS + k, POS + k)) {
                *x = s.sigma_pos_m[k] * s.sigma_pos_m[k];
            }
            if let Some(x) = p.get_mut((VEL + k, VEL + k)) {
                *x = s.sigma_vel_mps[k] * s.sigma_vel_mps[k];
            }
        }
        nav.set_covariance(p).map_err(WarmStartError::Filter)?;
        self.gyro_bias_align = [0.0; 3];
        self.running = true;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use subnav_wire::{DvlSample, DvlTracking, ImuSample, NavMode};

    fn record() -> WarmStart {
        let q = head::attitude(0.01, -0.02, 1.2);
        WarmStart {
            written_us: 100_050_000,
            t_us: 100_000_000,
            pos_ned_m: [120.0, -35.0, 10.0],
            vel_ned_mps: [0.36, 0.93, 0.0],
            att_nb_wxyz: [q.w, q.i, q.j, q.k],
            sigma_pos_m: [2.0, 2.1, 0.05],
            sigma_vel_mps: [0.02, 0.02, 0.01],
            sigma_att_rad: [0.002, 0.002, 0.01],
            gyro_bias_radps: [1e-3, -2e-3, 5e-4],
        }
    }

    #[test]
    fn a_record_round_trips_through_its_bytes() {
        let r = record();
        assert!(r.is_valid());
        let b = r.encode();
        assert_eq!(WarmStart::decode(&b), Ok(r));
        // Longer buffers (a board's region) are fine; shorter ones are no record.
        let mut long = [0u8; WARM_RECORD_BYTES + 8];
        long[..WARM_RECORD_BYTES].copy_from_slice(&b);
        assert_eq!(WarmStart::decode(&long), Ok(r));
        assert_eq!(WarmStart::decode(&b[..WARM_RECORD_BYTES - 1]), Err(WarmStartError::NoRecord));
    }

    #[test]
    fn a_corrupt_or_absent_record_is_ignored() {
        let b = record().encode();
        // Every single bit flipped past the header: the CRC catches it; in the header: no record.
        for byte in 0..WARM_RECORD_BYTES {
            for bit in 0..8 {
                let mut c = b;
                c[byte] ^= 1 << bit;
                let e = WarmStart::decode(&c).unwrap_err();
                assert!(matches!(e, WarmStartError::Corrupt | WarmStartError::NoRecord), "byte {byte} bit {bit}: {e:?}");
            }
        }
        assert_eq!(WarmStart::decode(&[0u8; WARM_RECORD_BYTES]), Err(WarmStartError::NoRecord));
        assert_eq!(WarmStart::decode(&[0xA5u8; WARM_RECORD_BYTES]), Err(WarmStartError::NoRecord));
        // Power-on garbage with a valid-looking header: the CRC.
        let mut g = [0x3Cu8; WARM_RECORD_BYTES];
        g[..8].copy_from_slice(&b[..8]);
        assert_eq!(WarmStart::decode(&g), Err(WarmStartError::Corrupt));
    }

    #[test]
    fn nan_implausible_and_stale_records_are_refused_even_with_a_good_crc() {
        let cases: [fn(&mut WarmStart); 8] = [
            |r| r.pos_ned_m[1] = f32::NAN,
            |r| r.sigma_att_rad[2] = f32::INFINITY,
            |r| r.sigma_pos_m[0] = 0.0,
            |r| r.sigma_vel_mps[2] = -1.0,
            |r| r.att_nb_wxyz = [0.5, 0.0, 0.0, 0.0],
            |r| r.vel_ned_mps[0] = 40.0,
            |r| r.written_us = r.t_us + 3_000_000,
            |r| r.written_us = r.t_us - 1,
        ];
        for (k, spoil) in cases.iter().enumerate() {
            let mut r = record();
            spoil(&mut r);
            assert!(!r.is_valid(), "case {k}");
            assert_eq!(WarmStart::decode(&r.encode()), Err(WarmStartError::Invalid), "case {k}");
            let mut e = Estimator::default();
            assert_eq!(e.warm_start(&r, 1.0), Err(WarmStartError::Invalid), "case {k}");
            assert_eq!(e.mode(), NavMode::Uninitialised);
        }
    }

    /// The truth of the moving-vehicle test: 1 m/s on a steady 1 deg/s turn at 10 m depth, level.
    struct Truth;
    const SPEED: f32 = 1.0;
    const TURN: f32 = 1.0 * core::f32::consts::PI / 180.0;
    impl Truth {
        fn yaw(t: f32) -> f32 {
            0.5 + TURN * t
        }
        fn vel(t: f32) -> [f32; 3] {
            [SPEED * libm::cosf(Self::yaw(t)), SPEED * libm::sinf(Self::yaw(t)), 0.0]
        }
        /// Position on the circle (radius SPEED / TURN), from the origin at t = 0.
        fn pos(t: f32) -> [f32; 3] {
            let r = SPEED / TURN;
            let (y0, y) = (Self::yaw(0.0), Self::yaw(t));
            [r * (libm::sinf(y) - libm::sinf(y0)), -r * (libm::cosf(y) - libm::cosf(y0)), 10.0]
        }
        fn imu(t_us: u64, bias: [f32; 3]) -> ImuSample {
            // Level, turning: the specific force is -g plus the centripetal acceleration (body
            // right, +y for a right turn), the gyro the turn rate about body down.
            ImuSample { t_us, gyro_radps: [bias[0], bias[1], TURN + bias[2]], accel_mps2: [0.0, SPEED * TURN, -9.806_65], temp_c: 20.0 }
        }
    }

    fn truth_record(t_s: f32, bias: [f32; 3]) -> WarmStart {
        let q = head::attitude(0.0, 0.0, Truth::yaw(t_s));
        let t_us = (t_s * 1e6) as u64;
        WarmStart {
            written_us: t_us + 20_000,
            t_us,
            pos_ned_m: Truth::pos(t_s),
            vel_ned_mps: Truth::vel(t_s),
            att_nb_wxyz: [q.w, q.i, q.j, q.k],
            sigma_pos_m: [0.5, 0.5, 0.05],
            sigma_vel_mps: [0.02, 0.02, 0.01],
            sigma_att_rad: [0.002, 0.002, 0.005],
            gyro_bias_radps: bias,
        }
    }

    fn yaw_deg_err(e: &Estimator, t: f32) -> (f32, f32) {
        let s = e.solution(0);
        let q = s.att_nb_wxyz;
        let q = UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]));
        let err = subnav_core::ukf::wrap_pi(yaw_of(&q) - Truth::yaw(t));
        (err, s.sigma_att_rad[2])
    }

    /// The head was navigating a turning vehicle at 60 s and is reset; it comes back 1.5 s
    /// later (world time 61.5 s, its own clock from 0): warm started, fed compass, depth and
    /// DVL, it is aided at once, its position and heading stay within 3 sigma of the truth
    /// throughout, and the heading converges; a cold start instead stays at the origin.
    #[test]
    fn a_warm_start_on_a_moving_vehicle_converges_with_compass_dvl_and_depth() {
        let bias = [2e-3, -1e-3, 3e-3];
        let rec = truth_record(60.0, bias);
        let world0 = 61.5f32;
        let mut e = Estimator::default();
        let dt = 1_000_000 / u64::from(head::IMU_RATE_HZ);
        let mut started_at = None;
        let mut worst = 0.0f32;
        for k in 0..(60 * head::IMU_RATE_HZ as u64) {
            let t_us = k * dt;
            let t = t_us as f32 * 1e-6;
            let w = world0 + t;
            e.on_imu(&Truth::imu(t_us, bias)).unwrap();
            if started_at.is_none() {
                match e.warm_start(&rec, 1.0 + t) {
                    Ok(()) => started_at = Some(t),
                    Err(WarmStartError::NotYet) => {}
                    Err(other) => panic!("{other:?}"),
                }
            }
            if k % 20 == 0 {
                let _ = e.on_depth(t_us, 10.0);
                e.on_heading_fix(t_us, Truth::yaw(w), 0.3f32.to_radians());
                // Bottom-track velocity in the body frame (level: the yaw rotation).
                // Bottom-track velocity in the DVL's axes: the body velocity (forward) plus the
                // lever arm's turn, rotated into the DVL's mounting.
                let m = head::dvl_mounting();
                let vb = Vector3::new(SPEED, 0.0, 0.0) + Vector3::new(0.0, 0.0, TURN).cross(&m.lever_arm_body_m);
                let vd = m.rot_body_from_dvl.inverse() * vb;
                let d = DvlSample {
                    t_us,
                    rx_us: t_us,
                    vel_dvl_mps: [vd.x, vd.y, vd.z],
                    fom_mps: 0.01,
                    altitude_m: 4.0,
                    covariance_m2ps2: None,
                    valid: true,
                    tracking: DvlTracking::Bottom,
                };
                e.on_dvl(&d).unwrap();
            }
            if started_at.is_some() && k % 20 == 10 {
                let s = e.solution(t_us);
                let p = Truth::pos(w);
                for a in 0..2 {
                    let r = (s.pos_ned_m[a] - p[a]).abs() / s.sigma_pos_m[a];
                    worst = worst.max(r);
                }
                let (ey, sy) = yaw_deg_err(&e, w);
                worst = worst.max(ey.abs() / sy);
            }
        }
        let started_at = started_at.expect("warm started");
        assert!(started_at < WARM_LEVEL_S + 0.05, "started at {started_at} s");
        assert_eq!(e.mode(), NavMode::Aided);
        assert!(worst < 3.0, "worst error / sigma after the warm start: {worst}");
        let end = 60.0 - 0.005;
        let s = e.solution(0);
        let p = Truth::pos(world0 + end);
        let horiz = libm::hypotf(s.pos_ned_m[0] - p[0], s.pos_ned_m[1] - p[1]);
        assert!(horiz < 3.0, "horizontal error {horiz} m: {:?} vs {p:?}", s.pos_ned_m);
        let (ey, sy) = yaw_deg_err(&e, world0 + end);
        assert!(ey.abs() < 1.0f32.to_radians() && sy < 1.0f32.to_radians(), "yaw error {ey} sigma {sy}");

        // The cold start for contrast: it aligns (wrongly at rest) at the origin.
        let mut c = Estimator::default();
        for k in 0..(15 * head::IMU_RATE_HZ as u64) {
            let _ = c.on_imu(&Truth::imu(k * dt, bias));
            let _ = c.on_depth(k * dt, 10.0);
        }
        let far = libm::hypotf(c.solution(0).pos_ned_m[0] - p[0], c.solution(0).pos_ned_m[1] - p[1]);
        assert!(far > 50.0, "cold start {far} m from the truth");
    }

    #[test]
    fn a_warm_start_waits_for_the_levelling_and_not_after_the_filter_runs() {
        let mut e = Estimator::default();
        let rec = truth_record(10.0, [0.0; 3]);
        assert_eq!(e.warm_start(&rec, 1.0), Err(WarmStartError::NotYet));
        assert_eq!(e.warm_start(&rec, f32::NAN), Err(WarmStartError::Gap));
        assert_eq!(e.warm_start(&rec, MAX_GAP_S + 1.0), Err(WarmStartError::Gap));
        let dt = 5_000;
        for k in 0..=(WARM_LEVEL_S * 200.0) as u64 {
            e.on_imu(&Truth::imu(k * dt, [0.0; 3])).unwrap();
        }
        assert_eq!(e.warm_start(&rec, 1.0), Ok(()));
        assert!(e.warm_start_record(1_000_000).is_some());
        assert_eq!(e.warm_start(&rec, 1.0), Err(WarmStartError::Running));
        e.reset();
        assert_eq!(e.warm_start_record(0), None, "no record while the filter is not running");
    }
}
