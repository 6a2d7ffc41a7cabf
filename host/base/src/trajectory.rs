//! Truth trajectory of a simulated dive: descent, then a lawnmower survey of straight legs joined
//! by half-circle turns, level flight (roll = pitch = 0, depth changes by heave). Speed changes
//! (start and end of the descent, start of the survey) are constant-acceleration ramps of
//! `ramp_s`, so the IMU sees them: an instantaneous speed step is invisible to a sampled
//! accelerometer and would make any inertial solution wrong by the step from then on.
//! Kinematics are exact for this motion: body rates `[0, 0, r]`, specific force
//! `R_nb^T (a_n - g_n)` ([`crate::imu::specific_force`]).
//! NED frame, metres from the origin; body FRD.

use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Survey geometry and speeds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Lawnmower {
    /// Survey depth (m, positive down).
    pub depth_m: f64,
    /// Descent rate from the surface (m/s).
    pub descent_mps: f64,
    /// Forward speed (m/s).
    pub speed_mps: f64,
    /// Straight leg length (m).
    pub leg_m: f64,
    /// Spacing between legs (m): turns are half circles of radius spacing / 2.
    pub spacing_m: f64,
    /// Heading of the first leg (rad from north).
    pub heading0_rad: f64,
    /// Time at rest at the start (alignment), s.
    pub rest_s: f64,
    /// Duration of each speed change (constant acceleration), s; 0 = instantaneous steps.
    #[serde(default = "default_ramp_s")]
    pub ramp_s: f64,
    /// 0: parallel legs forever (the pattern moves on sideways). `L > 0` (made odd): a
    /// cross-hatch that keeps crossing its own track: `L` legs, a quarter turn, `L` legs across
    /// the first block, a quarter turn back, and so on (square blocks when
    /// `leg_m = (L - 1) spacing_m`).
    #[serde(default)]
    pub cross_legs: u32,
}

fn default_ramp_s() -> f64 {
    4.0
}

impl Default for Lawnmower {
    fn default() -> Self {
        Self {
            depth_m: 10.0,
            descent_mps: 0.25,
            speed_mps: 1.0,
            leg_m: 60.0,
            spacing_m: 20.0,
            heading0_rad: 0.3,
            rest_s: 15.0,
            ramp_s: default_ramp_s(),
            cross_legs: 0,
        }
    }
}

/// The vehicle's true state at an instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Truth {
    pub t_s: f64,
    pub pos_ned_m: Vector3<f64>,
    pub vel_ned_mps: Vector3<f64>,
    pub att_nb: UnitQuaternion<f64>,
    pub yaw_rad: f64,
    /// Body angular rate (rad/s) and specific force (m/s^2), what a perfect IMU measures.
    pub gyro_radps: Vector3<f64>,
    pub specific_force_mps2: Vector3<f64>,
}

pub const GRAVITY_MPS2: f64 = 9.81;

/// Piecewise motion: forward speed `u + au t`, heave speed `w + aw t`, yaw rate `r` (turns
/// only at constant speed: `au = 0` when `r != 0`).
#[derive(Debug, Clone, Copy)]
struct Segment {
    t0: f64,
    dur: f64,
    u: f64,
    w: f64,
    r: f64,
    au: f64,
    aw: f64,
    // state at the segment start
    p0: Vector3<f64>,
    yaw0: f64,
}

/// A precomputed trajectory with exact evaluation at any time.
#[derive(Debug, Clone)]
pub struct Trajectory {
    segments: Vec<Segment>,
    /// A calibration rig's motion instead of the survey (when not empty).
    rig: Vec<RigSegment>,
    rig_depth_m: f64,
    pub duration_s: f64,
}

/// One step of a calibration rig (a turntable or an indexing fixture holding the head at a fixed
/// place): a turn at a constant rate about a body axis (rate 0: the head is held still).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RigStep {
    pub duration_s: f64,
    /// Unit axis of the turn, body FRD.
    pub axis_body: [f64; 3],
    pub rate_radps: f64,
}

/// A calibration rig's motion: the head at `depth_m` (north and east 0), starting level with
/// heading `heading0_rad`, turned through `steps` in order; still after the last one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RigMotion {
    pub depth_m: f64,
    pub heading0_rad: f64,
    pub steps: Vec<RigStep>,
}

impl RigMotion {
    /// Total length of the steps, s.
    pub fn duration_s(&self) -> f64 {
        self.steps.iter().map(|s| s.duration_s.max(0.0)).sum()
    }
}

#[derive(Debug, Clone, Copy)]
struct RigSegment {
    t0: f64,
    dur: f64,
    att0: UnitQuaternion<f64>,
    axis: Vector3<f64>,
    rate: f64,
}

impl RigSegment {
    fn att(&self, dt: f64) -> UnitQuaternion<f64> {
        self.att0 * UnitQuaternion::from_scaled_axis(self.axis * (self.rate * dt))
    }
}

fn advance(p0: Vector3<f64>, yaw0: f64, s: &Segment, dt: f64) -> (Vector3<f64>, f64) {
    let (u, w, r) = (s.u, s.w, s.r);
    let yaw = yaw0 + r * dt;
    let (dn, de) = if r.abs() < 1e-12 {
        let d = u * dt + 0.5 * s.au * dt * dt;
        (d * yaw0.cos(), d * yaw0.sin())
    } else {
        (u / r * (yaw.sin() - yaw0.sin()), -u / r * (yaw.cos() - yaw0.cos()))
    };
    (p0 + Vector3::new(dn, de, w * dt + 0.5 * s.aw * dt * dt), yaw)
}

impl Trajectory {
    pub fn lawnmower(cfg: &Lawnmower, duration_s: f64) -> Self {
        let mut segs = Vec::new();
        let mut t = 0.0;
        let mut p = Vector3::zeros();
        let mut yaw = cfg.heading0_rad;
        let mut push = |dur: f64, (u, w, r): (f64, f64, f64), (au, aw): (f64, f64), t: &mut f64, p: &mut Vector3<f64>, yaw: &mut f64| {
            if dur <= 0.0 {
                return;
            }
            let seg = Segment { t0: *t, dur, u, w, r, au, aw, p0: *p, yaw0: *yaw };
            let (np, ny) = advance(*p, *yaw, &seg, dur);
            segs.push(seg);
            *t += dur;
            *p = np;
            *yaw = ny;
        };
        let ramp = cfg.ramp_s.max(0.0);
        push(cfg.rest_s, (0.0, 0.0, 0.0), (0.0, 0.0), &mut t, &mut p, &mut yaw);
        if cfg.depth_m > 0.0 && cfg.descent_mps > 0.0 {
            // Ramps cover half their duration's worth of depth each.
            let ramp = ramp.min(cfg.depth_m / cfg.descent_mps);
            let w = cfg.descent_mps;
            if ramp > 0.0 {
                push(ramp, (0.0, 0.0, 0.0), (0.0, w / ramp), &mut t, &mut p, &mut yaw);
            }
            push(cfg.depth_m / w - ramp, (0.0, w, 0.0), (0.0, 0.0), &mut t, &mut p, &mut yaw);
            if ramp > 0.0 {
                push(ramp, (0.0, w, 0.0), (0.0, -w / ramp), &mut t, &mut p, &mut yaw);
            }
        }
        let radius = (cfg.spacing_m / 2.0).max(1.0);
        let turn_rate = cfg.speed_mps / radius;
        let u = cfg.speed_mps;
        // Accelerate along the first leg (it stays leg_m long).
        let ramp = ramp.min(cfg.leg_m / u);
        let mut first_leg_left = cfg.leg_m;
        if ramp > 0.0 && u > 0.0 {
            push(ramp, (0.0, 0.0, 0.0), (u / ramp, 0.0), &mut t, &mut p, &mut yaw);
            first_leg_left -= 0.5 * u * ramp;
        }
        let block_legs = if cfg.cross_legs > 0 { cfg.cross_legs | 1 } else { u32::MAX };
        let (mut k, mut in_block, mut block) = (0u64, 0u32, 0u32);
        while t < duration_s && u > 0.0 {
            let leg = if k == 0 { first_leg_left } else { cfg.leg_m };
            push(leg / u, (u, 0.0, 0.0), (0.0, 0.0), &mut t, &mut p, &mut yaw);
            // Blocks alternate their first turn (right, then left); between blocks a quarter
            // turn (left, then right) heads across the block just flown.
            let block_sign = if block % 2 == 0 { 1.0 } else { -1.0 };
            if in_block + 1 >= block_legs {
                push(std::f64::consts::FRAC_PI_2 / turn_rate, (u, 0.0, -block_sign * turn_rate), (0.0, 0.0), &mut t, &mut p, &mut yaw);
                block += 1;
                in_block = 0;
            } else {
                let dir = if in_block % 2 == 0 { block_sign } else { -block_sign };
                push(std::f64::consts::PI / turn_rate, (u, 0.0, dir * turn_rate), (0.0, 0.0), &mut t, &mut p, &mut yaw);
                in_block += 1;
            }
            k += 1;
        }
        Trajectory { segments: segs, rig: Vec::new(), rig_depth_m: 0.0, duration_s }
    }

    /// The exact motion of a calibration rig (body rate `axis * rate`, specific force `-R^T g`).
    pub fn rig(motion: &RigMotion) -> Self {
        let mut t = 0.0;
        let mut att = UnitQuaternion::from_euler_angles(0.0, 0.0, motion.heading0_rad);
        let mut rig = Vec::new();
        for s in &motion.steps {
            let a = Vector3::from(s.axis_body);
            let axis = if a.norm() > 0.0 { a.normalize() } else { Vector3::z() };
            let seg = RigSegment { t0: t, dur: s.duration_s.max(0.0), att0: att, axis, rate: s.rate_radps };
            att = seg.att(seg.dur);
            t += seg.dur;
            rig.push(seg);
        }
        rig.push(RigSegment { t0: t, dur: f64::INFINITY, att0: att, axis: Vector3::z(), rate: 0.0 });
        Trajectory { segments: Vec::new(), rig, rig_depth_m: motion.depth_m, duration_s: t }
    }

    fn rig_at(&self, t_s: f64) -> Option<Truth> {
        let seg = self.rig.iter().rev().find(|s| s.t0 <= t_s).or(self.rig.first())?;
        let dt = (t_s - seg.t0).clamp(0.0, seg.dur);
        let att = seg.att(dt);
        let g = Vector3::new(0.0, 0.0, GRAVITY_MPS2);
        Some(Truth {
            t_s,
            pos_ned_m: Vector3::new(0.0, 0.0, self.rig_depth_m),
            vel_ned_mps: Vector3::zeros(),
            att_nb: att,
            yaw_rad: att.euler_angles().2.rem_euclid(std::f64::consts::TAU),
            gyro_radps: seg.axis * seg.rate,
            specific_force_mps2: crate::imu::specific_force(&att, &Vector3::zeros(), &g),
        })
    }

    /// Truth at `t_s` (clamped to the trajectory).
    pub fn at(&self, t_s: f64) -> Truth {
        if let Some(truth) = self.rig_at(t_s) {
            return truth;
        }
        let seg = self.segments.iter().rev().find(|s| s.t0 <= t_s).or(self.segments.first()).copied().unwrap_or(Segment {
            t0: 0.0,
            dur: 0.0,
            u: 0.0,
            w: 0.0,
            r: 0.0,
            au: 0.0,
            aw: 0.0,
            p0: Vector3::zeros(),
            yaw0: 0.0,
        });
        let dt = (t_s - seg.t0).clamp(0.0, seg.dur.max(0.0));
        let (p, yaw) = advance(seg.p0, seg.yaw0, &seg, dt);
        let (u, w) = (seg.u + seg.au * dt, seg.w + seg.aw * dt);
        let vel = Vector3::new(u * yaw.cos(), u * yaw.sin(), w);
        // a_n: tangential + centripetal + heave.
        let (sy, cy) = yaw.sin_cos();
        let acc = Vector3::new(seg.au * cy - u * seg.r * sy, seg.au * sy + u * seg.r * cy, seg.aw);
        let att = UnitQuaternion::from_euler_angles(0.0, 0.0, yaw);
        let g = Vector3::new(0.0, 0.0, GRAVITY_MPS2);
        let f_b = crate::imu::specific_force(&att, &acc, &g);
        Truth {
            t_s,
            pos_ned_m: p,
            vel_ned_mps: vel,
            att_nb: att,
            yaw_rad: yaw.rem_euclid(std::f64::consts::TAU),
            gyro_radps: Vector3::new(0.0, 0.0, seg.r),
            specific_force_mps2: f_b,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_circle_turn_shifts_by_the_spacing_and_reverses_heading() {
        let cfg = Lawnmower { rest_s: 0.0, depth_m: 0.0, heading0_rad: 0.0, ramp_s: 0.0, ..Lawnmower::default() };
        let tr = Trajectory::lawnmower(&cfg, 200.0);
        let leg_t = cfg.leg_m / cfg.speed_mps;
        let turn_t = std::f64::consts::PI * (cfg.spacing_m / 2.0) / cfg.speed_mps;
        let a = tr.at(leg_t);
        let b = tr.at(leg_t + turn_t);
        assert!((a.pos_ned_m - Vector3::new(cfg.leg_m, 0.0, 0.0)).norm() < 1e-9);
        assert!((b.pos_ned_m - Vector3::new(cfg.leg_m, cfg.spacing_m, 0.0)).norm() < 1e-9, "{:?}", b.pos_ned_m);
        assert!((b.yaw_rad - std::f64::consts::PI).abs() < 1e-9);
    }

    #[test]
    fn cross_hatch_crosses_its_own_track() {
        let cfg = Lawnmower {
            rest_s: 0.0,
            depth_m: 0.0,
            heading0_rad: 0.0,
            ramp_s: 0.0,
            leg_m: 60.0,
            spacing_m: 15.0,
            cross_legs: 5,
            ..Lawnmower::default()
        };
        let tr = Trajectory::lawnmower(&cfg, 1800.0);
        let pts: Vec<Vector3<f64>> = (0..1800).map(|k| tr.at(k as f64).pos_ned_m).collect();
        // The first block's lanes run north-south; the second block's east-west, over the same square.
        let block_s = 5.0 * 60.0 + 4.0 * std::f64::consts::PI * 7.5 + std::f64::consts::FRAC_PI_2 * 7.5;
        let second = tr.at(block_s + 30.0);
        assert!(second.vel_ned_mps.x.abs() < 1e-9 && (second.vel_ned_mps.y.abs() - 1.0).abs() < 1e-9, "{:?}", second.vel_ned_mps);
        assert!((0.0..=70.0).contains(&second.pos_ned_m.x) && (-10.0..=70.0).contains(&second.pos_ned_m.y), "{:?}", second.pos_ned_m);
        // Every point of the later blocks passes within 8 m of the first block's track at some
        // time, and the whole dive stays over the first block's square (it does not wander off).
        let first: Vec<&Vector3<f64>> = pts.iter().take(block_s as usize).collect();
        let near = pts.iter().skip(block_s as usize).filter(|p| first.iter().any(|q| (*p - *q).norm() < 8.0)).count();
        let later = pts.len() - block_s as usize;
        assert!(near as f64 > 0.5 * later as f64, "{near} of {later}");
        assert!(pts.iter().all(|p| p.x > -40.0 && p.x < 100.0 && p.y > -40.0 && p.y < 100.0));
    }

    #[test]
    fn rig_turns_by_its_steps_and_reads_gravity_in_body_axes() {
        let q = std::f64::consts::FRAC_PI_2;
        let motion = RigMotion {
            depth_m: 3.0,
            heading0_rad: 0.0,
            steps: vec![
                RigStep { duration_s: 2.0, axis_body: [0.0, 0.0, 1.0], rate_radps: 0.0 },
                RigStep { duration_s: 3.0, axis_body: [1.0, 0.0, 0.0], rate_radps: q / 3.0 },
            ],
        };
        let tr = Trajectory::rig(&motion);
        assert!((tr.at(1.0).specific_force_mps2 - Vector3::new(0.0, 0.0, -GRAVITY_MPS2)).norm() < 1e-12);
        assert!((tr.at(3.5).gyro_radps - Vector3::new(q / 3.0, 0.0, 0.0)).norm() < 1e-12);
        // Rolled 90 deg right: the body y axis points down, gravity reads along -y.
        let after = tr.at(10.0);
        assert!((after.specific_force_mps2 - Vector3::new(0.0, -GRAVITY_MPS2, 0.0)).norm() < 1e-9, "{}", after.specific_force_mps2);
        assert_eq!(after.gyro_radps, Vector3::zeros());
        assert_eq!(after.pos_ned_m, Vector3::new(0.0, 0.0, 3.0));
        // The attitude integrates the body rate.
        let (a, b) = (tr.at(3.0), tr.at(3.0 + 1e-3));
        let w = crate::imu::body_rate_between(a.att_nb.to_rotation_matrix().matrix(), b.att_nb.to_rotation_matrix().matrix(), 1e-3);
        assert!((w - a.gyro_radps).norm() < 1e-9);
    }

    #[test]
    fn velocity_and_specific_force_are_consistent_with_position() {
        let tr = Trajectory::lawnmower(&Lawnmower::default(), 400.0);
        for k in 1..3000 {
            let t = k as f64 * 0.13;
            let h = 1e-4;
            let (a, b) = (tr.at(t - h), tr.at(t + h));
            let v_num = (b.pos_ned_m - a.pos_ned_m) / (2.0 * h);
            let s = tr.at(t);
            // away from segment boundaries, finite differences match
            if (v_num - s.vel_ned_mps).norm() < 1e-3 {
                let acc_num = (b.vel_ned_mps - a.vel_ned_mps) / (2.0 * h);
                let f_num = s.att_nb.inverse() * (acc_num - Vector3::new(0.0, 0.0, GRAVITY_MPS2));
                assert!((f_num - s.specific_force_mps2).norm() < 1e-3, "t={t}");
            }
        }
        // The ramps: speed and depth are continuous, and reach their targets.
        let cfg = Lawnmower::default();
        for k in 0..4000 {
            let t = k as f64 * 0.05;
            let (a, b) = (tr.at(t - 1e-6), tr.at(t + 1e-6));
            assert!((a.vel_ned_mps - b.vel_ned_mps).norm() < 1e-4, "velocity jump at {t}");
        }
        let descent_end = cfg.rest_s + cfg.depth_m / cfg.descent_mps + cfg.ramp_s;
        assert!((tr.at(descent_end).pos_ned_m.z - cfg.depth_m).abs() < 1e-9);
        assert!((tr.at(descent_end + cfg.ramp_s).vel_ned_mps.norm() - cfg.speed_mps).abs() < 1e-9);
        let rest = tr.at(1.0);
        assert!((rest.specific_force_mps2 - Vector3::new(0.0, 0.0, -GRAVITY_MPS2)).norm() < 1e-12);
    }
}
