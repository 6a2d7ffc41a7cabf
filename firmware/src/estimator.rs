//! The sensor head's estimator: static alignment, then the shared AUKF navigation filter fed by
//! the IMU, the polarization compass and the depth sensor. HAL-free; the application feeds it
//! samples and asks it for telemetry.
//!
//! Alignment (the head must be at rest): roll and pitch from the mean specific force over
//! `ALIGN_S`, the gyro bias from the mean rate; yaw from the
//! first compass fix within `ALIGN_MAX_S`, else yaw 0 with a large 1-sigma (the compass then
//! pulls it in). Depth is positive down (NED z).

use nalgebra::Vector3;
use subnav_shared::compass::{self, CompassInput, UnitModel};
use subnav_shared::ephemeris::{Observer, delta_t_estimate_s};
use subnav_shared::head;
use subnav_shared::nav::{NavConfig, NavError, NavFilter15, NavInit};
use subnav_shared::wire::{CompassReport, FilterHealth, ImuSample, NavMode, NavSolution};

const ALIGN_S: f32 = 1.0;
const ALIGN_MAX_S: f32 = 10.0;
/// Initial yaw 1-sigma when no compass fix came during alignment. Capped below pi/2: with larger
/// spreads the error-state sigma points wrap around the circle and the covariance collapses
/// (measured: an initial sigma of pi came out as 0.10 rad after 2 s of depth updates).
const YAW_UNKNOWN_SIGMA_RAD: f32 = 1.5;
/// 1-sigma of the gyro bias left after the at-rest estimate (rad/s): 0.01 deg/s.
const ALIGNED_GYRO_BIAS_SIGMA_RADPS: f32 = 1.75e-4;

#[derive(Debug, Clone, Copy, Default)]
struct Align {
    start_us: Option<u64>,
    n: u32,
    sum_accel: [f32; 3],
    sum_gyro: [f32; 3],
}

pub struct Estimator {
    cfg: NavConfig,
    compass_cfg: compass::CompassConfig,
    units: [Option<UnitModel>; head::POLARIZATION_UNITS],
    align: Align,
    nav: Option<NavFilter15>,
    /// Latest compass heading (rad, sigma) for alignment.
    yaw_fix: Option<(f32, f32)>,
    /// Low-passed specific force for the compass tilt (body FRD).
    accel_lp: [f32; 3],
    accel_seen: bool,
    /// Latest depth (for the initial position).
    last_depth_m: Option<f32>,
    /// Gyro bias measured at rest during alignment (rad/s), removed from every sample before the
    /// filter (which then estimates only the residual). The Earth rate (7.3e-5 rad/s) stays in
    /// it: below the residual the filter is tuned for.
    gyro_bias_align: [f32; 3],
    /// Rejected inputs outside the filter (non-finite before alignment, compass failures).
    pub input_rejects: u32,
}

impl Default for Estimator {
    fn default() -> Self {
        Self::new(head::nav_config())
    }
}

impl Estimator {
    pub fn new(cfg: NavConfig) -> Self {
        Self {
            cfg,
            compass_cfg: head::compass_config(),
            units: head::polarization_units(),
            align: Align::default(),
            nav: None,
            yaw_fix: None,
            accel_lp: [0.0; 3],
            accel_seen: false,
            last_depth_m: None,
            gyro_bias_align: [0.0; 3],
            input_rejects: 0,
        }
    }

    /// Back to alignment (downlink `ResetFilter`).
    pub fn reset(&mut self) {
        *self = Self::new(self.cfg);
    }

    pub fn mode(&self) -> NavMode {
        match &self.nav {
            Some(n) => n.mode(),
            None if self.align.n > 0 => NavMode::Aligning,
            None => NavMode::Uninitialised,
        }
    }

    pub fn on_imu(&mut self, s: &ImuSample) -> Result<(), NavError> {
        let finite = s.gyro_radps.iter().chain(s.accel_mps2.iter()).all(|v| v.is_finite());
        if finite {
            let a = 0.05;
            if !self.accel_seen {
                self.accel_lp = s.accel_mps2;
                self.accel_seen = true;
            }
            for (lp, v) in self.accel_lp.iter_mut().zip(s.accel_mps2) {
                *lp += a * (v - *lp);
            }
        }
        if let Some(nav) = self.nav.as_mut() {
            let mut c = *s;
            for (g, b) in c.gyro_radps.iter_mut().zip(self.gyro_bias_align) {
                *g -= b;
            }
            return nav.propagate(&c);
        }
        if !finite {
            self.input_rejects = self.input_rejects.wrapping_add(1);
            return Err(NavError::NonFinite);
        }
        let start = *self.align.start_us.get_or_insert(s.t_us);
        self.align.n += 1;
        for (acc, v) in self.align.sum_accel.iter_mut().zip(s.accel_mps2) {
            *acc += v;
        }
        for (acc, v) in self.align.sum_gyro.iter_mut().zip(s.gyro_radps) {
            *acc += v;
        }
        let elapsed_s = s.t_us.saturating_sub(start) as f32 * 1e-6;
        if elapsed_s >= ALIGN_S && (self.yaw_fix.is_some() || elapsed_s >= ALIGN_MAX_S) {
            let n = self.align.n as f32;
            let f = self.align.sum_accel.map(|v| v / n);
            let (roll, pitch) = head::level_from_accel(f);
            self.gyro_bias_align = self.align.sum_gyro.map(|v| v / n);
            let (yaw, yaw_sigma) = self.yaw_fix.unwrap_or((0.0, YAW_UNKNOWN_SIGMA_RAD));
            let mut cfg = self.cfg;
            cfg.init_sigma_att_rad[2] = yaw_sigma.max(cfg.init_sigma_att_rad[2]);
            // What is left of the gyro bias after the at-rest estimate: white noise over the
            // alignment plus the Earth rate, with margin.
            cfg.init_sigma_gyro_bias = ALIGNED_GYRO_BIAS_SIGMA_RADPS;
            let init = NavInit {
                t_us: s.t_us,
                att_nb: head::attitude(roll, pitch, yaw),
                vel_ned_mps: Vector3::zeros(),
                pos_ned_m: Vector3::new(0.0, 0.0, self.last_depth_m.unwrap_or(0.0)),
            };
            self.nav = Some(NavFilter15::new(cfg, init)?);
        }
        Ok(())
    }

    /// Run the compass on the units that were read (`(unit index, counts)`, the others failed);
    /// feed a heading fix to the filter.
    pub fn on_polarization(
        &mut self,
        t_us: u64,
        readings: &[(usize, [i16; 4])],
        utc_unix_us: Option<i64>,
        observer: Option<Observer>,
    ) -> CompassReport {
        let mut models: heapless::Vec<UnitModel, { head::POLARIZATION_UNITS }> = heapless::Vec::new();
        let mut counts: heapless::Vec<[i16; 4], { head::POLARIZATION_UNITS }> = heapless::Vec::new();
        for (idx, c) in readings {
            if let Some(Some(u)) = self.units.get(*idx) {
                if models.push(*u).is_ok() && counts.push(*c).is_err() {
                    let _ = models.pop();
                }
            }
        }
        let counts = counts.as_slice();
        let accel = if self.accel_seen { self.accel_lp } else { [f32::NAN; 3] };
        let input = CompassInput {
            counts,
            accel_body_mps2: accel,
            unix_us: utc_unix_us,
            observer,
            delta_t_s: utc_unix_us.map(delta_t_estimate_s).unwrap_or(69.0),
        };
        // Too few units is reported by the solver as a NoFix reason.
        let result = compass::solve(&models, &input, &self.compass_cfg);
        if let Ok(fix) = &result {
            self.yaw_fix = Some((fix.heading_rad, fix.sigma_heading_rad));
            if let Some(nav) = self.nav.as_mut() {
                let _ = nav.update_heading(t_us, fix.heading_rad, Some(fix.sigma_heading_rad));
            }
        }
        compass::report(t_us, &result)
    }

    pub fn on_depth(&mut self, t_us: u64, depth_m: f32) -> Result<(), NavError> {
        if !depth_m.is_finite() {
            self.input_rejects = self.input_rejects.wrapping_add(1);
            return Err(NavError::NonFinite);
        }
        self.last_depth_m = Some(depth_m);
        match self.nav.as_mut() {
            Some(nav) => nav.update_depth(t_us, depth_m, None).map(|_| ()),
            None => Ok(()),
        }
    }

    pub fn on_position_fix(&mut self, t_us: u64, pos_ned_m: [f32; 3], cov_ned_m2: [f32; 6]) -> Result<(), NavError> {
        match self.nav.as_mut() {
            Some(nav) => nav.update_position(t_us, pos_ned_m, cov_ned_m2).map(|_| ()),
            None => Err(NavError::BadTime),
        }
    }

    pub fn solution(&self, t_us: u64) -> NavSolution {
        match &self.nav {
            Some(nav) => nav.solution(),
            None => NavSolution {
                t_us,
                mode: self.mode(),
                pos_ned_m: [0.0, 0.0, self.last_depth_m.unwrap_or(0.0)],
                vel_ned_mps: [0.0; 3],
                att_nb_wxyz: [1.0, 0.0, 0.0, 0.0],
                sigma_pos_m: [f32::INFINITY; 3],
                sigma_vel_mps: [f32::INFINITY; 3],
                sigma_att_rad: [f32::INFINITY; 3],
            },
        }
    }

    pub fn health(&self, t_us: u64) -> FilterHealth {
        match &self.nav {
            Some(nav) => {
                let mut h = nav.health();
                h.nonfinite_rejects = h.nonfinite_rejects.saturating_add(self.input_rejects);
                h
            }
            None => FilterHealth {
                t_us,
                nis: [f32::NAN; 4],
                lambda: 1.0,
                q_diag: [0.0; 5],
                r_diag: [0.0; 4],
                pd_repairs: 0,
                gate_rejects: 0,
                nonfinite_rejects: self.input_rejects,
                cpu_load_permille: 0,
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn still(t_us: u64) -> ImuSample {
        ImuSample { t_us, gyro_radps: [0.0; 3], accel_mps2: [0.0, 0.0, -9.81], temp_c: 20.0 }
    }

    #[test]
    fn aligns_without_compass_after_the_timeout_and_then_aids_with_depth() {
        let mut e = Estimator::default();
        assert_eq!(e.mode(), NavMode::Uninitialised);
        let dt = 1_000_000 / u64::from(head::IMU_RATE_HZ);
        let mut t = 0;
        for k in 0..(12 * head::IMU_RATE_HZ) {
            t = u64::from(k) * dt;
            e.on_imu(&still(t)).unwrap();
            if k % 20 == 0 {
                e.on_depth(t, 10.0).unwrap();
            }
            if k == 10 {
                assert_eq!(e.mode(), NavMode::Aligning);
            }
        }
        assert!(matches!(e.mode(), NavMode::Aided), "{:?}", e.mode());
        let s = e.solution(t);
        assert!(s.pos_ned_m.iter().chain(s.vel_ned_mps.iter()).all(|v| v.is_finite()));
        assert!((s.pos_ned_m[2] - 10.0).abs() < 0.1, "depth {:?}", s.pos_ned_m);
        assert!(s.sigma_att_rad[2] > 1.0, "yaw is unknown without a compass: {:?}", s.sigma_att_rad);
    }

    #[test]
    fn nan_samples_do_not_poison_alignment_or_the_filter() {
        let mut e = Estimator::default();
        let dt = 5_000;
        for k in 0..3000u64 {
            let mut s = still(k * dt);
            if k % 97 == 0 {
                s.gyro_radps[1] = f32::NAN;
            }
            let _ = e.on_imu(&s);
        }
        let _ = e.on_depth(3000 * dt, f32::INFINITY);
        let s = e.solution(3000 * dt);
        assert!(s.pos_ned_m.iter().chain(s.att_nb_wxyz.iter()).all(|v| v.is_finite()));
        assert!(e.health(0).nonfinite_rejects > 0);
    }

    #[test]
    fn compass_without_time_says_so() {
        let mut e = Estimator::default();
        let r = e.on_polarization(0, &[(0, [100; 4]), (1, [100; 4]), (2, [100; 4]), (3, [100; 4])], None, None);
        assert!(r.heading_rad.is_none());
        assert_ne!(r.no_fix_reason, 0);
    }
}
