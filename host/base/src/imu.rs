//! IMU synthesis of the host simulators: what a perfect IMU measures on a truth trajectory
//! (specific force and body rate), the lawnmower turn schedule the simulators fly, and the IMU
//! error model (turn-on bias, bias random walk, white noise) driven by an [`ImuGrade`].
//!
//! Every simulator builds its IMU readings from these; each keeps its own scenario (path shape,
//! frames, which truth it integrates) and its own order of random draws ([`DrawOrder`]), so a
//! seed gives the readings it always gave.
//!
//! Frames: `n` is the simulator's navigation frame (NED or ENU), `b` the body frame (FRD or
//! FLU); `r_nb` rotates body vectors into `n`; gravity `g_n` is given in `n` by the caller.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use rand::Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::so3;

/// One IMU reading of a host simulator (body frame). The firmware's wire sample
/// (`subnav_wire::messages::ImuSample`, f32, µs) is a separate type.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ImuSample {
    pub t_s: f64,
    pub acc_mps2: Vector3<f64>,
    pub gyro_radps: Vector3<f64>,
}

/// An attitude `r_nb` that maps navigation-frame vectors into the body frame.
pub trait Attitude {
    /// `R_nb^T v_n`.
    fn nav_to_body(&self, v_n: &Vector3<f64>) -> Vector3<f64>;
}

impl Attitude for UnitQuaternion<f64> {
    fn nav_to_body(&self, v_n: &Vector3<f64>) -> Vector3<f64> {
        self.inverse() * v_n
    }
}

impl Attitude for Matrix3<f64> {
    fn nav_to_body(&self, v_n: &Vector3<f64>) -> Vector3<f64> {
        self.transpose() * v_n
    }
}

impl Attitude for Rotation3<f64> {
    fn nav_to_body(&self, v_n: &Vector3<f64>) -> Vector3<f64> {
        self.matrix().transpose() * v_n
    }
}

/// Specific force (what an accelerometer measures) from the navigation-frame acceleration:
/// `f_b = R_nb^T (a_n - g_n)`.
pub fn specific_force<R: Attitude>(r_nb: &R, acc_n_mps2: &Vector3<f64>, g_n_mps2: &Vector3<f64>) -> Vector3<f64> {
    r_nb.nav_to_body(&(acc_n_mps2 - g_n_mps2))
}

/// The same specific force from the body-frame motion: with `v_n = R_nb v_b` and
/// `dR_nb/dt = R_nb [w_b]x`, `a_n = R_nb (dv_b/dt + w_b x v_b)`, so
/// `f_b = dv_b/dt + w_b x v_b - R_nb^T g_n`.
pub fn specific_force_body<R: Attitude>(
    r_nb: &R,
    rate_b_radps: &Vector3<f64>,
    vel_b_mps: &Vector3<f64>,
    dvel_b_mps2: &Vector3<f64>,
    g_n_mps2: &Vector3<f64>,
) -> Vector3<f64> {
    dvel_b_mps2 + rate_b_radps.cross(vel_b_mps) - r_nb.nav_to_body(g_n_mps2)
}

/// Mean body rate over `dt_s` between two attitudes: `Log(R_0^T R_1) / dt`.
pub fn body_rate_between(r0_nb: &Matrix3<f64>, r1_nb: &Matrix3<f64>, dt_s: f64) -> Vector3<f64> {
    so3::log(&(r0_nb.transpose() * r1_nb)) / dt_s
}

/// Yaw-rate profile of a 180-degree turn.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum TurnProfile {
    /// Constant rate through the turn (a rate step at each end).
    Constant,
    /// `rate (1 - cos(2 pi u / turn_s))`, u the time into the turn: the rate and its derivative
    /// are continuous; `rate` is then the mean rate.
    RaisedCosine,
}

/// Lawnmower turns in time: straight legs of `straight_s`, then a 180-degree turn of `turn_s`,
/// alternating direction (the first turn has positive yaw rate), from `tau = 0`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TurnSchedule {
    pub straight_s: f64,
    pub turn_s: f64,
    /// Yaw rate magnitude of a turn (the mean rate for [`TurnProfile::RaisedCosine`]), rad/s.
    pub rate_radps: f64,
    pub profile: TurnProfile,
}

impl TurnSchedule {
    /// Turns at a constant rate: each lasts `pi / rate`.
    pub fn at_rate(straight_s: f64, rate_radps: f64) -> Self {
        Self { straight_s, turn_s: std::f64::consts::PI / rate_radps, rate_radps, profile: TurnProfile::Constant }
    }

    /// Turns of a given duration: mean rate `pi / turn_s`.
    pub fn of_duration(straight_s: f64, turn_s: f64, profile: TurnProfile) -> Self {
        Self { straight_s, turn_s, rate_radps: std::f64::consts::PI / turn_s, profile }
    }

    /// Yaw rate at `tau_s` (0 before the start).
    pub fn yaw_rate(&self, tau_s: f64) -> f64 {
        if tau_s <= 0.0 {
            return 0.0;
        }
        let period = self.straight_s + self.turn_s;
        let k = (tau_s / period).floor();
        let u = tau_s - k * period;
        if u < self.straight_s {
            return 0.0;
        }
        let sign = if (k as i64) % 2 == 0 { 1.0 } else { -1.0 };
        match self.profile {
            TurnProfile::Constant => sign * self.rate_radps,
            TurnProfile::RaisedCosine => {
                let u = u - self.straight_s;
                sign * self.rate_radps * (1.0 - (2.0 * std::f64::consts::PI * u / self.turn_s).cos())
            }
        }
    }
}

/// IMU grade: continuous-time noise densities, bias random walks and turn-on bias (1-sigma).
/// The sensor head's grade is `subnav_core::head::IMU_ICM42688P` (`From`); scenario-specific
/// IMUs (the FGO and under-ice simulators) build theirs from their own parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ImuGrade {
    /// Gyro white noise, rad/s/sqrt(Hz) (angle random walk).
    pub gyro_noise_density: f64,
    /// Accelerometer white noise, m/s^2/sqrt(Hz) (velocity random walk).
    pub accel_noise_density: f64,
    /// Gyro bias random walk, rad/s/sqrt(s).
    pub gyro_bias_rw: f64,
    /// Accelerometer bias random walk, m/s^2/sqrt(s).
    pub accel_bias_rw: f64,
    /// Turn-on bias, 1-sigma (rad/s, m/s^2).
    pub gyro_bias_sigma: f64,
    pub accel_bias_sigma: f64,
}

impl From<subnav_core::head::ImuGrade> for ImuGrade {
    fn from(g: subnav_core::head::ImuGrade) -> Self {
        Self {
            gyro_noise_density: g.gyro_arw as f64,
            accel_noise_density: g.accel_vrw as f64,
            gyro_bias_rw: g.gyro_bias_rw as f64,
            accel_bias_rw: g.accel_bias_rw as f64,
            gyro_bias_sigma: g.gyro_bias_sigma as f64,
            accel_bias_sigma: g.accel_bias_sigma as f64,
        }
    }
}

impl ImuGrade {
    /// Per-sample white-noise sigmas `(gyro, accel)` of readings `dt_s` apart: density / sqrt(dt).
    pub fn white_sigmas(&self, dt_s: f64) -> (f64, f64) {
        (self.gyro_noise_density / dt_s.sqrt(), self.accel_noise_density / dt_s.sqrt())
    }
}

/// Order of the random draws of a gyro/accelerometer triple (each simulator keeps the order its
/// seeds were generated with).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DrawOrder {
    /// Gyro x, y, z, then accelerometer x, y, z.
    GyroFirst,
    /// Accelerometer x, y, z, then gyro x, y, z.
    AccelFirst,
    /// Per axis: accelerometer x, gyro x, accelerometer y, ...
    PerAxisAccelFirst,
}

/// Zero-mean normal of sigma `s` (negative or NaN sigma: no noise).
pub fn normal(s: f64) -> Normal<f64> {
    Normal::new(0.0, s.max(0.0)).unwrap_or_else(|_| Normal::new(0.0, 0.0).expect("zero sigma is valid"))
}

fn draw_pair<R: Rng + ?Sized>(rng: &mut R, gyro: &Normal<f64>, acc: &Normal<f64>, order: DrawOrder) -> (Vector3<f64>, Vector3<f64>) {
    let (mut g, mut a) = (Vector3::zeros(), Vector3::zeros());
    match order {
        DrawOrder::GyroFirst => {
            g = Vector3::from_fn(|_, _| gyro.sample(rng));
            a = Vector3::from_fn(|_, _| acc.sample(rng));
        }
        DrawOrder::AccelFirst => {
            a = Vector3::from_fn(|_, _| acc.sample(rng));
            g = Vector3::from_fn(|_, _| gyro.sample(rng));
        }
        DrawOrder::PerAxisAccelFirst => {
            for k in 0..3 {
                a[k] = acc.sample(rng);
                g[k] = gyro.sample(rng);
            }
        }
    }
    (g, a)
}

/// The error state of one simulated IMU: current biases and the white-noise sigmas per reading.
/// A reading is `ideal + bias + white`; the biases walk by [`ImuErrors::walk`].
#[derive(Debug, Clone)]
pub struct ImuErrors {
    pub grade: ImuGrade,
    pub bias_gyro_radps: Vector3<f64>,
    pub bias_acc_mps2: Vector3<f64>,
    white_gyro: Normal<f64>,
    white_acc: Normal<f64>,
}

impl ImuErrors {
    /// Errors with the given turn-on biases and per-reading white-noise sigmas `(gyro, accel)`.
    pub fn new(grade: ImuGrade, bias_gyro_radps: Vector3<f64>, bias_acc_mps2: Vector3<f64>, white_sigmas: (f64, f64)) -> Self {
        Self { grade, bias_gyro_radps, bias_acc_mps2, white_gyro: normal(white_sigmas.0), white_acc: normal(white_sigmas.1) }
    }

    /// Turn-on biases drawn from the grade's sigmas.
    pub fn draw_turn_on<R: Rng + ?Sized>(grade: &ImuGrade, rng: &mut R, order: DrawOrder) -> (Vector3<f64>, Vector3<f64>) {
        draw_pair(rng, &normal(grade.gyro_bias_sigma), &normal(grade.accel_bias_sigma), order)
    }

    /// White noise `(gyro, accel)` of one reading.
    pub fn white<R: Rng + ?Sized>(&self, rng: &mut R, order: DrawOrder) -> (Vector3<f64>, Vector3<f64>) {
        draw_pair(rng, &self.white_gyro, &self.white_acc, order)
    }

    /// One reading `(gyro, accel)`: the ideal rate and specific force plus bias plus white noise.
    pub fn measure<R: Rng + ?Sized>(
        &self,
        rate_b_radps: &Vector3<f64>,
        specific_force_b_mps2: &Vector3<f64>,
        rng: &mut R,
        order: DrawOrder,
    ) -> (Vector3<f64>, Vector3<f64>) {
        let (ng, na) = self.white(rng, order);
        (rate_b_radps + self.bias_gyro_radps + ng, specific_force_b_mps2 + self.bias_acc_mps2 + na)
    }

    /// Advance the biases' random walks by `dt_s`.
    pub fn walk<R: Rng + ?Sized>(&mut self, rng: &mut R, dt_s: f64, order: DrawOrder) {
        let (wg, wa) =
            draw_pair(rng, &normal(self.grade.gyro_bias_rw * dt_s.sqrt()), &normal(self.grade.accel_bias_rw * dt_s.sqrt()), order);
        self.bias_gyro_radps += wg;
        self.bias_acc_mps2 += wa;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn both_specific_force_forms_agree_on_a_rotating_vehicle() {
        // Any attitude, body rate, body velocity and its derivative: a_n from the chain rule.
        let r = Rotation3::from_euler_angles(0.1, -0.2, 2.0);
        let (w, v, dv) = (Vector3::new(0.01, -0.02, 0.1), Vector3::new(1.5, 0.1, -0.2), Vector3::new(0.05, 0.0, 0.02));
        let g = Vector3::new(0.0, 0.0, 9.81);
        let a_n = r * (dv + w.cross(&v));
        let f1 = specific_force(&r, &a_n, &g);
        let f2 = specific_force_body(r.matrix(), &w, &v, &dv, &g);
        assert!((f1 - f2).norm() < 1e-12, "{f1} vs {f2}");
        let q = UnitQuaternion::from_rotation_matrix(&r);
        assert!((specific_force(&q, &a_n, &g) - f1).norm() < 1e-12);
        // at rest, level: minus gravity
        assert_eq!(specific_force(&Matrix3::identity(), &Vector3::zeros(), &g), -g);
    }

    #[test]
    fn body_rate_between_recovers_a_constant_rate() {
        let w = Vector3::new(0.02, -0.01, 0.3);
        let r0 = Rotation3::from_euler_angles(0.3, 0.1, -1.0).into_inner();
        let r1 = r0 * so3::exp(&(w * 0.01));
        assert!((body_rate_between(&r0, &r1, 0.01) - w).norm() < 1e-12);
    }

    #[test]
    fn turn_schedule_turns_half_a_circle_and_alternates() {
        for profile in [TurnProfile::Constant, TurnProfile::RaisedCosine] {
            let s = TurnSchedule::of_duration(30.0, 20.0, profile);
            let h = 1e-3;
            let yaw = |a: f64, b: f64| (0..((b - a) / h) as usize).map(|k| s.yaw_rate(a + (k as f64 + 0.5) * h) * h).sum::<f64>();
            assert!((yaw(0.0, 50.0) - std::f64::consts::PI).abs() < 1e-6, "{profile:?}");
            assert!((yaw(50.0, 100.0) + std::f64::consts::PI).abs() < 1e-6, "{profile:?}");
            assert_eq!(s.yaw_rate(10.0), 0.0);
            assert_eq!(s.yaw_rate(-1.0), 0.0);
        }
        let c = TurnSchedule::at_rate(90.0, 0.1);
        assert_eq!(c.yaw_rate(95.0), 0.1);
    }

    #[test]
    fn errors_have_the_grade_statistics() {
        let grade = ImuGrade::from(subnav_core::head::IMU_ICM42688P);
        let dt = 0.005;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let e = ImuErrors::new(grade, Vector3::zeros(), Vector3::zeros(), grade.white_sigmas(dt));
        let n = 20_000;
        let mut s2 = (0.0, 0.0);
        for _ in 0..n {
            let (g, a) = e.measure(&Vector3::zeros(), &Vector3::zeros(), &mut rng, DrawOrder::GyroFirst);
            s2.0 += g.norm_squared() / (3 * n) as f64;
            s2.1 += a.norm_squared() / (3 * n) as f64;
        }
        let (sg, sa) = grade.white_sigmas(dt);
        assert!((s2.0.sqrt() / sg - 1.0).abs() < 0.02 && (s2.1.sqrt() / sa - 1.0).abs() < 0.02, "{s2:?}");
        // The bias walk grows as rw sqrt(t).
        let mut walks = 0.0;
        for _ in 0..200 {
            let mut e = e.clone();
            for _ in 0..100 {
                e.walk(&mut rng, 1.0, DrawOrder::GyroFirst);
            }
            walks += e.bias_acc_mps2.norm_squared() / 600.0;
        }
        assert!((walks.sqrt() / (grade.accel_bias_rw * 10.0) - 1.0).abs() < 0.1, "{}", walks.sqrt());
    }
}
