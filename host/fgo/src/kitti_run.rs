//! The navigation methods on the real KITTI data ([`crate::kitti`]): the factor graph (fixed-lag
//! smoother and batch LM) and the sensor head's navigation filter (`subnav_core::nav::NavFilter15`
//! with the head's tuning), with the 1 Hz positions used as USBL-like fixes.
//!
//! Protocol:
//! - epochs = the GPS time stamps from `first_fix` on (the first row of the file is 3 s before
//!   the next and the IMU has a 1.9 s gap after it, so GTSAM's example starts at row 1 too), over
//!   `duration_s`; the graph has one node per epoch;
//! - every `fix_every`-th epoch's position is a fix (sigma `fix_sigma_m` per axis, the
//!   example's `0.07 m^2` variance by default), possibly corrupted by [`Faults`]; all epochs are
//!   scored against the recorded positions, reported separately for the held-out ones;
//! - initial state at the first epoch: position = its fix, velocity = the difference of the first
//!   two fixes, attitude = level with the yaw of that velocity, biases 0; a prior with
//!   `prior_sigmas` on it (both sides of every comparison get the same one);
//! - IMU noise from the metadata; the bias random walk per sample of the metadata turned into a
//!   density (`sigma / sqrt(AverageDeltaT)`), gravity 9.8 m/s^2 down (GTSAM's example), no
//!   Earth rate; IMU samples held on `[t_k, t_k+1)` ([`crate::smoother::imu_pieces`]).
//!
//! The filter is driven natively, not through the firmware's `Estimator`: that one starts with a
//! static alignment (the head at rest for 1 s), and the car is moving at 9 m/s in the first
//! sample. The filter is initialised from the same initial state with the same sigmas as the
//! graph's prior; its tuning is `subnav_core::head::nav_config()` (the ICM-42688-P MEMS noise)
//! with three data facts changed: the IMU rate (100 Hz; the covariance predict stays at 10 Hz),
//! gravity (9.8) and the fix noise given with each fix.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{Value, json};

use super::FgoError;
use super::factors::Factor;
use super::gating::{GateLog, GatingConfig, Sensor};
use super::kitti::{GpsFix, KittiData};
use super::log::{LogConfig, PriorConfig};
use super::preintegration::ImuParams;
use super::smoother::{Smoother, SmootherConfig, imu_pieces, thread_cpu_s};
use super::solver::{self, LmOptions, LmReport};
use super::state::{ImuBias, NavState, NodeState, enu_to_ned, f_flu_frd, t_enu_ned};
use subnav_base::so3;

/// Abnormal observations injected into the used fixes.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Faults {
    /// Probability that a used fix jumps (multipath-like): a horizontal offset of
    /// `jump_m * U(0.5, 1)` in a random direction.
    pub jump_probability: f64,
    pub jump_m: f64,
    /// Intervals (s, relative to the first epoch) with no fixes at all.
    pub dropouts_s: Vec<(f64, f64)>,
    pub seed: u64,
}

/// Evaluation only: decisions on the injected jumps made with the knowledge of which fixes
/// jumped, to bound what a gate could gain (the bounds in docs/PERFORMANCE.md, "Abnormal
/// observations on the real fixes").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Oracle {
    /// No knowledge: the gate decides.
    #[default]
    None,
    /// Each jumped fix taken out of the smoother when the next fix arrives (a perfect decision
    /// delayed by one fix; the fix is used until then).
    NextFix,
}

#[derive(Debug, Clone, PartialEq)]
pub struct KittiConfig {
    pub first_fix: usize,
    pub duration_s: f64,
    pub fix_every: usize,
    pub fix_sigma_m: f64,
    pub gravity_mps2: f64,
    /// Prior sigmas: attitude rad, position m, velocity m/s, acc bias, gyro bias.
    pub prior_sigmas: [f64; 5],
    pub lag_s: f64,
    pub iterations: usize,
    pub gating: GatingConfig,
    pub faults: Faults,
    pub oracle: Oracle,
}

impl Default for KittiConfig {
    fn default() -> Self {
        Self {
            first_fix: 1,
            duration_s: f64::INFINITY,
            fix_every: 10,
            fix_sigma_m: 0.07f64.sqrt(),
            gravity_mps2: 9.8,
            prior_sigmas: [0.1, 0.07f64.sqrt(), 1.0, 0.1, 1e-3],
            lag_s: 30.0,
            iterations: 2,
            gating: GatingConfig::default(),
            faults: Faults::default(),
            oracle: Oracle::None,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    Used,
    HeldOut,
    /// A fix epoch that fell in a dropout (scored like a held-out one).
    Dropped,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Epoch {
    pub t_s: f64,
    /// The recorded position (the reference every estimate is scored against).
    pub recorded: GpsFix,
    /// What the estimators receive (the recorded fix plus any injected jump) for `Role::Used`.
    pub measured_enu_m: Vector3<f64>,
    pub jumped: bool,
    pub role: Role,
}

#[derive(Debug, Clone)]
pub struct Scenario {
    pub epochs: Vec<Epoch>,
    pub imu: ImuParams,
    pub prior: PriorConfig,
}

pub fn imu_params(data: &KittiData, gravity_mps2: f64) -> ImuParams {
    let m = &data.meta;
    ImuParams {
        gravity_enu_mps2: [0.0, 0.0, -gravity_mps2],
        acc_noise_density: m.acc_sigma,
        gyro_noise_density: m.gyro_sigma,
        integration_sigma: m.integration_sigma,
        acc_bias_rw: m.acc_bias_sigma / m.average_dt_s.sqrt(),
        gyro_bias_rw: m.gyro_bias_sigma / m.average_dt_s.sqrt(),
    }
}

/// Select the epochs and corrupt the used fixes.
pub fn scenario(data: &KittiData, cfg: &KittiConfig) -> Result<Scenario, FgoError> {
    if cfg.fix_every == 0 || !(cfg.fix_sigma_m > 0.0) || !(cfg.duration_s > 0.0) {
        return Err(FgoError::Input(format!("fix_every must be >= 1, fix sigma and duration > 0: {cfg:?}")));
    }
    let gps = data.gps.get(cfg.first_fix..).unwrap_or(&[]);
    let Some(first) = gps.first() else {
        return Err(FgoError::Input(format!("first fix {} is beyond the {} GPS rows", cfg.first_fix, data.gps.len())));
    };
    let t0 = first.t_s;
    let imu_end = data.imu.last().map_or(f64::NEG_INFINITY, |s| s.t_s);
    if data.imu.first().is_none_or(|s| s.t_s > t0) {
        return Err(FgoError::Input(format!("no IMU sample at or before the first epoch t={t0}")));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.faults.seed);
    let mut epochs = Vec::new();
    for (k, g) in gps.iter().enumerate() {
        if g.t_s - t0 > cfg.duration_s || g.t_s > imu_end {
            break;
        }
        let rel = g.t_s - t0;
        let is_fix = k % cfg.fix_every == 0;
        let dropped = cfg.faults.dropouts_s.iter().any(|(a, b)| rel >= *a && rel < *b);
        let role = match (is_fix, dropped) {
            (true, false) => Role::Used,
            (true, true) => Role::Dropped,
            _ => Role::HeldOut,
        };
        let mut measured = g.pos_enu_m;
        let mut jumped = false;
        if role == Role::Used && k > 0 && rng.random::<f64>() < cfg.faults.jump_probability {
            let ang = rng.random::<f64>() * std::f64::consts::TAU;
            let mag = cfg.faults.jump_m * (0.5 + 0.5 * rng.random::<f64>());
            measured += Vector3::new(ang.cos(), ang.sin(), 0.0) * mag;
            jumped = true;
        }
        epochs.push(Epoch { t_s: g.t_s, recorded: *g, measured_enu_m: measured, jumped, role });
    }
    if epochs.len() < 2 {
        return Err(FgoError::Input("fewer than 2 epochs in the window".into()));
    }
    let (e0, e1) = (&epochs[0], &epochs[1]);
    let vel = (e1.recorded.pos_enu_m - e0.recorded.pos_enu_m) / (e1.t_s - e0.t_s);
    let yaw = vel.y.atan2(vel.x);
    let prior = PriorConfig {
        t_s: t0,
        rotvec_enu_flu: [0.0, 0.0, yaw],
        pos_enu_m: e0.recorded.pos_enu_m.into(),
        vel_enu_mps: vel.into(),
        bias_acc_mps2: [0.0; 3],
        bias_gyro_radps: [0.0; 3],
        sigmas: cfg.prior_sigmas,
    };
    Ok(Scenario { epochs, imu: imu_params(data, cfg.gravity_mps2), prior })
}

/// Position errors against the recorded fixes.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Score {
    /// RMS 3-D error over the held-out (and dropped) epochs, m.
    pub rmse_heldout_m: f64,
    pub max_heldout_m: f64,
    /// RMS 3-D error at the used epochs (against the recorded, uncorrupted position), m.
    pub rmse_used_m: f64,
    pub n_heldout: usize,
}

pub fn score(epochs: &[Epoch], pos_enu_m: &[Vector3<f64>]) -> Score {
    let (mut sh, mut mh, mut nh, mut su, mut nu) = (0.0, 0.0f64, 0usize, 0.0, 0usize);
    for (e, p) in epochs.iter().zip(pos_enu_m) {
        let d = (p - e.recorded.pos_enu_m).norm();
        let d = if d.is_finite() { d } else { f64::INFINITY };
        if e.role == Role::Used {
            su += d * d;
            nu += 1;
        } else {
            sh += d * d;
            mh = mh.max(d);
            nh += 1;
        }
    }
    let rms = |s: f64, n: usize| if n == 0 { f64::NAN } else { (s / n as f64).sqrt() };
    Score { rmse_heldout_m: rms(sh, nh), max_heldout_m: mh, rmse_used_m: rms(su, nu), n_heldout: nh }
}

/// The factor graph's run: fixed-lag smoother in arrival order, then batch LM.
pub struct GraphRun {
    /// Real-time (newest-node) estimate at each epoch.
    pub realtime: Vec<NodeState>,
    /// Initial values of the batch problem (the smoother's final estimates) and its optimum.
    pub initial: Vec<NodeState>,
    pub batch: Vec<NodeState>,
    pub times: Vec<f64>,
    pub factors: Vec<Factor>,
    pub gate_log: GateLog,
    /// Fixes inflated in the batch problem (the smoother's decisions, or the adaptive gate's
    /// batch re-decision, [`super::gating::robust_batch`]).
    pub batch_inflated: usize,
    pub batch_report: LmReport,
    /// IMU noise variance scale of the batch problem (1: the metadata's noise; also 1 with the
    /// neighbours rule, which keeps the IMU as given), the scale the batch's tests estimated
    /// ([`super::gating::robust_batch`]), and the smoother's estimate at the end of the run
    /// (adaptive gate, [`super::gating::imu_noise_scale`]).
    pub imu_scale: f64,
    pub estimated_imu_scale: f64,
    pub realtime_imu_scale: f64,
    /// Thread CPU time of all smoother updates, and of the batch LM, s.
    pub smoother_cpu_s: f64,
    pub batch_cpu_s: f64,
    pub smoother_wall_s: f64,
    pub batch_wall_s: f64,
    /// Times of the fixes the real-time neighbours rule took out one fix late
    /// (`Smoother::delayed`).
    pub realtime_taken_out: Vec<f64>,
}

pub fn log_config(sc: &Scenario) -> LogConfig {
    LogConfig { imu: sc.imu, dvl_rotvec_body: [0.0; 3], dvl_lever_body_m: [0.0; 3], usbl_lever_body_m: [0.0; 3], prior: sc.prior }
}

/// The batch LM's options here: GTSAM's defaults as the peer sets them (relative and absolute
/// cost-change tolerance 1e-10). Both solvers are timed with these; a cost-change test cannot
/// resolve the optimum to 1e-6 m on the full run (a 1e-6 m move along a weak direction changes
/// the cost by ~1e-11), so for the agreement check both are then polished ([`polish`]; the
/// peer: Gauss-Newton from its LM result), untimed.
pub fn batch_lm_options() -> LmOptions {
    LmOptions::default()
}

/// Iterate from an LM optimum until no step lowers the cost or the step is below 1e-12.
pub fn polish(nodes: &mut [NodeState], factors: &[Factor]) -> Result<LmReport, FgoError> {
    solver::solve_lm(nodes, factors, &LmOptions { relative_tol: 0.0, absolute_tol: 0.0, max_iterations: 20, ..Default::default() })
}

pub fn run_graph(data: &KittiData, sc: &Scenario, cfg: &KittiConfig) -> Result<GraphRun, FgoError> {
    let scfg = SmootherConfig { lag_s: cfg.lag_s, gating: cfg.gating, iterations: cfg.iterations };
    let mut sm = Smoother::new(log_config(sc), scfg)?;
    let mut next = 0;
    let t_start = std::time::Instant::now();
    let mut realtime = Vec::with_capacity(sc.epochs.len());
    realtime.push(NodeState::new(
        NavState::new(
            so3::exp(&Vector3::from(sc.prior.rotvec_enu_flu)),
            Vector3::from(sc.prior.pos_enu_m),
            Vector3::from(sc.prior.vel_enu_mps),
        ),
        ImuBias::default(),
    ));
    let mut prev_jumped: Option<f64> = None;
    for e in &sc.epochs[1..] {
        while next < data.imu.len() && data.imu[next].t_s <= e.t_s {
            sm.push_imu(data.imu[next])?;
            next += 1;
        }
        if e.role == Role::Used {
            sm.add_usbl(e.t_s, e.measured_enu_m, cfg.fix_sigma_m, cfg.fix_sigma_m)?;
            if cfg.oracle == Oracle::NextFix {
                if let Some(p) = prev_jumped.take() {
                    sm.exclude_fix(p)?;
                }
                prev_jumped = e.jumped.then_some(e.t_s);
            }
        } else if !sm.add_node(e.t_s)? {
            return Err(FgoError::Numeric(format!("epoch t={} fell before the smoother window", e.t_s)));
        }
        let last = sm.realtime.last().ok_or_else(|| FgoError::Numeric("no real-time output".into()))?;
        realtime.push(last.state);
    }
    let smoother_wall_s = t_start.elapsed().as_secs_f64();
    let smoother_cpu_s = sm.cpu_s.iter().sum();
    let realtime_taken_out = sm.delayed.iter().filter(|d| d.1).map(|d| d.0).collect();
    let (est, mut factors) = sm.batch_problem();
    if est.len() != sc.epochs.len() {
        return Err(FgoError::Numeric(format!("{} nodes for {} epochs", est.len(), sc.epochs.len())));
    }
    let initial: Vec<NodeState> = est.iter().map(|e| e.state).collect();
    let times = est.iter().map(|e| e.t_s).collect();
    let mut batch = initial.clone();
    let t_b = std::time::Instant::now();
    let c0 = thread_cpu_s();
    let (batch_report, batch_inflated, estimated_imu_scale) = if cfg.gating.enabled && cfg.gating.adaptive {
        super::gating::robust_batch(&mut batch, &mut factors, &cfg.gating, &batch_lm_options())?
    } else {
        (solver::solve_lm(&mut batch, &factors, &batch_lm_options())?, sm.gate_log.count(Sensor::Usbl, true), sm.imu_scale)
    };
    let batch_cpu_s = match (c0, thread_cpu_s()) {
        (Some(a), Some(b)) => b - a,
        _ => f64::NAN,
    };
    let batch_wall_s = t_b.elapsed().as_secs_f64();
    // the scale the batch problem's IMU factors carry
    let imu_scale = factors.iter().find_map(|f| if let Factor::Imu(x) = f { Some(x.noise_scale) } else { None }).unwrap_or(1.0);
    Ok(GraphRun {
        realtime,
        initial,
        batch,
        times,
        factors,
        gate_log: sm.gate_log,
        batch_inflated,
        batch_report,
        imu_scale,
        estimated_imu_scale,
        realtime_imu_scale: sm.imu_scale,
        smoother_cpu_s,
        batch_cpu_s,
        smoother_wall_s,
        batch_wall_s,
        realtime_taken_out,
    })
}

pub fn positions(states: &[NodeState]) -> Vec<Vector3<f64>> {
    states.iter().map(|s| s.nav.pos_enu_m).collect()
}

impl GraphRun {
    pub fn fixes_inflated(&self) -> usize {
        self.gate_log.count(Sensor::Usbl, true)
    }
}

/// The navigation filter's run.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FilterRun {
    pub score: Score,
    /// Mean NEES of the position error at the held-out epochs against `P_pos + R_fix` (3 for a
    /// consistent filter), and the fraction above the 99 % chi-square(3) quantile.
    pub nees_mean: f64,
    pub nees_above_99: f64,
    pub pd_repairs: u32,
    pub gate_rejects: u32,
    pub fixes_fused: usize,
    pub fixes_rejected: usize,
    pub update_errors: usize,
    /// Non-finite state or a held-out error above 100 m at any epoch.
    pub diverged: bool,
    pub final_error_m: f64,
    pub cpu_s: f64,
    #[serde(skip)]
    pub pos_enu_m: Vec<Vector3<f64>>,
}

pub fn run_filter(data: &KittiData, sc: &Scenario, cfg: &KittiConfig, gate: bool) -> Result<FilterRun, FgoError> {
    use subnav_core::nav::{NavFilter15, NavInit, state::POS};
    let mut nc = subnav_core::head::nav_config();
    nc.imu_rate_hz = 100.0;
    nc.cov_decimation = 10;
    nc.gravity_mps2 = cfg.gravity_mps2 as f32;
    let s = sc.prior.sigmas;
    nc.init_sigma_att_rad = [s[0] as f32; 3];
    nc.init_sigma_pos_m = s[1] as f32;
    nc.init_sigma_vel_mps = s[2] as f32;
    nc.init_sigma_accel_bias = s[3] as f32;
    nc.init_sigma_gyro_bias = s[4] as f32;
    nc.position.sigma = cfg.fix_sigma_m as f32;
    if !gate {
        nc.position.gate = f32::INFINITY;
    }
    let t0 = sc.prior.t_s;
    let us = |t: f64| ((t - t0) * 1e6).round().max(0.0) as u64 + 1_000_000;
    let r_enu = so3::exp(&Vector3::from(sc.prior.rotvec_enu_flu));
    let r_ned_frd = t_enu_ned() * r_enu * f_flu_frd();
    let att = UnitQuaternion::from_matrix(&r_ned_frd).cast::<f32>();
    let init = NavInit {
        t_us: us(t0),
        att_nb: att,
        vel_ned_mps: enu_to_ned(&Vector3::from(sc.prior.vel_enu_mps)).cast::<f32>(),
        pos_ned_m: enu_to_ned(&Vector3::from(sc.prior.pos_enu_m)).cast::<f32>(),
    };
    let mut nav = NavFilter15::new(nc, init).map_err(|e| FgoError::Numeric(format!("navigation filter: {e:?}")))?;
    let f = f_flu_frd();
    let r_fix = Matrix3::identity() * cfg.fix_sigma_m.powi(2);
    let var = (cfg.fix_sigma_m * cfg.fix_sigma_m) as f32;
    let cov = [var, 0.0, 0.0, var, 0.0, var];
    let mut next = data.imu.partition_point(|s| s.t_s <= t0);
    let (mut fused, mut rejected, mut errors) = (0, 0, 0);
    let mut pos = Vec::with_capacity(sc.epochs.len());
    let mut nees = Vec::new();
    let mut diverged = false;
    let cpu0 = thread_cpu_s();
    for e in &sc.epochs {
        while next < data.imu.len() && data.imu[next].t_s <= e.t_s {
            let smp = &data.imu[next];
            let a = f * smp.acc_mps2;
            let w = f * smp.gyro_radps;
            let m = subnav_wire::ImuSample {
                t_us: us(smp.t_s),
                gyro_radps: [w.x as f32, w.y as f32, w.z as f32],
                accel_mps2: [a.x as f32, a.y as f32, a.z as f32],
                temp_c: 20.0,
            };
            // rejected samples are counted by the filter (health)
            let _ = nav.propagate(&m);
            next += 1;
        }
        if e.role == Role::Used && e.t_s > t0 {
            let z = enu_to_ned(&e.measured_enu_m);
            match nav.update_position(us(e.t_s), [z.x as f32, z.y as f32, z.z as f32], cov) {
                Ok(rep) if rep.accepted => fused += 1,
                Ok(_) => rejected += 1,
                Err(_) => errors += 1,
            }
        }
        let sol = nav.solution();
        // the solution is at the last IMU sample (<= 10 ms before the epoch): carry it to the epoch
        let dt = e.t_s - ((sol.t_us as f64 - 1e6) * 1e-6 + t0);
        let p_ned = Vector3::new(sol.pos_ned_m[0] as f64, sol.pos_ned_m[1] as f64, sol.pos_ned_m[2] as f64)
            + Vector3::new(sol.vel_ned_mps[0] as f64, sol.vel_ned_mps[1] as f64, sol.vel_ned_mps[2] as f64) * dt.max(0.0);
        let p_enu = enu_to_ned(&p_ned);
        let err = p_enu - e.recorded.pos_enu_m;
        if !err.norm().is_finite() || (e.role != Role::Used && err.norm() > 100.0) {
            diverged = true;
        }
        if e.role != Role::Used {
            let pc = nav.covariance().fixed_view::<3, 3>(POS, POS).into_owned().cast::<f64>();
            let t = t_enu_ned();
            let s_enu = t * pc * t + r_fix;
            let n = s_enu.cholesky().map_or(f64::INFINITY, |c| err.dot(&c.solve(&err)));
            nees.push(n);
        }
        pos.push(p_enu);
    }
    let cpu_s = match (cpu0, thread_cpu_s()) {
        (Some(a), Some(b)) => b - a,
        _ => f64::NAN,
    };
    let h = nav.health();
    let score = score(&sc.epochs, &pos);
    let nees_mean = nees.iter().sum::<f64>() / nees.len().max(1) as f64;
    let nees_above_99 = nees.iter().filter(|n| **n > 11.344_866_730_144_373).count() as f64 / nees.len().max(1) as f64;
    let final_error_m = pos.last().zip(sc.epochs.last()).map_or(f64::NAN, |(p, e)| (p - e.recorded.pos_enu_m).norm());
    Ok(FilterRun {
        score,
        nees_mean,
        nees_above_99,
        pd_repairs: h.pd_repairs,
        gate_rejects: h.gate_rejects,
        fixes_fused: fused,
        fixes_rejected: rejected,
        update_errors: errors,
        diverged,
        final_error_m,
        cpu_s,
        pos_enu_m: pos,
    })
}

fn m3(m: &Matrix3<f64>) -> Value {
    json!([[m[(0, 0)], m[(0, 1)], m[(0, 2)]], [m[(1, 0)], m[(1, 1)], m[(1, 2)]], [m[(2, 0)], m[(2, 1)], m[(2, 2)]]])
}
fn v3(v: &Vector3<f64>) -> Value {
    json!([v.x, v.y, v.z])
}
fn node_json(x: &NodeState) -> Value {
    json!({"R": m3(&x.nav.rot_enu_flu), "p": v3(&x.nav.pos_enu_m), "v": v3(&x.nav.vel_enu_mps),
           "ba": v3(&x.bias.acc_mps2), "bg": v3(&x.bias.gyro_radps)})
}
fn dm(m: &nalgebra::DMatrix<f64>) -> Value {
    json!((0..m.nrows()).map(|r| (0..m.ncols()).map(|c| m[(r, c)]).collect::<Vec<_>>()).collect::<Vec<_>>())
}

/// The batch problem of `run` for `tests/peers/gtsam_kitti.py`: the same nodes (initial values),
/// prior, IMU intervals (the samples each of our preintegrations consumed), bias random walks
/// and fixes (with the covariances our gate left them), plus the lag for GTSAM's fixed-lag
/// smoother. The peer builds it from GTSAM's C++ factors only.
pub fn gtsam_problem(data: &KittiData, sc: &Scenario, run: &GraphRun, lag_s: f64) -> Result<Value, FgoError> {
    let p = &sc.imu;
    // the batch problem's IMU noise scale (the preintegrated covariance is linear in the noise
    // densities, so scaling them scales it; the bias random walks go with their covariances)
    let s = run.imu_scale;
    let mut imu = Vec::new();
    let mut bias_rw = Vec::new();
    let mut gps = Vec::new();
    let mut n_prior = 0;
    for f in &run.factors {
        match f {
            Factor::Imu(x) if (x.noise_scale - s).abs() > 1e-12 * s => {
                return Err(FgoError::Numeric(format!("IMU factor at scale {} in a problem at {s}", x.noise_scale)));
            }
            Factor::Imu(x) => imu.push(json!({
                "i": x.node_i, "j": x.node_j, "bias_hat": x.pim.bias_hat.to_array(),
                "samples": imu_pieces(&data.imu, run.times[x.node_i], run.times[x.node_j])?,
            })),
            Factor::BiasRw(x) => bias_rw.push(json!({"i": x.node_i, "j": x.node_j, "cov": dm(&x.noise.cov)})),
            Factor::Usbl(x) => gps.push(json!({"node": x.node, "pos": v3(&x.pos_enu_m), "cov": dm(&x.noise.cov)})),
            Factor::Prior(x) if x.node == 0 => n_prior += 1,
            other => return Err(FgoError::Input(format!("unexpected factor in the KITTI problem: {other:?}"))),
        }
    }
    if n_prior != 1 {
        return Err(FgoError::Input(format!("expected one prior, found {n_prior}")));
    }
    let pr = &sc.prior;
    let rot0 = so3::exp(&Vector3::from(pr.rotvec_enu_flu));
    Ok(json!({
        "params": {
            "gravity": p.gravity_enu_mps2, "acc_cov": m3(&(p.acc_cov() * s)), "gyro_cov": m3(&(p.gyro_cov() * s)),
            "int_cov": m3(&(p.integration_cov() * s)),
        },
        "times": run.times,
        "nodes": run.initial.iter().map(node_json).collect::<Vec<_>>(),
        "prior": {
            "R": m3(&rot0), "p": pr.pos_enu_m, "v": pr.vel_enu_mps, "ba": pr.bias_acc_mps2, "bg": pr.bias_gyro_radps,
            "sigmas": pr.sigmas,
        },
        "imu": imu, "bias_rw": bias_rw, "gps": gps, "lag_s": lag_s,
        "lm": {"max_iterations": batch_lm_options().max_iterations, "relative_tol": batch_lm_options().relative_tol,
               "absolute_tol": batch_lm_options().absolute_tol},
    }))
}

/// Largest differences of `ours` from a peer's node list (`[{R, p, v, ba, bg}]`): position m,
/// velocity m/s, attitude rad, bias.
pub fn max_state_diff(ours: &[NodeState], peer: &Value) -> Result<[f64; 4], FgoError> {
    let bad = || FgoError::Input("peer nodes malformed".into());
    let arr = peer.as_array().ok_or_else(bad)?;
    if arr.len() != ours.len() {
        return Err(FgoError::Input(format!("peer has {} nodes, ours {}", arr.len(), ours.len())));
    }
    let v = |x: &Value| -> Result<Vector3<f64>, FgoError> {
        let a = x.as_array().ok_or_else(bad)?;
        Ok(Vector3::new(
            a.first().and_then(Value::as_f64).ok_or_else(bad)?,
            a.get(1).and_then(Value::as_f64).ok_or_else(bad)?,
            a.get(2).and_then(Value::as_f64).ok_or_else(bad)?,
        ))
    };
    let m = |x: &Value| -> Result<Matrix3<f64>, FgoError> {
        let a = x.as_array().ok_or_else(bad)?;
        let r0 = v(a.first().ok_or_else(bad)?)?;
        let r1 = v(a.get(1).ok_or_else(bad)?)?;
        let r2 = v(a.get(2).ok_or_else(bad)?)?;
        Ok(Matrix3::from_rows(&[r0.transpose(), r1.transpose(), r2.transpose()]))
    };
    let mut d = [0.0f64; 4];
    for (x, g) in ours.iter().zip(arr) {
        d[0] = d[0].max((x.nav.pos_enu_m - v(&g["p"])?).amax());
        d[1] = d[1].max((x.nav.vel_enu_mps - v(&g["v"])?).amax());
        d[2] = d[2].max(so3::log(&(x.nav.rot_enu_flu.transpose() * m(&g["R"])?)).amax());
        d[3] = d[3].max((x.bias.acc_mps2 - v(&g["ba"])?).amax()).max((x.bias.gyro_radps - v(&g["bg"])?).amax());
    }
    Ok(d)
}

/// Positions of a peer's node list.
pub fn peer_positions(peer: &Value) -> Vec<Vector3<f64>> {
    peer.as_array()
        .map(|a| {
            a.iter()
                .map(|n| {
                    let p = &n["p"];
                    Vector3::new(p[0].as_f64().unwrap_or(f64::NAN), p[1].as_f64().unwrap_or(f64::NAN), p[2].as_f64().unwrap_or(f64::NAN))
                })
                .collect()
        })
        .unwrap_or_default()
}

/// Run a python peer script with `input` on stdin; its stdout parsed as JSON.
pub fn run_python_peer(python: &std::path::Path, script: &std::path::Path, input: &Value) -> Result<Value, FgoError> {
    use std::io::Write;
    use std::process::{Command, Stdio};
    let mut child = Command::new(python)
        .arg(script)
        .env("OMP_NUM_THREADS", "1")
        .env("MKL_NUM_THREADS", "1")
        .env("OPENBLAS_NUM_THREADS", "1")
        .env("TBB_NUM_THREADS", "1")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| FgoError::Input(format!("cannot run {} {}: {e}", python.display(), script.display())))?;
    let body = input.to_string();
    let mut stdin = child.stdin.take().ok_or_else(|| FgoError::Input("peer stdin".into()))?;
    // write from a thread so a peer that fails early cannot block us on a full pipe
    let writer = std::thread::spawn(move || stdin.write_all(body.as_bytes()));
    let out = child.wait_with_output().map_err(|e| FgoError::Input(format!("peer {}: {e}", script.display())))?;
    let _ = writer.join();
    if !out.status.success() {
        return Err(FgoError::Input(format!("{} failed:\n{}", script.display(), String::from_utf8_lossy(&out.stderr))));
    }
    serde_json::from_slice(&out.stdout).map_err(|e| FgoError::Input(format!("{} output is not JSON: {e}", script.display())))
}
