//! Measurements fused at their own (past) time of validity ([`super::history`]).
//!
//! The reference is never the code under test: a fix fed late is compared with the same fix fed
//! on time to an identical filter (same IMU samples), and the truth is a bare strapdown of the
//! same samples from the true initial state.

use nalgebra::{UnitQuaternion, Vector3};

use super::dvl::{DvlMeasurement, DvlMounting};
use super::history::{CURRENT_WITHIN_US, HISTORY_LEN, HISTORY_SPACING_US};
use super::strapdown::{self, Increments};
use super::*;
use subnav_wire::messages::ImuSample;

const DT_US: u64 = 10_000;
const SPEED_MPS: f32 = 1.5;

/// Yaw rate, rad/s, of the test manoeuvre at `t` s: a turn that changes direction.
fn yaw_rate(t: f32) -> f32 {
    0.08 * libm::cosf(0.15 * t)
}
/// Forward acceleration, m/s^2.
fn surge_accel(t: f32) -> f32 {
    0.3 * libm::sinf(0.7 * t)
}

/// The IMU sample ending at step `k` (level vehicle, forward speed u(t), yaw rate r(t)):
/// specific force (u', r u, -g) in body FRD, gyro (0, 0, r).
fn imu(k: u64) -> ImuSample {
    let t = k as f32 * DT_US as f32 * 1e-6;
    let u = SPEED_MPS + 0.3 / 0.7 * (1.0 - libm::cosf(0.7 * t));
    let r = yaw_rate(t);
    ImuSample { t_us: k * DT_US, gyro_radps: [0.0, 0.0, r], accel_mps2: [surge_accel(t), r * u, -9.81], temp_c: 10.0 }
}

fn truth_init() -> NominalState {
    NominalState {
        att_nb: UnitQuaternion::identity(),
        vel_ned_mps: Vector3::new(SPEED_MPS, 0.0, 0.0),
        pos_ned_m: Vector3::new(0.0, 0.0, 10.0),
        gyro_bias_radps: Vector3::zeros(),
        accel_bias_mps2: Vector3::zeros(),
        gyro_markov_radps: Vector3::zeros(),
    }
}

/// Truth: the bare strapdown of the same samples from the true initial state, at step `k`.
fn truth(k_end: u64) -> NominalState {
    let mut n = truth_init();
    let mut inc = Increments::zero();
    for k in 1..=k_end {
        let s = imu(k);
        strapdown::step(&mut n, &mut inc, &Vector3::from(s.gyro_radps), &Vector3::from(s.accel_mps2), 0.01, 9.81);
    }
    n
}

/// A filter started 5 m north, 3 m east of the truth, 0.2 m/s off in velocity, 10 m / 0.5 m/s
/// initial sigmas (so one fix moves it by metres), at step 0 (the first sample is step 0), with
/// the default attitude and gyro-bias sigmas (20 mrad tilt, 2 mrad/s).
fn filter() -> NavFilter15 {
    filter_with(false)
}

/// [`filter`]; `aligned`: attitude and gyro-bias sigmas as after an alignment (3 mrad tilt,
/// 50 mrad heading, 0.5 mrad/s).
fn filter_with(aligned: bool) -> NavFilter15 {
    let mut cfg = NavConfig { init_sigma_pos_m: 10.0, init_sigma_vel_mps: 0.5, ..NavConfig::default() };
    if aligned {
        cfg.init_sigma_att_rad = [0.003, 0.003, 0.05];
        cfg.init_sigma_gyro_bias = 5e-4;
    }
    let t = truth_init();
    let init = NavInit {
        t_us: 0,
        att_nb: t.att_nb,
        vel_ned_mps: t.vel_ned_mps + Vector3::new(-0.2, 0.15, 0.0),
        pos_ned_m: t.pos_ned_m + Vector3::new(5.0, 3.0, 0.0),
    };
    let mut nav = NavFilter15::new(cfg, init).unwrap();
    nav.propagate(&imu(0)).unwrap();
    nav
}

fn run(nav: &mut NavFilter15, from: u64, to: u64) {
    for k in from..=to {
        nav.propagate(&imu(k)).unwrap();
    }
}

const FIX_COV: [f32; 6] = [1.0, 0.0, 0.0, 1.0, 0.0, 1.0];

fn fix_at(k: u64) -> [f32; 3] {
    let p = truth(k).pos_ned_m;
    // A fix with an error of its own (not the truth): 0.7 m north, -0.4 m east, 0.2 m down.
    [p.x + 0.7, p.y - 0.4, p.z + 0.2]
}

fn pos(nav: &NavFilter15) -> Vector3<f32> {
    nav.nominal().pos_ned_m
}
fn vel(nav: &NavFilter15) -> Vector3<f32> {
    nav.nominal().vel_ned_mps
}

/// (position effect of the fix, late vs on time: position, velocity; as-current vs on time:
/// position) for a fix valid at 10 s that arrives at 13 s, run to 15 s.
fn fix_case(aligned: bool) -> (f32, f32, f32, f32) {
    let (k_m, k_late, k_end) = (1000u64, 1300u64, 1500u64);
    let z = fix_at(k_m);
    // Reference: on time.
    let mut on_time = filter_with(aligned);
    run(&mut on_time, 1, k_m);
    assert!(on_time.update_position(k_m * DT_US, z, FIX_COV).unwrap().accepted);
    run(&mut on_time, k_m + 1, k_end);
    // Late, at its own time.
    let mut late = filter_with(aligned);
    run(&mut late, 1, k_late);
    let rep = late.update_position(k_m * DT_US, z, FIX_COV).unwrap();
    assert!(rep.accepted, "nis {}", rep.nis);
    assert_eq!((late.delayed_updates(), late.delay_rejects()), (1, 0));
    run(&mut late, k_late + 1, k_end);
    // The old behaviour: the late fix fused as if it were current.
    let mut as_current = filter_with(aligned);
    run(&mut as_current, 1, k_late);
    assert!(as_current.update_position(k_late * DT_US, z, FIX_COV).unwrap().accepted);
    assert_eq!(as_current.delayed_updates(), 0);
    run(&mut as_current, k_late + 1, k_end);
    // Without the fix.
    let mut none = filter_with(aligned);
    run(&mut none, 1, k_end);

    let effect = (pos(&on_time) - pos(&none)).norm();
    let d_late = (pos(&late) - pos(&on_time)).norm();
    let d_cur = (pos(&as_current) - pos(&on_time)).norm();
    let dv_late = (vel(&late) - vel(&on_time)).norm();
    let dv_cur = (vel(&as_current) - vel(&on_time)).norm();
    let t = truth(k_end);
    println!(
        "aligned {aligned}: fix effect {effect:.3} m; late vs on time: {d_late:.4} m, {dv_late:.5} m/s; as-current vs on time: \
         {d_cur:.3} m, {dv_cur:.4} m/s; errors vs truth: on time {:.3} m, late {:.3} m, as current {:.3} m",
        (pos(&on_time) - t.pos_ned_m).norm(),
        (pos(&late) - t.pos_ned_m).norm(),
        (pos(&as_current) - t.pos_ned_m).norm()
    );
    // The history covers what it should.
    let h = late.history();
    assert_eq!(h.len(), HISTORY_LEN);
    let span = late.t_us() - h.oldest_t_us().unwrap();
    assert!(span >= 4_000_000, "history horizon {span} µs");
    (effect, d_late, dv_late, d_cur)
}

#[test]
fn a_fix_three_seconds_late_ends_where_the_same_fix_on_time_does() {
    // After an alignment: millimetres.
    let (effect, d_late, dv_late, d_cur) = fix_case(true);
    assert!(effect > 3.0, "the fix moved the estimate by only {effect} m");
    assert!(d_late < 0.005 && dv_late < 0.002, "late fix ends {d_late} m, {dv_late} m/s from the on-time one");
    // Fused as current, the 3 s of travel (~4.5 m) become a position error.
    assert!(d_cur > 2.0 && d_cur > 100.0 * d_late, "as-current {d_cur} m vs late {d_late} m");
    // With the default (unaligned) 20 mrad tilt and 2 mrad/s gyro-bias sigmas: centimetres. The
    // rest is second order in the tilt sigma (sigma^2 g T^2 ~ 4e-4 x 44 m = 2 cm): the on-time
    // filter meets that nonlinearity in 30 short predicts, the late one in one mapping.
    let (effect, d_late, dv_late, d_cur) = fix_case(false);
    assert!(effect > 3.0, "the fix moved the estimate by only {effect} m");
    assert!(d_late < 0.05 && dv_late < 0.015, "late fix ends {d_late} m, {dv_late} m/s from the on-time one");
    assert!(d_cur > 2.0 && d_cur > 50.0 * d_late, "as-current {d_cur} m vs late {d_late} m");
}

#[test]
fn the_18_state_filter_fuses_a_late_fix_like_an_on_time_one() {
    let mk = || {
        let cfg =
            NavConfig { init_sigma_pos_m: 10.0, init_sigma_vel_mps: 0.5, init_sigma_att_rad: [0.003, 0.003, 0.05], ..NavConfig::default() };
        let t = truth_init();
        let init = NavInit { t_us: 0, att_nb: t.att_nb, vel_ned_mps: t.vel_ned_mps, pos_ned_m: t.pos_ned_m + Vector3::new(5.0, 3.0, 0.0) };
        let mut nav = NavFilter18::new(cfg, init).unwrap();
        nav.propagate(&imu(0)).unwrap();
        nav
    };
    let (k_m, k_late, k_end) = (1000u64, 1250u64, 1400u64);
    let z = fix_at(k_m);
    let (mut a, mut b) = (mk(), mk());
    for k in 1..=k_end {
        a.propagate(&imu(k)).unwrap();
        b.propagate(&imu(k)).unwrap();
        if k == k_m {
            assert!(a.update_position(k_m * DT_US, z, FIX_COV).unwrap().accepted);
        }
        if k == k_late {
            assert!(b.update_position(k_m * DT_US, z, FIX_COV).unwrap().accepted);
        }
    }
    let d = (a.nominal().pos_ned_m - b.nominal().pos_ned_m).norm();
    assert_eq!(b.delayed_updates(), 1);
    assert!(d < 0.005, "18-state: late fix ends {d} m from the on-time one");
    assert!(b.nominal().gyro_markov_radps.iter().all(|v| v.is_finite()));
}

fn dvl_at(k: u64, nav_mount: &DvlMounting) -> DvlMeasurement {
    // True body velocity: (u, 0, 0) plus w x l, in DVL axes; no noise (the filter's R is 5 cm/s).
    let t = truth(k);
    let s = imu(k);
    let w = Vector3::from(s.gyro_radps);
    let v_b = t.att_nb.inverse_transform_vector(&t.vel_ned_mps) + w.cross(&nav_mount.lever_arm_body_m);
    let v_d = nav_mount.rot_body_from_dvl.inverse_transform_vector(&v_b);
    DvlMeasurement {
        t_us: k * DT_US,
        vel_dvl_mps: [v_d.x, v_d.y, v_d.z],
        covariance_m2ps2: None,
        fom_mps: Some(0.05),
        gyro_radps: s.gyro_radps,
    }
}

fn mount() -> DvlMounting {
    DvlMounting {
        rot_body_from_dvl: UnitQuaternion::from_euler_angles(0.0, 0.0, 45f32.to_radians()),
        lever_arm_body_m: Vector3::new(0.5, 0.0, 0.3),
    }
}

#[test]
fn a_dvl_velocity_300_ms_late_ends_where_the_same_velocity_on_time_does() {
    // Valid at 6.73 s (peak surge deceleration, 0.3 m/s^2: 9 cm/s over the delay), arrives
    // 0.3 s later; run to 8 s.
    let (k_m, k_late, k_end) = (673u64, 703u64, 800u64);
    let m = dvl_at(k_m, &mount());
    let mut on_time = filter();
    run(&mut on_time, 1, k_m);
    assert!(on_time.update_dvl(&m, &mount()).unwrap().accepted);
    run(&mut on_time, k_m + 1, k_end);
    let mut late = filter();
    run(&mut late, 1, k_late);
    assert!(late.update_dvl(&m, &mount()).unwrap().accepted);
    assert_eq!(late.delayed_updates(), 1);
    run(&mut late, k_late + 1, k_end);
    let mut as_current = filter();
    run(&mut as_current, 1, k_late);
    assert!(as_current.update_dvl(&DvlMeasurement { t_us: k_late * DT_US, ..m }, &mount()).unwrap().accepted);
    run(&mut as_current, k_late + 1, k_end);
    let mut none = filter();
    run(&mut none, 1, k_end);

    let effect = (vel(&on_time) - vel(&none)).norm();
    let d_late = (vel(&late) - vel(&on_time)).norm();
    let d_cur = (vel(&as_current) - vel(&on_time)).norm();
    let dp_late = (pos(&late) - pos(&on_time)).norm();
    println!("DVL effect {effect:.4} m/s; late vs on time {d_late:.5} m/s ({dp_late:.5} m); as-current vs on time {d_cur:.4} m/s");
    assert!(effect > 0.1, "the DVL moved the velocity by only {effect} m/s");
    assert!(d_late < 0.002, "late DVL ends {d_late} m/s from the on-time one");
    assert!(dp_late < 0.005, "late DVL position {dp_late} m from the on-time one");
    assert!(d_cur > 0.03 && d_cur > 10.0 * d_late, "as-current {d_cur} m/s vs late {d_late} m/s");
}

/// Everything a refused measurement must leave alone.
fn snapshot(
    nav: &NavFilter15,
) -> (NominalState, nalgebra::SMatrix<f32, 15, 15>, nalgebra::SVector<f32, 15>, std::vec::Vec<super::history::Snapshot>) {
    let h = nav.history();
    (*nav.nominal(), *nav.covariance(), *nav.ukf().x(), (0..h.len()).filter_map(|i| h.get(i).copied()).collect())
}

#[test]
fn too_old_and_from_the_future_are_refused_with_the_state_untouched() {
    let mut nav = filter();
    run(&mut nav, 1, 605); // 6.05 s: the history is full; the covariance interval is partial
    let t_now = nav.t_us();
    let oldest = nav.history().oldest_t_us().unwrap();
    let max_future = nav.config().max_future_us;
    let z = fix_at(300);
    let m = dvl_at(300, &mount());
    let before = snapshot(&nav);
    let cases: [(u64, NavError); 4] = [
        (oldest - 1, NavError::TooOld),
        (0, NavError::TooOld),
        (t_now + max_future + 1, NavError::FromFuture),
        (u64::MAX, NavError::FromFuture),
    ];
    let mut n = 0;
    for (t, e) in cases {
        assert_eq!(nav.update_position(t, z, FIX_COV).map(|_| ()), Err(e), "fix at {t}");
        assert_eq!(nav.update_dvl(&DvlMeasurement { t_us: t, ..m }, &mount()).map(|_| ()), Err(e), "DVL at {t}");
        assert_eq!(nav.update_body_velocity(t, [1.5, 0.0, 0.0], None).map(|_| ()), Err(e), "velocity at {t}");
        n += 3;
        assert_eq!(snapshot(&nav), before, "state changed by a refused measurement at {t}");
    }
    assert_eq!(nav.delay_rejects(), n);
    assert_eq!((nav.delayed_updates(), nav.input_rejects()), (0, 0));
    // The boundaries are fused: the oldest entry itself (delayed), up to max_future (current),
    // within CURRENT_WITHIN_US before now (current), just beyond it (delayed).
    let d0 = nav.delayed_updates();
    nav.update_body_velocity(oldest, [1.5, 0.0, 0.0], Some(1.0)).unwrap();
    assert_eq!(nav.delayed_updates(), d0 + 1);
    nav.update_body_velocity(t_now + max_future, [1.5, 0.0, 0.0], Some(1.0)).unwrap();
    nav.update_body_velocity(t_now - CURRENT_WITHIN_US, [1.5, 0.0, 0.0], Some(1.0)).unwrap();
    assert_eq!(nav.delayed_updates(), d0 + 1);
    nav.update_body_velocity(t_now - CURRENT_WITHIN_US - 1, [1.5, 0.0, 0.0], Some(1.0)).unwrap();
    assert_eq!(nav.delayed_updates(), d0 + 2);
    assert_eq!(nav.delay_rejects(), n);
    // The error messages name the reason.
    assert!(NavError::TooOld.to_string().contains("too old"));
    assert!(NavError::FromFuture.to_string().contains("future"));
}

#[test]
fn history_stays_on_its_grid_and_an_imu_gap_restarts_it() {
    let mut nav = filter();
    // Just after new and the first sample: one entry, the start.
    assert_eq!((nav.history().len(), nav.history().oldest_t_us()), (1, Some(0)));
    // A first sample within max_imu_dt_s of the initial time keeps the initial entry; one later
    // than that restarts the history at its own time.
    let init = NavInit { t_us: 1_000, att_nb: UnitQuaternion::identity(), vel_ned_mps: Vector3::zeros(), pos_ned_m: Vector3::zeros() };
    let mut a = NavFilter15::new(NavConfig::default(), init).unwrap();
    a.propagate(&imu(1)).unwrap();
    assert_eq!((a.history().len(), a.history().oldest_t_us()), (1, Some(1_000)));
    a.propagate(&imu(2)).unwrap();
    assert!(a.update_position(5_000, [0.0, 0.0, 0.0], FIX_COV).is_ok());
    assert_eq!(a.delayed_updates(), 1);
    let mut b = NavFilter15::new(NavConfig::default(), init).unwrap();
    b.propagate(&imu(30)).unwrap();
    assert_eq!((b.history().len(), b.history().oldest_t_us()), (1, Some(300_000)));
    run(&mut nav, 1, 700);
    let h = nav.history();
    assert_eq!(h.len(), HISTORY_LEN);
    for i in 1..h.len() {
        let (a, b) = (h.get(i - 1).unwrap().t_us, h.get(i).unwrap().t_us);
        assert!(b - a == HISTORY_SPACING_US, "entries {a} -> {b}");
    }
    assert!(h.get(HISTORY_LEN).is_none());
    // A 0.5 s gap (max_imu_dt_s 0.1): refused, the nominal did not move; the history restarts
    // at the gap's end, so a fix from before the gap is too old, and one after it is fused.
    let t_gap_end = 750 * DT_US;
    assert_eq!(nav.propagate(&imu(750)), Err(NavError::BadTime));
    assert_eq!(nav.history().len(), 1);
    assert_eq!(nav.history().oldest_t_us(), Some(t_gap_end));
    run(&mut nav, 751, 900);
    assert_eq!(nav.update_position(700 * DT_US, fix_at(700), FIX_COV).map(|_| ()), Err(NavError::TooOld));
    assert_eq!(nav.delay_rejects(), 1);
    let rep = nav.update_position(800 * DT_US, fix_at(800), FIX_COV).unwrap();
    assert!(rep.accepted);
    assert_eq!(nav.delayed_updates(), 1);
    assert!(nav.nominal().is_finite());
    // Reinit clears it.
    let init = NavInit { t_us: 5_000_000, att_nb: UnitQuaternion::identity(), vel_ned_mps: Vector3::zeros(), pos_ned_m: Vector3::zeros() };
    nav.reinit(*nav.config(), init).unwrap();
    assert_eq!((nav.history().len(), nav.history().oldest_t_us()), (1, Some(5_000_000)));
    assert_eq!((nav.delayed_updates(), nav.delay_rejects()), (0, 0));
}

#[test]
fn the_history_carries_the_corrections_so_the_same_fix_twice_barely_moves_the_state() {
    let mut nav = filter();
    run(&mut nav, 1, 1300);
    let z = fix_at(1000);
    let p0 = pos(&nav);
    nav.update_position(1000 * DT_US, z, FIX_COV).unwrap();
    let first = (pos(&nav) - p0).norm();
    // The past the filter compares with is the corrected one: at the fix time, the corrected
    // history now sits near the fix (its correction applied: it is deferred to the next read).
    nav.flush_history();
    let ep = nav.history().epoch(1000 * DT_US, nav.t_us(), nav.nominal(), 9.81, 300.0).unwrap();
    let resid = (ep.nom.pos_ned_m - Vector3::from(z)).norm();
    let p1 = pos(&nav);
    let rep = nav.update_position(1000 * DT_US, z, FIX_COV).unwrap();
    assert!(rep.accepted);
    let second = (pos(&nav) - p1).norm();
    println!("first late fix moved {first:.3} m; residual against the corrected past {resid:.3} m; second moved {second:.4} m");
    assert!(first > 3.0, "{first}");
    assert!(resid < 0.1, "corrected past {resid} m from the fix");
    // Uncorrected, the second would see the full residual again and move ~half of it.
    assert!(second < 0.02 * first, "second fusion of the same fix moved {second} m (first {first} m)");
}

#[test]
fn nan_in_a_delayed_measurement_is_refused_and_leaves_no_nan() {
    let mut nav = filter();
    run(&mut nav, 1, 605);
    let before = snapshot(&nav);
    let t = 400 * DT_US;
    let m = dvl_at(400, &mount());
    for bad in [f32::NAN, f32::INFINITY] {
        assert_eq!(nav.update_position(t, [bad, 0.0, 10.0], FIX_COV).map(|_| ()), Err(NavError::NonFinite));
        assert_eq!(nav.update_position(t, fix_at(400), [1.0, 0.0, 0.0, bad, 0.0, 1.0]).map(|_| ()), Err(NavError::NonFinite));
        assert_eq!(nav.update_dvl(&DvlMeasurement { vel_dvl_mps: [1.0, bad, 0.0], ..m }, &mount()).map(|_| ()), Err(NavError::NonFinite));
        assert_eq!(nav.update_body_velocity(t, [bad, 0.0, 0.0], None).map(|_| ()), Err(NavError::NonFinite));
    }
    assert_eq!(snapshot(&nav), before);
    assert_eq!(nav.input_rejects(), 8);
    assert_eq!((nav.delayed_updates(), nav.delay_rejects()), (0, 0));
    // A good delayed one afterwards is fused, and everything stays finite.
    assert!(nav.update_dvl(&m, &mount()).unwrap().accepted);
    let h = nav.history();
    assert!(nav.nominal().is_finite() && nav.covariance().iter().all(|v| v.is_finite()));
    assert!((0..h.len()).all(|i| {
        h.get(i).is_some_and(|e| e.att_nb.coords.iter().chain(e.vel_ned_mps.iter()).chain(e.pos_ned_m.iter()).all(|v| v.is_finite()))
    }));
}

#[test]
fn a_late_fix_while_coasting_matches_the_on_time_one() {
    // The IMU is gone; the filter coasts at constant velocity, a fix arrives 1.5 s late.
    let mut a = filter();
    run(&mut a, 1, 500);
    let mut b = a.clone();
    let t0 = a.t_us();
    let z = {
        let p = pos(&a);
        [p.x - 2.0, p.y + 1.0, p.z]
    };
    let (t_m, t_late) = (t0 + 1_000_000, t0 + 2_500_000);
    for t in (t0 + 100_000..=t_m).step_by(100_000) {
        a.coast(t, 0.01, 0.05).unwrap();
    }
    assert!(a.update_position(t_m, z, FIX_COV).unwrap().accepted);
    for t in (t_m + 100_000..=t_late).step_by(100_000) {
        a.coast(t, 0.01, 0.05).unwrap();
    }
    for t in (t0 + 100_000..=t_late).step_by(100_000) {
        b.coast(t, 0.01, 0.05).unwrap();
    }
    assert!(b.update_position(t_m, z, FIX_COV).unwrap().accepted);
    assert_eq!(b.delayed_updates(), 1);
    let (dp, dv) = ((pos(&a) - pos(&b)).norm(), (vel(&a) - vel(&b)).norm());
    println!("coasting: late vs on time {dp:.4} m, {dv:.5} m/s");
    assert!(dp < 0.05 && dv < 0.01, "{dp} m {dv} m/s");
}

#[test]
fn print_filter_size() {
    println!(
        "size_of NavFilter15 = {} B, NavFilter18 = {} B, History = {} B, Snapshot = {} B",
        core::mem::size_of::<NavFilter15>(),
        core::mem::size_of::<NavFilter18>(),
        core::mem::size_of::<super::history::History>(),
        core::mem::size_of::<super::history::Snapshot>()
    );
}

/// 200 updates of one kind after 6 s of IMU, for instruction counts under callgrind:
/// `SUBNAV_DELAY_COST=setup|fix_current|fix_late|dvl_current|dvl_late cargo test --release -p
/// subnav-core --features std --lib -- --ignored delayed_update_cost` (the difference to `setup`
/// over 200 is the cost of one update, its injection into the history included).
#[test]
#[ignore = "for callgrind, see the doc comment"]
fn delayed_update_cost() {
    let kind = std::env::var("SUBNAV_DELAY_COST").unwrap_or_default();
    let mut nav = filter_with(true);
    run(&mut nav, 1, 600);
    let k = 600u64;
    let t = nav.t_us();
    let (z, z_late, m, m_late, mt) = (fix_at(k), fix_at(k - 200), dvl_at(k, &mount()), dvl_at(k - 30, &mount()), mount());
    let mut accepted = 0u32;
    for _ in 0..200 {
        let ok = match kind.as_str() {
            "fix_current" => nav.update_position(t, z, FIX_COV).is_ok_and(|r| r.accepted),
            "fix_late" => nav.update_position(t - 2_000_000, z_late, FIX_COV).is_ok_and(|r| r.accepted),
            "dvl_current" => nav.update_dvl(&m, &mt).is_ok_and(|r| r.accepted),
            "dvl_late" => nav.update_dvl(&m_late, &mt).is_ok_and(|r| r.accepted),
            _ => std::hint::black_box(true),
        };
        accepted += u32::from(ok);
    }
    println!("{kind}: {accepted} of 200 accepted, {} delayed", nav.delayed_updates());
}

/// Five simulated seconds at the head's rates, as `nav.five_seconds_at_head_rates` of
/// `cargo xtask bench-target` runs them, for a function-level profile on the host:
/// `valgrind --tool=callgrind` on `cargo test --release -p subnav-core --features std --lib --
/// --ignored head_rates_profile` (then `callgrind_annotate --inclusive=yes`).
#[test]
#[ignore = "for callgrind, see the doc comment"]
fn head_rates_profile() {
    use crate::head;
    let imu = |t_us: u64| ImuSample { t_us, gyro_radps: [0.001, -0.002, 0.01], accel_mps2: [0.05, 0.01, -9.81], temp_c: 10.0 };
    let init = NavInit {
        t_us: 0,
        att_nb: UnitQuaternion::from_euler_angles(0.01, -0.02, 0.5),
        vel_ned_mps: Vector3::new(1.0, 0.5, 0.0),
        pos_ned_m: Vector3::new(0.0, 0.0, 10.0),
    };
    let mut nav = NavFilter15::new(head::nav_config(), init).unwrap();
    let mut t = 0u64;
    for _ in 0..1000 {
        t += 5_000;
        let _ = nav.propagate(&imu(t));
    }
    let mount = head::dvl_mounting();
    let mut accepted = 0u32;
    for _rep in 0..3 {
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
                let v_b = nav.nominal().att_nb.inverse_transform_vector(&nav.nominal().vel_ned_mps);
                let v_d = mount.rot_body_from_dvl.inverse_transform_vector(&v_b);
                let m = DvlMeasurement {
                    t_us: t.saturating_sub(100_000),
                    vel_dvl_mps: [v_d.x, v_d.y, v_d.z],
                    covariance_m2ps2: None,
                    fom_mps: Some(0.01),
                    gyro_radps: [0.0; 3],
                };
                accepted += u32::from(nav.update_dvl(&m, &mount).is_ok_and(|r| r.accepted));
            }
            if k == 500 {
                let p = nav.nominal().pos_ned_m;
                let fix = nav.update_position(t.saturating_sub(3_000_000), [p.x, p.y, p.z], [4.0, 0.0, 0.0, 4.0, 0.0, 4.0]);
                accepted += u32::from(fix.is_ok_and(|r| r.accepted));
            }
        }
    }
    println!("accepted {accepted}, predicts {}", nav.ukf().health().predicts);
}
