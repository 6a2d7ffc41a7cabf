//! A refused step changes nothing, at the navigation filter's level: for every refusal path the
//! whole `NavFilter` (nominal state, pending IMU increments, history, the UKF's state, `P`, `Q`
//! and adaptive accumulators, each sensor's `R` and Sage-Husa / fading statistics) is compared
//! bit for bit before and after; only the counters may move.

use nalgebra::{SMatrix, UnitQuaternion, Vector3};

use super::*;
use crate::ukf::UkfError;
use subnav_wire::messages::ImuSample;

/// The adaptive configuration with every adaptive part on (Q and q too).
fn all_adaptive() -> NavConfig {
    let mut cfg = NavConfig::default().adaptive();
    cfg.ukf.adapt.q_cov = true;
    cfg.ukf.adapt.q_mean = true;
    cfg
}

fn init() -> NavInit {
    NavInit {
        t_us: 0,
        att_nb: UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3),
        vel_ned_mps: Vector3::new(1.0, 0.0, 0.0),
        pos_ned_m: Vector3::zeros(),
    }
}

fn imu(t_us: u64) -> ImuSample {
    ImuSample { t_us, gyro_radps: [0.0, 0.0, 0.001], accel_mps2: [0.0, 0.0, -9.81], temp_c: 10.0 }
}

/// Everything but the counters (and the latest NIS, which reports a rejected measurement too),
/// exactly: `{:?}` prints every float in its shortest round-trip form.
fn snap<const N: usize, const S: usize>(nav: &NavFilter<N, S>) -> String {
    let mut c = nav.clone();
    c.ukf.clear_counters();
    (c.imu_rejects, c.time_rejects, c.delay_rejects, c.nis) = (0, 0, 0, [0.0; 4]);
    for r in [&mut c.noise_heading.consecutive_rejects, &mut c.noise_depth.consecutive_rejects] {
        *r = 0;
    }
    for r in [&mut c.noise_vel.consecutive_rejects, &mut c.noise_pos.consecutive_rejects] {
        *r = 0;
    }
    format!("{c:?}")
}

/// [`snap`] without the Sage-Husa R statistics (R, r, their counter), which a gate rejection
/// feeds with the clipped innovation when R adaptation is on.
fn snap_but_r<const N: usize, const S: usize>(nav: &NavFilter<N, S>) -> String {
    let mut c = nav.clone();
    (c.noise_heading.r, c.noise_heading.r_mean, c.noise_heading.k) = (SMatrix::zeros(), SMatrix::zeros(), 0);
    (c.noise_depth.r, c.noise_depth.r_mean, c.noise_depth.k) = (SMatrix::zeros(), SMatrix::zeros(), 0);
    (c.noise_vel.r, c.noise_vel.r_mean, c.noise_vel.k) = (SMatrix::zeros(), SMatrix::zeros(), 0);
    (c.noise_pos.r, c.noise_pos.r_mean, c.noise_pos.k) = (SMatrix::zeros(), SMatrix::zeros(), 0);
    snap(&c)
}

/// 5 s of IMU, compass, depth, DVL and a fix, ending with an accepted update since the last
/// predict (the Sage-Husa Q accumulators are not empty) and no pending IMU increments.
fn warmed(cfg: NavConfig) -> NavFilter15 {
    let mut nav = NavFilter15::new(cfg, init()).unwrap();
    for k in 0..=500u64 {
        let t = k * 10_000;
        nav.propagate(&imu(t)).unwrap();
        if k % 20 == 0 {
            let _ = nav.update_heading(t, 0.3 + 0.001 * k as f32 / 500.0, None).unwrap();
            let _ = nav.update_depth(t, 0.01, None).unwrap();
            let _ = nav.update_body_velocity(t, [1.0, 0.01, 0.0], None).unwrap();
        }
    }
    let t = nav.t_us();
    assert!(nav.update_position(t, [3.0, 0.9, 0.0], [1.0, 0.0, 0.0, 1.0, 0.0, 1.0]).unwrap().accepted);
    nav
}

#[test]
fn refused_navigation_steps_change_nothing() {
    let base = warmed(all_adaptive());
    let t = base.t_us();
    type Step = fn(&mut NavFilter15, u64) -> Result<bool, NavError>;
    let cases: [(&str, Step, Result<bool, NavError>); 14] = [
        (
            "IMU NaN",
            |n, t| n.propagate(&ImuSample { gyro_radps: [f32::NAN, 0.0, 0.0], ..imu(t + 10_000) }).map(|_| true),
            Err(NavError::NonFinite),
        ),
        ("IMU not after the last", |n, t| n.propagate(&imu(t)).map(|_| true), Err(NavError::BadTime)),
        ("heading NaN", |n, t| n.update_heading(t, f32::NAN, None).map(|r| r.accepted), Err(NavError::NonFinite)),
        ("heading sigma Inf", |n, t| n.update_heading(t, 0.3, Some(f32::INFINITY)).map(|r| r.accepted), Err(NavError::NonFinite)),
        ("heading gated", |n, t| n.update_heading(t, 1.3, None).map(|r| r.accepted), Ok(false)),
        ("depth NaN", |n, t| n.update_depth(t, f32::NAN, None).map(|r| r.accepted), Err(NavError::NonFinite)),
        ("depth gated", |n, t| n.update_depth(t, 50.0, None).map(|r| r.accepted), Ok(false)),
        ("DVL NaN", |n, t| n.update_body_velocity(t, [1.0, f32::NAN, 0.0], None).map(|r| r.accepted), Err(NavError::NonFinite)),
        ("DVL gated", |n, t| n.update_body_velocity(t, [5.0, 3.0, 0.0], None).map(|r| r.accepted), Ok(false)),
        ("fix gated", |n, t| n.update_position(t, [300.0, 0.0, 0.0], [1.0, 0.0, 0.0, 1.0, 0.0, 1.0]).map(|r| r.accepted), Ok(false)),
        (
            "fix too old",
            |n, t| n.update_position(t - 4_900_000, [3.0, 0.0, 0.0], [1.0, 0.0, 0.0, 1.0, 0.0, 1.0]).map(|r| r.accepted),
            Err(NavError::TooOld),
        ),
        (
            "fix from the future",
            |n, t| n.update_position(t + 1_000_000, [3.0, 0.0, 0.0], [1.0, 0.0, 0.0, 1.0, 0.0, 1.0]).map(|r| r.accepted),
            Err(NavError::FromFuture),
        ),
        (
            "fix covariance not PD",
            |n, t| n.update_position(t, [3.0, 0.0, 0.0], [1.0, 2.0, 0.0, 1.0, 0.0, 1.0]).map(|r| r.accepted),
            Err(NavError::NonFinite),
        ),
        ("covariance NaN", |n, _| n.set_covariance(SMatrix::from_element(f32::NAN)).map(|_| true), Err(NavError::NonFinite)),
    ];
    for (name, step, want) in cases {
        let mut nav = base.clone();
        let (before, before_but_r) = (snap(&nav), snap_but_r(&nav));
        assert_eq!(step(&mut nav, t), want, "{name}");
        if want == Ok(false) {
            // Gated: everything but the Sage-Husa R statistics, which take the clipped innovation.
            assert_eq!(snap_but_r(&nav), before_but_r, "{name}: a gate rejection changed the filter");
        } else {
            assert_eq!(snap(&nav), before, "{name}: a refused step changed the filter");
        }
    }
    // The position fix brings its own covariance (no R adaptation): its rejection changes
    // nothing at all but the counts.
    let mut nav = base.clone();
    let before = snap(&nav);
    assert!(!nav.update_position(t, [300.0, 0.0, 0.0], [1.0, 0.0, 0.0, 1.0, 0.0, 1.0]).unwrap().accepted);
    assert_eq!(snap(&nav), before);
    assert_eq!(nav.health().gate_rejects, base.health().gate_rejects + 1);
}

/// Without the adaptive layer a gate rejection changes nothing but the counts, and the filter
/// goes on exactly as one that never saw the rejected measurements.
#[test]
fn without_adaptation_a_gated_filter_goes_on_as_if_never_asked() {
    let base = warmed(NavConfig::default());
    let t = base.t_us();
    let mut nav = base.clone();
    let before = snap(&nav);
    assert!(!nav.update_heading(t, 1.3, None).unwrap().accepted);
    assert!(!nav.update_body_velocity(t, [5.0, 3.0, 0.0], None).unwrap().accepted);
    assert_eq!(snap(&nav), before);
    assert_eq!(nav.health().gate_rejects, base.health().gate_rejects + 2);
    let mut twin = base.clone();
    for k in 1..=50u64 {
        let tk = t + k * 10_000;
        nav.propagate(&imu(tk)).unwrap();
        twin.propagate(&imu(tk)).unwrap();
    }
    let tk = t + 500_000;
    assert_eq!(nav.update_heading(tk, 0.3, None), twin.update_heading(tk, 0.3, None));
    assert_eq!(snap(&nav), snap(&twin));
}

/// With the adaptive layer off a sensor brings its own sigma; a gated measurement used to leave
/// its variance in R. Now R is the one of the last accepted measurement.
#[test]
fn a_gated_measurement_leaves_no_noise_behind() {
    let mut nav = warmed(NavConfig::default());
    let t = nav.t_us();
    let before = snap(&nav);
    assert!(!nav.update_heading(t, 1.3, Some(0.02)).unwrap().accepted);
    assert_eq!(snap(&nav), before);
}

/// A predict that fails after the Sage-Husa Q step (position and velocity variances near the
/// f32 limit: the propagated position variance, `P_pp + 2 T P_pv + T^2 P_vv`, overflows) leaves
/// Q, q, the accumulators and the pending IMU increments as they were, so the next predict still
/// covers the interval.
#[test]
fn a_refused_adaptive_predict_changes_nothing() {
    let mut nav = warmed(all_adaptive());
    let mut p = *nav.covariance();
    let (v, x) = (super::state::VEL, super::state::POS);
    for i in 0..15 {
        for j in [v, x] {
            p[(j, i)] = 0.0;
            p[(i, j)] = 0.0;
        }
    }
    (p[(v, v)], p[(x, x)], p[(v, x)], p[(x, v)]) = (3.3e38, 3.3e38, 1.65e38, 1.65e38);
    nav.set_covariance(p).unwrap();
    let t = nav.t_us();
    for k in 1..=9u64 {
        nav.propagate(&imu(t + k * 10_000)).unwrap();
    }
    assert_eq!(nav.inc.samples, 9);
    let before = snap(&nav);
    assert_eq!(nav.flush_covariance(), Err(NavError::Filter(UkfError::NonFiniteResult)));
    assert_eq!(snap(&nav), before);
    assert_eq!(nav.inc.samples, 9);
}

/// An update whose posterior covariance is exactly singular and cannot be repaired (no floor):
/// refused as `CovarianceUnrepairable`, nothing changed, and reported in the health as its own
/// counter, not as a non-finite rejection. Weights alpha = 1, beta = 0, kappa = 1 on 15 states
/// are dyadic (gamma = 4, weights 1/16 and 1/32) and P starts diagonal with a unit depth
/// variance, so a depth with (nearly) no noise makes the posterior depth variance exactly 0.
#[test]
fn an_unrepairable_covariance_is_refused_and_reported() {
    let mut cfg = all_adaptive();
    (cfg.ukf.alpha, cfg.ukf.beta, cfg.ukf.kappa) = (1.0, 0.0, 1.0);
    (cfg.ukf.p_floor, cfg.ukf.p_rel_floor) = (0.0, 0.0);
    cfg.init_sigma_pos_m = 1.0;
    cfg.depth.adapt = false;
    // Depth noise 1e-20 m^2: S = 1 + 1e-20 rounds to 1 in f32, so the posterior depth variance
    // 1 - 1 * 1 is exactly 0.
    cfg.depth.sigma = 1e-10;
    let mut nav = NavFilter15::new(cfg, init()).unwrap();
    let before = snap(&nav);
    assert_eq!(nav.update_depth(0, 0.0, None).map(|r| r.accepted), Err(NavError::Filter(UkfError::CovarianceUnrepairable)));
    assert_eq!(snap(&nav), before);
    let h = nav.health();
    assert_eq!((h.cov_unrepairable, h.nonfinite_rejects, h.pd_repairs), (1, 0, 0));
    // Setting a singular covariance is refused the same way.
    let mut p = *nav.covariance();
    p[(0, 0)] = 0.0;
    assert_eq!(nav.set_covariance(p), Err(NavError::Filter(UkfError::CovarianceUnrepairable)));
    assert_eq!(snap(&nav), before);
    assert_eq!(nav.health().cov_unrepairable, 2);
    // With the sensor head's floor the same update is repaired and accepted.
    cfg.ukf.p_floor = 1e-12;
    let mut nav = NavFilter15::new(cfg, init()).unwrap();
    assert!(nav.update_depth(0, 0.0, None).unwrap().accepted);
    assert_eq!((nav.health().cov_unrepairable, nav.health().pd_repairs), (0, 1));
}
