//! Target benchmark cases of the UKF and the navigation filter (issue 4).
//! Call `b.run("area.name", iterations, || work)`; keep iterations x instructions < 300 M.
//!
//! The filter is the AUKF configuration (`NavConfig::default().adaptive()`), 15 error states,
//! 31 sigma points, f32. Each update is fed a consistent measurement, so it is accepted and
//! runs the full path (gate, gain, covariance, Sage-Husa R step, injection).

use core::hint::black_box;

use nalgebra::{Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};
use subnav_core::head;
use subnav_core::nav::dvl::DvlMeasurement;
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
    // Late measurements (the history lookup and the retrodicted sigma points): a position fix
    // 3 s old and a DVL report 0.1 s old, each consistent with the stored past.
    if let Some(mut nav) = head_filter() {
        let t = nav.t_us();
        nav.flush_history();
        // The first stored instant at least 3 s back, and the position the filter had then.
        let past = (0..64).filter_map(|i| nav.history().get(i)).filter(|s| s.t_us + 3_000_000 <= t).last().copied();
        let (t_fix, p) = past.map(|s| (s.t_us, [s.pos_ned_m.x, s.pos_ned_m.y, s.pos_ned_m.z])).unwrap_or((t, [0.0; 3]));
        b.run("nav.update_position_3s_late", 200, || {
            nav.update_position(t_fix, black_box(p), [4.0, 0.0, 0.0, 4.0, 0.0, 4.0]).map(|r| r.accepted).unwrap_or(false)
        });
        let m = dvl_now(&nav, t - 100_000);
        b.run("nav.update_dvl_100ms_late", 200, || {
            nav.update_dvl(black_box(&m), &head::dvl_mounting()).map(|r| r.accepted).unwrap_or(false)
        });
        let m = dvl_now(&nav, t);
        b.run("nav.update_dvl_current", 200, || nav.update_dvl(black_box(&m), &head::dvl_mounting()).map(|r| r.accepted).unwrap_or(false));
    }
    // Five simulated seconds at the sensor head's rates and configuration (`head::nav_config`):
    // IMU 200 Hz (UKF predict every 10th sample), compass heading 10 Hz, depth 10 Hz, DVL 5 Hz
    // fused 0.1 s late, one position fix fused 3 s late. Divide by 5 for a second.
    if let Some(mut nav) = head_filter() {
        let mut t = nav.t_us();
        b.run("nav.five_seconds_at_head_rates", 3, || {
            let mut accepted = 0u32;
            for k in 0..1000u32 {
                t += 5_000;
                let _ = nav.propagate(&imu(t));
                if k % 20 == 0 {
                    let yaw = nav.nominal().yaw_rad();
                    let z = nav.nominal().pos_ned_m.z;
                    accepted += u32::from(nav.update_heading(t, yaw, None).is_ok_and(|r| r.accepted));
                    accepted += u32::from(nav.update_depth(t, z, None).is_ok_and(|r| r.accepted));
                }
                if k % 40 == 7 {
                    let m = dvl_now(&nav, t.saturating_sub(100_000));
                    accepted += u32::from(nav.update_dvl(&m, &head::dvl_mounting()).is_ok_and(|r| r.accepted));
                }
                if k == 500 {
                    let p = nav.nominal().pos_ned_m;
                    let fix = nav.update_position(t.saturating_sub(3_000_000), [p.x, p.y, p.z], [4.0, 0.0, 0.0, 4.0, 0.0, 4.0]);
                    accepted += u32::from(fix.is_ok_and(|r| r.accepted));
                }
            }
            accepted
        });
    }
}

/// The head's filter after 5 s of IMU samples at 200 Hz (the history is full enough for a fix
/// 3 s late).
fn head_filter() -> Option<NavFilter15> {
    let mut nav = filter(head::nav_config())?;
    let mut t = nav.t_us();
    for _ in 0..1000 {
        t += 5_000;
        let _ = nav.propagate(&imu(t));
    }
    Some(nav)
}

/// A DVL measurement consistent with the filter's current state, stamped `t_us`.
fn dvl_now(nav: &NavFilter15, t_us: u64) -> DvlMeasurement {
    let mount = head::dvl_mounting();
    let v_b = nav.nominal().att_nb.inverse_transform_vector(&nav.nominal().vel_ned_mps);
    let v_d = mount.rot_body_from_dvl.inverse_transform_vector(&v_b);
    DvlMeasurement { t_us, vel_dvl_mps: [v_d.x, v_d.y, v_d.z], covariance_m2ps2: None, fom_mps: Some(0.01), gyro_radps: [0.0; 3] }
}
