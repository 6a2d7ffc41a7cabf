//! Filtering baseline for the Monte Carlo: an INS/DVL/USBL unscented Kalman filter built on the
//! shared UKF core (`subnav_core::ukf`, the one the sensor head uses), fed the same log.
//! State `[p_enu, v_enu, rotvec body->ENU, b_acc, b_gyro]` (15) with an SO(3)-aware state space;
//! IMU prediction per sample (split at observation time stamps), DVL and USBL updates with the
//! UKF's own chi-square gate (p = 0.999, with its floor). A filter cannot put a delayed USBL fix
//! at its valid time, so the fix is applied at arrival, shifted by the filter's own estimated
//! displacement since the valid time (the usual practice).

use std::collections::VecDeque;

use nalgebra::{SMatrix, SVector, Vector3};
use subnav_core::ukf::{MeasNoise, Space, Ukf, UkfConfig, gate};

use super::FgoError;
use super::log::SensorLog;
use super::smoother::Estimate;
use super::state::{ImuBias, NavState, NodeState};
use subnav_base::so3;

type X = SVector<f64, 15>;

/// Position/velocity/biases Euclidean, attitude as a rotation vector composed on the right.
pub struct NavSpace;

fn rot(x: &X) -> nalgebra::Matrix3<f64> {
    so3::exp(&Vector3::new(x[6], x[7], x[8]))
}

impl Space<f64, 15> for NavSpace {
    fn add(x: &X, dx: &X) -> X {
        let mut out = x + dx;
        let r = rot(x) * so3::exp(&Vector3::new(dx[6], dx[7], dx[8]));
        out.fixed_rows_mut::<3>(6).copy_from(&so3::log(&r));
        out
    }
    fn residual(a: &X, b: &X) -> X {
        let mut out = a - b;
        out.fixed_rows_mut::<3>(6).copy_from(&so3::log(&(rot(b).transpose() * rot(a))));
        out
    }
    fn mean<const S: usize>(points: &[X; S], wm: &[f64; S]) -> X {
        let reference = points[0];
        let mut m = X::zeros();
        for (p, w) in points.iter().zip(wm.iter()) {
            m += Self::residual(p, &reference) * *w;
        }
        Self::add(&reference, &m)
    }
}

fn state_of(x: &X) -> NodeState {
    NodeState::new(
        NavState::new(rot(x), Vector3::new(x[0], x[1], x[2]), Vector3::new(x[3], x[4], x[5])),
        ImuBias::new(Vector3::new(x[9], x[10], x[11]), Vector3::new(x[12], x[13], x[14])),
    )
}

fn err(e: impl std::fmt::Display) -> FgoError {
    FgoError::Numeric(format!("shared UKF: {e}"))
}

/// Run the UKF over the log; returns the estimate after each DVL/USBL update.
pub fn run(log: &SensorLog) -> Result<Vec<Estimate>, FgoError> {
    log.validate()?;
    let c = log.config;
    let ip = c.imu;
    let g = ip.gravity();
    let pr = c.prior;
    let mut x0 = X::zeros();
    x0.fixed_rows_mut::<3>(0).copy_from(&Vector3::from(pr.pos_enu_m));
    x0.fixed_rows_mut::<3>(3).copy_from(&Vector3::from(pr.vel_enu_mps));
    x0.fixed_rows_mut::<3>(6).copy_from(&Vector3::from(pr.rotvec_enu_flu));
    x0.fixed_rows_mut::<3>(9).copy_from(&Vector3::from(pr.bias_acc_mps2));
    x0.fixed_rows_mut::<3>(12).copy_from(&Vector3::from(pr.bias_gyro_radps));
    let s = pr.sigmas;
    let p0 = SMatrix::<f64, 15, 15>::from_diagonal(&X::from_fn(|i, _| {
        let k = [1, 2, 0, 3, 4][i / 3]; // state order p, v, rot, ba, bg -> sigma index
        s[k] * s[k]
    }));
    // process noise for a 1 s step, scaled by dt in predict
    let q = SMatrix::<f64, 15, 15>::from_diagonal(&X::from_fn(|i, _| match i / 3 {
        0 => ip.integration_sigma.powi(2),
        1 => ip.acc_noise_density.powi(2),
        2 => ip.gyro_noise_density.powi(2),
        3 => ip.acc_bias_rw.powi(2),
        _ => ip.gyro_bias_rw.powi(2),
    }));
    let mut cfg = UkfConfig::plain(0.5, 2.0, 0.0);
    cfg.p_floor = 1e-15;
    cfg.p_rel_floor = 1e-14;
    let mut ukf: Ukf<f64, 15, 31, NavSpace> = Ukf::new(cfg, x0, p0, q).map_err(err)?;

    let r_bd = so3::exp(&Vector3::from(c.dvl_rotvec_body));
    let dvl_lever = Vector3::from(c.dvl_lever_body_m);
    let usbl_lever = Vector3::from(c.usbl_lever_body_m);
    let chi = gate::chi2_999::<f64>(3);

    // events: (time, kind, index); IMU samples drive the prediction between events
    let mut evs: Vec<(f64, bool, usize)> = log.dvl.iter().enumerate().map(|(i, d)| (d.t_s, true, i)).collect();
    evs.extend(log.usbl.iter().enumerate().map(|(i, u)| (u.t_arrival_s, false, i)));
    evs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut out = Vec::with_capacity(evs.len());
    let mut history: VecDeque<(f64, Vector3<f64>)> = VecDeque::new();
    let mut t_now = pr.t_s;
    let mut k = 0usize; // current IMU sample index (held on [t_k, t_k+1))
    let imu = &log.imu;
    let predict_to = |ukf: &mut Ukf<f64, 15, 31, NavSpace>,
                      t_to: f64,
                      t_now: &mut f64,
                      k: &mut usize,
                      history: &mut VecDeque<(f64, Vector3<f64>)>|
     -> Result<(), FgoError> {
        while *t_now < t_to {
            while *k + 1 < imu.len() && imu[*k + 1].t_s <= *t_now {
                *k += 1;
            }
            let seg_end = imu.get(*k + 1).map_or(t_to, |n| n.t_s.min(t_to));
            let dt = seg_end - *t_now;
            if dt <= 0.0 {
                break;
            }
            let acc = Vector3::from(imu[*k].acc_mps2);
            let gyro = Vector3::from(imu[*k].gyro_radps);
            ukf.predict(dt, |x| {
                let r = rot(x);
                let a = r * (acc - Vector3::new(x[9], x[10], x[11])) + g;
                let w = gyro - Vector3::new(x[12], x[13], x[14]);
                let mut y = *x;
                let v = Vector3::new(x[3], x[4], x[5]);
                y.fixed_rows_mut::<3>(0).copy_from(&(Vector3::new(x[0], x[1], x[2]) + v * dt + a * (0.5 * dt * dt)));
                y.fixed_rows_mut::<3>(3).copy_from(&(v + a * dt));
                y.fixed_rows_mut::<3>(6).copy_from(&so3::log(&(r * so3::exp(&(w * dt)))));
                y
            })
            .map_err(err)?;
            *t_now = seg_end;
            let xs = ukf.x();
            history.push_back((*t_now, Vector3::new(xs[0], xs[1], xs[2])));
            while history.front().is_some_and(|(t, _)| *t < *t_now - 30.0) {
                history.pop_front();
            }
        }
        Ok(())
    };
    let mut dvl_noise: Option<MeasNoise<f64, 3>> = None;
    let mut usbl_noise: Option<MeasNoise<f64, 3>> = None;
    for (t, is_dvl, i) in evs {
        if t <= pr.t_s {
            continue;
        }
        predict_to(&mut ukf, t, &mut t_now, &mut k, &mut history)?;
        if is_dvl {
            let d = &log.dvl[i];
            let z = Vector3::from(d.vel_dvl_mps);
            let gyro = Vector3::from(imu[k].gyro_radps);
            let n = dvl_noise.get_or_insert_with(|| {
                let mut m = MeasNoise::new(SMatrix::<f64, 3, 3>::identity() * d.sigma_mps.powi(2)).with_gate(chi, 1e4, 10);
                m.adapt = false;
                m
            });
            n.r = SMatrix::<f64, 3, 3>::identity() * d.sigma_mps.powi(2);
            ukf.update::<3, subnav_core::ukf::Euclidean, _>(&z, n, |x| {
                let r = rot(x);
                let w = gyro - Vector3::new(x[12], x[13], x[14]);
                r_bd.transpose() * (r.transpose() * Vector3::new(x[3], x[4], x[5]) + w.cross(&dvl_lever))
            })
            .map_err(err)?;
        } else {
            let u = &log.usbl[i];
            // displacement since the valid time from the filter's own track
            let p_valid = history
                .iter()
                .rev()
                .find(|(th, _)| *th <= u.t_valid_s)
                .map(|(_, p)| *p)
                .unwrap_or_else(|| Vector3::new(ukf.x()[0], ukf.x()[1], ukf.x()[2]));
            let p_now = Vector3::new(ukf.x()[0], ukf.x()[1], ukf.x()[2]);
            let z = Vector3::from(u.pos_enu_m) + (p_now - p_valid);
            let r = SMatrix::<f64, 3, 3>::from_diagonal(&Vector3::new(u.sigma_h_m.powi(2), u.sigma_h_m.powi(2), u.sigma_v_m.powi(2)));
            let n = usbl_noise.get_or_insert_with(|| {
                let mut m = MeasNoise::new(r).with_gate(chi, 1e4, 3);
                m.adapt = false;
                m
            });
            n.r = r;
            let rep = ukf
                .update::<3, subnav_core::ukf::Euclidean, _>(&z, n, |x| Vector3::new(x[0], x[1], x[2]) + rot(x) * usbl_lever)
                .map_err(err)?;
            if std::env::var_os("FGO_UKF_DEBUG").is_some() {
                eprintln!(
                    "usbl t {t:.1} nis {:.2} gate {:.2} acc {} Ppos {:.2} {:.2} Pvel {:.3}",
                    rep.nis,
                    rep.nis_gate,
                    rep.accepted,
                    ukf.p()[(0, 0)],
                    ukf.p()[(1, 1)],
                    ukf.p()[(3, 3)]
                );
            }
        }
        out.push(Estimate { id: out.len(), t_s: t, state: state_of(ukf.x()) });
    }
    Ok(out)
}
