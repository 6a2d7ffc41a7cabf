//! Simulated dive for the AUKF-vs-UKF Monte Carlo and for trying `subnav filter` without
//! hardware.
//!
//! Truth: a level lawnmower survey at 1.5 m/s (straight legs, 180-degree turns at 0.1 rad/s),
//! a slow depth profile (heave), 600 s. The IMU readings are derived exactly from the truth
//! (`subnav_base::imu`: `f_b = dv_b/dt + w x v_b - R^T g`, `w_b = (0, 0, r)`, turns from a
//! [`TurnSchedule`]), then corrupted with a per-run constant bias and white noise
//! ([`ImuErrors`]). Aiding: polarization heading 5 Hz, depth 10 Hz, DVL body velocity 5 Hz.
//!
//! Noise statistics change mid-run (unknown to the filter, the sensors keep reporting their
//! nominal sigma): heading noise x10 for 60 s (`heading_burst`), DVL noise x20 in two 10 s bursts
//! (`dvl_bursts`).

use nalgebra::{Rotation3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use subnav_base::imu::{self, DrawOrder, ImuErrors, ImuGrade, TurnSchedule};
use subnav_wire::messages::ImuSample;

/// One entry of a sensor log (time-ordered).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    Imu(ImuSample),
    Heading { t_us: u64, heading_rad: f32, sigma_rad: Option<f32> },
    Depth { t_us: u64, depth_m: f32, sigma_m: Option<f32> },
    Dvl { t_us: u64, vel_frd_mps: [f32; 3], sigma_mps: Option<f32> },
    Fix { t_us: u64, pos_ned_m: [f32; 3], cov_ned_m2: [f32; 6] },
}

impl Event {
    pub fn t_us(&self) -> u64 {
        match self {
            Event::Imu(s) => s.t_us,
            Event::Heading { t_us, .. } | Event::Depth { t_us, .. } | Event::Dvl { t_us, .. } | Event::Fix { t_us, .. } => *t_us,
        }
    }
}

/// True state at a time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Truth {
    pub t_us: u64,
    pub pos_ned_m: [f64; 3],
    pub vel_ned_mps: [f64; 3],
    pub yaw_rad: f64,
}

/// Scenario parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct DiveConfig {
    pub duration_s: f64,
    pub imu_hz: f64,
    pub heading_hz: f64,
    pub depth_hz: f64,
    pub dvl_hz: f64,
    pub speed_mps: f64,
    pub leg_s: f64,
    pub turn_rate_radps: f64,
    pub gyro_noise_radps: f64,
    pub accel_noise_mps2: f64,
    pub gyro_bias_sigma: f64,
    pub accel_bias_sigma: f64,
    pub heading_sigma_rad: f64,
    pub depth_sigma_m: f64,
    pub dvl_sigma_mps: f64,
    /// (start s, end s, noise multiplier) of the heading noise change.
    pub heading_burst: (f64, f64, f64),
    /// DVL noise bursts (start s, end s, multiplier).
    pub dvl_bursts: Vec<(f64, f64, f64)>,
    /// A step in the gyro bias (time s, step rad/s per body axis), unknown to the filter whose
    /// bias random walk does not cover it: genuine state divergence, the case the fading
    /// factor is for.
    pub gyro_bias_step: Option<(f64, [f64; 3])>,
    /// Truth is recorded at this rate.
    pub truth_hz: f64,
}

impl Default for DiveConfig {
    fn default() -> Self {
        Self {
            duration_s: 600.0,
            imu_hz: 100.0,
            heading_hz: 5.0,
            depth_hz: 10.0,
            dvl_hz: 5.0,
            speed_mps: 1.5,
            leg_s: 90.0,
            turn_rate_radps: 0.1,
            // 0.003 rad/sqrt(s) ARW and 0.003 m/s/sqrt(s) VRW at 100 Hz
            gyro_noise_radps: 0.03,
            accel_noise_mps2: 0.03,
            gyro_bias_sigma: 0.001,
            accel_bias_sigma: 0.02,
            heading_sigma_rad: 0.01,
            depth_sigma_m: 0.05,
            dvl_sigma_mps: 0.02,
            heading_burst: (150.0, 210.0, 10.0),
            dvl_bursts: vec![(300.0, 310.0, 20.0), (450.0, 460.0, 20.0)],
            gyro_bias_step: None,
            truth_hz: 1.0,
        }
    }
}

/// A generated dive: the sensor log, the truth, and the initial state.
#[derive(Debug, Clone)]
pub struct Dive {
    pub events: Vec<Event>,
    pub truth: Vec<Truth>,
    pub init_yaw_rad: f64,
}

fn mult(t: f64, windows: &[(f64, f64, f64)]) -> f64 {
    windows.iter().find(|(a, b, _)| t >= *a && t < *b).map(|w| w.2).unwrap_or(1.0)
}

/// The lawnmower's turns: legs of `leg_s`, then a 180-degree turn at `turn_rate_radps`,
/// alternating direction.
fn turns(cfg: &DiveConfig) -> TurnSchedule {
    TurnSchedule::at_rate(cfg.leg_s, cfg.turn_rate_radps)
}

impl DiveConfig {
    /// The IMU grade of the scenario (white noise given per reading at `imu_hz`, constant bias).
    pub fn imu_grade(&self) -> ImuGrade {
        let dt = 1.0 / self.imu_hz;
        ImuGrade {
            gyro_noise_density: self.gyro_noise_radps * dt.sqrt(),
            accel_noise_density: self.accel_noise_mps2 * dt.sqrt(),
            gyro_bias_rw: 0.0,
            accel_bias_rw: 0.0,
            gyro_bias_sigma: self.gyro_bias_sigma,
            accel_bias_sigma: self.accel_bias_sigma,
        }
    }
}

/// Heave (body z velocity, down positive) and its derivative.
fn heave(t: f64) -> (f64, f64) {
    let w = 2.0 * std::f64::consts::PI / 200.0;
    (0.2 * (w * t).sin(), 0.2 * w * (w * t).cos())
}

/// Generate one dive from `seed`.
pub fn generate(cfg: &DiveConfig, seed: u64) -> Dive {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n01 = Normal::new(0.0, 1.0).unwrap_or_else(|_| unreachable!());
    let g = |rng: &mut ChaCha8Rng| -> f64 { n01.sample(rng) };
    let grade = cfg.imu_grade();
    let (bg, ba) = ImuErrors::draw_turn_on(&grade, &mut rng, DrawOrder::GyroFirst);
    let errors = ImuErrors::new(grade, bg, ba, (cfg.gyro_noise_radps, cfg.accel_noise_mps2));
    let turns = turns(cfg);
    let g_ned = Vector3::new(0.0, 0.0, 9.81);
    let yaw0 = (g(&mut rng) * 1.0).clamp(-3.0, 3.0);
    let dt = 1.0 / cfg.imu_hz;
    let steps = (cfg.duration_s * cfg.imu_hz).round() as u64;
    let every = |hz: f64| ((cfg.imu_hz / hz).round() as u64).max(1);
    let (k_head, k_depth, k_dvl, k_truth) = (every(cfg.heading_hz), every(cfg.depth_hz), every(cfg.dvl_hz), every(cfg.truth_hz));

    let mut events = Vec::with_capacity(steps as usize * 12 / 10);
    let mut truth = Vec::new();
    let (mut yaw, mut pos) = (yaw0, [0.0f64, 0.0, 10.0]);
    let u = cfg.speed_mps;
    let sub = 10;
    for k in 0..=steps {
        let t = k as f64 * dt;
        let t_us = (t * 1e6).round() as u64;
        // The IMU sample at t_k stands for the interval (t_k - dt, t_k]: mid-interval rates.
        let tm = (t - 0.5 * dt).max(0.0);
        let r = turns.yaw_rate(tm);
        let (_, wdot) = heave(tm);
        let (w, _) = heave(t);
        // Body-frame truth: v_b = (u, 0, w), w_b = (0, 0, r), level.
        let vel_n = [u * yaw.cos(), u * yaw.sin(), w];
        if k % k_truth == 0 {
            truth.push(Truth { t_us, pos_ned_m: pos, vel_ned_mps: vel_n, yaw_rad: yaw });
        }
        let (rate_b, vel_b, dvel_b) = (Vector3::new(0.0, 0.0, r), Vector3::new(u, 0.0, w), Vector3::new(0.0, 0.0, wdot));
        let f_b = imu::specific_force_body(Rotation3::from_euler_angles(0.0, 0.0, yaw).matrix(), &rate_b, &vel_b, &dvel_b, &g_ned);
        let (mut gyro, accel) = errors.measure(&rate_b, &f_b, &mut rng, DrawOrder::GyroFirst);
        if let Some((_, step)) = cfg.gyro_bias_step.filter(|(t_step, _)| t >= *t_step) {
            gyro += Vector3::from(step);
        }
        events.push(Event::Imu(ImuSample {
            t_us,
            gyro_radps: [0, 1, 2].map(|i| gyro[i] as f32),
            accel_mps2: [0, 1, 2].map(|i| accel[i] as f32),
            temp_c: 10.0,
        }));
        if k > 0 && k % k_head == 0 {
            let s = cfg.heading_sigma_rad * mult(t, &[cfg.heading_burst]);
            let h = subnav_core::ukf::wrap_pi(yaw + g(&mut rng) * s);
            events.push(Event::Heading { t_us, heading_rad: h as f32, sigma_rad: None });
        }
        if k > 0 && k % k_depth == 0 {
            events.push(Event::Depth { t_us, depth_m: (pos[2] + g(&mut rng) * cfg.depth_sigma_m) as f32, sigma_m: None });
        }
        if k > 0 && k % k_dvl == 0 {
            let s = cfg.dvl_sigma_mps * mult(t, &cfg.dvl_bursts);
            let v = [u + g(&mut rng) * s, g(&mut rng) * s, w + g(&mut rng) * s];
            events.push(Event::Dvl { t_us, vel_frd_mps: v.map(|x| x as f32), sigma_mps: None });
        }
        // Integrate the truth to the next IMU time (fine sub-steps).
        let h = dt / sub as f64;
        for j in 0..sub {
            let tj = t + j as f64 * h;
            let rj = turns.yaw_rate(tj);
            let (wj, _) = heave(tj + 0.5 * h);
            let ym = yaw + 0.5 * h * rj;
            pos[0] += u * ym.cos() * h;
            pos[1] += u * ym.sin() * h;
            pos[2] += wj * h;
            yaw += rj * h;
        }
    }
    Dive { events, truth, init_yaw_rad: yaw0 }
}
