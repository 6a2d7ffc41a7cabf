//! [`NavFilter`]: nominal state + error-state UKF, the propagation entry point and the plumbing
//! shared by the per-sensor updates (`heading.rs`, `depth.rs`, `velocity.rs`, `position.rs`).

use nalgebra::{Matrix3, Quaternion, SMatrix, SVector, UnitQuaternion, Vector3};

use crate::ukf::gate::chi2_999;
use crate::ukf::{AdaptConfig, MeasNoise, NisQScale, QScaleConfig, Ukf, UkfConfig, UkfError, UpdateReport};
use subnav_wire::messages::{ImuSample, NavMode, NavSolution};

use super::history::{CURRENT_WITHIN_US, History, PastEpoch, Snapshot};
use super::rotation::{a3, add, cross, dot, mul, quat_from_rotation_vector, rows_of, scale, sub, us_to_s};
use super::state::{ATT, BA, BG, MARKOV, NominalState, POS, VEL, seg, set_seg, yaw_of};
use super::strapdown::{self, Increments};

/// Update kinds, in the order of `FilterHealth::nis` / `r_diag`.
pub const KIND_HEADING: usize = 0;
pub const KIND_DEPTH: usize = 1;
pub const KIND_VELOCITY: usize = 2;
pub const KIND_POSITION: usize = 3;

/// Noise and gate of one aiding sensor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorConfig {
    /// Default 1-sigma noise per axis (unit of the measurement).
    pub sigma: f32,
    /// Floor for an adapted R, as a 1-sigma.
    pub sigma_floor: f32,
    /// Chi-square gate on the NIS (`f32::INFINITY` = no gate).
    pub gate: f32,
    /// Gate floor: state part of the gating covariance capped at this multiple of R.
    pub gate_state_max: f32,
    /// Lift the cap after this many consecutive rejections (0 = never).
    pub gate_release_after: u32,
    /// Sage-Husa R adaptation for this sensor (if on in the UKF config).
    pub adapt: bool,
    /// Error states the fading factor may scale on this sensor's updates (bit i = state i).
    pub fading_mask: u64,
}

const fn bits(idx: &[usize]) -> u64 {
    let mut m = 0u64;
    let mut i = 0;
    while i < idx.len() {
        m |= 1u64 << idx[i];
        i += 1;
    }
    m
}

impl SensorConfig {
    pub(crate) fn noise<const M: usize>(&self) -> MeasNoise<f32, M> {
        let mut n = MeasNoise::new(SMatrix::<f32, M, M>::identity() * (self.sigma * self.sigma))
            .with_gate(self.gate, self.gate_state_max, self.gate_release_after)
            .with_floor(self.sigma_floor * self.sigma_floor);
        n.adapt = self.adapt;
        n.fading_mask = self.fading_mask;
        n
    }
}

/// Navigation filter configuration. [`NavConfig::default`] is the sensor head's tuning.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavConfig {
    /// UKF parameters and the adaptive-layer switches.
    pub ukf: UkfConfig<f32>,
    /// Nominal IMU rate (used for the nominal covariance interval).
    pub imu_rate_hz: f32,
    /// Covariance (UKF predict) every this many IMU samples; updates flush a partial interval.
    pub cov_decimation: u32,
    pub gravity_mps2: f32,
    /// IMU samples further apart than this are not integrated (clock jump); counted.
    pub max_imu_dt_s: f32,
    /// Plausibility limits of an IMU sample (beyond: rejected like a non-finite one).
    pub max_gyro_radps: f32,
    pub max_accel_mps2: f32,
    /// Gyro angle random walk, rad/sqrt(s).
    pub gyro_arw: f32,
    /// Accelerometer velocity random walk, m/s/sqrt(s).
    pub accel_vrw: f32,
    /// Position random walk (model error), m/sqrt(s).
    pub pos_rw: f32,
    /// Gyro bias random walk, rad/s/sqrt(s).
    pub gyro_bias_rw: f32,
    /// Accelerometer bias random walk, m/s^2/sqrt(s).
    pub accel_bias_rw: f32,
    /// First-order Markov gyro drift (18-state): steady-state sigma (rad/s) and time constant (s).
    pub markov_sigma: f32,
    pub markov_tau_s: f32,
    /// Initial 1-sigma of the error groups.
    pub init_sigma_att_rad: [f32; 3],
    pub init_sigma_vel_mps: f32,
    pub init_sigma_pos_m: f32,
    pub init_sigma_gyro_bias: f32,
    pub init_sigma_accel_bias: f32,
    pub heading: SensorConfig,
    pub depth: SensorConfig,
    pub velocity: SensorConfig,
    pub position: SensorConfig,
    /// Mode falls back to `Inertial` when no aiding update was accepted for this long.
    pub aided_timeout_s: f32,
    /// Horizontal position random walk added while coasting without the IMU, m/sqrt(s): the
    /// constant-velocity coast cannot follow a turn between two velocity updates (at 1 m/s on
    /// a 10 m radius, 3 mm per 0.25 s, always toward the outside), a bias a DVL-held velocity
    /// sigma does not cover.
    pub coast_position_rw: f32,
    /// A position or velocity measurement stamped more than this after the filter time is
    /// refused (`NavError::FromFuture`); up to it, it is fused as current. µs.
    pub max_future_us: u64,
    /// The IMU's process noise (attitude and velocity random walks) scaled to match the
    /// velocity and position innovations, refused ones included ([`NisQScale`]): an IMU noisier
    /// than `gyro_arw` / `accel_vrw` widens the filter instead of starving it at its gates.
    pub imu_q_adapt: QScaleConfig<f32>,
}

impl Default for NavConfig {
    fn default() -> Self {
        let mut ukf = UkfConfig::plain(0.5, 2.0, 0.0);
        ukf.p_floor = 1e-12;
        ukf.p_rel_floor = 1e-9;
        ukf.q_floor = 1e-14;
        Self {
            ukf,
            imu_rate_hz: 100.0,
            cov_decimation: 10,
            gravity_mps2: 9.81,
            max_imu_dt_s: 0.1,
            max_gyro_radps: 35.0,
            max_accel_mps2: 160.0,
            gyro_arw: 0.003,
            accel_vrw: 0.003,
            pos_rw: 0.005,
            gyro_bias_rw: 2e-5,
            accel_bias_rw: 1e-4,
            markov_sigma: 1e-4,
            markov_tau_s: 300.0,
            init_sigma_att_rad: [0.02, 0.02, 0.1],
            init_sigma_vel_mps: 0.1,
            init_sigma_pos_m: 1.0,
            init_sigma_gyro_bias: 0.002,
            init_sigma_accel_bias: 0.05,
            heading: SensorConfig {
                sigma: 0.01,
                sigma_floor: 0.003,
                gate: chi2_999(1),
                gate_state_max: 16.0,
                gate_release_after: 10,
                adapt: true,
                fading_mask: bits(&[0, 1, 2, 9, 10, 11]),
            },
            depth: SensorConfig {
                sigma: 0.05,
                sigma_floor: 0.01,
                gate: chi2_999(1),
                gate_state_max: 16.0,
                gate_release_after: 10,
                adapt: true,
                fading_mask: bits(&[5, 8]),
            },
            velocity: SensorConfig {
                sigma: 0.02,
                sigma_floor: 0.005,
                gate: chi2_999(3),
                gate_state_max: 16.0,
                gate_release_after: 10,
                adapt: true,
                fading_mask: bits(&[0, 1, 2, 3, 4, 5]),
            },
            position: SensorConfig {
                sigma: 1.0,
                sigma_floor: 0.01,
                gate: chi2_999(3),
                gate_state_max: 16.0,
                gate_release_after: 3,
                adapt: false,
                fading_mask: bits(&[3, 4, 5, 6, 7, 8]),
            },
            aided_timeout_s: 5.0,
            max_future_us: 200_000,
            coast_position_rw: 0.15,
            imu_q_adapt: QScaleConfig::off(),
        }
    }
}

impl NavConfig {
    /// The adaptive (AUKF) variant of a configuration: Sage-Husa R estimation and the fading
    /// factor with its persistence test on (Q adaptation stays off: the aiding sensors observe
    /// too little of the 15-state process noise to estimate it; it can be switched on in
    /// `ukf.adapt`). `fading_persist = 0` gives the seed's fading factor (its divergence test
    /// alone), which reads a rise in sensor noise as divergence (`crate::ukf::adapt`).
    pub fn adaptive(mut self) -> Self {
        self.ukf.adapt = AdaptConfig {
            b: 0.95,
            k0: 20,
            r_cov: true,
            fading: true,
            fading_s: 4.0,
            lambda0: 1.0,
            lambda_max: 3.0,
            rho: 0.95,
            fading_persist: 1.0,
            ..AdaptConfig::plain()
        };
        self
    }

    /// Nominal covariance interval, s.
    pub fn cov_dt_s(&self) -> f32 {
        self.cov_decimation.max(1) as f32 / self.imu_rate_hz
    }

    fn is_valid(&self) -> bool {
        let pos = |v: f32| v.is_finite() && v > 0.0;
        pos(self.imu_rate_hz)
            && pos(self.gravity_mps2)
            && pos(self.max_imu_dt_s)
            && pos(self.markov_tau_s)
            && self.coast_position_rw.is_finite()
            && self.coast_position_rw >= 0.0
            && self.imu_q_adapt.is_valid()
            && [self.heading, self.depth, self.velocity, self.position]
                .iter()
                .all(|s| pos(s.sigma) && s.sigma_floor >= 0.0 && s.gate > 0.0 && s.gate_state_max > 0.0)
    }
}

/// Initial state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavInit {
    pub t_us: u64,
    pub att_nb: UnitQuaternion<f32>,
    pub vel_ned_mps: Vector3<f32>,
    pub pos_ned_m: Vector3<f32>,
}

/// Why a call had no effect.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NavError {
    /// Configuration out of range.
    BadConfig,
    /// NaN / Inf (or implausibly large) sample: rejected, state untouched, counted.
    NonFinite,
    /// Sample time not after the previous one, or a gap longer than `max_imu_dt_s`.
    BadTime,
    /// The UKF refused the step (state untouched).
    Filter(UkfError),
    /// Measurement valid before the oldest entry of the state history (see
    /// [`super::history`]): refused, state untouched, counted.
    TooOld,
    /// Measurement stamped more than `NavConfig::max_future_us` after the filter time: refused,
    /// state untouched, counted.
    FromFuture,
}

impl core::fmt::Display for NavError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            NavError::BadConfig => f.write_str("navigation filter configuration out of range"),
            NavError::NonFinite => f.write_str("sample is NaN, infinite or implausibly large: rejected"),
            NavError::BadTime => f.write_str("sample time not after the previous one, or the IMU gap exceeds max_imu_dt_s"),
            NavError::Filter(e) => write!(f, "the UKF refused the step: {e}"),
            NavError::TooOld => f.write_str("measurement valid before the oldest entry of the state history: too old to fuse"),
            NavError::FromFuture => f.write_str("measurement stamped further in the future than max_future_us: refused"),
        }
    }
}

impl core::error::Error for NavError {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        match self {
            NavError::Filter(e) => Some(e),
            _ => None,
        }
    }
}

/// Keep what a UKF update applied from the trial copy `trial` of a sensor's noise statistics
/// (the copy carries a sensor-supplied sigma, which only an accepted measurement may leave
/// behind): all of it after an accepted update; after a gate rejection the gate's count and, if
/// the Sage-Husa recursion ran (its counter moved), R, r and that counter; nothing after a
/// refusal.
pub(crate) fn settle<const M: usize>(stored: &mut MeasNoise<f32, M>, trial: MeasNoise<f32, M>, r: &Result<UpdateReport<f32>, UkfError>) {
    match r {
        Ok(rep) if rep.accepted => *stored = trial,
        Ok(_) => {
            stored.consecutive_rejects = trial.consecutive_rejects;
            if trial.k != stored.k {
                (stored.r, stored.r_mean, stored.k) = (trial.r, trial.r_mean, trial.k);
            }
        }
        Err(_) => {}
    }
}

impl From<UkfError> for NavError {
    fn from(e: UkfError) -> Self {
        match e {
            UkfError::NonFiniteInput => NavError::NonFinite,
            other => NavError::Filter(other),
        }
    }
}

/// The sensor head's navigation filter: `N` = 15 (or 18 with Markov gyro drift) error states,
/// `S = 2N + 1` sigma points. Use [`NavFilter15`] / [`NavFilter18`].
#[derive(Debug, Clone)]
pub struct NavFilter<const N: usize, const S: usize> {
    pub(crate) cfg: NavConfig,
    pub(crate) ukf: Ukf<f32, N, S>,
    pub(crate) nom: NominalState,
    pub(crate) inc: Increments,
    pub(crate) noise_heading: MeasNoise<f32, 1>,
    pub(crate) noise_depth: MeasNoise<f32, 1>,
    pub(crate) noise_vel: MeasNoise<f32, 3>,
    pub(crate) noise_pos: MeasNoise<f32, 3>,
    pub(crate) t_us: u64,
    pub(crate) last_imu_t_us: Option<u64>,
    pub(crate) last_aided_t_us: Option<u64>,
    pub(crate) nis: [f32; 4],
    pub(crate) imu_rejects: u32,
    pub(crate) time_rejects: u32,
    pub(crate) lambda: f32,
    /// Past nominal states for measurements fused at their own time (see [`super::history`]).
    pub(crate) hist: History,
    pub(crate) delayed_updates: u32,
    pub(crate) delay_rejects: u32,
    /// The IMU process-noise scale (`NavConfig::imu_q_adapt`) and the scale the UKF's `Q` holds.
    pub(crate) q_scale: NisQScale<f32>,
    pub(crate) q_scale_applied: f32,
    /// Time of validity of the last accepted velocity update (for the IMU noise scale's
    /// evidence).
    pub(crate) last_vel_accepted_us: Option<u64>,
    /// The history correction not yet applied ([`Self::inject`]): the summed error means
    /// injected at `pend_now.t_us`, the nominal before the first of them; `pend_on` if any.
    pub(crate) pend_dx: SVector<f32, N>,
    /// (Attitude, velocity and position of the nominal, and the time: 48 B.)
    pub(crate) pend_now: Snapshot,
    pub(crate) pend_on: bool,
    /// Filter time at which `inc` started (the last covariance step).
    pub(crate) inc_start_us: u64,
    /// The yaw has had no heading aid yet ([`Self::set_yaw_unobserved`]).
    pub(crate) yaw_unobserved: bool,
}

pub type NavFilter15 = NavFilter<15, 31>;
pub type NavFilter18 = NavFilter<18, 37>;

/// The yaw error (the NED attitude error's down component) made independent of every other
/// state, with variance `var_rad2`: its row and column zeroed but the diagonal. Zeroing one row
/// and column of a positive definite matrix leaves it positive definite. Used by the heading
/// reset and while the yaw is unobserved ([`NavFilter::set_yaw_unobserved`]).
pub(crate) fn set_yaw_uncorrelated<const N: usize>(p: &mut SMatrix<f32, N, N>, var_rad2: f32) {
    let yaw = ATT + 2;
    for i in 0..N {
        for idx in [(yaw, i), (i, yaw)] {
            if let Some(v) = p.get_mut(idx) {
                *v = 0.0;
            }
        }
    }
    if let Some(v) = p.get_mut((yaw, yaw)) {
        *v = var_rad2;
    }
}

fn group_diag<const N: usize>(d: &mut SVector<f32, N>, start: usize, v: f32) {
    set_seg(d, start, &Vector3::new(v, v, v));
}

impl<const N: usize, const S: usize> NavFilter<N, S> {
    /// A filter at `init` (N must be 15 or 18).
    pub fn new(cfg: NavConfig, init: NavInit) -> Result<Self, NavError> {
        let (nom, p0) = Self::initial(&cfg, &init)?;
        let ukf = Ukf::new(cfg.ukf, SVector::zeros(), SMatrix::from_diagonal(&p0), Self::nominal_q(&cfg))?;
        // Built in one literal (no by-value builder steps: each moved the whole filter, 8 KB,
        // through the M4F's stack at boot).
        let k0 = cfg.ukf.adapt.k0;
        let mut hist = History::new();
        hist.restart(init.t_us, &nom);
        Ok(Self {
            cfg,
            ukf,
            nom,
            inc: Increments::zero(),
            noise_heading: cfg.heading.noise().with_k(k0),
            noise_depth: cfg.depth.noise().with_k(k0),
            noise_vel: cfg.velocity.noise().with_k(k0),
            noise_pos: cfg.position.noise().with_k(k0),
            t_us: init.t_us,
            last_imu_t_us: None,
            last_aided_t_us: None,
            nis: [0.0; 4],
            imu_rejects: 0,
            time_rejects: 0,
            lambda: 1.0,
            hist,
            delayed_updates: 0,
            delay_rejects: 0,
            q_scale: NisQScale::default(),
            q_scale_applied: 1.0,
            last_vel_accepted_us: None,
            pend_dx: SVector::zeros(),
            // Unused while `pend_on` is false.
            pend_now: Snapshot::of(0, &NominalState::zero()),
            pend_on: false,
            inc_start_us: init.t_us,
            yaw_unobserved: false,
        })
    }

    /// Re-initialise in place, exactly as [`NavFilter::new`] would build the filter (on failure
    /// it is left unchanged). The sensor head uses this at the end of its alignment: building a
    /// second filter by value cost 26 KB of stack on the M4F.
    pub fn reinit(&mut self, cfg: NavConfig, init: NavInit) -> Result<(), NavError> {
        let (nom, p0) = Self::initial(&cfg, &init)?;
        self.ukf.reinit(cfg.ukf, SVector::zeros(), SMatrix::from_diagonal(&p0), Self::nominal_q(&cfg))?;
        self.cfg = cfg;
        self.nom = nom;
        self.inc = Increments::zero();
        self.noise_heading = cfg.heading.noise();
        self.noise_depth = cfg.depth.noise();
        self.noise_vel = cfg.velocity.noise();
        self.noise_pos = cfg.position.noise();
        let k0 = cfg.ukf.adapt.k0;
        self.noise_heading.k = k0;
        self.noise_depth.k = k0;
        self.noise_vel.k = k0;
        self.noise_pos.k = k0;
        self.t_us = init.t_us;
        self.last_imu_t_us = None;
        self.last_aided_t_us = None;
        self.nis = [0.0; 4];
        self.imu_rejects = 0;
        self.time_rejects = 0;
        self.lambda = 1.0;
        self.restart_history();
        self.delayed_updates = 0;
        self.delay_rejects = 0;
        self.q_scale = NisQScale::default();
        self.q_scale_applied = 1.0;
        self.last_vel_accepted_us = None;
        self.pend_on = false;
        self.pend_dx = SVector::zeros();
        self.inc_start_us = init.t_us;
        self.yaw_unobserved = false;
        Ok(())
    }

    /// Checked nominal state and initial covariance diagonal of `init`.
    fn initial(cfg: &NavConfig, init: &NavInit) -> Result<(NominalState, SVector<f32, N>), NavError> {
        if (N != 15 && N != 18) || !cfg.is_valid() {
            return Err(NavError::BadConfig);
        }
        let nom = NominalState {
            att_nb: init.att_nb,
            vel_ned_mps: init.vel_ned_mps,
            pos_ned_m: init.pos_ned_m,
            gyro_bias_radps: Vector3::zeros(),
            accel_bias_mps2: Vector3::zeros(),
            gyro_markov_radps: Vector3::zeros(),
        };
        if !nom.is_finite() {
            return Err(NavError::NonFinite);
        }
        let mut p0 = SVector::<f32, N>::zeros();
        let a = cfg.init_sigma_att_rad;
        set_seg(&mut p0, ATT, &Vector3::new(a[0] * a[0], a[1] * a[1], a[2] * a[2]));
        group_diag(&mut p0, VEL, cfg.init_sigma_vel_mps * cfg.init_sigma_vel_mps);
        group_diag(&mut p0, POS, cfg.init_sigma_pos_m * cfg.init_sigma_pos_m);
        group_diag(&mut p0, BG, cfg.init_sigma_gyro_bias * cfg.init_sigma_gyro_bias);
        group_diag(&mut p0, BA, cfg.init_sigma_accel_bias * cfg.init_sigma_accel_bias);
        if N >= MARKOV + 3 {
            group_diag(&mut p0, MARKOV, cfg.markov_sigma * cfg.markov_sigma);
        }
        Ok((nom, p0))
    }

    /// Process noise over one nominal covariance interval.
    fn nominal_q(cfg: &NavConfig) -> SMatrix<f32, N, N> {
        Self::scaled_q(cfg, 1.0)
    }

    /// Process noise over one nominal covariance interval with the IMU's white-noise parts
    /// (attitude and velocity random walks) scaled by `imu_scale` (a variance ratio).
    fn scaled_q(cfg: &NavConfig, imu_scale: f32) -> SMatrix<f32, N, N> {
        let t = cfg.cov_dt_s();
        let mut d = SVector::<f32, N>::zeros();
        group_diag(&mut d, ATT, cfg.gyro_arw * cfg.gyro_arw * t * imu_scale);
        group_diag(&mut d, VEL, cfg.accel_vrw * cfg.accel_vrw * t * imu_scale);
        group_diag(&mut d, POS, cfg.pos_rw * cfg.pos_rw * t);
        group_diag(&mut d, BG, cfg.gyro_bias_rw * cfg.gyro_bias_rw * t);
        group_diag(&mut d, BA, cfg.accel_bias_rw * cfg.accel_bias_rw * t);
        if N >= MARKOV + 3 {
            group_diag(&mut d, MARKOV, 2.0 * cfg.markov_sigma * cfg.markov_sigma / cfg.markov_tau_s * t);
        }
        SMatrix::from_diagonal(&d)
    }

    /// IMU-rate propagation: strapdown of the nominal state; a UKF predict every
    /// `cov_decimation` samples. A non-finite or implausible sample is rejected (state
    /// untouched); the next good sample integrates over the gap.
    pub fn propagate(&mut self, imu: &ImuSample) -> Result<(), NavError> {
        let g = Vector3::from(imu.gyro_radps);
        let a = Vector3::from(imu.accel_mps2);
        if !g.iter().chain(a.iter()).all(|v| v.is_finite()) || g.amax() > self.cfg.max_gyro_radps || a.amax() > self.cfg.max_accel_mps2 {
            self.imu_rejects = self.imu_rejects.saturating_add(1);
            return Err(NavError::NonFinite);
        }
        let Some(last) = self.last_imu_t_us else {
            // The first sample starts the integration at its time. The initial state's history
            // entry stays valid if the sample follows it within an IMU interval (the nominal is
            // taken as unchanged across it, as across any sample interval); else it restarts.
            let near = imu.t_us >= self.t_us && (imu.t_us - self.t_us) as f32 * 1e-6 <= self.cfg.max_imu_dt_s;
            self.last_imu_t_us = Some(imu.t_us);
            self.t_us = imu.t_us;
            if self.inc.samples == 0 {
                self.inc_start_us = imu.t_us;
            }
            if !near {
                self.restart_history();
            }
            return Ok(());
        };
        if imu.t_us <= last {
            self.time_rejects = self.time_rejects.saturating_add(1);
            return Err(NavError::BadTime);
        }
        let dt = us_to_s(imu.t_us - last);
        self.last_imu_t_us = Some(imu.t_us);
        self.t_us = imu.t_us;
        if dt > self.cfg.max_imu_dt_s {
            // The nominal did not move across the gap: the past before it is no trajectory.
            self.restart_history();
            self.time_rejects = self.time_rejects.saturating_add(1);
            return Err(NavError::BadTime);
        }
        let before = self.nom;
        let inc_before = self.inc;
        strapdown::step(&mut self.nom, &mut self.inc, &g, &a, dt, self.cfg.gravity_mps2);
        if !self.nom.is_finite() {
            self.nom = before;
            self.inc = inc_before;
            self.imu_rejects = self.imu_rejects.saturating_add(1);
            return Err(NavError::NonFinite);
        }
        if self.inc.samples >= self.cfg.cov_decimation.max(1) {
            self.cov_predict()?;
        }
        self.record_history();
        Ok(())
    }

    /// Degraded IMU (a gyro axis stuck, the other five good): propagate on `imu`, whose gyro
    /// axes in `unknown_axes` (bit k = body axis k) carry no rate (the caller zeroed them), and
    /// let the attitude error grow about those body axes by a rate random walk `rate_rw`
    /// (rad/sqrt(s)): the unmeasured turn. The velocity and tilt keep the accelerometer and the
    /// good gyro axes (coasting would lose both: measured, a 5-minute coast with a stuck gyro
    /// axis let roll and pitch wander to 96 and 52 deg, nothing observing them); the compass
    /// carries the heading. A refused sample changes nothing.
    pub fn propagate_unknown_rates(&mut self, imu: &ImuSample, unknown_axes: u8, rate_rw: f32) -> Result<(), NavError> {
        if !(rate_rw.is_finite() && rate_rw >= 0.0) {
            return Err(self.reject_nonfinite());
        }
        let last = self.last_imu_t_us;
        self.propagate(imu)?;
        let dt = match last {
            Some(l) if imu.t_us > l => (imu.t_us - l) as f32 * 1e-6,
            _ => 0.0,
        };
        let mut var_body = Vector3::zeros();
        for k in 0..3 {
            if unknown_axes & (1 << k) != 0 {
                if let Some(v) = var_body.get_mut(k) {
                    *v = rate_rw * rate_rw * dt;
                }
            }
        }
        if var_body != Vector3::zeros() {
            self.add_unknown_rate_noise(&var_body)?;
        }
        Ok(())
    }

    /// Run the UKF predict now over the IMU increments accumulated since the last one (updates
    /// do this themselves; a firmware app may call it to bound the latency of `solution()`'s
    /// sigmas).
    pub fn flush_covariance(&mut self) -> Result<(), NavError> {
        self.cov_predict()
    }

    /// Whether the yaw has had no heading aid yet (an alignment without the compass): then the
    /// yaw error is kept independent of the other states after each predict
    /// ([`Self::decouple_yaw`]) and the DVL's velocity is fused as if it did not depend on it. At rest (or drifting at
    /// the surface) the body velocity's dependence on the yaw is `|v| x dpsi` with the filter's
    /// own near-zero velocity in place of the unknown true one, and the sigma points read that
    /// as information: measured in the simulated dives, the yaw sigma of an unaided alignment fell
    /// from 86 to 48 deg in 4.5 s at rest with the DVL and depth as the only aids. The
    /// caller clears it at the first heading aid (a compass fix fused or a heading reset);
    /// re-initialisation clears it.
    pub fn set_yaw_unobserved(&mut self, unobserved: bool) {
        self.yaw_unobserved = unobserved;
    }

    pub fn yaw_unobserved(&self) -> bool {
        self.yaw_unobserved
    }

    /// The yaw error made independent of every other state, its variance kept (while
    /// [`Self::set_yaw_unobserved`]; after each predict). The predict couples a yaw error into
    /// the velocity through the nominal's horizontal specific force (`Exp(phi) dv_f`): real on
    /// a vehicle that accelerates, at rest only the noise the aids left in the nominal, and
    /// with the yaw's sigma points 166 deg apart that noise built yaw-velocity and
    /// yaw-accelerometer-bias correlations through which the DVL and the depth took the yaw
    /// sigma from 86 to 32 deg in 20 s at rest.
    #[inline(never)]
    #[cold]
    fn decouple_yaw(&mut self) -> Result<(), NavError> {
        let mut p = *self.ukf.p();
        let var = p.get((ATT + 2, ATT + 2)).copied().unwrap_or(0.0);
        set_yaw_uncorrelated(&mut p, var);
        self.ukf.set_p(p)?;
        Ok(())
    }

    /// UKF predict over the increments accumulated since the last one.
    pub(crate) fn cov_predict(&mut self) -> Result<(), NavError> {
        if self.inc.samples == 0 || !(self.inc.dt_s > 0.0) {
            return Ok(());
        }
        let inc = self.inc;
        let decay = libm::expf(-inc.dt_s / self.cfg.markov_tau_s);
        let q_scale = inc.dt_s / self.cfg.cov_dt_s();
        // A refused predict keeps the increments: the next predict covers their interval too.
        // Without an attitude error in the mean (the usual case: every step injects it), the
        // error transition is linear in the other states (`strapdown::propagate_error`):
        // their sigma points pair up (`Ukf::predict_dep`).
        let lin_from = if seg(self.ukf.x(), ATT) == Vector3::zeros() { ATT + 3 } else { N };
        self.ukf.predict_dep(q_scale, lin_from, |dx| strapdown::propagate_error(dx, &inc, decay))?;
        if self.yaw_unobserved {
            self.decouple_yaw()?;
        }
        // A history correction pending since the start of these increments is carried to now
        // through the same error transition (to first order, retrodicting the carried error
        // from now is retrodicting the original one from its time), so the injections of
        // successive instants share one pass over the history (see `inject`).
        if self.pend_on && self.pend_now.t_us == self.inc_start_us {
            self.pend_dx = strapdown::propagate_error(&self.pend_dx, &inc, decay);
            self.pend_now = Snapshot::of(self.t_us, &self.nom);
        }
        self.inc = Increments::zero();
        self.inc_start_us = self.t_us;
        self.inject()
    }

    /// The attitude noise of gyro axes with unknown rates ([`Self::propagate_unknown_rates`]):
    /// the body axes' variances in the NED attitude error, `P_att += R diag(v) R^T`, at every
    /// degraded sample (a `set_p`, so a Cholesky factor, per IMU sample: degraded mode only).
    /// Not accumulated in the filter until the next predict: a 12-byte field grew the boot
    /// path's frame by 1.5 KB. Out of line and cold, so its candidate `P` stays out of the
    /// propagation's frame (the M4F's stack).
    #[inline(never)]
    #[cold]
    fn add_unknown_rate_noise(&mut self, var_body: &Vector3<f32>) -> Result<(), NavError> {
        let r: Matrix3<f32> = self.nom.att_nb.to_rotation_matrix().into_inner();
        let add = r * Matrix3::from_diagonal(var_body) * r.transpose();
        let mut p = *self.ukf.p();
        let mut blk = p.fixed_view_mut::<3, 3>(ATT, ATT);
        blk += add;
        self.ukf.set_p(p)?;
        Ok(())
    }

    /// Degraded mode without the IMU (failed or stuck): advance to `t_us` at constant velocity;
    /// the error covariance grows by the nominal process noise plus random walks of
    /// `attitude_rw` (rad/sqrt(s)) and `velocity_rw` (m/s/sqrt(s)) per axis and
    /// `NavConfig::coast_position_rw` on the horizontal position, so the aiding
    /// sensors (compass, depth, fixes) carry the state instead of being gated out against a
    /// frozen, over-confident one. The next IMU sample continues from `t_us`.
    pub fn coast(&mut self, t_us: u64, attitude_rw: f32, velocity_rw: f32) -> Result<(), NavError> {
        if !(attitude_rw.is_finite() && velocity_rw.is_finite() && attitude_rw >= 0.0 && velocity_rw >= 0.0) {
            return Err(self.reject_nonfinite());
        }
        self.cov_predict()?;
        if t_us <= self.t_us {
            return Ok(());
        }
        let dt = (t_us - self.t_us) as f32 * 1e-6;
        let mut nom = self.nom;
        nom.pos_ned_m += nom.vel_ned_mps * dt;
        if !nom.is_finite() {
            return Err(NavError::NonFinite);
        }
        let mut inc = Increments::zero();
        inc.dt_s = dt;
        let decay = libm::expf(-dt / self.cfg.markov_tau_s);
        self.ukf.predict(dt / self.cfg.cov_dt_s(), |dx| strapdown::propagate_error(dx, &inc, decay))?;
        let mut p = *self.ukf.p();
        for k in 0..3 {
            if let Some(v) = p.get_mut((ATT + k, ATT + k)) {
                *v += attitude_rw * attitude_rw * dt;
            }
            if let Some(v) = p.get_mut((VEL + k, VEL + k)) {
                *v += velocity_rw * velocity_rw * dt;
            }
        }
        let prw = self.cfg.coast_position_rw.max(0.0);
        for k in 0..2 {
            if let Some(v) = p.get_mut((POS + k, POS + k)) {
                *v += prw * prw * dt;
            }
        }
        self.ukf.set_p(p)?;
        self.nom = nom;
        self.t_us = t_us;
        self.last_imu_t_us = Some(t_us);
        // The pending correction belongs to the time before the coast (its coast model).
        self.flush_history();
        self.hist.mark_coast(t_us);
        self.inject()?;
        self.record_history();
        Ok(())
    }

    /// Fold the error mean into the nominal state and reset it; the same correction, mapped back
    /// to each entry's time, goes into the state history, after updates and predicts alike: the
    /// history's increments (`dv_f`, `dp_f`) are differences of nominal states, so every change
    /// of the current nominal must reach the past too, or those differences would count the
    /// change as specific force (measured: skipping the predicts' means made a 3 s late fix end
    /// 7.5 mm instead of 0.7 mm from the on-time one).
    ///
    /// The history's share is deferred and summed over the injections at one filter time (the
    /// predict and the updates of one instant: compass and depth after the predict they flush):
    /// one pass over the 28 entries instead of one per injection (at the head's rates ~40
    /// injections a second fall to ~15). Summing instead of composing the corrections neglects
    /// their products (`phi_1 x phi_2 / 2` in the attitude: 5e-7 rad for two mrad-sized
    /// corrections, against 1.2e-5 rad of the map itself). It is applied before the history is
    /// read or appended to ([`Self::flush_history`]).
    pub(crate) fn inject(&mut self) -> Result<(), NavError> {
        let dx = *self.ukf.x();
        let mut nom = self.nom;
        nom.inject(&dx);
        if !nom.is_finite() {
            return Err(NavError::NonFinite);
        }
        self.ukf.set_x(SVector::zeros())?;
        if dx.iter().all(|v| *v == 0.0) {
            return Ok(());
        }
        if !(self.pend_on && self.pend_now.t_us == self.t_us) {
            self.flush_history();
            self.pend_on = true;
            self.pend_now = Snapshot::of(self.t_us, &self.nom);
            self.pend_dx = SVector::zeros();
        }
        self.pend_dx += dx;
        self.nom = nom;
        Ok(())
    }

    /// Apply the pending history correction (see [`Self::inject`]); the history is then
    /// consistent with the nominal state. Called before every read of the history; public for
    /// callers that inspect [`Self::history`].
    pub fn flush_history(&mut self) {
        if !self.pend_on {
            return;
        }
        self.pend_on = false;
        let dx = self.pend_dx;
        self.pend_dx = SVector::zeros();
        if !self.correct_history(&dx) {
            // Not reachable with a finite state; an emptied history refuses delayed updates.
            self.restart_history();
        }
    }

    /// Forget the past (and the pending correction, which was for it) and restart the history
    /// at the current state.
    pub(crate) fn restart_history(&mut self) {
        self.pend_on = false;
        self.pend_dx = SVector::zeros();
        self.hist.restart(self.t_us, &self.nom);
    }

    /// Record the current nominal at its grid point (the pending correction first: the new
    /// entry already has it).
    fn record_history(&mut self) {
        if self.pend_on && self.hist.due(self.t_us) {
            self.flush_history();
        }
        self.hist.record(self.t_us, &self.nom);
    }

    /// Apply the error mean `dx` (at the filter time, against the nominal before its injection)
    /// to every history entry, mapped back to the entry's time as
    /// [`strapdown::retrodict_error`] does (see [`super::history`]); `false` if a result was not
    /// finite (the history is then empty).
    fn correct_history(&mut self, dx: &SVector<f32, N>) -> bool {
        if dx.iter().all(|v| *v == 0.0) {
            return true;
        }
        let map = self.correction_map(dx);
        self.hist.correct(map)
    }

    /// The map of a history entry under the error mean `dx` injected at `pend_now.t_us` against the
    /// nominal `pend_now` (see `correct_history`), by value (it borrows nothing).
    fn correction_map(&self, dx: &SVector<f32, N>) -> impl Fn(&Snapshot) -> Snapshot + use<N, S> {
        let (now, t_now) = (self.pend_now, self.pend_now.t_us);
        let g = Vector3::new(0.0, 0.0, self.cfg.gravity_mps2);
        let inv_tau = 1.0 / self.cfg.markov_tau_s;
        let coast_end = self.hist.coast_end_us();
        let (phi, dv, dp, dba, dbg, eps) = (seg(dx, ATT), seg(dx, VEL), seg(dx, POS), seg(dx, BA), seg(dx, BG), seg(dx, MARKOV));
        let (na_dba, na_dbg, na_eps) = (now.att_nb * dba, now.att_nb * dbg, now.att_nb * eps);
        // The map of `strapdown::retrodict_core` with `Exp(phi_m) = Exp(phi) Exp(b)` taken to
        // first order in the bias part `b` (|b| <= bias correction x 4 s, ~1e-5 rad): one
        // exponential per call instead of one per entry.
        let q0 = quat_from_rotation_vector(&phi);
        let r0 = rows_of(q0.w, q0.i, q0.j, q0.k);
        let q0v = [q0.i, q0.j, q0.k];
        // Plain f32 arithmetic: with nalgebra's quaternion and vector operations the map cost
        // ~2,300 instructions per entry on the M4F (`opt-level = "s"` kept them out of line),
        // 12 % of the head's estimator.
        let markov = N >= MARKOV + 3;
        let (dv, dp, dba, dbg, eps) = (a3(&dv), a3(&dp), a3(&dba), a3(&dbg), a3(&eps));
        let (na_dba, na_dbg, na_eps) = (a3(&na_dba), a3(&na_dbg), a3(&na_eps));
        let (nv, np, gz) = (a3(&now.vel_ned_mps), a3(&now.pos_ned_m), g.z);
        move |e: &Snapshot| {
            let t_s = us_to_s(t_now.saturating_sub(e.t_us));
            let qe = e.att_nb.quaternion();
            let (ew, ev_q) = (qe.w, [qe.i, qe.j, qe.k]);
            let (ev, ep) = (a3(&e.vel_ned_mps), a3(&e.pos_ned_m));
            let (dv_e, dp_e, b) = if coast_end.is_some_and(|c| e.t_us < c) {
                // Across a coast: constant velocity, no specific-force or bias coupling.
                (dv, sub(dp, scale(dv, t_s)), [0.0; 3])
            } else {
                let dv_f = [nv[0] - ev[0], nv[1] - ev[1], nv[2] - ev[2] - gz * t_s];
                let hts2 = 0.5 * t_s * t_s;
                let dp_f = [np[0] - ep[0] - ev[0] * t_s, np[1] - ep[1] - ev[1] * t_s, np[2] - ep[2] - ev[2] * t_s - gz * hts2];
                // exp(T / tau) to third order (T / tau < 0.02 over the history).
                let x = t_s * inv_tau;
                let growth = 1.0 + x * (1.0 + x * 0.5);
                let re = rows_of(ew, ev_q[0], ev_q[1], ev_q[2]);
                let ea_dba = mul(&re, dba);
                let (ea_drift, na_drift) = if markov {
                    (mul(&re, add(dbg, scale(eps, growth))), add(na_dbg, scale(na_eps, growth)))
                } else {
                    (mul(&re, dbg), na_dbg)
                };
                // c = T (R_e + R_now) / 2, cc = T^2 (R_e / 3 + R_now / 6), applied to vectors.
                let (h, t2) = (0.5 * t_s, t_s * t_s);
                let b = scale(add(ea_drift, na_drift), h);
                let b_v = if t_s > 0.0 { scale(add(scale(ea_drift, 1.0 / 3.0), scale(na_drift, 1.0 / 6.0)), t_s) } else { [0.0; 3] };
                let b_p = sub(b_v, [b[0] / 6.0, b[1] / 6.0, b[2] / 6.0]);
                let w = sub(sub(dv_f, scale(add(ea_dba, na_dba), h)), cross(b_v, dv_f));
                let dv_e = sub(dv, sub(mul(&r0, add(w, cross(b, w))), dv_f));
                let u = sub(sub(dp_f, scale(add(scale(ea_dba, 1.0 / 3.0), scale(na_dba, 1.0 / 6.0)), t2)), cross(b_p, dp_f));
                let dp_e = sub(sub(dp, scale(dv_e, t_s)), sub(mul(&r0, add(u, cross(b, u))), dp_f));
                (dv_e, dp_e, b)
            };
            // q0 (qb qe), qb = (1, b / 2), then renormalised to first order.
            let hb = scale(b, 0.5);
            let pw = ew - dot(hb, ev_q);
            let pv = add(add(ev_q, scale(hb, ew)), cross(hb, ev_q));
            let aw = q0.w * pw - dot(q0v, pv);
            let av = add(add(scale(pv, q0.w), scale(q0v, pw)), cross(q0v, pv));
            let k = 0.5 * (3.0 - (aw * aw + dot(av, av)));
            let att = UnitQuaternion::new_unchecked(Quaternion::new(aw * k, av[0] * k, av[1] * k, av[2] * k));
            let (v, p) = (add(ev, dv_e), add(ep, dp_e));
            Snapshot { t_us: e.t_us, att_nb: att, vel_ned_mps: Vector3::new(v[0], v[1], v[2]), pos_ned_m: Vector3::new(p[0], p[1], p[2]) }
        }
    }

    /// Before an aiding update: finite check, flush the partial covariance interval.
    pub(crate) fn begin_update(&mut self, values: &[f32]) -> Result<(), NavError> {
        if !values.iter().all(|v| v.is_finite()) {
            return Err(self.reject_nonfinite());
        }
        self.cov_predict()
    }

    /// Where a measurement valid at `t_m_us` is fused (rules in [`super::history`]):
    /// `Ok(false)` as current, `Ok(true)` at its own past time; `TooOld` / `FromFuture` refused
    /// and counted, state untouched.
    pub(crate) fn check_time(&mut self, t_m_us: u64) -> Result<bool, NavError> {
        if t_m_us > self.t_us.saturating_add(self.cfg.max_future_us) {
            self.delay_rejects = self.delay_rejects.saturating_add(1);
            return Err(NavError::FromFuture);
        }
        if t_m_us.saturating_add(CURRENT_WITHIN_US) >= self.t_us {
            return Ok(false);
        }
        match self.hist.oldest_t_us() {
            Some(t0) if t_m_us >= t0 => Ok(true),
            _ => {
                self.delay_rejects = self.delay_rejects.saturating_add(1);
                Err(NavError::TooOld)
            }
        }
    }

    /// The nominal at `t_m_us` and the interval back to it (after [`Self::check_time`] said
    /// delayed and the partial covariance interval was flushed).
    pub(crate) fn past_epoch(&mut self, t_m_us: u64) -> Result<PastEpoch, NavError> {
        match self.epoch_at(t_m_us) {
            Some(e) => Ok(e),
            None => {
                self.delay_rejects = self.delay_rejects.saturating_add(1);
                Err(NavError::TooOld)
            }
        }
    }

    /// The history's epoch at `t_m_us`, with a pending correction applied to the two entries it
    /// reads (the history itself stays pending: see `inject`).
    pub(crate) fn epoch_at(&self, t_m_us: u64) -> Option<PastEpoch> {
        let (g, tau) = (self.cfg.gravity_mps2, self.cfg.markov_tau_s);
        if self.pend_on && self.pend_dx.iter().any(|v| *v != 0.0) {
            let map = self.correction_map(&self.pend_dx);
            self.hist.epoch_with(t_m_us, self.t_us, &self.nom, g, tau, map)
        } else {
            self.hist.epoch(t_m_us, self.t_us, &self.nom, g, tau)
        }
    }

    /// After an aiding update: record, inject (`delayed`: fused at its own past time).
    pub(crate) fn end_update(
        &mut self,
        kind: usize,
        t_us: u64,
        r: Result<UpdateReport<f32>, UkfError>,
        delayed: bool,
    ) -> Result<UpdateReport<f32>, NavError> {
        let rep = r?;
        if let Some(n) = self.nis.get_mut(kind) {
            *n = rep.nis;
        }
        // The velocity aid's NIS drives the IMU noise scale; position fixes only while no
        // velocity aid works (with one, their innovations measure the slow drift, not the IMU).
        // (Weighting a rare fix by the seconds since the last one was tried on KITTI: 45 m
        // held-out RMSE against 28 m.)
        if kind == KIND_VELOCITY {
            self.adapt_imu_q(rep.nis, 3);
            if rep.accepted {
                self.last_vel_accepted_us = Some(t_us);
            }
        } else if kind == KIND_POSITION {
            let vel_aided = self.last_vel_accepted_us.is_some_and(|t| self.t_us.saturating_sub(t) < 5_000_000);
            if !vel_aided {
                self.adapt_imu_q(rep.nis, 3);
            }
        }
        if rep.accepted && delayed {
            self.delayed_updates = self.delayed_updates.saturating_add(1);
        }
        if rep.accepted {
            self.lambda = rep.lambda;
            self.last_aided_t_us = Some(t_us.max(self.t_us));
            self.inject()?;
        }
        Ok(rep)
    }

    /// Feed one velocity or position NIS (accepted or refused) to the IMU process-noise scale
    /// and give the UKF the new `Q` when the scale moved by more than 10 % since the last time
    /// (not with the Sage-Husa `Q` recursion on: that one owns `Q`).
    #[inline(never)] // its candidate Q (900 B) stays out of the update path's frame (M4F stack)
    fn adapt_imu_q(&mut self, nis: f32, m: usize) {
        let cfg = self.cfg.imu_q_adapt;
        if !cfg.on || self.cfg.ukf.adapt.q_cov {
            return;
        }
        self.q_scale.observe(&cfg, nis, m);
        let s = self.q_scale.scale();
        let ratio = s / self.q_scale_applied;
        if (ratio > 1.1 || ratio < 1.0 / 1.1) && self.apply_imu_q_scale(s) {
            self.q_scale_applied = s;
        }
    }

    /// Start the IMU process-noise scale at `scale` (e.g. the IMU's noise measured at rest
    /// against the configuration), within the configured bounds; no effect with the
    /// adaptation off.
    #[inline(never)]
    #[cold]
    pub fn seed_imu_q_scale(&mut self, scale: f32) {
        let cfg = self.cfg.imu_q_adapt;
        if !cfg.on || self.cfg.ukf.adapt.q_cov || !scale.is_finite() {
            return;
        }
        self.q_scale.seed(&cfg, scale);
        let s = self.q_scale.scale();
        if self.apply_imu_q_scale(s) {
            self.q_scale_applied = s;
        }
    }

    /// Set the UKF's `Q` diagonal for the IMU's attitude and velocity random walks scaled by
    /// `s` (the entries `scaled_q` gives, without its `N x N` temporary).
    fn apply_imu_q_scale(&mut self, s: f32) -> bool {
        let t = self.cfg.cov_dt_s();
        let (att, vel) = (self.cfg.gyro_arw * self.cfg.gyro_arw * t * s, self.cfg.accel_vrw * self.cfg.accel_vrw * t * s);
        (0..3).all(|k| self.ukf.set_q_diag(ATT + k, att).is_ok() && self.ukf.set_q_diag(VEL + k, vel).is_ok())
    }

    /// The IMU process-noise scale in use (variance ratio against the configuration, see
    /// `NavConfig::imu_q_adapt`).
    pub fn imu_q_scale(&self) -> f32 {
        self.q_scale_applied
    }

    /// Count a non-finite input that never reached the UKF.
    pub(crate) fn reject_nonfinite(&mut self) -> NavError {
        self.imu_rejects = self.imu_rejects.saturating_add(1);
        NavError::NonFinite
    }

    /// Replace the error covariance (symmetrized and eigenvalue-floored by the UKF), e.g. with
    /// the correlated covariance a static alignment leaves (tilt error against accelerometer
    /// bias). Non-finite input is refused and counted.
    pub fn set_covariance(&mut self, p: SMatrix<f32, N, N>) -> Result<(), NavError> {
        self.ukf.set_p(p)?;
        Ok(())
    }

    pub fn nominal(&self) -> &NominalState {
        &self.nom
    }
    pub fn covariance(&self) -> &SMatrix<f32, N, N> {
        self.ukf.p()
    }
    pub fn ukf(&self) -> &Ukf<f32, N, S> {
        &self.ukf
    }
    pub fn config(&self) -> &NavConfig {
        &self.cfg
    }
    pub fn t_us(&self) -> u64 {
        self.t_us
    }
    /// Samples rejected before reaching the UKF (non-finite or implausible IMU/aiding values).
    pub fn input_rejects(&self) -> u32 {
        self.imu_rejects
    }
    /// IMU samples with a bad time stamp (not increasing, or a gap).
    pub fn time_rejects(&self) -> u32 {
        self.time_rejects
    }
    /// Measurements accepted at their own past time of validity (see [`super::history`]).
    pub fn delayed_updates(&self) -> u32 {
        self.delayed_updates
    }
    /// Measurements refused for their time: older than the history (`TooOld`) or too far in
    /// the future (`FromFuture`).
    pub fn delay_rejects(&self) -> u32 {
        self.delay_rejects
    }
    /// The state history for delayed measurements. The correction of the latest injections may
    /// still be pending (see `inject`): call [`Self::flush_history`] first to read it consistent
    /// with the nominal state.
    pub fn history(&self) -> &History {
        &self.hist
    }

    pub fn mode(&self) -> NavMode {
        match self.last_aided_t_us {
            None => NavMode::Inertial,
            Some(t) if (self.t_us.saturating_sub(t) as f32) * 1e-6 > self.cfg.aided_timeout_s => NavMode::Inertial,
            Some(_) => NavMode::Aided,
        }
    }

    /// The navigation solution as the telemetry message.
    pub fn solution(&self) -> NavSolution {
        let p = self.ukf.p();
        let sd = |i: usize| libm::sqrtf(p.get((i, i)).copied().unwrap_or(0.0).max(0.0));
        // Attitude sigmas in the heading-aligned level frame: roll ~ about forward, pitch ~ right.
        let yaw = yaw_of(&self.nom.att_nb);
        let (s, c) = (libm::sinf(yaw), libm::cosf(yaw));
        let rz_t = Matrix3::new(c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0);
        let patt: Matrix3<f32> = p.fixed_view::<3, 3>(ATT, ATT).into_owned();
        let pl = rz_t * patt * rz_t.transpose();
        let q = self.nom.att_nb;
        NavSolution {
            t_us: self.t_us,
            mode: self.mode(),
            pos_ned_m: self.nom.pos_ned_m.into(),
            vel_ned_mps: self.nom.vel_ned_mps.into(),
            att_nb_wxyz: [q.w, q.i, q.j, q.k],
            sigma_pos_m: [sd(POS), sd(POS + 1), sd(POS + 2)],
            sigma_vel_mps: [sd(VEL), sd(VEL + 1), sd(VEL + 2)],
            sigma_att_rad: [libm::sqrtf(pl[(0, 0)].max(0.0)), libm::sqrtf(pl[(1, 1)].max(0.0)), libm::sqrtf(pl[(2, 2)].max(0.0))],
            cov_ne_m2: p.get((POS, POS + 1)).copied().unwrap_or(0.0),
        }
    }

    /// Current measurement noise (adapted or configured) of each aiding kind, as variances:
    /// heading, depth, velocity (mean of the diagonal), position (mean of the diagonal).
    pub fn r_diag(&self) -> [f32; 4] {
        [self.noise_heading.r[(0, 0)], self.noise_depth.r[(0, 0)], self.noise_vel.r.trace() / 3.0, self.noise_pos.r.trace() / 3.0]
    }

    /// Latest fading factor applied by an accepted update.
    pub fn lambda(&self) -> f32 {
        self.lambda
    }

    /// Latest NIS per kind (heading, depth, velocity, position).
    pub fn nis(&self) -> [f32; 4] {
        self.nis
    }
}
