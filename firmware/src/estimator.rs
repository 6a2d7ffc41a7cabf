//! The sensor head's estimator: static alignment, then the shared AUKF navigation filter fed by
//! the IMU, the polarization compass, the depth sensor, the DVL (bottom-track velocity, at its
//! time of validity) and position fixes from the host (at their time of validity). HAL-free;
//! the application feeds it samples and asks it for telemetry.
//!
//! Alignment (the head must be at rest): roll and pitch from the mean specific force over
//! `ALIGN_S`, the gyro bias from the mean rate; yaw from `ALIGN_YAW_FIXES` mutually consistent
//! compass fixes within `ALIGN_MAX_S`, else yaw 0 with a large 1-sigma (the compass then pulls
//! it in). A single fix is not trusted: near the surface the compass can return an isolated
//! wrong fix (measured: one fix 133 deg off at 6.9 s, the only one in 13 s, in the default
//! scenario with seed 1), and a filter aligned on it rejects every later fix at its gate.
//!
//! Heading re-acquisition: when the heading gate has rejected `RESET_YAW_FIXES` compass fixes in
//! a row and their innovations agree with each other, the filter's heading is wrong, not the
//! compass: the estimator resets the heading to the fixes' circular mean
//! ([`NavFilter15::reset_heading`]). Position re-acquisition is the same for position fixes:
//! `RESET_POSITION_FIXES` refused in a row whose innovations (the fix minus the estimate at its
//! time of validity) agree within the fixes' own noise mean the position is lost, not the fixes
//! wrong: the estimator moves it by their mean ([`NavFilter15::reset_position`]); a run that
//! disagrees starts over from its last refusal (USBL multipath comes one fix at a time). With
//! nothing else holding the position (no DVL fused in 5 s), the position aid has a timeout: fixes
//! refused for `POSITION_TIMEOUT_S` (two or more) reset the position to the latest; a fix that is
//! the first refused since the last fused one and comes `POSITION_TIMEOUT_S` or more after it
//! (fixes sparser than the timeout: no run of refusals can form) is fused with the covariance
//! faded by its NIS instead, so the correction also reaches the velocity and attitude that
//! walked the position away. Depth is positive down (NED z).

use nalgebra::{Matrix3, SMatrix, Vector3};
use subnav_core::compass::{self, ChannelCal, CompassInput, UnitModel};
use subnav_core::ephemeris::{Observer, delta_t_estimate_s};
use subnav_core::head;
use subnav_core::nav::dvl::DvlMeasurement;
use subnav_core::nav::{KIND_DEPTH, KIND_HEADING, KIND_VELOCITY};
use subnav_core::nav::{NavConfig, NavError, NavFilter15, NavInit};
use subnav_core::ukf::UpdateReport;
use subnav_wire::{AidSource, AidStatuses, CompassReport, DvlSample, DvlTracking, FilterHealth, ImuSample, NavMode, NavSolution};

/// Warm start after a reset while moving (the board's warm-start record).
#[path = "estimator_warm.rs"]
pub mod warm;

const ALIGN_S: f32 = 1.0;
const ALIGN_MAX_S: f32 = 10.0;
/// Initial yaw 1-sigma when no compass fix came during alignment. Capped below pi/2: with larger
/// spreads the error-state sigma points wrap around the circle and the covariance collapses
/// (measured: an initial sigma of pi came out as 0.10 rad after 2 s of depth updates).
const YAW_UNKNOWN_SIGMA_RAD: f32 = 1.5;
/// Consistent compass fixes needed to take the yaw during alignment.
const ALIGN_YAW_FIXES: u32 = 5;
/// Consecutive gate-rejected, mutually consistent fixes that trigger a heading reset (3 s at
/// 10 Hz: longer than any plausible run of outliers from a working compass).
const RESET_YAW_FIXES: u32 = 30;
/// Consecutive gate-refused, mutually consistent position fixes that trigger a position reset
/// (25 s of USBL at one fix per 5 s; an outlier of a working USBL comes alone).
const RESET_POSITION_FIXES: u32 = 5;
/// A working DVL refused by the gate for this long (and at least `DVL_RESET_MIN_REFUSED`
/// reports) resets the velocity to the DVL's (PX4 EKF2's reset on a timeout of refused
/// measurements): 5 s is 25-50 reports; a DVL's own faults (a bad ping, a lost lock) come as
/// single reports or as invalid ones, which do not count.
const DVL_RESET_AFTER_S: f32 = 5.0;
const DVL_RESET_MIN_REFUSED: u32 = 10;
/// Attitude error added to the filter's own when the DVL's velocity is turned into NED at a
/// velocity reset (the filter's attitude may be off too when its velocity is).
const DVL_RESET_ATTITUDE_SIGMA_RAD: f32 = 0.05;
/// Position fixes refused in a row, over at least `POSITION_TIMEOUT_S`, with no DVL fused in
/// the last `DVL_HOLDS_POSITION_US`, reset the position to the latest fix whether or not the
/// refused fixes agree (they cannot, on a vehicle whose filter drifts away between them).
const POSITION_TIMEOUT_FIXES: u32 = 2;
const POSITION_TIMEOUT_S: f32 = 9.0;
/// Bound of the fading factor of the position aid's timeout for sparse fixes.
const FADE_LAMBDA_MAX: f32 = 1.0e4;
const DVL_HOLDS_POSITION_US: u64 = 5_000_000;
/// Yaw 1-sigma (at least) after a position timeout reset.
const POSITION_RESET_YAW_SIGMA_RAD: f32 = 0.5;
/// Minimum mean resultant length of a consistent set of angles: 0.98 is a circular standard
/// deviation of 11.5 deg (`sqrt(-2 ln R)`), twice the worst compass RMSE measured in the
/// simulated dives (6.3 deg).
const CONSISTENT_RESULTANT: f32 = 0.98;
/// Heading error the compass's own sigma does not include (unit calibration residuals, the
/// polarization model's limits). The solver's sigma covers only photodiode noise: in the
/// simulated 5-minute dives it reported 0.09 deg while the fixes were 0.3 deg off (RMS), and a
/// filter that believed it claimed a yaw sigma of 0.02 deg. This error changes slowly (with the
/// sun geometry and the attitude), so averaging fixes does not reduce it: it is added to every
/// fix with its variance multiplied by the number of fixes in one correlation time
/// (`HEADING_MODEL_CORR_S` at the polarization rate), the usual treatment of time-correlated
/// measurement noise without a state for it.
const HEADING_MODEL_SIGMA_RAD: f32 = 0.5 * core::f32::consts::PI / 180.0;
const HEADING_MODEL_CORR_S: f32 = 10.0;

/// Without the IMU (failed or stuck axis) the filter coasts: attitude and velocity random walks
/// large enough for an AUV's unobserved turns and speed changes (0.05 rad/sqrt(s): 3 deg in the
/// first second), so the compass and the fixes carry it. Coasting starts after this long
/// without an IMU sample.
const COAST_ATTITUDE_RW: f32 = 0.05;
const COAST_VELOCITY_RW: f32 = 0.2;
const COAST_AFTER_US: u64 = 20_000;
/// With a gyro axis stuck (the other five good), the rate about it is unknown: the attitude
/// error about that body axis grows as a random walk of this much (rad/sqrt(s), the coast's
/// attitude walk), and the compass carries the heading.
const UNKNOWN_RATE_RW: f32 = COAST_ATTITUDE_RW;

/// 1-sigma of the tilt error of the levelling itself (noise of the mean specific force over
/// `ALIGN_S`, residual motion), on top of the part the accelerometer bias explains.
const ALIGNED_TILT_SIGMA_RAD: f32 = 1e-3;
/// 1-sigma of the gyro bias left after the at-rest estimate (rad/s): 0.01 deg/s.
const ALIGNED_GYRO_BIAS_SIGMA_RADPS: f32 = 1.75e-4;

/// Memory of the adaptive heading R (exponential forgetting factor per fix): about
/// `1 / (1 - b)` = 200 fixes, 20 s at the polarization rate (a sea state changes over minutes, a
/// wave group lasts seconds).
const ADAPTIVE_R_B: f32 = 0.995;

/// The adaptive heading R (the AUKF's R adaptation, on the compass fixes): the fixes' error
/// variance estimated online from the filter's heading innovations, `V_k = (1 - d_k) V_{k-1} +
/// d_k e_k^2`, `d_k = (1 - b) / (1 - b^(k+1))` (Sage-Husa's weights), from the fixes the gate
/// accepted only: learning from rejected ones (clipped to the gate, as the core's Sage-Husa does)
/// widened the gate until a wrong heading's consistent rejected fixes were accepted one by one
/// and never reset it (`a_wrong_heading_is_reset_after_a_run_of_consistent_rejected_fixes`);
/// a sea state's scatter stays far inside the gate (the inflated R is 5 deg or more a fix).
/// The filter gets `sigma_solver^2 + max(model, n_corr (V - sigma_solver^2))`: the part beyond the photodiode noise is correlated (waves over seconds, the model error over
/// minutes), so it is inflated by the fixes in one correlation time like the fixed model error,
/// and floored by that model error, because a compass bias never shows in the innovations (the
/// filter's heading takes it). Two choices of the seed's Sage-Husa recursion are left out, both
/// measured in the wind-step dives (docs/PERFORMANCE.md): subtracting the predicted `P_zz`
/// (then `V` fell to its floor during the convergence and the filter claimed a heading sigma
/// far below its error: 21-76 % within 3 sigma) and adapting the uninflated R. `V` is floored at
/// the model error's per-fix variance and adapts only while the filter's heading variance is
/// below it: before that (an alignment without the compass, a heading reset) the innovations
/// measure the filter. The weights are computed by a running power of `b` (the core's
/// `sage_husa_d` uses `powi`; the figures were measured with this form).
#[derive(Debug, Clone, Copy)]
struct AdaptiveHeadingR {
    on: bool,
    b_pow: f32,
    var_rad2: f32,
}

impl AdaptiveHeadingR {
    fn new(on: bool) -> Self {
        Self { on, b_pow: 1.0, var_rad2: HEADING_MODEL_SIGMA_RAD * HEADING_MODEL_SIGMA_RAD }
    }

    /// The variance the filter gets for a fix (see the type's doc).
    fn filter_var_rad2(&self, solver_var_rad2: f32, model_var_rad2: f32, n_corr: f32) -> f32 {
        let excess = self.var_rad2 - solver_var_rad2;
        solver_var_rad2 + model_var_rad2.max(excess * n_corr)
    }

    /// One heading innovation `e` (rad) gated with innovation variance `s`.
    fn observe(&mut self, e: f32, s: f32) {
        let e2 = (e * e).min(subnav_core::ukf::gate::chi2_999::<f32>(1) * s);
        self.b_pow *= ADAPTIVE_R_B;
        let d = (1.0 - ADAPTIVE_R_B) / (1.0 - self.b_pow * ADAPTIVE_R_B);
        let v = (1.0 - d) * self.var_rad2 + d * e2;
        if v.is_finite() {
            self.var_rad2 = v.max(HEADING_MODEL_SIGMA_RAD * HEADING_MODEL_SIGMA_RAD);
        }
    }
}

/// Circular statistics of a run of angles (compass fixes, or heading innovations).
#[derive(Debug, Clone, Copy, Default)]
struct AngleRun {
    n: u32,
    sum_sin: f32,
    sum_cos: f32,
    sum_sigma: f32,
}

impl AngleRun {
    fn push(&mut self, angle_rad: f32, sigma_rad: f32) {
        self.n += 1;
        self.sum_sin += libm::sinf(angle_rad);
        self.sum_cos += libm::cosf(angle_rad);
        self.sum_sigma += sigma_rad;
    }

    /// With at least `min_n` angles: `Some((circular mean, 1-sigma))` if they agree (mean
    /// resultant length >= [`CONSISTENT_RESULTANT`]); the sigma is the larger of the mean
    /// reported sigma and the circular standard deviation. `None` otherwise.
    fn consensus(&self, min_n: u32) -> Option<(f32, f32)> {
        if self.n < min_n || self.n == 0 {
            return None;
        }
        let n = self.n as f32;
        let r = libm::sqrtf(self.sum_sin * self.sum_sin + self.sum_cos * self.sum_cos) / n;
        if !(r >= CONSISTENT_RESULTANT) {
            return None;
        }
        let circ_std = libm::sqrtf(-2.0 * libm::logf(r.min(1.0)));
        Some((libm::atan2f(self.sum_sin, self.sum_cos), (self.sum_sigma / n).max(circ_std)))
    }
}

/// The position aid's fading (see `Estimator::on_position_fix`): `P` scaled by `lambda`, then the
/// fix fused; if that is refused too, `P` is put back exactly (a refused update changes
/// nothing) and `None` returned. Out of line: its two 15x15 copies stay off the stack of every
/// other position fix.
#[inline(never)]
fn fuse_position_faded(
    nav: &mut NavFilter15,
    t_us: u64,
    pos_ned_m: [f32; 3],
    cov_ned_m2: [f32; 6],
    lambda: f32,
) -> Option<UpdateReport<f32>> {
    let p_before = *nav.covariance();
    nav.set_covariance(p_before * lambda).ok()?;
    match nav.update_position(t_us, pos_ned_m, cov_ned_m2) {
        Ok(faded) if faded.accepted => Some(faded),
        _ => {
            let _ = nav.set_covariance(p_before);
            None
        }
    }
}

/// Innovations of a run of gate-refused position fixes (NED, m), with the fixes' variances.
#[derive(Debug, Clone, Copy, Default)]
struct PositionRun {
    n: u32,
    sum_m: [f32; 3],
    sum_sq_m2: [f32; 3],
    sum_var_m2: [f32; 3],
}

impl PositionRun {
    fn push(&mut self, innovation_m: [f32; 3], var_m2: [f32; 3]) {
        self.n += 1;
        let axes = self.sum_m.iter_mut().zip(self.sum_sq_m2.iter_mut()).zip(self.sum_var_m2.iter_mut());
        for (((s, sq), sv), (e, v)) in axes.zip(innovation_m.into_iter().zip(var_m2)) {
            *s += e;
            *sq += e * e;
            *sv += v;
        }
    }

    /// With at least `min_n` innovations: `Some((mean, variance))` per axis if they agree (on
    /// every axis the scatter about their mean is within 3 sigma of the fixes' own noise); the
    /// variance is the larger of the fixes' mean variance and the scatter. `None` otherwise.
    fn consensus(&self, min_n: u32) -> Option<([f32; 3], [f32; 3])> {
        if self.n < min_n || self.n == 0 {
            return None;
        }
        let n = self.n as f32;
        let (mut mean, mut var) = ([0.0f32; 3], [0.0f32; 3]);
        let sums = self.sum_m.iter().zip(&self.sum_sq_m2).zip(&self.sum_var_m2);
        for ((m, v), ((s, sq), sv)) in mean.iter_mut().zip(var.iter_mut()).zip(sums) {
            *m = s / n;
            let scatter = (sq / n - *m * *m).max(0.0);
            let noise = sv / n;
            if !(scatter <= 9.0 * noise) {
                return None;
            }
            *v = noise.max(scatter);
        }
        Some((mean, var))
    }
}

#[derive(Debug, Clone, Copy, Default)]
struct Align {
    start_us: Option<u64>,
    n: u32,
    sum_accel: [f32; 3],
    sum_gyro: [f32; 3],
    /// Sums of squares, for the IMU's noise measured at rest.
    sum_sq_accel: [f32; 3],
    sum_sq_gyro: [f32; 3],
    first_accel: [f32; 3],
    first_gyro: [f32; 3],
}

impl Align {
    /// The mean specific force so far (body FRD, m/s^2).
    fn mean_accel(&self) -> [f32; 3] {
        let n = self.n.max(1) as f32;
        [0, 1, 2].map(|k| self.first_accel[k] + self.sum_accel[k] / n)
    }

    /// Per-axis mean and sample variance (mean over the axes) of `sum`, `sum_sq` over `n`.
    fn mean_var(n: u32, sum: &[f32; 3], sum_sq: &[f32; 3]) -> ([f32; 3], f32) {
        let nf = n.max(1) as f32;
        let mean = sum.map(|v| v / nf);
        let mut var = 0.0;
        for (m, sq) in mean.iter().zip(sum_sq) {
            var += (sq / nf - m * m).max(0.0);
        }
        (mean, var / 3.0 * nf / (nf - 1.0).max(1.0))
    }
}

pub struct Estimator {
    cfg: NavConfig,
    compass_cfg: compass::CompassConfig,
    /// Each unit's channel calibration (`None`: no valid model); the model (geometry, noise, the
    /// channel model's inverse) is built from it where used: the 88 B per unit it would add
    /// sit in the board loop's frame at the stack peak.
    unit_channels: [Option<[ChannelCal; compass::CHANNELS]>; head::POLARIZATION_UNITS],
    align: Align,
    /// The navigation filter's storage (built once, at construction: `None` only if the
    /// configuration is invalid) and whether it is running (after the alignment). Re-used in
    /// place by every alignment, so the M4F never holds two filters on its stack.
    nav: Option<NavFilter15>,
    running: bool,
    /// Compass fixes during alignment, and the heading the alignment takes from them.
    align_fixes: AngleRun,
    yaw_fix: Option<(f32, f32)>,
    /// Innovations of the current run of gate-rejected compass fixes.
    rejected_run: AngleRun,
    /// Heading resets done (re-acquisitions after a run of consistent rejected fixes).
    pub heading_resets: u32,
    /// Innovations of the current run of gate-refused position fixes.
    refused_positions: PositionRun,
    /// Position resets done (the same for position fixes).
    pub position_resets: u32,
    /// The current run of gate-refused position fixes: the time of validity of its first fix
    /// (for the timeout reset, which does not need them to agree), and of the last DVL
    /// velocity fused (a working DVL holds the position: no timeout reset then).
    position_refused_since_us: Option<u64>,
    position_refused_run: u32,
    last_dvl_fused_us: Option<u64>,
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
    /// The latest IMU rate (alignment bias removed), for the DVL's lever-arm term.
    last_gyro_radps: [f32; 3],
    /// DVL velocities fused (accepted by the gate) since boot.
    pub dvl_fused: u32,
    /// Every aid source's status (`Health::aid`), kept by its fuse step.
    aid: AidStatuses,
    /// The current run of gate-refused DVL velocities: the filter time of its first refusal and
    /// its length.
    dvl_refused_since_us: Option<u64>,
    dvl_refused_run: u32,
    /// The compass's wave-error tracker (`compass::WaveSigma`), its heading reference carried by
    /// the gyro's turn about the vertical between fixes, and the last IMU time.
    wave: compass::WaveSigma,
    last_imu_us: Option<u64>,
    /// Give the filter the wave part; off (default): the solver's sigma and the model error
    /// only, which measured better in the sea dives (docs/PERFORMANCE.md); the report carries
    /// the wave part either way.
    wave_sigma: bool,
    adaptive_r: AdaptiveHeadingR,
    /// The compass's reported variance, averaged over `HEADING_MODEL_CORR_S` of fixes (rad^2; 0
    /// before the first fix): the heading-bias term of the reported yaw sigma (see
    /// [`Estimator::solution`]).
    compass_var_mean_rad2: f32,
    /// The IMU's calibration (stored record), applied to every sample first.
    imu_correction: Option<crate::calibration::ImuCorrection>,
    /// Where the DVL sits and its scale factor (stored record, else the head's nominal).
    dvl_mounting: subnav_core::nav::dvl::DvlMounting,
    dvl_scale: f32,
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
            unit_channels: core::array::from_fn(|i| head::polarization_unit(i).map(|m| m.channels)),
            align: Align::default(),
            nav: filter_storage(cfg),
            running: false,
            align_fixes: AngleRun::default(),
            yaw_fix: None,
            rejected_run: AngleRun::default(),
            heading_resets: 0,
            refused_positions: PositionRun::default(),
            position_resets: 0,
            position_refused_since_us: None,
            position_refused_run: 0,
            last_dvl_fused_us: None,
            accel_lp: [0.0; 3],
            accel_seen: false,
            last_depth_m: None,
            gyro_bias_align: [0.0; 3],
            input_rejects: 0,
            last_gyro_radps: [0.0; 3],
            dvl_fused: 0,
            aid: AidStatuses::default(),
            dvl_refused_since_us: None,
            dvl_refused_run: 0,
            imu_correction: None,
            wave: compass::WaveSigma::default(),
            last_imu_us: None,
            wave_sigma: false,
            adaptive_r: AdaptiveHeadingR::new(true),
            compass_var_mean_rad2: 0.0,
            dvl_mounting: head::dvl_mounting(),
            dvl_scale: 1.0,
        }
    }

    /// Use `model` for polarization unit `unit` (a stored calibration; `None`: the nominal model).
    pub fn set_polarization_unit(&mut self, unit: usize, model: Option<UnitModel>) {
        if let Some(slot) = self.unit_channels.get_mut(unit) {
            *slot = model.or_else(|| head::polarization_unit(unit)).map(|m| m.channels);
        }
    }

    /// The model polarization unit `unit` is solved with (the head's geometry and noise, its
    /// channel calibration).
    pub fn units_model(&self, unit: usize) -> Option<UnitModel> {
        let channels = (*self.unit_channels.get(unit)?)?;
        let (view, axis0) = head::polarization_unit_geometry(unit);
        UnitModel::new(view, axis0, channels, head::PHOTODIODE_NOISE).ok()
    }

    /// The IMU calibration applied to every sample (`None`: raw samples are body samples).
    pub fn set_imu_correction(&mut self, c: Option<crate::calibration::ImuCorrection>) {
        self.imu_correction = c;
    }

    /// The DVL's mounting and scale factor (`None`: the head's nominal mounting, scale 1).
    pub fn set_dvl_mounting(&mut self, m: Option<(subnav_core::nav::dvl::DvlMounting, f32)>) {
        let (m, scale) = m.unwrap_or((head::dvl_mounting(), 1.0));
        self.dvl_mounting = m;
        self.dvl_scale = scale;
    }

    /// Run `cfg` instead of the head's tuning (an evaluation switch for the host's simulations:
    /// the AUKF against the plain UKF), back to alignment.
    pub fn set_nav_config(&mut self, cfg: NavConfig) {
        self.cfg = cfg;
        self.nav = filter_storage(cfg);
        self.reset();
    }

    /// Back to alignment (downlink `ResetFilter`), keeping the filter's storage. Every field
    /// but the configuration, the unit models and the storage goes back to its `new` value.
    pub fn reset(&mut self) {
        self.align = Align::default();
        self.running = false;
        self.align_fixes = AngleRun::default();
        self.yaw_fix = None;
        self.rejected_run = AngleRun::default();
        self.heading_resets = 0;
        self.refused_positions = PositionRun::default();
        self.position_resets = 0;
        self.position_refused_since_us = None;
        self.position_refused_run = 0;
        self.last_dvl_fused_us = None;
        self.accel_lp = [0.0; 3];
        self.accel_seen = false;
        self.last_depth_m = None;
        self.gyro_bias_align = [0.0; 3];
        self.input_rejects = 0;
        self.last_gyro_radps = [0.0; 3];
        self.dvl_refused_since_us = None;
        self.dvl_refused_run = 0;
        self.aid = AidStatuses::default();
        self.wave.reset();
        self.adaptive_r = AdaptiveHeadingR::new(self.adaptive_r.on);
        self.compass_var_mean_rad2 = 0.0;
        self.last_imu_us = None;
    }

    /// The IMU process-noise scale the filter uses (variance ratio against the tuning; 1 before
    /// the filter runs). See `subnav_core::ukf::adapt::NisQScale`.
    pub fn imu_q_scale(&self) -> f32 {
        self.nav.as_ref().filter(|_| self.running).map_or(1.0, |n| n.imu_q_scale())
    }

    pub fn mode(&self) -> NavMode {
        match self.nav.as_ref().filter(|_| self.running) {
            Some(n) => n.mode(),
            None if self.align.n > 0 => NavMode::Aligning,
            None => NavMode::Uninitialised,
        }
    }

    pub fn on_imu(&mut self, s: &ImuSample) -> Result<(), NavError> {
        self.on_imu_with(s, 0)
    }

    /// An IMU sample whose gyro axes in `stuck_gyro` (bit k = body axis k) are stuck, the other
    /// five good (degraded mode): those axes' rates are taken as unknown (zero, with the
    /// attitude error growing about them by `UNKNOWN_RATE_RW`), the rest is used as usual. Before
    /// the alignment ends: ignored (the alignment needs all six).
    pub fn on_imu_degraded(&mut self, s: &ImuSample, stuck_gyro: u8) -> Result<(), NavError> {
        if !self.running {
            return Ok(());
        }
        self.on_imu_with(s, stuck_gyro & 0b111)
    }

    fn on_imu_with(&mut self, s: &ImuSample, stuck_gyro: u8) -> Result<(), NavError> {
        let corrected = self.imu_correction.map(|c| c.apply(s));
        let mut s = corrected.unwrap_or(*s);
        // A stuck axis reads the alignment's bias: zero rate once it is removed below.
        for ((g, b), k) in s.gyro_radps.iter_mut().zip(self.gyro_bias_align).zip(0..) {
            if stuck_gyro & (1 << k) != 0 {
                *g = b;
            }
        }
        let s = &s;
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
            self.carry_wave_reference(s);
        }
        if let Some(nav) = self.nav.as_mut().filter(|_| self.running) {
            let mut c = *s;
            for (g, b) in c.gyro_radps.iter_mut().zip(self.gyro_bias_align) {
                *g -= b;
            }
            if finite {
                self.last_gyro_radps = c.gyro_radps;
            }
            if stuck_gyro != 0 {
                return nav.propagate_unknown_rates(&c, stuck_gyro, UNKNOWN_RATE_RW);
            }
            return nav.propagate(&c);
        }
        if !finite {
            self.input_rejects = self.input_rejects.wrapping_add(1);
            return Err(NavError::NonFinite);
        }
        let start = *self.align.start_us.get_or_insert(s.t_us);
        self.align.n += 1;
        // Deviations from the first sample: the sums of squares stay well conditioned in f32.
        if self.align.n == 1 {
            self.align.first_accel = s.accel_mps2;
            self.align.first_gyro = s.gyro_radps;
        }
        let (a0, g0) = (self.align.first_accel, self.align.first_gyro);
        for k in 0..3 {
            let (da, dg) = (s.accel_mps2[k] - a0[k], s.gyro_radps[k] - g0[k]);
            self.align.sum_accel[k] += da;
            self.align.sum_gyro[k] += dg;
            self.align.sum_sq_accel[k] += da * da;
            self.align.sum_sq_gyro[k] += dg * dg;
        }
        let elapsed_s = s.t_us.saturating_sub(start) as f32 * 1e-6;
        if elapsed_s >= ALIGN_S && (self.yaw_fix.is_some() || elapsed_s >= ALIGN_MAX_S) {
            self.finish_alignment(s.t_us)?;
        }
        Ok(())
    }

    /// End of the alignment: start the filter (re-initialised in place; building it by value
    /// here took a 26 KB stack frame on the M4F). Not inlined, so the IMU path does not carry
    /// its frame.
    #[inline(never)]
    fn finish_alignment(&mut self, t_us: u64) -> Result<(), NavError> {
        let n = self.align.n as f32;
        let (da, var_accel) = Align::mean_var(self.align.n, &self.align.sum_accel, &self.align.sum_sq_accel);
        let (dg, var_gyro) = Align::mean_var(self.align.n, &self.align.sum_gyro, &self.align.sum_sq_gyro);
        let f = [0, 1, 2].map(|k| self.align.first_accel[k] + da[k]);
        let (roll, pitch) = head::level_from_accel(f);
        self.gyro_bias_align = [0, 1, 2].map(|k| self.align.first_gyro[k] + dg[k]);
        // The IMU's white noise measured at rest, against the tuning: the process noise starts
        // at the larger ratio (an IMU noisier than configured), and the at-rest means are
        // trusted only as far as that noise allows.
        let rate = self.cfg.imu_rate_hz;
        let noise_scale =
            (var_gyro / (self.cfg.gyro_arw * self.cfg.gyro_arw * rate)).max(var_accel / (self.cfg.accel_vrw * self.cfg.accel_vrw * rate));
        let (yaw, yaw_sigma) = self.yaw_fix.unwrap_or((0.0, YAW_UNKNOWN_SIGMA_RAD));
        let mut cfg = self.cfg;
        cfg.init_sigma_att_rad[2] = yaw_sigma.max(cfg.init_sigma_att_rad[2]);
        let tilt_var = ALIGNED_TILT_SIGMA_RAD * ALIGNED_TILT_SIGMA_RAD + var_accel / (n * cfg.gravity_mps2 * cfg.gravity_mps2);
        cfg.init_sigma_att_rad[0] = libm::sqrtf(tilt_var);
        cfg.init_sigma_att_rad[1] = libm::sqrtf(tilt_var);
        // What is left of the gyro bias after the at-rest estimate: white noise over the
        // alignment plus the Earth rate, with margin, and the mean's own noise.
        cfg.init_sigma_gyro_bias = libm::sqrtf(ALIGNED_GYRO_BIAS_SIGMA_RADPS * ALIGNED_GYRO_BIAS_SIGMA_RADPS + var_gyro / n);
        let init = NavInit {
            t_us,
            att_nb: head::attitude(roll, pitch, yaw),
            vel_ned_mps: Vector3::zeros(),
            pos_ned_m: Vector3::new(0.0, 0.0, self.last_depth_m.unwrap_or(0.0)),
        };
        let Some(nav) = self.nav.as_mut() else { return Err(NavError::BadConfig) };
        nav.reinit(cfg, init)?;
        if noise_scale.is_finite() {
            nav.seed_imu_q_scale(noise_scale);
        }
        let p = aligned_covariance(nav.covariance(), yaw, cfg.init_sigma_accel_bias, cfg.gravity_mps2);
        nav.set_covariance(p)?;
        // Without a compass yaw the DVL must not pretend to know it (`set_yaw_unobserved`),
        // until the first compass fix is fused.
        nav.set_yaw_unobserved(self.yaw_fix.is_none());
        self.running = true;
        Ok(())
    }

    /// Turns the wave tracker's heading reference by the body's rotation about the vertical
    /// since the last sample: `(gyro - at-rest bias) . down * dt`, down from the low-passed
    /// specific force (at rest it reads -g: it points up). During the alignment the head is at
    /// rest and the gyro's bias is not yet known: the reference stays (a MEMS gyro's turn-on
    /// bias would turn it by degrees and read as waves).
    fn carry_wave_reference(&mut self, s: &ImuSample) {
        let dt_s = match self.last_imu_us {
            Some(t0) if self.running && s.t_us > t0 && s.t_us - t0 < 100_000 => (s.t_us - t0) as f32 * 1e-6,
            _ => 0.0,
        };
        self.last_imu_us = Some(s.t_us);
        let f = self.accel_lp;
        let n = libm::sqrtf(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
        if dt_s > 0.0 && n > 1.0 {
            let mut rate = 0.0;
            for ((g, b), fk) in s.gyro_radps.iter().zip(self.gyro_bias_align).zip(f) {
                rate -= (g - b) * fk / n;
            }
            self.wave.rotate(rate * dt_s);
        }
    }

    /// Whether the filter gets the compass's wave part (default off: the solver's sigma and the
    /// model error). The compass report carries the wave part either way.
    pub fn set_wave_sigma(&mut self, on: bool) {
        self.wave_sigma = on;
    }

    /// Whether the heading R adapts (see `AdaptiveHeadingR`; on by default; off: the solver's
    /// sigma and the fixed model error, the fixed-R filter of the comparisons).
    pub fn set_adaptive_heading_r(&mut self, on: bool) {
        self.adaptive_r = AdaptiveHeadingR::new(on);
    }

    /// The compass's wave-error tracker (its wave part is in every fix's sigma).
    pub fn wave(&self) -> &compass::WaveSigma {
        &self.wave
    }

    /// The IMU read failed at `t_us` (bus error, stuck axis): coast the filter once the gap
    /// exceeds `COAST_AFTER_US` (degraded mode, see `NavFilter::coast`). Not inlined: the
    /// coast's temporaries would otherwise sit in the scheduler's frame on every tick.
    #[inline(never)]
    pub fn on_imu_unavailable(&mut self, t_us: u64) {
        if let Some(nav) = self.nav.as_mut().filter(|_| self.running) {
            if t_us.saturating_sub(nav.t_us()) >= COAST_AFTER_US {
                let _ = nav.coast(t_us, COAST_ATTITUDE_RW, COAST_VELOCITY_RW);
            }
        }
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
        // The units that were read and have a model, each built as the solver takes it.
        let pairs = readings.iter().filter_map(|(idx, c)| self.units_model(*idx).map(|u| (u, c)));
        let accel = if self.accel_seen { self.accel_lp } else { [f32::NAN; 3] };
        let input = CompassInput {
            counts: &[],
            accel_body_mps2: accel,
            unix_us: utc_unix_us,
            observer,
            delta_t_s: utc_unix_us.map(delta_t_estimate_s).unwrap_or(69.0),
        };
        // Too few units is reported by the solver as a NoFix reason.
        let mut result = compass::solve_pairs(pairs, &input, &self.compass_cfg);
        if let Ok(fix) = result.as_mut() {
            // The reported sigma includes the waves' part; the filter takes each fix as
            // independent, so it gets that part inflated for the fixes' correlation.
            let solver_sigma = fix.sigma_heading_rad;
            let sigma = self.wave.update(t_us, fix.heading_rad, solver_sigma);
            if sigma.is_finite() {
                fix.sigma_heading_rad = sigma;
            }
            let wave_var = if self.wave_sigma { self.wave.filter_wave_var_rad2() } else { 0.0 };
            self.on_heading_fix_correlated(t_us, fix.heading_rad, solver_sigma, wave_var);
        }
        compass::report(t_us, &result)
    }

    /// A compass heading fix (rad, with the solver's 1-sigma): alignment, filter update, and
    /// heading re-acquisition (see the module doc).
    pub fn on_heading_fix(&mut self, t_us: u64, heading_rad: f32, solver_sigma_rad: f32) {
        self.on_heading_fix_correlated(t_us, heading_rad, solver_sigma_rad, 0.0);
    }

    /// As [`Estimator::on_heading_fix`], with the compass's measured correlated error (the wave
    /// tracker's part, already inflated for its correlation, rad^2). It and the fixed model
    /// error describe the same slowly varying error, so the larger of the two is used: in a calm
    /// sea the model term (as before the tracker), in a rough one the measured waves.
    pub fn on_heading_fix_correlated(&mut self, t_us: u64, heading_rad: f32, solver_sigma_rad: f32, measured_var_rad2: f32) {
        if !(heading_rad.is_finite() && solver_sigma_rad.is_finite()) {
            self.input_rejects = self.input_rejects.wrapping_add(1);
            return;
        }
        let n_corr = HEADING_MODEL_CORR_S * head::POLARIZATION_RATE_HZ as f32;
        let model_var = HEADING_MODEL_SIGMA_RAD * HEADING_MODEL_SIGMA_RAD * n_corr;
        let measured = if measured_var_rad2.is_finite() { measured_var_rad2 } else { 0.0 };
        let solver_var = solver_sigma_rad * solver_sigma_rad;
        let w = 1.0 / n_corr.max(1.0);
        self.compass_var_mean_rad2 = if self.compass_var_mean_rad2 > 0.0 {
            self.compass_var_mean_rad2 + w * (solver_var - self.compass_var_mean_rad2)
        } else {
            solver_var
        };
        let mut sigma = libm::sqrtf(solver_var + model_var.max(measured));
        let Some(nav) = self.nav.as_mut().filter(|_| self.running) else {
            self.align_on_fix(heading_rad, sigma);
            return;
        };
        let yaw_before = nav.nominal().yaw_rad();
        let p_yaw = nav.covariance().get((2, 2)).copied().unwrap_or(0.0);
        if self.adaptive_r.on {
            sigma = libm::sqrtf(self.adaptive_r.filter_var_rad2(solver_var, model_var, n_corr).max(solver_var + measured));
        }
        let result = nav.update_heading(t_us, heading_rad, Some(sigma));
        if let Ok(rep) = &result {
            let (gate, var) = (nav.config().heading.gate, nav.r_diag()[KIND_HEADING]);
            record(&mut self.aid, AidSource::Heading, t_us, rep, gate, var);
        }
        match result {
            Ok(rep) if rep.accepted => {
                nav.set_yaw_unobserved(false);
                self.rejected_run = AngleRun::default();
                if self.adaptive_r.on && p_yaw < self.adaptive_r.var_rad2 {
                    let e = subnav_core::ukf::wrap_pi(heading_rad - yaw_before);
                    self.adaptive_r.observe(e, p_yaw + sigma * sigma);
                }
            }
            Ok(_) => {
                let innovation = subnav_core::ukf::wrap_pi(heading_rad - yaw_before);
                self.rejected_run.push(innovation, sigma);
                if let Some((mean, sigma)) = self.rejected_run.consensus(RESET_YAW_FIXES) {
                    let yaw = nav.nominal().yaw_rad() + mean;
                    if nav.reset_heading(yaw, sigma).is_ok() {
                        nav.set_yaw_unobserved(false);
                        self.heading_resets = self.heading_resets.wrapping_add(1);
                        self.aid.heading.resets = self.aid.heading.resets.wrapping_add(1);
                        // The rejected run's innovations measured the wrong heading, not the compass.
                        self.adaptive_r = AdaptiveHeadingR::new(self.adaptive_r.on);
                    }
                    self.rejected_run = AngleRun::default();
                } else if self.rejected_run.n >= RESET_YAW_FIXES {
                    // Inconsistent rejections (outliers, not a wrong heading): start over.
                    self.rejected_run = AngleRun::default();
                }
            }
            Err(_) => {}
        }
    }

    /// A compass fix during alignment: the yaw is taken once `ALIGN_YAW_FIXES` consecutive fixes
    /// agree; a disagreeing set starts over.
    fn align_on_fix(&mut self, heading_rad: f32, sigma_rad: f32) {
        self.align_fixes.push(heading_rad, sigma_rad);
        if self.align_fixes.n >= ALIGN_YAW_FIXES {
            self.yaw_fix = self.align_fixes.consensus(ALIGN_YAW_FIXES);
            if self.yaw_fix.is_none() {
                self.align_fixes = AngleRun::default();
            }
        }
    }

    pub fn on_depth(&mut self, t_us: u64, depth_m: f32) -> Result<(), NavError> {
        if !depth_m.is_finite() {
            self.input_rejects = self.input_rejects.wrapping_add(1);
            return Err(NavError::NonFinite);
        }
        self.last_depth_m = Some(depth_m);
        let Some(nav) = self.nav.as_mut().filter(|_| self.running) else { return Ok(()) };
        let rep = nav.update_depth(t_us, depth_m, None)?;
        let (gate, var) = (nav.config().depth.gate, nav.r_diag()[KIND_DEPTH]);
        record(&mut self.aid, AidSource::Depth, t_us, &rep, gate, var);
        Ok(())
    }

    /// A position fix (NED, m, covariance upper triangle) valid at `t_us`; position
    /// re-acquisition (see the module doc).
    pub fn on_position_fix(&mut self, t_us: u64, pos_ned_m: [f32; 3], cov_ned_m2: [f32; 6]) -> Result<(), NavError> {
        let Some(nav) = self.nav.as_mut().filter(|_| self.running) else { return Err(NavError::BadTime) };
        let prior = nav.position_at(t_us);
        let rep = nav.update_position(t_us, pos_ned_m, cov_ned_m2)?;
        let (gate, var) = (nav.config().position.gate, (cov_ned_m2[0] + cov_ned_m2[3] + cov_ned_m2[5]) / 3.0);
        record(&mut self.aid, AidSource::Position, t_us, &rep, gate, var);
        if rep.accepted {
            self.refused_positions = PositionRun::default();
            self.position_refused_since_us = None;
            self.position_refused_run = 0;
            return Ok(());
        }
        let Some(prior) = prior else { return Ok(()) };
        let innovation = [pos_ned_m[0] - prior.x, pos_ned_m[1] - prior.y, pos_ned_m[2] - prior.z];
        let since = *self.position_refused_since_us.get_or_insert(t_us);
        self.position_refused_run = self.position_refused_run.saturating_add(1);
        let refused_s = t_us.saturating_sub(since) as f32 * 1e-6;
        let dvl_holds = self.last_dvl_fused_us.is_some_and(|t| nav.t_us().saturating_sub(t) < DVL_HOLDS_POSITION_US);
        let unaided_s = t_us.saturating_sub(self.aid.position.last_fused_us) as f32 * 1e-6;
        if !dvl_holds && self.position_refused_run == 1 && unaided_s >= POSITION_TIMEOUT_S {
            // Fixes sparser than the timeout (e.g. one per 10 s, the only aid): the first refusal
            // already comes after `POSITION_TIMEOUT_S` unaided, and waiting for a second one
            // would coast twice as long. Nothing else holds the position, so the filter is the
            // likelier to be wrong: P is faded by `lambda = NIS / 3` (the seed's fading factor,
            // the factor that brings this fix's NIS to its chi-square mean) and the fix fused,
            // so the correction reaches velocity, attitude and biases through their
            // correlations with the position (a reset would drop them). If that is refused
            // too, the fading is undone (a refused update changes nothing) and the fix counts
            // towards the reset below.
            let lambda = (rep.nis / 3.0).clamp(1.0, FADE_LAMBDA_MAX);
            if let Some(faded) = fuse_position_faded(nav, t_us, pos_ned_m, cov_ned_m2, lambda) {
                record(&mut self.aid, AidSource::Position, t_us, &faded, gate, var);
                self.position_resets = self.position_resets.wrapping_add(1);
                self.aid.position.resets = self.aid.position.resets.wrapping_add(1);
                // P was `lambda` too small: the IMU noise scale takes that ratio at once
                // (covariance matching in one step, bounded as the reset's), so P does not
                // shrink back to where the gate refused the fix.
                nav.seed_imu_q_scale(nav.imu_q_scale() * lambda.min(100.0));
                self.refused_positions = PositionRun::default();
                self.position_refused_since_us = None;
                self.position_refused_run = 0;
                return Ok(());
            }
        }
        if !dvl_holds && self.position_refused_run >= POSITION_TIMEOUT_FIXES && refused_s >= POSITION_TIMEOUT_S {
            // Nothing else holds the position and the fixes have been refused for longer than a
            // run of outliers lasts: the filter is lost (PX4's reset on a timeout of refused
            // fixes). The position goes to the fix; the velocity error that walked it away
            // (the innovation over the run's span) is added to the velocity's variance.
            let now = nav.nominal().pos_ned_m;
            let var = [cov_ned_m2[0], cov_ned_m2[3], cov_ned_m2[5]];
            let span_s = refused_s.max(1.0);
            let vel = nav.nominal().vel_ned_mps;
            let sv = nav.solution().sigma_vel_mps;
            let var_vel = [0, 1, 2].map(|k| sv[k] * sv[k] + (innovation[k] / span_s) * (innovation[k] / span_s));
            let fix_now = [now.x + innovation[0], now.y + innovation[1], now.z + innovation[2]];
            if nav.reset_position(fix_now, var).is_ok() {
                self.position_resets = self.position_resets.wrapping_add(1);
                self.aid.position.resets = self.aid.position.resets.wrapping_add(1);
                let _ = nav.reset_velocity(vel.into(), var_vel);
                // The run measured how far the filter's process noise is from the truth's (its
                // NIS against M): the IMU noise scale takes that ratio at once (covariance
                // matching in one step, bounded), instead of 1.6x a fix.
                let ratio = (rep.nis / 3.0).clamp(1.0, 100.0);
                nav.seed_imu_q_scale(nav.imu_q_scale() * ratio);
                // A filter this lost has its heading wrong too (nothing else held it: no DVL,
                // and a compass, if any, pulls it back at once): the yaw keeps its value with
                // an honest sigma, so the next fixes can turn it.
                let yaw_sigma = libm::sqrtf(nav.covariance().get((2, 2)).copied().unwrap_or(0.0)).max(POSITION_RESET_YAW_SIGMA_RAD);
                let _ = nav.reset_heading(nav.nominal().yaw_rad(), yaw_sigma);
            }
            self.refused_positions = PositionRun::default();
            self.position_refused_since_us = None;
            self.position_refused_run = 0;
            return Ok(());
        }
        self.refused_positions.push(innovation, [cov_ned_m2[0], cov_ned_m2[3], cov_ned_m2[5]]);
        if let Some((mean, var)) = self.refused_positions.consensus(RESET_POSITION_FIXES) {
            let now = nav.nominal().pos_ned_m;
            if nav.reset_position([now.x + mean[0], now.y + mean[1], now.z + mean[2]], var).is_ok() {
                self.position_resets = self.position_resets.wrapping_add(1);
                self.aid.position.resets = self.aid.position.resets.wrapping_add(1);
            }
            self.refused_positions = PositionRun::default();
        } else if self.refused_positions.n >= RESET_POSITION_FIXES {
            // Inconsistent refusals (outliers, not a lost position): start over from this one
            // (it may be the first of a lost position's run).
            self.refused_positions = PositionRun::default();
            self.refused_positions.push(innovation, [cov_ned_m2[0], cov_ned_m2[3], cov_ned_m2[5]]);
        }
        Ok(())
    }

    /// A DVL report. Only valid bottom-track velocities reach the filter, at their time of
    /// validity, with the noise `head::dvl_sigma_mps` gives (the caller counts invalid reports
    /// as faults; water-track velocities are recorded but not fused: they are relative to a
    /// moving water column). Before the alignment ends: ignored.
    pub fn on_dvl(&mut self, s: &DvlSample) -> Result<(), NavError> {
        if !dvl_usable(s) {
            return Ok(());
        }
        let Some(nav) = self.nav.as_mut().filter(|_| self.running) else { return Ok(()) };
        let m = DvlMeasurement {
            t_us: s.t_us,
            vel_dvl_mps: s.vel_dvl_mps.map(|v| v / self.dvl_scale),
            covariance_m2ps2: s.covariance_m2ps2.map(|c| head::dvl_covariance_m2ps2(c, s.vel_dvl_mps)),
            fom_mps: Some(head::dvl_sigma_mps(s.fom_mps, s.vel_dvl_mps)),
            gyro_radps: self.last_gyro_radps,
        };
        let rep = nav.update_dvl(&m, &self.dvl_mounting)?;
        let (gate, var) = (nav.config().velocity.gate, dvl_noise_var(&m, nav.r_diag()[KIND_VELOCITY]));
        record(&mut self.aid, AidSource::Dvl, s.t_us, &rep, gate, var);
        if rep.accepted {
            self.dvl_fused = self.dvl_fused.saturating_add(1);
            self.last_dvl_fused_us = Some(s.t_us);
            self.dvl_refused_since_us = None;
            self.dvl_refused_run = 0;
            return Ok(());
        }
        let since = *self.dvl_refused_since_us.get_or_insert(s.t_us);
        self.dvl_refused_run = self.dvl_refused_run.saturating_add(1);
        let refused_s = s.t_us.saturating_sub(since) as f32 * 1e-6;
        if refused_s >= DVL_RESET_AFTER_S && self.dvl_refused_run >= DVL_RESET_MIN_REFUSED {
            self.reset_velocity_to_dvl(s, &m);
        }
        Ok(())
    }

    /// The DVL aid's timeout reset (see `on_dvl`). Out of line and cold: its temporaries stay
    /// out of the DVL path's frame (the M4F's stack).
    #[inline(never)]
    #[cold]
    fn reset_velocity_to_dvl(&mut self, s: &DvlSample, m: &DvlMeasurement) {
        let Some(nav) = self.nav.as_mut().filter(|_| self.running) else { return };
        // The DVL has been refused for longer than a velocity error can honestly explain
        // with it working (its own faults come as single reports or as no lock, not as a
        // consistent velocity for seconds): the filter's velocity is wrong. Take the DVL's,
        // in NED through the filter's attitude, with its noise plus the attitude's share.
        let sigma = head::dvl_sigma_mps(s.fom_mps, s.vel_dvl_mps);
        let v_dvl = nalgebra::Vector3::from(m.vel_dvl_mps);
        let w = nalgebra::Vector3::from(self.last_gyro_radps) - nav.nominal().gyro_bias_radps;
        let v_body = self.dvl_mounting.rot_body_from_dvl * v_dvl - w.cross(&self.dvl_mounting.lever_arm_body_m);
        let v_ned = nav.nominal().att_nb * v_body;
        let att_var = nav.covariance().fixed_view::<3, 3>(subnav_core::nav::state::ATT, subnav_core::nav::state::ATT).trace();
        let var = sigma * sigma + v_ned.norm_squared() * (att_var + DVL_RESET_ATTITUDE_SIGMA_RAD * DVL_RESET_ATTITUDE_SIGMA_RAD);
        if nav.reset_velocity(v_ned.into(), [var; 3]).is_ok() {
            self.aid.dvl.resets = self.aid.dvl.resets.wrapping_add(1);
        }
        self.dvl_refused_since_us = None;
        self.dvl_refused_run = 0;
    }

    pub fn solution(&self, t_us: u64) -> NavSolution {
        match self.nav.as_ref().filter(|_| self.running) {
            Some(nav) => {
                let mut s = nav.solution();
                // The compass's error is mostly a bias that lasts, not noise: its reported sigma
                // is the model departure and the waves' scatter inflated by the fit's
                // chi-square (within 2 sigma of 92 % of its fixes at 5 m/s,
                // docs/PERFORMANCE.md), and a filter that averages its fixes tracks heading +
                // bias, however well it averages. Measured in the 5-m/s dives: fixes 1.1 deg off
                // for a whole 5-minute dive (seed 9) with a reported sigma of 0.7-1.5 deg; the
                // filter claimed 0.33 deg, 57 % of its heading within 3 sigma. A heading-bias
                // state would not change the estimate (the compass is the only absolute heading)
                // but its covariance: the yaw cannot be known better than the compass's bias.
                // So the reported yaw sigma is at least the compass's recent mean sigma, a
                // consider term (Schmidt) for that bias: the filter's gains and state are
                // untouched. The larger of the two, not their sum: the filter's own sigma
                // already carries the fixes' correlated model error (`HEADING_MODEL_SIGMA_RAD`);
                // the sum reported 0.86 deg in the calm dive against a 0.31-deg error. (Holding
                // the filter's own yaw variance at that level instead shortened its averaging of
                // the fixes: heading RMSE +20 % calm, +12 % at 5 m/s.)
                if let Some(v) = s.sigma_att_rad.get_mut(2) {
                    *v = v.max(libm::sqrtf(self.compass_var_mean_rad2));
                }
                s
            }
            None => NavSolution {
                t_us,
                mode: self.mode(),
                pos_ned_m: [0.0, 0.0, self.last_depth_m.unwrap_or(0.0)],
                vel_ned_mps: [0.0; 3],
                att_nb_wxyz: [1.0, 0.0, 0.0, 0.0],
                sigma_pos_m: [f32::INFINITY; 3],
                sigma_vel_mps: [f32::INFINITY; 3],
                sigma_att_rad: [f32::INFINITY; 3],
                cov_ne_m2: 0.0,
            },
        }
    }

    pub fn health(&self, t_us: u64) -> FilterHealth {
        match self.nav.as_ref().filter(|_| self.running) {
            Some(nav) => {
                let mut h = nav.health();
                h.aid = self.aid;
                h.nonfinite_rejects = h.nonfinite_rejects.saturating_add(self.input_rejects);
                h.heading_resets = self.heading_resets;
                h.position_resets = self.position_resets;
                h
            }
            None => FilterHealth {
                t_us,
                aid: self.aid,
                imu_q_scale: 1.0,
                lambda: 1.0,
                q_diag: [0.0; 5],
                pd_repairs: 0,
                cov_unrepairable: 0,
                gate_rejects: 0,
                nonfinite_rejects: self.input_rejects,
                late_fused: 0,
                late_refused: 0,
                heading_resets: self.heading_resets,
                position_resets: self.position_resets,
                cpu_load_permille: 0,
            },
        }
    }
}

/// One aid source's fuse step into its status (`Health::aid`).
fn record(aid: &mut AidStatuses, src: AidSource, t_us: u64, rep: &UpdateReport<f32>, gate: f32, noise_var: f32) {
    let st = aid.get_mut(src);
    st.t_us = t_us;
    st.nis = rep.nis;
    st.test_ratio = if gate.is_finite() && gate > 0.0 { rep.nis_gate / gate } else { 0.0 };
    st.noise_var = noise_var;
    st.fused = rep.accepted;
    if rep.accepted {
        st.fused_count = st.fused_count.wrapping_add(1);
        st.last_fused_us = t_us;
    } else {
        st.refused_count = st.refused_count.wrapping_add(1);
    }
}

/// The DVL noise variance for its status: the mean of its covariance's diagonal when it sent
/// one, else its figure-of-merit sigma squared, else the filter's.
fn dvl_noise_var(m: &DvlMeasurement, filter_var: f32) -> f32 {
    match (m.covariance_m2ps2, m.fom_mps) {
        (Some(c), _) => (c[0] + c[4] + c[8]) / 3.0,
        (None, Some(f)) => f * f,
        (None, None) => filter_var,
    }
}

/// The DVL's acceptance rule, the one place it is written: a valid bottom-track report with its
/// altitude inside the DVL's bottom-lock range (Water Linked DVL-A50: 0.05-50 m; an altitude
/// outside it, or negative = unknown, means the lock is on something else or the report is
/// bad). Water-track velocities are relative to a moving water column: not fused.
pub fn dvl_usable(s: &DvlSample) -> bool {
    s.valid && s.tracking == DvlTracking::Bottom && (DVL_MIN_ALTITUDE_M..=DVL_MAX_ALTITUDE_M).contains(&s.altitude_m)
}

/// The DVL's bottom-lock altitude range, m (Water Linked DVL-A50).
pub const DVL_MIN_ALTITUDE_M: f32 = 0.05;
pub const DVL_MAX_ALTITUDE_M: f32 = 50.0;

/// The filter's storage, built once at construction (not inlined: its frame is transient, at
/// boot). `None` only for an invalid configuration (then the estimator never leaves alignment
/// and says so through `finish_alignment`'s error).
#[inline(never)]
fn filter_storage(cfg: NavConfig) -> Option<NavFilter15> {
    let level = NavInit { t_us: 0, att_nb: head::attitude(0.0, 0.0, 0.0), vel_ned_mps: Vector3::zeros(), pos_ned_m: Vector3::zeros() };
    NavFilter15::new(cfg, level).ok()
}

/// The covariance a static alignment leaves: levelling on the mean specific force turns the
/// accelerometer bias `b` (body) into a tilt error that cancels it at rest. With the error model
/// of `subnav_core::nav::strapdown` (`dv' = dv + (Exp(phi) - I) f_n T - R dba T`, `f_n = [0, 0,
/// -g]` at rest) cancellation means `phi x f_n = R b`, i.e. `phi_N = (R b)_E / g`,
/// `phi_E = -(R b)_N / g`: `phi = M b` with `M = [[0, 1, 0], [-1, 0, 0], [0, 0, 0]] R / g` and
/// `R` the yaw rotation. So `P_phi,phi += M P_b M^T`, `P_phi,b = M P_b`. Without this the filter
/// treats tilt and bias as independent and its horizontal velocity sigma grows by g * tilt
/// sigma per second (measured: 0.2 m/s per s), which lets every aiding update swing the
/// unobserved horizontal velocity.
fn aligned_covariance(p0: &SMatrix<f32, 15, 15>, yaw_rad: f32, sigma_accel_bias: f32, g: f32) -> SMatrix<f32, 15, 15> {
    use subnav_core::nav::state::{ATT, BA};
    let (s, c) = (libm::sinf(yaw_rad), libm::cosf(yaw_rad));
    let r = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
    let swap = Matrix3::new(0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    let m = swap * r / g;
    let pb = Matrix3::identity() * (sigma_accel_bias * sigma_accel_bias);
    let mut p = *p0;
    let att = p.fixed_view::<3, 3>(ATT, ATT) + m * pb * m.transpose();
    p.fixed_view_mut::<3, 3>(ATT, ATT).copy_from(&att);
    let cross = m * pb;
    p.fixed_view_mut::<3, 3>(ATT, BA).copy_from(&cross);
    p.fixed_view_mut::<3, 3>(BA, ATT).copy_from(&cross.transpose());
    p
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

    fn deg(d: f32) -> f32 {
        d.to_radians()
    }

    /// Still IMU samples from `from_s` to `to_s` (200 Hz), with a compass fix every 100 ms from
    /// `fix(t_s)` (None: no fix).
    fn run(e: &mut Estimator, from_s: f32, to_s: f32, fix: impl Fn(f32) -> Option<f32>) {
        let dt = 1_000_000 / u64::from(head::IMU_RATE_HZ);
        let (a, b) = ((from_s * 1e6) as u64 / dt, (to_s * 1e6) as u64 / dt);
        for k in a..b {
            let t = k * dt;
            let _ = e.on_imu(&still(t));
            if k % 20 == 0 {
                let _ = e.on_depth(t, 10.0);
                if let Some(h) = fix(t as f32 * 1e-6) {
                    e.on_heading_fix(t, h, deg(0.1));
                }
            }
        }
    }

    fn yaw_deg(e: &Estimator) -> f32 {
        let q = e.solution(0).att_nb_wxyz;
        let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
        q.euler_angles().2.to_degrees()
    }

    #[test]
    fn alignment_ignores_an_isolated_fix_and_takes_a_consistent_set() {
        let mut e = Estimator::default();
        // One fix 133 deg off at 0.5 s, then nothing until 3 s, then consistent fixes at 17 deg.
        run(&mut e, 0.0, 6.0, |t| {
            if (0.45..0.55).contains(&t) {
                Some(deg(150.0))
            } else if t >= 3.0 {
                Some(deg(17.0) + deg(0.2) * libm::sinf(7.0 * t))
            } else {
                None
            }
        });
        assert!(matches!(e.mode(), NavMode::Aided), "{:?}", e.mode());
        assert!((yaw_deg(&e) - 17.0).abs() < 1.0, "aligned on {} deg", yaw_deg(&e));
        // The first consistent set is 5 fixes: alignment cannot have happened before 3.4 s.
        let mut e = Estimator::default();
        run(&mut e, 0.0, 3.35, |t| {
            if (0.45..0.55).contains(&t) {
                Some(deg(150.0))
            } else if t >= 3.0 {
                Some(deg(17.0))
            } else {
                None
            }
        });
        assert_eq!(e.mode(), NavMode::Aligning);
    }

    #[test]
    fn a_wrong_heading_is_reset_after_a_run_of_consistent_rejected_fixes() {
        let mut e = Estimator::default();
        // Align on a consistent but wrong compass (40 deg), then the compass says 160 deg.
        run(&mut e, 0.0, 2.0, |_| Some(deg(40.0)));
        assert!((yaw_deg(&e) - 40.0).abs() < 1.0);
        run(&mut e, 2.0, 20.0, |_| Some(deg(40.0)));
        let sigma_before = e.solution(0).sigma_att_rad[2];
        assert!(sigma_before < deg(3.0), "converged on the wrong heading: {sigma_before}");
        // 2.9 s of rejected fixes: not yet.
        run(&mut e, 20.0, 22.9, |_| Some(deg(160.0)));
        assert_eq!(e.heading_resets, 0);
        assert!((yaw_deg(&e) - 40.0).abs() < 2.0, "{}", yaw_deg(&e));
        run(&mut e, 22.9, 30.0, |_| Some(deg(160.0)));
        assert_eq!(e.heading_resets, 1);
        assert_eq!(e.health(0).heading_resets, 1, "reported in Health");
        assert!((yaw_deg(&e) - 160.0).abs() < 1.0, "after the reset: {}", yaw_deg(&e));
        let s = e.solution(0);
        assert!(s.att_nb_wxyz.iter().chain(s.pos_ned_m.iter()).all(|v| v.is_finite()));
    }

    /// The head at rest believes it is at the origin while the USBL says it is 60 m away: the
    /// gate refuses those fixes; after `RESET_POSITION_FIXES` consistent ones the position is
    /// reset there and the next fix is accepted. Single outliers among good fixes, and a run of
    /// refusals that disagree with each other, reset nothing.
    #[test]
    fn a_lost_position_is_reset_after_a_run_of_consistent_refused_fixes() {
        let cov = [4.0, 0.0, 0.0, 4.0, 0.0, 1.0];
        let pos = |e: &Estimator| e.solution(0).pos_ned_m;
        let mut e = Estimator::default();
        run(&mut e, 0.0, 20.0, |_| Some(deg(40.0)));
        let start = pos(&e);
        let t0 = 20_000_000u64;
        let fix = |e: &mut Estimator, k: u64, dn: f32, de: f32| {
            let t = t0 + k * 1_000_000;
            run(e, (t - 1_000_000) as f32 * 1e-6, t as f32 * 1e-6, |_| Some(deg(40.0)));
            // Half a second late, as a USBL fix arrives.
            e.on_position_fix(t - 500_000, [start[0] + dn, start[1] + de, start[2]], cov).unwrap();
        };
        // Good fixes with an outlier every fourth; then five refusals that disagree.
        for k in 1..=12 {
            let off = if k % 4 == 0 { 40.0 } else { 0.3 };
            fix(&mut e, k, off, -0.2);
        }
        for (k, dn) in (13..=17).zip([50.0, -50.0, 50.0, -50.0, 50.0]) {
            fix(&mut e, k, dn, 0.0);
        }
        assert_eq!(e.position_resets, 0);
        assert!((pos(&e)[0] - start[0]).abs() < 1.0, "{:?} vs {start:?}", pos(&e));
        // Lost: the fixes agree that the head is 60 m north, 20 m west (scatter about 1 m). The
        // run that ends the disagreeing one holds two of them: the reset comes at the 5th to
        // 8th lost fix.
        let (mut reset_at, mut last_k) = (None, 17);
        for k in 18..=26 {
            last_k = k;
            fix(&mut e, k, 60.0 + (k % 3) as f32 - 1.0, -20.0 + 0.3 * (k % 2) as f32);
            if e.position_resets > 0 && reset_at.is_none() {
                reset_at = Some(k - 17);
                break;
            }
        }
        // Without a DVL the position aid's timeout (refused fixes over `POSITION_TIMEOUT_S`,
        // agreeing or not) may come first: the run began with the disagreeing fixes.
        assert!(reset_at.is_some_and(|n| (4..=8).contains(&n)), "reset at lost fix {reset_at:?}");
        assert_eq!(e.position_resets, 1);
        assert_eq!((e.health(0).position_resets, e.health(0).heading_resets), (1, 0), "reported in Health");
        let p = pos(&e);
        assert!((p[0] - start[0] - 60.0).abs() < 1.5 && (p[1] - start[1] + 20.0).abs() < 1.5, "after the reset: {p:?}");
        let sigma = e.solution(0).sigma_pos_m;
        assert!(sigma[0] > 1.0 && sigma[0] < 3.0, "the fixes' own sigma: {sigma:?}");
        // The next fix there is accepted (the run does not grow).
        fix(&mut e, last_k + 1, 60.2, -19.8);
        assert_eq!(e.refused_positions.n, 0);
        assert!(e.solution(0).pos_ned_m.iter().all(|v| v.is_finite()));
    }

    /// Without a DVL, a fix that is the first refused since the last fused one and comes
    /// `POSITION_TIMEOUT_S` or more after it is fused with the covariance faded: the head is 300 m
    /// north of where its IMU says after 20 s without a fix. The fix reaches the position and,
    /// through its correlation, the velocity; the IMU noise scale takes the fading ratio.
    #[test]
    fn a_sparse_fix_refused_after_the_timeout_is_fused_with_a_faded_covariance() {
        let cov = [0.25, 0.0, 0.0, 0.25, 0.0, 0.25];
        let mut e = Estimator::default();
        run(&mut e, 0.0, 20.0, |_| Some(deg(40.0)));
        let start = e.solution(0).pos_ned_m;
        let (rejects, q0) = (e.health(0).gate_rejects, e.imu_q_scale());
        run(&mut e, 20.0, 40.0, |_| Some(deg(40.0)));
        e.on_position_fix(40_000_000, [start[0] + 300.0, start[1], start[2]], cov).unwrap();
        let h = e.health(0);
        assert_eq!(h.gate_rejects, rejects + 1, "the gate refused the fix");
        assert!(h.aid.position.fused && h.aid.position.resets == 1, "then the timeout fused it: {:?}", h.aid.position);
        let s = e.solution(0);
        assert!((s.pos_ned_m[0] - start[0] - 300.0).abs() < 1.0, "at the fix: {:?}", s.pos_ned_m);
        assert!(s.vel_ned_mps[0] > 0.5, "the velocity corrected northward: {:?}", s.vel_ned_mps);
        assert!(e.imu_q_scale() > 10.0 * q0, "IMU noise scale {} (was {q0})", e.imu_q_scale());
        assert!(s.sigma_pos_m.iter().chain(s.sigma_vel_mps.iter()).all(|v| v.is_finite() && *v > 0.0));
        // A second fix 2 s later, far off again (an outlier right after): refused, and not
        // faded in (it is not a sparse fix: one was fused 2 s ago).
        run(&mut e, 40.0, 42.0, |_| Some(deg(40.0)));
        e.on_position_fix(42_000_000, [start[0] + 900.0, start[1], start[2]], cov).unwrap();
        let h = e.health(0);
        assert!(!h.aid.position.fused && h.aid.position.resets == 1, "{:?}", h.aid.position);
    }

    /// The compass's scatter grows tenfold (0.3 -> 3 deg, white) after 60 s: the adaptive heading
    /// R grows with it (the fixed R does not), the heading stays near the truth and within 3
    /// of its sigma, and the R stays finite.
    #[test]
    fn the_adaptive_heading_r_follows_the_compass_scatter() {
        let noisy = |sigma_deg: f32, k: u32| {
            // A deterministic, roughly Gaussian sequence (sum of 4 uniforms from an LCG).
            let mut x = k.wrapping_mul(2_654_435_761).wrapping_add(12_345);
            let mut sum = 0.0;
            for _ in 0..4 {
                x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                sum += (x >> 8) as f32 / (1u32 << 24) as f32 - 0.5;
            }
            deg(40.0 + sigma_deg * sum * libm::sqrtf(3.0))
        };
        let r_sigma_deg = |e: &Estimator| libm::sqrtf(e.health(0).aid.heading.noise_var).to_degrees();
        let mut results = [(0.0f32, 0.0f32); 2];
        for (on, out) in [true, false].into_iter().zip(results.iter_mut()) {
            let mut e = Estimator::default();
            e.set_adaptive_heading_r(on);
            run(&mut e, 0.0, 60.0, |t| Some(noisy(0.3, (t * 10.0) as u32)));
            let calm = r_sigma_deg(&e);
            run(&mut e, 60.0, 120.0, |t| Some(noisy(3.0, (t * 10.0) as u32)));
            let rough = r_sigma_deg(&e);
            assert!(rough.is_finite() && calm.is_finite());
            let err = (yaw_deg(&e) - 40.0).abs();
            assert!(err < 1.0 && deg(err) < 3.0 * e.solution(0).sigma_att_rad[2], "heading error {err} deg");
            *out = (calm, rough);
        }
        let [(calm, rough), (fixed_calm, fixed_rough)] = results;
        assert!((calm - fixed_calm).abs() < 0.01 * fixed_calm, "calm: the model error's floor: {calm} vs {fixed_calm}");
        assert!(rough > 2.0 * calm, "adaptive: {calm} -> {rough} deg");
        assert!((fixed_rough - fixed_calm).abs() < 0.01 * fixed_calm, "fixed: {fixed_calm} -> {fixed_rough} deg");
    }

    #[test]
    fn reset_goes_back_to_alignment_and_realigns_in_place() {
        let mut e = Estimator::default();
        run(&mut e, 0.0, 3.0, |_| Some(deg(40.0)));
        assert_eq!(e.mode(), NavMode::Aided);
        e.reset();
        assert_eq!(e.mode(), NavMode::Uninitialised);
        assert!(e.solution(0).sigma_att_rad[2].is_infinite());
        run(&mut e, 3.0, 6.0, |_| Some(deg(-100.0)));
        assert_eq!(e.mode(), NavMode::Aided);
        assert!((yaw_deg(&e) + 100.0).abs() < 1.0, "{}", yaw_deg(&e));
    }

    #[test]
    fn inconsistent_outliers_do_not_reset_the_heading() {
        let mut e = Estimator::default();
        run(&mut e, 0.0, 20.0, |_| Some(deg(40.0)));
        // Wild fixes all over the circle for 10 s: all rejected, never consistent.
        run(&mut e, 20.0, 30.0, |t| Some(deg(40.0 + 90.0 + 180.0 * libm::sinf(13.0 * t))));
        assert_eq!(e.heading_resets, 0);
        assert!((yaw_deg(&e) - 40.0).abs() < 2.0, "{}", yaw_deg(&e));
    }

    /// Aligned without the compass (the units dark at the surface), at rest with the DVL and the
    /// depth: nothing measures the yaw, and its sigma stays near its prior until the first
    /// compass fix. The same run with the DVL allowed to read the yaw (`set_yaw_unobserved(false)`)
    /// shows what it guards against: the yaw sigma falls with no heading aid at all.
    #[test]
    fn an_unaided_yaw_keeps_its_sigma_at_rest_until_the_compass() {
        let yaw_sigma_deg = |e: &Estimator| e.solution(0).sigma_att_rad[2].to_degrees();
        let mut results = [0.0f32; 2];
        for (guard, out) in [true, false].into_iter().zip(&mut results) {
            let mut e = Estimator::default();
            run(&mut e, 0.0, 10.5, |_| None);
            assert_eq!(e.mode(), NavMode::Aided);
            assert!(yaw_sigma_deg(&e) > 80.0, "{}", yaw_sigma_deg(&e));
            if let Some(nav) = e.nav.as_mut() {
                assert!(nav.yaw_unobserved(), "aligned without a compass fix");
                nav.set_yaw_unobserved(guard);
            }
            // 20 s at rest: DVL reports of a few mm/s of noise at 5 Hz.
            for k in 0..100u32 {
                let t0 = 10.5 + 0.2 * k as f32;
                run(&mut e, t0, t0 + 0.2, |_| None);
                let noise = 0.004 * libm::sinf(7.3 * k as f32);
                e.on_dvl(&DvlSample { vel_dvl_mps: [noise, -0.7 * noise, 0.3 * noise], ..dvl_with_cov(t0 + 0.2, 0.0, None) }).unwrap();
            }
            *out = yaw_sigma_deg(&e);
        }
        let [guarded, unguarded] = results;
        assert!(guarded > 75.0, "no heading aid, yet the yaw sigma fell to {guarded} deg");
        assert!(
            unguarded < 0.8 * guarded,
            "the DVL at rest reads no yaw here anyway ({unguarded} vs {guarded} deg): the test shows nothing"
        );
        // The first compass fixes take the yaw and clear the flag.
        let mut e = Estimator::default();
        run(&mut e, 0.0, 10.5, |_| None);
        run(&mut e, 10.5, 14.0, |_| Some(deg(40.0)));
        assert!((yaw_deg(&e) - 40.0).abs() < 1.0, "{}", yaw_deg(&e));
        assert!(e.nav.as_ref().is_some_and(|n| !n.yaw_unobserved()));
    }

    /// A compass whose fixes say 1 deg (1-sigma) and are all 1.2 deg off: averaging them for a
    /// minute does not make the heading better than 1 deg, and the reported sigma does not claim
    /// it (the filter's own said 0.26 deg). With fixes of 0.1 deg the term stays small.
    #[test]
    fn the_heading_sigma_is_not_below_the_compass_sigma_however_many_fixes() {
        let sigma_after = |solver_sigma_deg: f32| {
            let mut e = Estimator::default();
            let dt = 1_000_000 / u64::from(head::IMU_RATE_HZ);
            for k in 0..(60 * head::IMU_RATE_HZ) {
                let t = u64::from(k) * dt;
                let _ = e.on_imu(&still(t));
                if k % 10 == 0 {
                    let _ = e.on_depth(t, 10.0);
                    e.on_heading_fix(t, deg(41.2), deg(solver_sigma_deg));
                }
            }
            assert!((yaw_deg(&e) - 41.2).abs() < 0.3, "{}", yaw_deg(&e));
            e.solution(0).sigma_att_rad[2].to_degrees()
        };
        let wide = sigma_after(1.0);
        assert!(wide >= 0.85, "1-deg compass, filter claims {wide} deg");
        let narrow = sigma_after(0.1);
        assert!(narrow < 0.5 && narrow > 0.1, "0.1-deg compass: {narrow} deg (the model error's own level)");
    }

    /// A DVL report with its altitude outside the bottom-lock range (or unknown) is not fused,
    /// however plausible its velocity; inside the range the same report is.
    #[test]
    fn a_dvl_report_with_an_out_of_range_altitude_is_not_fused() {
        let mut e = Estimator::default();
        run(&mut e, 0.0, 3.0, |_| Some(deg(40.0)));
        let dvl = |t_s: f32, altitude_m: f32, v: f32| DvlSample { altitude_m, ..dvl_with_cov(t_s, v, None) };
        for (k, alt) in [80.0, 50.5, 0.01, -1.0, f32::NAN].into_iter().enumerate() {
            run(&mut e, 3.0 + k as f32 * 0.2, 3.2 + k as f32 * 0.2, |_| Some(deg(40.0)));
            e.on_dvl(&dvl(3.2 + k as f32 * 0.2, alt, 0.5)).unwrap();
        }
        assert_eq!(e.dvl_fused, 0, "no out-of-range report fused");
        assert!(e.solution(0).vel_ned_mps.iter().all(|v| v.abs() < 0.05), "{:?}", e.solution(0).vel_ned_mps);
        run(&mut e, 4.0, 4.2, |_| Some(deg(40.0)));
        e.on_dvl(&dvl(4.2, 5.0, 0.005)).unwrap();
        assert_eq!(e.dvl_fused, 1, "in range: fused");
    }

    fn dvl_with_cov(t_s: f32, v: f32, cov: Option<[f32; 9]>) -> DvlSample {
        DvlSample {
            t_us: (t_s * 1e6) as u64,
            rx_us: (t_s * 1e6) as u64,
            tracking: DvlTracking::Bottom,
            valid: true,
            vel_dvl_mps: [v, 0.0, 0.0],
            fom_mps: 0.01,
            altitude_m: 5.0,
            covariance_m2ps2: cov,
        }
    }

    fn diag(var: f32) -> Option<[f32; 9]> {
        Some([var, 0.0, 0.0, 0.0, var, 0.0, 0.0, 0.0, var])
    }

    /// The DVL's own covariance is the noise it is fused with (plus the head's model error);
    /// without one, its figure of merit. Named in its status.
    #[test]
    fn a_dvl_report_is_fused_with_its_own_covariance() {
        let mut e = Estimator::default();
        run(&mut e, 0.0, 3.0, |_| Some(deg(40.0)));
        e.on_dvl(&dvl_with_cov(3.0, 0.0, None)).unwrap();
        let fom_var = e.health(0).aid.dvl.noise_var;
        assert!((fom_var - 1e-4).abs() < 1e-6, "figure of merit 0.01 m/s: {fom_var}");
        run(&mut e, 3.0, 3.2, |_| Some(deg(40.0)));
        e.on_dvl(&dvl_with_cov(3.2, 0.0, diag(0.03 * 0.03))).unwrap();
        let st = e.health(0).aid.dvl;
        assert!((st.noise_var - 9e-4).abs() < 1e-6, "its own covariance: {}", st.noise_var);
        assert!(st.fused && st.fused_count == 2 && st.refused_count == 0, "{st:?}");
        assert!(st.test_ratio >= 0.0 && st.test_ratio < 1.0, "{st:?}");
    }

    /// A huge covariance says the report carries nothing: fused, and the velocity does not
    /// move toward it; a NaN or not positive definite one is refused (counted), nothing changes.
    #[test]
    fn a_dvl_report_with_a_huge_or_broken_covariance_does_nothing() {
        let mut e = Estimator::default();
        run(&mut e, 0.0, 3.0, |_| Some(deg(40.0)));
        e.on_dvl(&dvl_with_cov(3.0, 2.0, diag(1e6))).unwrap();
        let v = e.solution(0).vel_ned_mps;
        assert!(v.iter().all(|x| x.abs() < 0.01), "a 2 m/s report with a 1000 m/s sigma moved the velocity to {v:?}");
        assert_eq!(e.health(0).aid.dvl.fused_count, 1);
        run(&mut e, 3.0, 3.2, |_| Some(deg(40.0)));
        let before = (e.solution(0), e.health(0).nonfinite_rejects);
        let mut nan = diag(1e-4);
        if let Some(c) = nan.as_mut() {
            c[4] = f32::NAN;
        }
        let not_pd = Some([1e-4, 1.0, 0.0, 1.0, 1e-4, 0.0, 0.0, 0.0, 1e-4]);
        for cov in [nan, not_pd] {
            assert!(e.on_dvl(&dvl_with_cov(3.2, 0.5, cov)).is_err(), "{cov:?} refused");
        }
        assert_eq!(e.solution(0), before.0, "a refused report changes nothing");
        assert_eq!(e.health(0).nonfinite_rejects, before.1 + 2, "and is counted");
        assert_eq!(e.health(0).aid.dvl.fused_count, 1);
    }

    /// Every aid source has its status in `Health`, by name (a new `AidSource` does not compile
    /// until `AidStatuses::get` has it), and each moves with its own sensor only.
    #[test]
    fn every_aid_source_reports_its_own_status() {
        let mut e = Estimator::default();
        run(&mut e, 0.0, 3.0, |_| Some(deg(40.0)));
        e.on_dvl(&dvl_with_cov(3.0, 0.0, None)).unwrap();
        e.on_position_fix(2_900_000, [0.0, 0.0, 10.0], [4.0, 0.0, 0.0, 4.0, 0.0, 1.0]).unwrap();
        let h = e.health(0);
        let names: heapless::Vec<&str, 8> = AidSource::ALL.iter().map(|s| s.name()).collect();
        for (k, a) in names.iter().enumerate() {
            assert!(!names[k + 1..].contains(a), "names are distinct: {names:?}");
        }
        for src in AidSource::ALL {
            let st = h.aid.get(src);
            assert!(st.fused_count > 0 && st.t_us > 0 && st.noise_var > 0.0 && st.nis.is_finite(), "{}: {st:?}", src.name());
        }
        assert_eq!((h.aid.dvl.fused_count, h.aid.position.fused_count), (1, 1));
        assert!(h.aid.heading.fused_count > 10 && h.aid.depth.fused_count > 10);
    }

    #[test]
    fn compass_without_time_says_so() {
        let mut e = Estimator::default();
        let r = e.on_polarization(0, &[(0, [100; 4]), (1, [100; 4]), (2, [100; 4]), (3, [100; 4])], None, None);
        assert!(r.heading_rad.is_none());
        assert_ne!(r.no_fix_reason, 0);
    }
}
