//! Target benchmark cases of the UKF and the navigation filter (issue 4).
//! Call `b.run("area.name", iterations, || work)`; keep iterations x instructions < 300 M.
//!
//! The filter is the AUKF configuration (`NavConfig::default().adaptive()`), 15 error states,
//! 31 sigma points, f32. Each update is fed a consistent measurement, so it is accepted and
//! runs the full path (gate, gain, covariance, Sage-Husa R step, injection).

use core::hint::black_box;

use nalgebra::{Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};
use subnav_core::nav::strapdown::{Increments, propagate_error};
use subnav_core::nav::{NavConfig, NavFilter15, NavInit};
use subnav_core::ukf::pd::cholesky_into;
use subnav_wire::messages::ImuSample;

use crate::Bench;

fn imu(t_us: u64) -> ImuSample {
    ImuSample { t_us, gyro_radps: [0.001, -0.002, 0.01], accel_mps2: [0.05, 0.01, -9.81], temp_c: 10.0 }
}

fn filter(cfg: NavConfig) -> Option<NavFilter15> {
    let init = NavInit {
        t_us: 0,
        att_nb: UnitQuaternion::from_euler_angles(0.01, -0.02, 0.5),
        vel_ned_mps: Vector3::new(1.0, 0.5, 0.0),
        pos_ned_m: Vector3::new(0.0, 0.0, 10.0),
    };
    let mut nav = NavFilter15::new(cfg, init).ok()?;
    for k in 0..=20u64 {
        let _ = nav.propagate(&imu(k * 10_000));
    }
    Some(nav)
}

pub fn run(b: &mut Bench) {
    // The parts of the UKF predict: one sigma point through the error propagation (31 per
    // predict) and the 15 x 15 Cholesky factor (one per predict and per update).
    let mut inc = Increments::zero();
    inc.dt_s = 0.1;
    inc.dv_f = Vector3::new(0.1, 0.05, -0.98);
    inc.dp_f = Vector3::new(0.01, 0.005, -0.05);
    inc.c = Matrix3::identity() * 0.1;
    inc.cc = Matrix3::identity() * 0.005;
    inc.samples = 10;
    let dx = SVector::<f32, 15>::from_fn(|i, _| 1e-3 * (i as f32 + 1.0));
    b.run("nav.propagate_error_one_point", 500, || propagate_error(black_box(&dx), black_box(&inc), 0.99)[0] > 0.0);
    let a = SMatrix::<f32, 15, 15>::from_fn(|i, j| if i == j { 2.0 } else { 0.1 / (1.0 + (i + j) as f32) });
    let p = a * a.transpose();
    let mut l = SMatrix::<f32, 15, 15>::zeros();
    b.run("ukf.cholesky_15", 500, || cholesky_into(black_box(&p), &mut l));
    // Strapdown only: covariance step pushed out of the loop.
    let mut cfg = NavConfig::default().adaptive();
    cfg.cov_decimation = u32::MAX;
    if let Some(mut nav) = filter(cfg) {
        let mut t = 1_000_000u64;
        b.run("nav.propagate_strapdown", 2000, || {
            t += 10_000;
            nav.propagate(black_box(&imu(t))).is_ok()
        });
    }
    // Strapdown + UKF predict (15 states, 31 sigma points) on every call.
    let mut cfg = NavConfig::default().adaptive();
    cfg.cov_decimation = 1;
    if let Some(mut nav) = filter(cfg) {
        let mut t = 1_000_000u64;
        b.run("nav.propagate_with_ukf_predict", 200, || {
            t += 10_000;
            nav.propagate(black_box(&imu(t))).is_ok()
        });
    }
    let cfg = NavConfig::default().adaptive();
    if let Some(mut nav) = filter(cfg) {
        let t = nav.t_us();
        let yaw = nav.nominal().yaw_rad();
        b.run("nav.update_heading", 200, || nav.update_heading(t, black_box(yaw), None).map(|r| r.accepted).unwrap_or(false));
        let d = nav.nominal().pos_ned_m.z;
        b.run("nav.update_depth", 200, || nav.update_depth(t, black_box(d), None).map(|r| r.accepted).unwrap_or(false));
        let v = nav.nominal().att_nb.inverse_transform_vector(&nav.nominal().vel_ned_mps);
        b.run("nav.update_body_velocity", 200, || {
            nav.update_body_velocity(t, black_box([v.x, v.y, v.z]), None).map(|r| r.accepted).unwrap_or(false)
        });
        let p = nav.nominal().pos_ned_m;
        b.run("nav.update_position", 200, || {
            nav.update_position(t, black_box([p.x, p.y, p.z]), [1.0, 0.0, 0.0, 1.0, 0.0, 1.0]).map(|r| r.accepted).unwrap_or(false)
        });
        b.run("nav.health", 1000, || black_box(nav.health()).pd_repairs);
        b.run("nav.solution", 1000, || black_box(nav.solution()).t_us);
    }
}
