//! The KITTI drive GTSAM ships (real IMU, GNSS positions) through the product's estimator
//! ([`subnav_firmware::estimator::Estimator`], the code the head runs): a moving start from the
//! first two fixes ([`Estimator::start_moving`]), the used fixes as position fixes at their time,
//! the others held out and scored (`subnav_fgo::kitti_run`'s scenario and score, so the figures
//! sit beside the factor graph's). The head's tuning is for its own MEMS IMU, not KITTI's OXTS
//! unit: only the IMU rate, gravity and the fix noise are set from the data, as a user would.

use nalgebra::{Matrix3, Vector3};
use subnav_fgo::kitti::KittiData;
use subnav_fgo::kitti_run::{KittiConfig, Role, Scenario, Score, score};
use subnav_fgo::state::{enu_to_ned, f_flu_frd, t_enu_ned};
use subnav_firmware::estimator::Estimator;
use subnav_firmware::estimator::warm::MovingStart;

/// One run's figures.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct EstimatorRun {
    pub score: Score,
    /// Mean NEES of the held-out position error against `P_pos + R_fix` (3 for a consistent
    /// filter) and the fraction above the 99 % chi-square(3) quantile.
    pub nees_mean: f64,
    pub nees_above_99: f64,
    /// Fixes fused (at once or by the position aid's timeout) and left out.
    pub fixes_fused: usize,
    pub fixes_refused: usize,
    /// Fixes the gate refused (some then fused by the timeout, with the covariance faded).
    pub fixes_gate_refused: usize,
    pub fix_errors: usize,
    pub position_resets: u32,
    pub velocity_resets: u32,
    /// The IMU process-noise scale the filter ended with (variance ratio to the head's tuning).
    pub imu_q_scale: f32,
    /// Non-finite state or a held-out error above 100 m at any epoch.
    pub diverged: bool,
    #[serde(skip)]
    pub pos_enu_m: Vec<Vector3<f64>>,
}

/// Run the head's estimator on `sc` (from [`subnav_fgo::kitti_run::scenario`]); `gate`: the
/// position gate as configured (`false`: off, for the comparison).
pub fn run_estimator(data: &KittiData, sc: &Scenario, cfg: &KittiConfig, gate: bool) -> anyhow::Result<EstimatorRun> {
    let mut nc = subnav_core::head::nav_config();
    nc.imu_rate_hz = 100.0;
    nc.cov_decimation = 10;
    nc.gravity_mps2 = cfg.gravity_mps2 as f32;
    nc.position.sigma = cfg.fix_sigma_m as f32;
    if !gate {
        nc.position.gate = f32::INFINITY;
    }
    let mut est = Estimator::new(nc);
    let t0 = sc.prior.t_s;
    // Head time: 1 s before the first epoch is 0 (the levelling samples come before it).
    let us = |t: f64| ((t - t0 + 1.0) * 1e6).round().max(0.0) as u64;
    let f = f_flu_frd();
    let imu_at = |k: usize| {
        let smp = &data.imu[k];
        let a = f * smp.acc_mps2;
        let w = f * smp.gyro_radps;
        subnav_wire::ImuSample {
            t_us: us(smp.t_s),
            gyro_radps: [w.x as f32, w.y as f32, w.z as f32],
            accel_mps2: [a.x as f32, a.y as f32, a.z as f32],
            temp_c: 20.0,
        }
    };
    // The moving start: the scenario's prior (position of the first fix, velocity and yaw from
    // the first two) with its sigmas; levelled on the specific force of the samples before.
    let s = sc.prior.sigmas;
    let p0 = enu_to_ned(&Vector3::from(sc.prior.pos_enu_m));
    let v0 = enu_to_ned(&Vector3::from(sc.prior.vel_enu_mps));
    let yaw_ned = std::f64::consts::FRAC_PI_2 - sc.prior.rotvec_enu_flu[2];
    let start = MovingStart {
        pos_ned_m: [p0.x as f32, p0.y as f32, p0.z as f32],
        vel_ned_mps: [v0.x as f32, v0.y as f32, v0.z as f32],
        yaw_rad: yaw_ned as f32,
        sigma_pos_m: [s[1] as f32; 3],
        sigma_vel_mps: [s[2] as f32; 3],
        sigma_yaw_rad: s[0] as f32,
        sigma_tilt_rad: s[0] as f32,
    };
    let mut next = data.imu.partition_point(|x| x.t_s < t0 - 0.25);
    while next < data.imu.len() && data.imu[next].t_s <= t0 {
        let _ = est.on_imu(&imu_at(next));
        next += 1;
    }
    est.start_moving(&start).map_err(|e| anyhow::anyhow!("the moving start was refused: {e:?}"))?;
    let var = (cfg.fix_sigma_m * cfg.fix_sigma_m) as f32;
    let cov = [var, 0.0, 0.0, var, 0.0, var];
    let r_fix = Matrix3::identity() * cfg.fix_sigma_m.powi(2);
    let (mut fused, mut refused, mut gate_refused, mut errors) = (0, 0, 0, 0);
    let mut pos = Vec::with_capacity(sc.epochs.len());
    let (mut nees, mut diverged) = (Vec::new(), false);
    for e in &sc.epochs {
        while next < data.imu.len() && data.imu[next].t_s <= e.t_s {
            let _ = est.on_imu(&imu_at(next));
            next += 1;
        }
        if e.role == Role::Used && e.t_s > t0 {
            let z = enu_to_ned(&e.measured_enu_m);
            let before = est.health(0).gate_rejects;
            match est.on_position_fix(us(e.t_s), [z.x as f32, z.y as f32, z.z as f32], cov) {
                Ok(()) => {
                    let h = est.health(0);
                    gate_refused += (h.gate_rejects != before) as usize;
                    // Fused at once, or by the position aid's timeout after the gate refused it.
                    if h.aid.position.fused && h.aid.position.t_us == us(e.t_s) {
                        fused += 1;
                    } else {
                        refused += 1;
                    }
                }
                Err(_) => errors += 1,
            }
        }
        let sol = est.solution(us(e.t_s));
        if std::env::var_os("SUBNAV_KITTI_DEBUG").is_some() {
            let h = est.health(0);
            let pe = enu_to_ned(&e.recorded.pos_enu_m);
            eprintln!(
                "t {:.1} role {:?} err_ned {:.2} {:.2} {:.2} sig {:?} vel {:?} nis {:?} q {:.1} rej {}",
                e.t_s - t0,
                e.role,
                sol.pos_ned_m[0] as f64 - pe.x,
                sol.pos_ned_m[1] as f64 - pe.y,
                sol.pos_ned_m[2] as f64 - pe.z,
                sol.sigma_pos_m,
                sol.vel_ned_mps,
                h.aid.position.nis,
                est.imu_q_scale(),
                h.gate_rejects
            );
        }
        // The solution is at the last IMU sample (<= 10 ms before the epoch): carry it there.
        let dt = e.t_s - ((sol.t_us as f64 - 1e6) * 1e-6 + t0);
        let p_ned = Vector3::from(sol.pos_ned_m.map(f64::from)) + Vector3::from(sol.vel_ned_mps.map(f64::from)) * dt.max(0.0);
        let p_enu = enu_to_ned(&p_ned);
        let err = p_enu - e.recorded.pos_enu_m;
        if !err.norm().is_finite() || (e.role != Role::Used && err.norm() > 100.0) {
            diverged = true;
        }
        if e.role != Role::Used {
            let sp = sol.sigma_pos_m.map(f64::from);
            let mut pc = Matrix3::from_diagonal(&Vector3::new(sp[0] * sp[0], sp[1] * sp[1], sp[2] * sp[2]));
            pc[(0, 1)] = f64::from(sol.cov_ne_m2);
            pc[(1, 0)] = f64::from(sol.cov_ne_m2);
            let t = t_enu_ned();
            let s_enu = t * pc * t + r_fix;
            nees.push(s_enu.cholesky().map_or(f64::INFINITY, |c| err.dot(&c.solve(&err))));
        }
        pos.push(p_enu);
    }
    let h = est.health(0);
    let nees_mean = nees.iter().sum::<f64>() / nees.len().max(1) as f64;
    let nees_above_99 = nees.iter().filter(|n| **n > 11.344_866_730_144_373).count() as f64 / nees.len().max(1) as f64;
    Ok(EstimatorRun {
        score: score(&sc.epochs, &pos),
        nees_mean,
        nees_above_99,
        fixes_fused: fused,
        fixes_refused: refused,
        fixes_gate_refused: gate_refused,
        fix_errors: errors,
        position_resets: h.position_resets,
        velocity_resets: h.aid.dvl.resets,
        imu_q_scale: est.imu_q_scale(),
        diverged,
        pos_enu_m: pos,
    })
}
