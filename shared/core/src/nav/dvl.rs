//! DVL bottom-track velocity update, with the DVL's mounting rotation and lever arm.
//!
//! The DVL measures the velocity of its own transducer head over the bottom, in its own axes:
//!
//! `z = R_bd^T (R_nb^T v_n + w_b x l_b)`
//!
//! - `R_nb = Exp(phi) R_nom`: body (FRD) -> NED, with the sigma point's attitude error;
//! - `v_n = v_nom + dv`: velocity of the IMU (the body origin), NED;
//! - `w_b = gyro - (b_g + db_g) - eps`: body rate, the IMU sample nearest the ping with the
//!   estimated gyro bias (and 18-state Markov drift) removed;
//! - `l_b`: lever arm from the IMU to the DVL, body axes, m ([`DvlMounting::lever_arm_body_m`]);
//! - `R_bd`: DVL axes -> body axes ([`DvlMounting::rot_body_from_dvl`]).
//!
//! The update shares the body-velocity noise, gate and NIS slot (`KIND_VELOCITY`,
//! `NavConfig::velocity`) with [`super::velocity`], which is the special case `R_bd = I`,
//! `l_b = 0`. Its noise: the DVL's covariance when given (checked finite and positive
//! definite after symmetrizing, else the measurement is refused), else its figure of merit as
//! a per-axis 1-sigma, else the configured / adapted noise; as for the other sensors a
//! measured noise replaces R only when Sage-Husa adaptation is off for it.
//!
//! Only bottom-referenced, valid velocities belong here (water-track velocity is relative to a
//! moving water column); the firmware driver hands out nothing else to fuse.

use nalgebra::{Matrix3, SVector, UnitQuaternion, Vector3};

use crate::ukf::pd;
use crate::ukf::{Euclidean, UpdateReport};

use super::filter::{KIND_VELOCITY, NavError, NavFilter, settle};
use super::rotation::quat_from_rotation_vector;
use super::state::{ATT, BA, BG, MARKOV, NominalState, VEL, seg};

/// A DVL velocity of more than this (m/s, any axis) is implausible for the vehicle and refused
/// like a non-finite one.
pub const DVL_MAX_SPEED_MPS: f32 = 20.0;

/// Where the DVL sits on the body.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DvlMounting {
    /// DVL axes -> body (FRD) axes: `v_body = rot_body_from_dvl * v_dvl`.
    pub rot_body_from_dvl: UnitQuaternion<f32>,
    /// From the IMU (body origin) to the DVL's transducer centre, body axes, m.
    pub lever_arm_body_m: Vector3<f32>,
}

impl Default for DvlMounting {
    /// DVL axes equal to the body axes, at the IMU.
    fn default() -> Self {
        Self { rot_body_from_dvl: UnitQuaternion::identity(), lever_arm_body_m: Vector3::zeros() }
    }
}

impl DvlMounting {
    fn is_finite(&self) -> bool {
        self.rot_body_from_dvl.coords.iter().chain(self.lever_arm_body_m.iter()).all(|v| v.is_finite())
    }
}

/// One DVL bottom-track report, as the filter needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DvlMeasurement {
    /// Time of validity of the velocity (centre of ping) in the filter's clock, µs.
    pub t_us: u64,
    /// Velocity over the bottom, DVL axes, m/s.
    pub vel_dvl_mps: [f32; 3],
    /// The DVL's velocity covariance, DVL axes, row-major, (m/s)^2.
    pub covariance_m2ps2: Option<[f32; 9]>,
    /// The DVL's figure of merit, m/s (used as a per-axis 1-sigma when there is no covariance).
    pub fom_mps: Option<f32>,
    /// Raw gyro output (body FRD, rad/s) at the time of validity, for the lever-arm term.
    pub gyro_radps: [f32; 3],
}

/// Predicted DVL velocity of an error sigma point (see the module doc).
pub fn h_dvl<const N: usize>(nom: &NominalState, dx: &SVector<f32, N>, mount: &DvlMounting, gyro_radps: &Vector3<f32>) -> Vector3<f32> {
    let q = quat_from_rotation_vector(&seg(dx, ATT)) * nom.att_nb;
    let v_b = q.inverse_transform_vector(&(nom.vel_ned_mps + seg(dx, VEL)));
    let mut w_b = gyro_radps - (nom.gyro_bias_radps + seg(dx, BG)) - nom.gyro_markov_radps;
    if N >= MARKOV + 3 {
        w_b -= seg(dx, MARKOV);
    }
    mount.rot_body_from_dvl.inverse_transform_vector(&(v_b + w_b.cross(&mount.lever_arm_body_m)))
}

/// The measurement noise a report asks for: its covariance (symmetrized; `Err` if not finite
/// and positive definite), else its figure of merit squared on the diagonal, else `None`.
fn reported_noise(m: &DvlMeasurement) -> Result<Option<Matrix3<f32>>, ()> {
    if let Some(c) = m.covariance_m2ps2 {
        let c = Matrix3::from_row_slice(&c);
        let r = (c + c.transpose()) * 0.5;
        if !pd::all_finite(&r) || nalgebra::linalg::Cholesky::new(r).is_none() {
            return Err(());
        }
        return Ok(Some(r));
    }
    Ok(m.fom_mps.filter(|f| *f > 0.0).map(|f| Matrix3::identity() * (f * f)))
}

impl<const N: usize, const S: usize> NavFilter<N, S> {
    /// Fuse one DVL bottom-track velocity (see the module doc). Non-finite or implausible input
    /// (velocity, covariance, figure of merit, gyro, mounting) and a covariance that is not
    /// positive definite are refused (`NavError::NonFinite`, counted, state untouched); a
    /// measurement outside the gate is reported with `accepted = false`. The velocity is fused at
    /// its time of validity `m.t_us` (see [`super::history`]: `NavError::TooOld` /
    /// `NavError::FromFuture` refused and counted, state untouched).
    pub fn update_dvl(&mut self, m: &DvlMeasurement, mount: &DvlMounting) -> Result<UpdateReport<f32>, NavError> {
        let cov = m.covariance_m2ps2.unwrap_or([0.0; 9]);
        let finite = m.vel_dvl_mps.iter().chain(cov.iter()).chain(m.gyro_radps.iter()).all(|v| v.is_finite())
            && m.fom_mps.is_none_or(|f| f.is_finite())
            && mount.is_finite();
        if !finite || m.vel_dvl_mps.iter().any(|v| v.abs() > DVL_MAX_SPEED_MPS) {
            return Err(self.reject_nonfinite());
        }
        let Ok(noise) = reported_noise(m) else {
            return Err(self.reject_nonfinite());
        };
        let delayed = self.check_time(m.t_us)?;
        self.begin_update(&[])?;
        let mut meas = self.noise_vel;
        if let Some(r) = noise {
            if !(self.cfg.ukf.adapt.r_cov && meas.adapt) {
                meas.r = r;
            }
        }
        let gyro = Vector3::from(m.gyro_radps);
        let z = Vector3::from(m.vel_dvl_mps);
        let mount = *mount;
        // One closure for both cases (one instantiation of the UKF update: flash on the M4F).
        let past = if delayed { Some(self.past_epoch(m.t_us)?) } else { None };
        let nom = self.nom;
        // Current, 15 states: the model reads attitude, velocity and gyro bias (states 0..12),
        // not the accelerometer bias (`update_dep`); the retrodiction reads every state.
        let dep = if past.is_some() || N > BA + 3 { N } else { BA };
        let yaw_unobserved = self.yaw_unobserved;
        let h = |dx: &SVector<f32, N>| match &past {
            Some(ep) => h_dvl(&ep.nom, &ep.map(dx), &mount, &gyro),
            None => h_dvl(&nom, dx, &mount, &gyro),
        };
        let r = self.ukf.update_dep::<3, Euclidean, _>(&z, &mut meas, dep, |dx| {
            if yaw_unobserved {
                // `set_yaw_unobserved`: no yaw error (the NED attitude error's down component)
                // reaches the model.
                let mut d = *dx;
                d[ATT + 2] = 0.0;
                h(&d)
            } else {
                h(dx)
            }
        });
        settle(&mut self.noise_vel, meas, &r);
        self.end_update(KIND_VELOCITY, m.t_us, r, delayed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nav::{NavConfig, NavFilter15, NavFilter18, NavInit};
    use core::f32::consts::FRAC_PI_2;
    use subnav_wire::messages::ImuSample;

    fn close(a: &Vector3<f32>, b: &Vector3<f32>, tol: f32) -> bool {
        (a - b).amax() <= tol
    }

    fn nominal(yaw: f32, vel_ned: Vector3<f32>) -> NominalState {
        NominalState {
            att_nb: UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
            vel_ned_mps: vel_ned,
            pos_ned_m: Vector3::zeros(),
            gyro_bias_radps: Vector3::zeros(),
            accel_bias_mps2: Vector3::zeros(),
            gyro_markov_radps: Vector3::zeros(),
        }
    }

    #[test]
    fn predicted_measurement_analytic_cases() {
        let dx = SVector::<f32, 15>::zeros();
        // Heading east (yaw 90 deg), moving north at 1 m/s: in body FRD that is (0, -1, 0).
        let nom = nominal(FRAC_PI_2, Vector3::new(1.0, 0.0, 0.0));
        let z = h_dvl(&nom, &dx, &DvlMounting::default(), &Vector3::zeros());
        assert!(close(&z, &Vector3::new(0.0, -1.0, 0.0), 1e-6), "{z}");
        // Yaw rate 0.5 rad/s with the DVL 1 m ahead of the IMU: w x l = (0, 0.5, 0).
        let lever = DvlMounting { lever_arm_body_m: Vector3::new(1.0, 0.0, 0.0), ..Default::default() };
        let z = h_dvl(&nom, &dx, &lever, &Vector3::new(0.0, 0.0, 0.5));
        assert!(close(&z, &Vector3::new(0.0, -0.5, 0.0), 1e-6), "{z}");
        // The same with a gyro bias of 0.1 rad/s in z: the estimated bias is removed.
        let mut biased = nom;
        biased.gyro_bias_radps = Vector3::new(0.0, 0.0, 0.1);
        let z = h_dvl(&biased, &dx, &lever, &Vector3::new(0.0, 0.0, 0.6));
        assert!(close(&z, &Vector3::new(0.0, -0.5, 0.0), 1e-6), "{z}");
        // DVL turned +45 deg about body z: v_dvl = Rz(45)^T v_b. Body (1, 0, 0) -> (c, -s, 0).
        let nom = nominal(0.0, Vector3::new(1.0, 0.0, 0.0));
        let turned =
            DvlMounting { rot_body_from_dvl: UnitQuaternion::from_euler_angles(0.0, 0.0, 45f32.to_radians()), ..Default::default() };
        let z = h_dvl(&nom, &dx, &turned, &Vector3::zeros());
        let h = core::f32::consts::FRAC_1_SQRT_2;
        assert!(close(&z, &Vector3::new(h, -h, 0.0), 1e-6), "{z}");
        // Mounted looking down with its axes rolled 180 deg about x (z up in DVL axes): a
        // vehicle sinking at 0.2 m/s (NED down +) reads vz = -0.2, vy flips sign.
        let nom = nominal(0.0, Vector3::new(0.0, 0.3, 0.2));
        let rolled =
            DvlMounting { rot_body_from_dvl: UnitQuaternion::from_euler_angles(core::f32::consts::PI, 0.0, 0.0), ..Default::default() };
        let z = h_dvl(&nom, &dx, &rolled, &Vector3::zeros());
        assert!(close(&z, &Vector3::new(0.0, -0.3, -0.2), 1e-6), "{z}");
        // Error state: a velocity error dv_n = (0.1, 0, 0) at yaw 90 adds (0, -0.1, 0).
        let nom = nominal(FRAC_PI_2, Vector3::new(1.0, 0.0, 0.0));
        let mut dx = SVector::<f32, 15>::zeros();
        dx[VEL] = 0.1;
        let z = h_dvl(&nom, &dx, &DvlMounting::default(), &Vector3::zeros());
        assert!(close(&z, &Vector3::new(0.0, -1.1, 0.0), 1e-6), "{z}");
        // A gyro bias error db_g = (0, 0, 0.5) with the lever arm: w = -0.5 -> (0, -0.5, 0).
        let mut dx = SVector::<f32, 15>::zeros();
        dx[BG + 2] = 0.5;
        let z = h_dvl(&nominal(0.0, Vector3::zeros()), &dx, &lever, &Vector3::zeros());
        assert!(close(&z, &Vector3::new(0.0, -0.5, 0.0), 1e-6), "{z}");
        // 18-state: the Markov drift error enters like the bias.
        let mut dx = SVector::<f32, 18>::zeros();
        dx[MARKOV + 2] = 0.5;
        let z = h_dvl(&nominal(0.0, Vector3::zeros()), &dx, &lever, &Vector3::zeros());
        assert!(close(&z, &Vector3::new(0.0, -0.5, 0.0), 1e-6), "{z}");
    }

    /// Tiny deterministic normal generator (no `rand` in the no_std core).
    struct Lcg(u64);
    impl Lcg {
        fn uniform(&mut self) -> f32 {
            self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((self.0 >> 40) as f32 + 0.5) / (1u64 << 24) as f32
        }
        fn normal(&mut self) -> f32 {
            let (u1, u2) = (self.uniform(), self.uniform());
            libm::sqrtf(-2.0 * libm::logf(u1)) * libm::cosf(2.0 * core::f32::consts::PI * u2)
        }
    }

    const ACCEL_BIAS_X: f32 = 0.02;

    /// A straight run north at 1 m/s, level, heading 0, with an uncompensated accelerometer
    /// bias of 0.02 m/s^2 in x and an initial velocity error of 0.3 m/s east. The DVL is 0.5 m
    /// ahead and 0.3 m below the IMU, turned 45 deg in yaw; the vehicle yaws slowly (a
    /// +-0.05 rad/s sine) so the lever arm matters. Returns the final horizontal velocity error.
    fn straight_run(with_dvl: bool) -> (f32, NavFilter15) {
        run_with(with_dvl, None)
    }

    /// [`straight_run`], optionally telling the filter a different mounting than the truth.
    fn run_with(with_dvl: bool, filter_mount: Option<DvlMounting>) -> (f32, NavFilter15) {
        let mount = DvlMounting {
            rot_body_from_dvl: UnitQuaternion::from_euler_angles(0.0, 0.0, 45f32.to_radians()),
            lever_arm_body_m: Vector3::new(0.5, 0.0, 0.3),
        };
        let told = filter_mount.unwrap_or(mount);
        let cfg = NavConfig { init_sigma_vel_mps: 0.5, ..NavConfig::default() };
        let init = NavInit {
            t_us: 0,
            att_nb: UnitQuaternion::identity(),
            vel_ned_mps: Vector3::new(1.0, 0.3, 0.0),
            pos_ned_m: Vector3::new(0.0, 0.0, 10.0),
        };
        let mut nav = NavFilter15::new(cfg, init).unwrap();
        let mut rng = Lcg(7);
        let (speed, yaw_amp, w) = (1.0f32, 0.05f32 / 0.2, 0.2f32);
        let mut yaw = 0.0f32;
        let mut max_err = 0.0f32;
        for k in 1..=6000u64 {
            let t = k as f32 * 0.01;
            // Truth: yaw(t) = A sin(w t), yaw rate r = A w cos(w t); forward speed constant in
            // body x, so v_n = speed (cos yaw, sin yaw). Specific force: centripetal r * speed
            // in body y, gravity reaction -g in z.
            let r = yaw_amp * w * libm::cosf(w * t);
            yaw = yaw_amp * libm::sinf(w * t);
            let imu = ImuSample { t_us: k * 10_000, gyro_radps: [0.0, 0.0, r], accel_mps2: [ACCEL_BIAS_X, r * speed, -9.81], temp_c: 10.0 };
            nav.propagate(&imu).unwrap();
            if with_dvl && k % 20 == 0 {
                // 5 Hz DVL: body velocity (speed, 0, 0) plus w x l, in DVL axes, with 5 mm/s noise.
                let v_b = Vector3::new(speed, 0.0, 0.0) + Vector3::new(0.0, 0.0, r).cross(&mount.lever_arm_body_m);
                let v_d = mount.rot_body_from_dvl.inverse_transform_vector(&v_b);
                let sigma = 0.005;
                let z = [v_d.x + sigma * rng.normal(), v_d.y + sigma * rng.normal(), v_d.z + sigma * rng.normal()];
                let m = DvlMeasurement {
                    t_us: imu.t_us,
                    vel_dvl_mps: z,
                    covariance_m2ps2: None,
                    fom_mps: Some(sigma),
                    gyro_radps: imu.gyro_radps,
                };
                let rep = nav.update_dvl(&m, &told).unwrap();
                if filter_mount.is_some() {
                    continue;
                }
                // The gate floor (state part capped at 16 R) holds the first reports out until
                // `gate_release_after` consecutive rejections lift the cap (~2 s at 5 Hz).
                assert!(rep.accepted || t < 5.0, "DVL update rejected at t = {t} s (nis {})", rep.nis);
                let truth = Vector3::new(speed * libm::cosf(yaw), speed * libm::sinf(yaw), 0.0);
                if t > 10.0 {
                    max_err = max_err.max((nav.nominal().vel_ned_mps - truth).xy().norm());
                }
            }
        }
        let truth = Vector3::new(speed * libm::cosf(yaw), speed * libm::sinf(yaw), 0.0);
        let err = (nav.nominal().vel_ned_mps - truth).xy().norm();
        if with_dvl && filter_mount.is_none() {
            assert!(max_err < 0.05, "horizontal velocity error up to {max_err} m/s after the first 10 s");
        }
        (err, nav)
    }

    #[test]
    fn dvl_bounds_the_horizontal_velocity_error_on_a_straight_run() {
        let (err_free, _) = straight_run(false);
        let (err_dvl, nav) = straight_run(true);
        // Inertial only: the 0.02 m/s^2 bias over 60 s and the initial 0.3 m/s error remain.
        assert!(err_free > 0.8, "inertial-only error {err_free} m/s");
        assert!(err_dvl < 0.03, "DVL-aided error {err_dvl} m/s");
        // (The accelerometer bias itself is not separable from a pitch error on a level run:
        // the filter splits it between the two, so only the velocity is checked.)
        println!("horizontal velocity error after 60 s: inertial only {err_free:.3} m/s, with DVL {err_dvl:.4} m/s");
        // Along-track sigma is the DVL's; cross-track sigma is the unobserved heading error
        // times the speed (a body-frame velocity does not observe heading).
        let sol = nav.solution();
        let (s, yaw_sigma) = (sol.sigma_vel_mps, sol.sigma_att_rad[2]);
        assert!(s[0] < 0.02, "along-track velocity sigma {s:?}");
        assert!(s[1] < 1.1 * yaw_sigma * 1.0 + 0.02, "cross-track velocity sigma {s:?}, yaw sigma {yaw_sigma}");
    }

    #[test]
    fn the_mounting_matters() {
        // Telling the filter the DVL is aligned with the body (it is turned 45 deg) leaves a
        // large velocity error: the rotation is not something the filter absorbs.
        let (err_wrong, _) = run_with(true, Some(DvlMounting::default()));
        let (err_right, _) = straight_run(true);
        assert!(err_wrong > 10.0 * err_right && err_wrong > 0.2, "wrong mounting {err_wrong} m/s vs {err_right} m/s");
    }

    #[test]
    fn gate_rejects_a_gross_outlier() {
        let (_, mut nav) = straight_run(true);
        let (nom, p) = (*nav.nominal(), *nav.covariance());
        let mount = DvlMounting {
            rot_body_from_dvl: UnitQuaternion::from_euler_angles(0.0, 0.0, 45f32.to_radians()),
            lever_arm_body_m: Vector3::new(0.5, 0.0, 0.3),
        };
        // 3 m/s off in DVL x (hundreds of sigmas of a 5 mm/s DVL).
        let v = mount.rot_body_from_dvl.inverse_transform_vector(&nom.att_nb.inverse_transform_vector(&nom.vel_ned_mps));
        let m = DvlMeasurement {
            t_us: nav.t_us(),
            vel_dvl_mps: [v.x + 3.0, v.y, v.z],
            covariance_m2ps2: None,
            fom_mps: Some(0.005),
            gyro_radps: [0.0; 3],
        };
        let rep = nav.update_dvl(&m, &mount).unwrap();
        assert!(!rep.accepted, "outlier accepted, nis {}", rep.nis);
        assert_eq!(nav.nominal().vel_ned_mps, nom.vel_ned_mps);
        // The rejection only flushed the (empty) covariance interval: P unchanged.
        assert_eq!(*nav.covariance(), p);
        // A consistent report right after is accepted.
        let ok = DvlMeasurement { vel_dvl_mps: [v.x, v.y, v.z], ..m };
        assert!(nav.update_dvl(&ok, &mount).unwrap().accepted);
    }

    fn fresh() -> NavFilter18 {
        let init = NavInit { t_us: 0, att_nb: UnitQuaternion::identity(), vel_ned_mps: Vector3::zeros(), pos_ned_m: Vector3::zeros() };
        NavFilter18::new(NavConfig::default(), init).unwrap()
    }

    #[test]
    fn nonfinite_or_implausible_input_is_refused_without_touching_the_state() {
        let mut nav = fresh();
        let (nom, p) = (*nav.nominal(), *nav.covariance());
        let good = DvlMeasurement { t_us: 0, vel_dvl_mps: [0.0; 3], covariance_m2ps2: None, fom_mps: None, gyro_radps: [0.0; 3] };
        let mount = DvlMounting::default();
        let mut cases = std::vec::Vec::new();
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            cases.push((DvlMeasurement { vel_dvl_mps: [0.0, bad, 0.0], ..good }, mount));
            cases.push((DvlMeasurement { gyro_radps: [0.0, 0.0, bad], ..good }, mount));
            cases.push((DvlMeasurement { fom_mps: Some(bad), ..good }, mount));
            let mut c = [1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 1e-4];
            c[4] = bad;
            cases.push((DvlMeasurement { covariance_m2ps2: Some(c), ..good }, mount));
            cases.push((good, DvlMounting { lever_arm_body_m: Vector3::new(bad, 0.0, 0.0), ..mount }));
        }
        // Implausible speed, and a covariance that is not positive definite.
        cases.push((DvlMeasurement { vel_dvl_mps: [DVL_MAX_SPEED_MPS * 2.0, 0.0, 0.0], ..good }, mount));
        cases.push((DvlMeasurement { covariance_m2ps2: Some([1.0, 2.0, 0.0, 2.0, 1.0, 0.0, 0.0, 0.0, 1.0]), ..good }, mount));
        cases.push((DvlMeasurement { covariance_m2ps2: Some([0.0; 9]), ..good }, mount));
        let before = nav.input_rejects();
        for (m, mt) in &cases {
            assert_eq!(nav.update_dvl(m, mt).map(|_| ()), Err(NavError::NonFinite), "{m:?} {mt:?}");
        }
        assert_eq!(nav.input_rejects() - before, cases.len() as u32);
        assert_eq!(*nav.nominal(), nom);
        assert_eq!(*nav.covariance(), p);
        assert!(nav.update_dvl(&good, &mount).unwrap().accepted);
    }

    #[test]
    fn reported_covariance_or_fom_sets_r_when_not_adapting() {
        let mut nav = fresh();
        let mount = DvlMounting::default();
        let c = [4e-4, 1e-5, 0.0, 0.0, 9e-4, 0.0, 0.0, 0.0, 1e-4];
        let m = DvlMeasurement { t_us: 0, vel_dvl_mps: [0.0; 3], covariance_m2ps2: Some(c), fom_mps: Some(0.5), gyro_radps: [0.0; 3] };
        nav.update_dvl(&m, &mount).unwrap();
        let r = nav.r_diag()[crate::nav::KIND_VELOCITY];
        assert!((r - (4e-4 + 9e-4 + 1e-4) / 3.0).abs() < 1e-9, "{r}");
        nav.update_dvl(&DvlMeasurement { covariance_m2ps2: None, fom_mps: Some(0.05), ..m }, &mount).unwrap();
        let r = nav.r_diag()[crate::nav::KIND_VELOCITY];
        assert!((r - 0.0025).abs() < 1e-9, "{r}");
        // Adaptive: the adapted R is kept, not replaced by the report's.
        let init = NavInit { t_us: 0, att_nb: UnitQuaternion::identity(), vel_ned_mps: Vector3::zeros(), pos_ned_m: Vector3::zeros() };
        let mut nav = NavFilter15::new(NavConfig::default().adaptive(), init).unwrap();
        let r0 = nav.r_diag()[crate::nav::KIND_VELOCITY];
        nav.update_dvl(&DvlMeasurement { covariance_m2ps2: None, fom_mps: Some(0.5), ..m }, &mount).unwrap();
        assert!((nav.r_diag()[crate::nav::KIND_VELOCITY] - 0.25).abs() > 0.1, "adaptive R replaced by the report's (was {r0})");
    }

    #[test]
    fn identity_mounting_matches_the_body_velocity_update() {
        let mut a = fresh();
        let mut b = fresh();
        let m = DvlMeasurement { t_us: 0, vel_dvl_mps: [0.1, -0.05, 0.02], covariance_m2ps2: None, fom_mps: None, gyro_radps: [0.0; 3] };
        let ra = a.update_dvl(&m, &DvlMounting::default()).unwrap();
        let rb = b.update_body_velocity(0, m.vel_dvl_mps, None).unwrap();
        assert_eq!(ra, rb);
        assert_eq!(a.nominal(), b.nominal());
        assert_eq!(a.covariance(), b.covariance());
    }
}
