//! IMU propagation (spec D1, D2): static initialization from still data, the nominal state
//! integrated with 4th-order Runge-Kutta (IMU readings interpolated linearly inside the step), and
//! the error-state covariance by the linearized transition
//! `Phi = I + F dt + (F dt)^2 / 2` and the discrete noise `Q_k = Phi G Q G^T Phi^T dt`.
//!
//! First-estimate Jacobians (see [`super::state`]): the attitude columns of `Phi` that carry the
//! unobservable yaw direction are written from the first estimate `x_k^fej` (propagated, before any
//! update at `t_k`) and the newly propagated `x_k+1`, as OpenVINS does:
//! `Phi_thth = R_k+1^T R_k^fej`, `Phi_vth = -[v_k+1 - v_k^fej - g dt]x R_k^fej`,
//! `Phi_pth = -[p_k+1 - p_k^fej - v_k^fej dt - g dt^2 / 2]x R_k^fej`. Without updates these equal
//! the series terms to first order; with them `Phi_k N(x_k^fej) = N(x_k+1)` holds exactly for the
//! yaw direction `N = [R^T e_z; -[v]x e_z; -[p]x e_z; 0]`, so no yaw information is created.

use nalgebra::{DMatrix, Matrix3, Quaternion, SMatrix, UnitQuaternion, Vector3};

use super::state::{BA, BG, FilterState, IMU_DIM, ImuFej, ImuState, POS, SCALE, SONAR_BIAS, TH, VEL, symmetrize};
use subnav_base::so3::hat;

/// Gravity in NED, m/s^2 (points down).
pub const GRAVITY_MPS2: f64 = 9.81;

pub fn gravity_w() -> Vector3<f64> {
    Vector3::new(0.0, 0.0, GRAVITY_MPS2)
}

/// Random walk of the sonar speed-scale state, 1/sqrt(s).
pub const SONAR_SCALE_WALK: f64 = 1e-4;

/// One IMU reading (body frame FRD): the host simulators' sample.
pub use subnav_base::imu::ImuSample;

/// IMU noise (continuous-time densities).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ImuNoise {
    pub gyro_radps_rthz: f64,
    pub acc_mps2_rthz: f64,
    pub gyro_bias_walk: f64,
    pub acc_bias_walk: f64,
}

impl Default for ImuNoise {
    fn default() -> Self {
        // A tactical-grade MEMS IMU.
        Self { gyro_radps_rthz: 1.5e-4, acc_mps2_rthz: 6.0e-4, gyro_bias_walk: 2.0e-6, acc_bias_walk: 4.0e-5 }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub enum InitError {
    TooFewSamples(usize),
    NotStill { gyro_std_radps: f64, acc_std_mps2: f64 },
    NonFinite,
}

impl std::fmt::Display for InitError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::TooFewSamples(n) => write!(f, "static initialization needs >= 50 IMU samples, got {n}"),
            Self::NotStill { gyro_std_radps, acc_std_mps2 } => {
                write!(f, "vehicle not still during initialization (gyro std {gyro_std_radps:.4} rad/s, accel std {acc_std_mps2:.3} m/s^2)")
            }
            Self::NonFinite => write!(f, "NaN or infinite IMU sample in the initialization window"),
        }
    }
}
impl std::error::Error for InitError {}

/// Static initialization (D1) from still samples: attitude from the mean specific force
/// against gravity (Gram-Schmidt with the body x axis for the heading, so yaw = 0), gyro bias =
/// mean rate, accelerometer bias = mean specific force minus the attitude's gravity reaction.
pub fn static_init(samples: &[ImuSample]) -> Result<ImuState, InitError> {
    if samples.len() < 50 {
        return Err(InitError::TooFewSamples(samples.len()));
    }
    if samples.iter().any(|s| s.gyro_radps.iter().chain(s.acc_mps2.iter()).any(|v| !v.is_finite())) {
        return Err(InitError::NonFinite);
    }
    let n = samples.len() as f64;
    let w_avg: Vector3<f64> = samples.iter().map(|s| s.gyro_radps).sum::<Vector3<f64>>() / n;
    let a_avg: Vector3<f64> = samples.iter().map(|s| s.acc_mps2).sum::<Vector3<f64>>() / n;
    let gstd = (samples.iter().map(|s| (s.gyro_radps - w_avg).norm_squared()).sum::<f64>() / n).sqrt();
    let astd = (samples.iter().map(|s| (s.acc_mps2 - a_avg).norm_squared()).sum::<f64>() / n).sqrt();
    if gstd > 0.02 || astd > 0.3 {
        return Err(InitError::NotStill { gyro_std_radps: gstd, acc_std_mps2: astd });
    }
    // Row 3 of R (world down in body) is -a/|a|; row 1 the body x axis made orthogonal to it.
    let z = -a_avg.normalize();
    let ex = Vector3::x();
    let x = (ex - z * z.dot(&ex)).normalize();
    let y = z.cross(&x);
    let rot = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
    let bias_acc = a_avg + rot.transpose() * gravity_w();
    Ok(ImuState {
        t_s: samples.last().map_or(0.0, |s| s.t_s),
        rot,
        vel_w_mps: Vector3::zeros(),
        pos_w_m: Vector3::zeros(),
        bias_gyro_radps: w_avg,
        bias_acc_mps2: bias_acc,
        sonar_scale: 1.0,
        depth_ref_err_m: 0.0,
        sonar_bias_mps: 0.0,
    })
}

type M15 = SMatrix<f64, IMU_DIM, IMU_DIM>;
type M15x12 = SMatrix<f64, IMU_DIM, 13>;

fn set3(m: &mut M15, r: usize, c: usize, b: &Matrix3<f64>) {
    m.fixed_view_mut::<3, 3>(r, c).copy_from(b);
}

/// Quaternion derivative `q_dot = q (0, w) / 2`.
fn qdot(q: &Quaternion<f64>, w: &Vector3<f64>) -> Quaternion<f64> {
    q * Quaternion::new(0.0, w.x, w.y, w.z) * 0.5
}

/// Propagate the filter from `s0` (at the state's time) to `s1` (its `t_s` is the new time).
/// `sonar_bias` = (sigma m/s, correlation time s) of the sonar speed error's Gauss-Markov state.
pub fn propagate(st: &mut FilterState, s0: &ImuSample, s1: &ImuSample, noise: &ImuNoise, sonar_bias: (f64, f64)) {
    let dt = s1.t_s - st.imu.t_s;
    if dt <= 0.0 {
        return;
    }
    let bg = st.imu.bias_gyro_radps;
    let ba = st.imu.bias_acc_mps2;
    let span = (s1.t_s - s0.t_s).max(1e-12);
    let at = |t: f64| {
        let u = ((t - s0.t_s) / span).clamp(0.0, 1.0);
        (s0.gyro_radps * (1.0 - u) + s1.gyro_radps * u - bg, s0.acc_mps2 * (1.0 - u) + s1.acc_mps2 * u - ba)
    };
    let g = gravity_w();
    let t0 = st.imu.t_s;
    let q0 = *UnitQuaternion::from_matrix(&st.imu.rot).quaternion();
    let (v0, p0) = (st.imu.vel_w_mps, st.imu.pos_w_m);
    let deriv = |q: &Quaternion<f64>, v: &Vector3<f64>, t: f64| {
        let (w, a) = at(t);
        let r = UnitQuaternion::from_quaternion(*q).to_rotation_matrix().into_inner();
        (qdot(q, &w), r * a + g, *v)
    };
    let (k1q, k1v, k1p) = deriv(&q0, &v0, t0);
    let (k2q, k2v, k2p) = deriv(&(q0 + k1q * (dt / 2.0)), &(v0 + k1v * (dt / 2.0)), t0 + dt / 2.0);
    let (k3q, k3v, k3p) = deriv(&(q0 + k2q * (dt / 2.0)), &(v0 + k2v * (dt / 2.0)), t0 + dt / 2.0);
    let (k4q, k4v, k4p) = deriv(&(q0 + k3q * dt), &(v0 + k3v * dt), t0 + dt);
    let q1 = q0 + (k1q + k2q * 2.0 + k3q * 2.0 + k4q) * (dt / 6.0);
    let v1 = v0 + (k1v + k2v * 2.0 + k3v * 2.0 + k4v) * (dt / 6.0);
    let p1 = p0 + (k1p + k2p * 2.0 + k3p * 2.0 + k4p) * (dt / 6.0);
    let r0 = st.imu.rot;
    let lin = st.imu_lin();
    let r1 = UnitQuaternion::from_quaternion(q1).to_rotation_matrix().into_inner();

    // Error-state transition at the step's midpoint.
    let (w_mid, a_mid) = at(t0 + dt / 2.0);
    let mut f = M15::zeros();
    set3(&mut f, TH, TH, &(-hat(&w_mid)));
    set3(&mut f, TH, BG, &(-Matrix3::identity()));
    set3(&mut f, VEL, TH, &(-r0 * hat(&a_mid)));
    set3(&mut f, VEL, BA, &(-r0));
    set3(&mut f, POS, VEL, &Matrix3::identity());
    let fdt = f * dt;
    let mut phi = M15::identity() + fdt + fdt * fdt * 0.5;
    // First-order Gauss-Markov sonar speed error: decay exp(-dt / tau), stationary variance sigma^2.
    let (sb_sigma, sb_tau) = sonar_bias;
    let decay = if sb_tau > 0.0 && sb_tau.is_finite() { (-dt / sb_tau).exp() } else { 1.0 };
    phi[(SONAR_BIAS, SONAR_BIAS)] = decay;
    st.imu.sonar_bias_mps *= decay;
    // The attitude columns from the first estimates (module doc).
    let lr = lin.rot;
    set3(&mut phi, TH, TH, &(r1.transpose() * lr));
    set3(&mut phi, VEL, TH, &(-hat(&(v1 - lin.vel_w_mps - g * dt)) * lr));
    set3(&mut phi, POS, TH, &(-hat(&(p1 - lin.pos_w_m - lin.vel_w_mps * dt - g * (0.5 * dt * dt))) * lr));
    let mut gm = M15x12::zeros();
    gm.fixed_view_mut::<3, 3>(TH, 0).copy_from(&(-Matrix3::identity()));
    gm.fixed_view_mut::<3, 3>(VEL, 3).copy_from(&(-r0));
    gm.fixed_view_mut::<3, 3>(BG, 6).copy_from(&Matrix3::identity());
    gm.fixed_view_mut::<3, 3>(BA, 9).copy_from(&Matrix3::identity());
    let mut qc = SMatrix::<f64, 13, 13>::zeros();
    qc[(12, 12)] = SONAR_SCALE_WALK * SONAR_SCALE_WALK;
    gm[(SCALE, 12)] = 1.0;
    for i in 0..3 {
        qc[(i, i)] = noise.gyro_radps_rthz.powi(2);
        qc[(3 + i, 3 + i)] = noise.acc_mps2_rthz.powi(2);
        qc[(6 + i, 6 + i)] = noise.gyro_bias_walk.powi(2);
        qc[(9 + i, 9 + i)] = noise.acc_bias_walk.powi(2);
    }
    let qk = phi * gm * qc * gm.transpose() * phi.transpose() * dt;

    let n = st.dim();
    let pii: M15 = st.cov.fixed_view::<IMU_DIM, IMU_DIM>(0, 0).into_owned();
    let mut new_ii = phi * pii * phi.transpose() + qk;
    new_ii[(SONAR_BIAS, SONAR_BIAS)] += sb_sigma * sb_sigma * (1.0 - decay * decay);
    st.cov.fixed_view_mut::<IMU_DIM, IMU_DIM>(0, 0).copy_from(&new_ii);
    if n > IMU_DIM {
        let pic = st.cov.view((0, IMU_DIM), (IMU_DIM, n - IMU_DIM)).into_owned();
        let new_ic: DMatrix<f64> = DMatrix::from_iterator(IMU_DIM, IMU_DIM, phi.iter().copied()) * pic;
        st.cov.view_mut((0, IMU_DIM), (IMU_DIM, n - IMU_DIM)).copy_from(&new_ic);
        st.cov.view_mut((IMU_DIM, 0), (n - IMU_DIM, IMU_DIM)).copy_from(&new_ic.transpose());
    }
    symmetrize(&mut st.cov);

    st.imu.rot = r1;
    st.imu.vel_w_mps = v1;
    st.imu.pos_w_m = p1;
    st.imu.t_s = s1.t_s;
    st.fej = ImuFej::of(&st.imu);
}

#[cfg(test)]
mod tests {
    use super::*;
    use subnav_base::so3;

    #[test]
    fn static_init_recovers_tilt_and_biases() {
        // Truth: roll 0.1, pitch -0.05, yaw 0 (the init fixes yaw to 0); biases as below.
        let rot = nalgebra::Rotation3::from_euler_angles(0.1, -0.05, 0.0).into_inner();
        let bg = Vector3::new(0.001, -0.002, 0.0005);
        // Along gravity (in the body frame): only this part of the bias is observable when still.
        let ba = rot.transpose() * Vector3::new(0.0, 0.0, 0.05);
        let f = -rot.transpose() * gravity_w() + ba;
        let s: Vec<ImuSample> = (0..200).map(|i| ImuSample { t_s: i as f64 * 0.005, gyro_radps: bg, acc_mps2: f }).collect();
        let st = static_init(&s).unwrap();
        assert!(so3::log(&(st.rot.transpose() * rot)).norm() < 1e-9, "{}", st.rot);
        assert!((st.bias_gyro_radps - bg).norm() < 1e-12);
        // The specific force is explained exactly: bias + gravity reaction.
        assert!((st.bias_acc_mps2 - ba).norm() < 1e-9, "{}", st.bias_acc_mps2);
        assert!(static_init(&s[..10]).is_err());
        let mut moving = s.clone();
        for (i, m) in moving.iter_mut().enumerate() {
            m.gyro_radps.z = if i % 2 == 0 { 0.2 } else { -0.2 };
        }
        assert!(matches!(static_init(&moving), Err(InitError::NotStill { .. })));
    }

    /// The yaw-about-gravity direction `N = [R^T e_z; -[v]x e_z; -[p]x e_z; 0]` of the first
    /// estimate is carried by the FEJ transition exactly onto `N` of the new estimate, even after an
    /// update moved the estimate away from the first estimate (so no yaw information appears);
    /// the plain EKF transition does not.
    #[test]
    fn fej_transition_keeps_the_yaw_direction() {
        let ez = Vector3::z();
        let n_of = |rot: &Matrix3<f64>, v: &Vector3<f64>, p: &Vector3<f64>| {
            let mut n = DMatrix::zeros(IMU_DIM, 1);
            n.view_mut((TH, 0), (3, 1)).copy_from(&(rot.transpose() * ez));
            n.view_mut((VEL, 0), (3, 1)).copy_from(&(-hat(v) * ez));
            n.view_mut((POS, 0), (3, 1)).copy_from(&(-hat(p) * ez));
            n
        };
        let fej_rot = so3::exp(&Vector3::new(0.05, -0.02, 0.8));
        let (fej_v, fej_p) = (Vector3::new(1.0, 0.2, 0.1), Vector3::new(3.0, 4.0, 5.0));
        let zero = ImuNoise { gyro_radps_rthz: 0.0, acc_mps2_rthz: 0.0, gyro_bias_walk: 0.0, acc_bias_walk: 0.0 };
        let s0 = ImuSample { t_s: 0.0, gyro_radps: Vector3::new(0.01, 0.02, 0.3), acc_mps2: Vector3::new(0.3, -0.1, -9.7) };
        let s1 = ImuSample { t_s: 0.005, gyro_radps: Vector3::new(0.012, 0.018, 0.29), acc_mps2: Vector3::new(0.32, -0.1, -9.72) };
        let mut errs = Vec::new();
        for fej in [true, false] {
            let imu = ImuState {
                t_s: 0.0,
                // The estimate after an update: 10 mrad, 2 cm/s and 5 cm from the first estimate.
                rot: fej_rot * so3::exp(&Vector3::new(0.0, 0.01, -0.005)),
                vel_w_mps: fej_v + Vector3::new(0.02, -0.01, 0.0),
                pos_w_m: fej_p + Vector3::new(0.05, 0.03, 0.0),
                bias_gyro_radps: Vector3::zeros(),
                bias_acc_mps2: Vector3::zeros(),
                sonar_scale: 1.0,
                depth_ref_err_m: 0.0,
                sonar_bias_mps: 0.0,
            };
            let n0 = n_of(&fej_rot, &fej_v, &fej_p);
            let mut st = FilterState::new(imu, &n0 * n0.transpose());
            st.fej = ImuFej { rot: fej_rot, vel_w_mps: fej_v, pos_w_m: fej_p };
            st.fej_enabled = fej;
            propagate(&mut st, &s0, &s1, &zero, (0.0, 0.0));
            let n1 = n_of(&st.imu.rot, &st.imu.vel_w_mps, &st.imu.pos_w_m);
            let expect = &n1 * n1.transpose();
            errs.push((st.cov.view((0, 0), (9, 9)) - expect.view((0, 0), (9, 9))).abs().max());
        }
        assert!(errs[0] < 1e-9, "FEJ: {}", errs[0]);
        assert!(errs[1] > 1e-3, "plain EKF unexpectedly exact: {}", errs[1]);
    }

    #[test]
    fn propagation_of_constant_rate_and_acceleration_is_exact_enough() {
        // Constant yaw rate, at rest otherwise except the gravity reaction: position stays, yaw grows.
        let w = Vector3::new(0.0, 0.0, 0.2);
        let mut st = FilterState::new(
            ImuState {
                t_s: 0.0,
                rot: Matrix3::identity(),
                vel_w_mps: Vector3::new(1.0, 0.0, 0.0),
                pos_w_m: Vector3::zeros(),
                bias_gyro_radps: Vector3::zeros(),
                bias_acc_mps2: Vector3::zeros(),
                sonar_scale: 1.0,
                depth_ref_err_m: 0.0,
                sonar_bias_mps: 0.0,
            },
            DMatrix::identity(IMU_DIM, IMU_DIM) * 1e-4,
        );
        let f = -gravity_w();
        let mut prev = ImuSample { t_s: 0.0, gyro_radps: w, acc_mps2: f };
        for i in 1..=1000 {
            let s = ImuSample { t_s: i as f64 * 0.005, gyro_radps: w, acc_mps2: f };
            propagate(&mut st, &prev, &s, &ImuNoise::default(), (0.0, 0.0));
            prev = s;
        }
        // 5 s: yaw 1 rad, position 5 m along x (velocity is constant in world frame).
        let yaw = so3::log(&st.imu.rot).z;
        assert!((yaw - 1.0).abs() < 1e-9, "{yaw}");
        assert!((st.imu.pos_w_m - Vector3::new(5.0, 0.0, 0.0)).norm() < 1e-9, "{}", st.imu.pos_w_m);
        // Covariance grows and stays symmetric positive definite.
        assert!(st.cov[(POS, POS)] > 1e-4 + 1e-5);
        assert!(st.cov.clone().cholesky().is_some());
        assert_eq!(st.cov, st.cov.transpose());
    }
}
