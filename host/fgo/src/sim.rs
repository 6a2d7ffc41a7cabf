//! AUV mission simulator with truth: lawnmower survey at 1.5 m/s with small roll/pitch motion,
//! IMU at `imu_hz` (>= 100 Hz) with white noise and random-walk biases, DVL at `dvl_hz` with
//! bottom-lock losses and bursts of abnormal velocities, USBL every `usbl_period_s` with the
//! acoustic delay (slant range / 1500 m/s + processing), packet loss and multipath outliers.
//! The truth is integrated with piecewise-constant inputs (`R Exp(w dt)` per IMU step), so an
//! error-free IMU reproduces it up to the tangent preintegration's own second-order error. The
//! inputs come from `subnav_base::imu` (turns from a [`TurnSchedule`], specific force from the
//! body motion, errors of [`imu_grade`] by [`ImuErrors`]). `abnormal_fraction` of the delivered DVL and USBL
//! observations are abnormal (the tests' "10 %").

use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use super::log::{DvlObs, ImuSample, LogConfig, PriorConfig, SensorLog, UsblObs};
use super::preintegration::ImuParams;
use super::state::{ImuBias, NavState, NodeState};
use subnav_base::imu::{self, DrawOrder, ImuErrors, ImuGrade, TurnProfile, TurnSchedule};
use subnav_base::so3;

/// The simulated IMU's grade: the navigator's noise model (`ImuParams`) and the turn-on biases.
pub fn imu_grade(imu: &ImuParams) -> ImuGrade {
    ImuGrade {
        gyro_noise_density: imu.gyro_noise_density,
        accel_noise_density: imu.acc_noise_density,
        gyro_bias_rw: imu.gyro_bias_rw,
        accel_bias_rw: imu.acc_bias_rw,
        gyro_bias_sigma: 2e-4,
        accel_bias_sigma: 0.01,
    }
}

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SimConfig {
    pub seed: u64,
    pub duration_s: f64,
    pub imu_hz: f64,
    pub dvl_hz: f64,
    pub usbl_period_s: f64,
    pub abnormal_fraction: f64,
    pub usbl_packet_loss: f64,
    /// Number of DVL bottom-lock losses (each 15-40 s).
    pub dvl_lock_losses: usize,
    pub dvl_sigma_mps: f64,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            seed: 1,
            duration_s: 600.0,
            imu_hz: 100.0,
            dvl_hz: 2.0,
            usbl_period_s: 5.0,
            abnormal_fraction: 0.1,
            usbl_packet_loss: 0.1,
            dvl_lock_losses: 2,
            dvl_sigma_mps: 0.01,
        }
    }
}

/// Truth at IMU rate plus the inputs, to evaluate at any time.
#[derive(Debug, Clone)]
pub struct Truth {
    pub t_s: Vec<f64>,
    pub states: Vec<NodeState>,
    /// true specific force and rate held on [t_k, t_k+1)
    pub inputs: Vec<(Vector3<f64>, Vector3<f64>)>,
    pub gravity: Vector3<f64>,
}

impl Truth {
    /// Exact truth at `t` (within the simulated span).
    pub fn at(&self, t: f64) -> NavState {
        let k = match self.t_s.binary_search_by(|x| x.total_cmp(&t)) {
            Ok(k) => return self.states[k].nav,
            Err(0) => return self.states[0].nav,
            Err(k) => k - 1,
        };
        let k = k.min(self.states.len() - 1);
        let dt = t - self.t_s[k];
        let (f, w) = self.inputs.get(k).copied().unwrap_or((Vector3::zeros(), Vector3::zeros()));
        step(&self.states[k].nav, &f, &w, dt, &self.gravity)
    }
}

fn step(x: &NavState, f: &Vector3<f64>, w: &Vector3<f64>, dt: f64, g: &Vector3<f64>) -> NavState {
    let a = x.rot_enu_flu * f + g;
    NavState {
        rot_enu_flu: x.rot_enu_flu * so3::exp(&(w * dt)),
        pos_enu_m: x.pos_enu_m + x.vel_enu_mps * dt + a * (0.5 * dt * dt),
        vel_enu_mps: x.vel_enu_mps + a * dt,
    }
}

/// Counts of what the simulator injected.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct SimStats {
    pub dvl_delivered: usize,
    pub dvl_abnormal: usize,
    pub usbl_delivered: usize,
    pub usbl_abnormal: usize,
    pub usbl_lost: usize,
}

pub struct Simulation {
    pub log: SensorLog,
    pub truth: Truth,
    pub stats: SimStats,
}

/// Run the simulator.
pub fn simulate(cfg: &SimConfig) -> Simulation {
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let std = |s: f64| Normal::new(0.0, s.max(0.0)).unwrap_or_else(|_| Normal::new(0.0, 0.0).expect("zero sigma is valid"));
    let imu = ImuParams::default();
    let g = imu.gravity();
    let dt = 1.0 / cfg.imu_hz.max(1.0);
    let n = (cfg.duration_s / dt).ceil() as usize + 1;
    let speed = 1.5;
    let v_b = Vector3::new(speed, 0.0, 0.0);
    let heading0 = rng.random_range(0.0..std::f64::consts::TAU);
    let r0 = so3::exp(&Vector3::new(0.0, 0.0, heading0));
    let mut x = NavState::new(r0, Vector3::new(50.0, -30.0, -40.0), r0 * v_b);
    let grade = imu_grade(&imu);
    let (bg, ba) = ImuErrors::draw_turn_on(&grade, &mut rng, DrawOrder::AccelFirst);
    let mut errors = ImuErrors::new(grade, bg, ba, grade.white_sigmas(dt));
    let start = NodeState::new(x, ImuBias::new(ba, bg));
    // Legs of 60 s, 180-degree turns of 20 s.
    let turns = TurnSchedule::of_duration(60.0, 20.0, TurnProfile::Constant);
    let mut truth = Truth { t_s: Vec::with_capacity(n), states: Vec::with_capacity(n), inputs: Vec::with_capacity(n), gravity: g };
    let mut samples = Vec::with_capacity(n);
    for k in 0..n {
        let t = k as f64 * dt;
        let w = Vector3::new(0.03 * (0.5 * t).sin(), 0.02 * (0.3 * t).cos(), turns.yaw_rate(t) + 0.01 * (0.2 * t).sin());
        // hold body velocity ~ (u, 0, 0) plus a slow heave (its derivative is left out: the truth
        // integrates these inputs, so it stays consistent with them)
        let vb = v_b + Vector3::new(0.0, 0.0, 0.05 * (0.05 * t).sin());
        let f = imu::specific_force_body(&x.rot_enu_flu, &w, &vb, &Vector3::zeros(), &g);
        truth.t_s.push(t);
        truth.states.push(NodeState::new(x, ImuBias::new(errors.bias_acc_mps2, errors.bias_gyro_radps)));
        truth.inputs.push((f, w));
        let (gyro, acc) = errors.measure(&w, &f, &mut rng, DrawOrder::AccelFirst);
        samples.push(ImuSample { t_s: t, acc_mps2: acc.into(), gyro_radps: gyro.into() });
        x = step(&x, &f, &w, dt, &g);
        errors.walk(&mut rng, dt, DrawOrder::AccelFirst);
    }
    let t_end = (n - 1) as f64 * dt;

    let dvl_rot = Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_4);
    let r_bd = so3::exp(&dvl_rot);
    let dvl_lever = Vector3::new(0.8, 0.0, -0.3);
    let usbl_lever = Vector3::new(-0.5, 0.0, 0.4);
    let mut stats = SimStats::default();

    // bottom-lock losses
    let losses: Vec<(f64, f64)> = (0..cfg.dvl_lock_losses)
        .map(|_| {
            let a = rng.random_range(30.0..(t_end - 60.0).max(31.0));
            (a, a + rng.random_range(15.0..40.0))
        })
        .collect();
    // DVL: Markov bursts with stationary abnormal probability `abnormal_fraction`
    let p_exit = 0.3;
    let p_enter = if cfg.abnormal_fraction < 1.0 { p_exit * cfg.abnormal_fraction / (1.0 - cfg.abnormal_fraction) } else { 1.0 };
    let mut in_burst = false;
    let mut dvl = Vec::new();
    let mut t = 0.5 / cfg.dvl_hz + 0.0037; // off the IMU grid on purpose
    while t < t_end - 0.5 {
        in_burst = if in_burst { !rng.random_bool(p_exit) } else { rng.random_bool(p_enter.min(1.0)) };
        if losses.iter().any(|(a, b)| t >= *a && t <= *b) {
            t += 1.0 / cfg.dvl_hz;
            continue;
        }
        let xt = truth.at(t);
        let k = ((t / dt).floor() as usize).min(truth.inputs.len() - 1);
        let w_true = truth.inputs[k].1;
        let mut v = r_bd.transpose() * (xt.rot_enu_flu.transpose() * xt.vel_enu_mps + w_true.cross(&dvl_lever));
        v += Vector3::from_fn(|_, _| std(cfg.dvl_sigma_mps).sample(&mut rng));
        stats.dvl_delivered += 1;
        if in_burst {
            stats.dvl_abnormal += 1;
            let dir = Vector3::from_fn(|_, _| std(1.0).sample(&mut rng)).normalize();
            v += dir * rng.random_range(0.2..1.0);
        }
        dvl.push(DvlObs { t_s: t, vel_dvl_mps: v.into(), sigma_mps: cfg.dvl_sigma_mps });
        t += 1.0 / cfg.dvl_hz;
    }

    let mut usbl = Vec::new();
    let mut tv = cfg.usbl_period_s;
    while tv < t_end - 5.0 {
        let xt = truth.at(tv);
        let p_tr = xt.pos_enu_m + xt.rot_enu_flu * usbl_lever;
        let slant = p_tr.norm();
        if rng.random_bool(cfg.usbl_packet_loss.clamp(0.0, 1.0)) {
            stats.usbl_lost += 1;
            tv += cfg.usbl_period_s;
            continue;
        }
        let sh = (0.005 * slant).max(1.0);
        let sv = 0.5;
        let mut p = p_tr + Vector3::new(std(sh).sample(&mut rng), std(sh).sample(&mut rng), std(sv).sample(&mut rng));
        stats.usbl_delivered += 1;
        if rng.random_bool(cfg.abnormal_fraction.clamp(0.0, 1.0)) {
            stats.usbl_abnormal += 1;
            let ang = rng.random_range(0.0..std::f64::consts::TAU);
            let mag = rng.random_range(15.0..40.0);
            p += Vector3::new(ang.cos() * mag, ang.sin() * mag, rng.random_range(-5.0..5.0));
        }
        let delay = slant / 1500.0 + rng.random_range(0.3..1.0);
        usbl.push(UsblObs { t_arrival_s: tv + delay, t_valid_s: tv, pos_enu_m: p.into(), sigma_h_m: sh, sigma_v_m: sv });
        tv += cfg.usbl_period_s;
    }

    // the navigator starts from a noisy prior around the true start
    let ps = [0.02, 2.0, 0.1, 0.02, 5e-4];
    let rot_err = Vector3::from_fn(|_, _| std(ps[0]).sample(&mut rng));
    let prior = PriorConfig {
        t_s: 0.0,
        rotvec_enu_flu: so3::log(&(start.nav.rot_enu_flu * so3::exp(&rot_err))).into(),
        pos_enu_m: (start.nav.pos_enu_m + Vector3::from_fn(|_, _| std(ps[1]).sample(&mut rng))).into(),
        vel_enu_mps: (start.nav.vel_enu_mps + Vector3::from_fn(|_, _| std(ps[2]).sample(&mut rng))).into(),
        bias_acc_mps2: [0.0; 3],
        bias_gyro_radps: [0.0; 3],
        sigmas: ps,
    };
    let config =
        LogConfig { imu, dvl_rotvec_body: dvl_rot.into(), dvl_lever_body_m: dvl_lever.into(), usbl_lever_body_m: usbl_lever.into(), prior };
    Simulation { log: SensorLog { config, imu: samples, dvl, usbl }, truth, stats }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::preintegration::Preintegrated;

    #[test]
    fn noise_free_imu_reproduces_truth() {
        let sim = simulate(&SimConfig { duration_s: 30.0, ..Default::default() });
        let tr = &sim.truth;
        let x0 = tr.states[0];
        let mut pim = Preintegrated::new(sim.log.config.imu, x0.bias);
        for k in 0..1000 {
            let (f, w) = tr.inputs[k];
            pim.integrate(&(f + x0.bias.acc_mps2), &(w + x0.bias.gyro_radps), tr.t_s[k + 1] - tr.t_s[k]).unwrap();
        }
        let pred = pim.predict(&x0.nav, &x0.bias);
        let t = tr.states[1000].nav;
        // 10 s of turning: the tangent-space rotation update differs from Exp-composition at 2nd order
        assert!((pred.pos_enu_m - t.pos_enu_m).norm() < 1e-4, "{} vs {}", pred.pos_enu_m, t.pos_enu_m);
        assert!((pred.vel_enu_mps - t.vel_enu_mps).norm() < 1e-4);
        // stats: roughly the requested abnormal fraction
        assert!(sim.stats.dvl_delivered > 30 && sim.stats.usbl_delivered > 2);
    }
}
