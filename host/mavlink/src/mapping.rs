//! The head's solution in the forms ArduSub and PX4 consume: pure conversions, no I/O.
//!
//! Frames: the head's navigation frame is NED (metres from its origin), its body frame FRD, its
//! attitude a body -> NED quaternion `[w, x, y, z]` (`subnav_wire::messages`). MAVLink's
//! `VISION_POSITION_ESTIMATE`, `GLOBAL_VISION_POSITION_ESTIMATE` and `VISION_SPEED_ESTIMATE` are in
//! an earth-fixed NED frame (ArduPilot's `handle_common_vision_position_estimate_data`, PX4's
//! `mavlink_receiver`), Euler angles roll/pitch/yaw (ZYX, rad); `ODOMETRY` carries the pose in
//! `frame_id` and the velocity in the body frame (`child_frame_id = MAV_FRAME_BODY_FRD`).
//! Covariances: MAVLink's "upper-right triangle, row-major" of the 6x6 (x, y, z, roll, pitch,
//! yaw) or (vx, vy, vz, p, q, r) matrix; `NaN` in the first element means unknown.
//!
//! Never a velocity the head does not have: [`velocity_usable`] decides, from the mode and the
//! velocity sigma, whether the speed messages go out at all; a withheld velocity is never sent
//! as zeros.

use mavlink::dialects::ardupilotmega as mav;
use subnav_wire::{NavMode, NavSolution};

/// WGS84 semi-major axis, m, and first eccentricity squared.
const WGS84_A_M: f64 = 6_378_137.0;
const WGS84_E2: f64 = 6.694_379_990_14e-3;

/// A geodetic point (WGS84 latitude and longitude in degrees, altitude in metres).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Geodetic {
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub alt_m: f64,
}

impl Geodetic {
    /// `None` unless latitude and longitude are finite and in range (and not exactly 0, 0:
    /// what an autopilot without a fix sends).
    pub fn checked(lat_deg: f64, lon_deg: f64, alt_m: f64) -> Option<Self> {
        let ok = lat_deg.is_finite()
            && lon_deg.is_finite()
            && alt_m.is_finite()
            && lat_deg.abs() <= 90.0
            && lon_deg.abs() <= 180.0
            && !(lat_deg == 0.0 && lon_deg == 0.0);
        ok.then_some(Self { lat_deg, lon_deg, alt_m })
    }

    /// From MAVLink's integer form (degE7, mm).
    pub fn from_e7(lat_e7: i32, lon_e7: i32, alt_mm: i32) -> Option<Self> {
        Self::checked(f64::from(lat_e7) * 1e-7, f64::from(lon_e7) * 1e-7, f64::from(alt_mm) * 1e-3)
    }

    /// Meridian and prime-vertical radii of curvature at this latitude, m.
    fn radii_m(&self) -> (f64, f64) {
        let s = self.lat_deg.to_radians().sin();
        let w = 1.0 - WGS84_E2 * s * s;
        (WGS84_A_M * (1.0 - WGS84_E2) / (w * w.sqrt()), WGS84_A_M / w.sqrt())
    }

    /// `p` in the local NED frame at `self` (tangent-plane approximation: under 1 cm of error
    /// within 2 km of the origin, about 0.3 m at 20 km, the bridge's limit).
    pub fn ned_of(&self, p: &Geodetic) -> [f64; 3] {
        let (rn, re) = self.radii_m();
        let dlat = (p.lat_deg - self.lat_deg).to_radians();
        let mut dlon = p.lon_deg - self.lon_deg;
        if dlon > 180.0 {
            dlon -= 360.0;
        } else if dlon < -180.0 {
            dlon += 360.0;
        }
        [dlat * (rn + self.alt_m), dlon.to_radians() * (re + self.alt_m) * self.lat_deg.to_radians().cos(), self.alt_m - p.alt_m]
    }

    /// The point at `ned_m` from `self` (inverse of [`Self::ned_of`]).
    pub fn at_ned(&self, ned_m: [f64; 3]) -> Geodetic {
        let (rn, re) = self.radii_m();
        let lat = self.lat_deg + (ned_m[0] / (rn + self.alt_m)).to_degrees();
        let lon = self.lon_deg + (ned_m[1] / ((re + self.alt_m) * self.lat_deg.to_radians().cos())).to_degrees();
        Geodetic { lat_deg: lat, lon_deg: lon, alt_m: self.alt_m - ned_m[2] }
    }
}

/// Roll, pitch, yaw (ZYX Euler, rad) of a body -> NED quaternion `[w, x, y, z]`.
pub fn euler_rpy_rad(q_nb_wxyz: [f32; 4]) -> [f32; 3] {
    let [w, x, y, z] = q_nb_wxyz.map(f64::from);
    let roll = (2.0 * (w * x + y * z)).atan2(1.0 - 2.0 * (x * x + y * y));
    let pitch = (2.0 * (w * y - z * x)).clamp(-1.0, 1.0).asin();
    let yaw = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
    [roll as f32, pitch as f32, yaw as f32]
}

/// The body -> NED rotation matrix of a quaternion `[w, x, y, z]` (normalised here).
pub fn r_nb(q_nb_wxyz: [f32; 4]) -> [[f64; 3]; 3] {
    let [w, x, y, z] = q_nb_wxyz.map(f64::from);
    let n = (w * w + x * x + y * y + z * z).sqrt().max(1e-12);
    let (w, x, y, z) = (w / n, x / n, y / n, z / n);
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

/// A NED vector in the body (FRD) frame: `R_nb^T v`.
pub fn body_frd_of(q_nb_wxyz: [f32; 4], v_ned: [f64; 3]) -> [f64; 3] {
    let r = r_nb(q_nb_wxyz);
    core::array::from_fn(|j| (0..3).map(|i| r[i][j] * v_ned[i]).sum())
}

/// Index of element (r, c), r <= c, of a 6x6 matrix's upper-right triangle, row-major (21).
pub const fn ut6(r: usize, c: usize) -> usize {
    r * 6 - r * (r.saturating_sub(1)) / 2 + (c - r)
}

/// The 21-element pose covariance (x, y, z, roll, pitch, yaw) of a solution: the position's
/// north-east block with its cross term, the depth variance, the attitude variances. Cross terms
/// between position and attitude are not in the telemetry: zero.
pub fn pose_covariance(n: &NavSolution) -> [f32; 21] {
    let mut c = [0.0f32; 21];
    let [sn, se, sd] = n.sigma_pos_m;
    c[ut6(0, 0)] = sn * sn;
    c[ut6(0, 1)] = n.cov_ne_m2;
    c[ut6(1, 1)] = se * se;
    c[ut6(2, 2)] = sd * sd;
    for k in 0..3 {
        c[ut6(3 + k, 3 + k)] = n.sigma_att_rad[k] * n.sigma_att_rad[k];
    }
    c
}

/// The NED velocity covariance (3x3 row-major): the per-axis sigmas (the telemetry has no cross
/// terms).
pub fn velocity_covariance_ned(n: &NavSolution) -> [f32; 9] {
    let mut c = [0.0f32; 9];
    for k in 0..3 {
        c[4 * k] = n.sigma_vel_mps[k] * n.sigma_vel_mps[k];
    }
    c
}

/// The body-frame (FRD) velocity covariance `R^T Σ_ned R` as ODOMETRY's 21 elements (vx, vy, vz
/// then the body rates, which the telemetry does not carry: their variances NaN).
pub fn velocity_covariance_body(n: &NavSolution) -> [f32; 21] {
    let r = r_nb(n.att_nb_wxyz);
    let s2: [f64; 3] = n.sigma_vel_mps.map(|s| f64::from(s) * f64::from(s));
    let mut c = [0.0f32; 21];
    for a in 0..3 {
        for b in a..3 {
            let v: f64 = (0..3).map(|i| r[i][a] * s2[i] * r[i][b]).sum();
            c[ut6(a, b)] = v as f32;
        }
    }
    for k in 3..6 {
        c[ut6(k, k)] = f32::NAN;
    }
    c
}

/// What the bridge may say about the head's velocity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Velocity {
    /// Aided, finite, horizontal sigma within the bound: sent with its covariance.
    Usable,
    /// Aligning or uninitialised: the head has no velocity yet.
    NotYet,
    /// Its sigma is above the bound (e.g. the DVL lost for a while) or not finite: withheld.
    TooUncertain,
}

/// Whether the solution's velocity may be sent (bound on the larger horizontal sigma, m/s).
pub fn velocity_usable(n: &NavSolution, max_sigma_mps: f32) -> Velocity {
    match n.mode {
        NavMode::Uninitialised | NavMode::Aligning => return Velocity::NotYet,
        NavMode::Inertial | NavMode::Aided => {}
    }
    let finite = n.vel_ned_mps.iter().chain(&n.sigma_vel_mps).all(|v| v.is_finite());
    let sigma_h = n.sigma_vel_mps[0].max(n.sigma_vel_mps[1]);
    if finite && sigma_h <= max_sigma_mps { Velocity::Usable } else { Velocity::TooUncertain }
}

/// Whether the solution's pose may be sent: a running filter with finite values.
pub fn pose_usable(n: &NavSolution) -> bool {
    matches!(n.mode, NavMode::Inertial | NavMode::Aided)
        && n.pos_ned_m.iter().chain(&n.att_nb_wxyz).chain(&n.sigma_pos_m).chain(&n.sigma_att_rad).all(|v| v.is_finite())
}

/// ODOMETRY's quality (0-100 %): 100 at a horizontal position sigma of 0, half at 5 m; an
/// inertial-only solution at most 10.
pub fn quality_percent(n: &NavSolution) -> i8 {
    let sigma_h = f64::from(n.sigma_pos_m[0].max(n.sigma_pos_m[1]));
    let q = (100.0 * (-sigma_h * core::f64::consts::LN_2 / 5.0).exp()).round().clamp(1.0, 100.0);
    let q = if n.mode == NavMode::Inertial { q.min(10.0) } else { q };
    q as i8
}

/// The frame ODOMETRY's pose is in: ArduPilot only takes `MAV_FRAME_LOCAL_FRD` (its
/// `handle_odometry` drops other frames); PX4 takes `MAV_FRAME_LOCAL_NED` as north-aligned
/// (our absolute heading used as such) and `LOCAL_FRD` as a frame whose yaw it estimates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum OdometryFrame {
    LocalFrd,
    LocalNed,
}

/// The clock the messages' time stamps are in. Both hold the measurement's time of validity.
/// - `companion` (default): our own clock, the one we answer the autopilot's `TIMESYNC` with.
///   MAVLink's convention (the receiver maps a sender's stamps with its own TIMESYNC estimate):
///   PX4 maps `time_usec`/`usec` through `Timesync::sync_stamp` (adds its offset, estimated from
///   its TIMESYNC requests to us); ArduPilot's `JitterCorrection` takes any monotonic clock.
/// - `autopilot`: already mapped to the autopilot's clock with our own TIMESYNC estimate (before
///   it converges: our clock). Only for a receiver that neither runs TIMESYNC nor corrects
///   jitter; PX4 would map such a stamp a second time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize, Default)]
pub enum StampClock {
    #[default]
    Companion,
    Autopilot,
}

/// A solution as the autopilot's messages, positions in the output frame (`pos_out_ned_m`: the
/// head's NED re-based to the autopilot's origin when it has one), stamped `t_remote_us`.
pub struct Outgoing {
    pub vision_position: mav::VISION_POSITION_ESTIMATE_DATA,
    pub global_vision_position: Option<mav::GLOBAL_VISION_POSITION_ESTIMATE_DATA>,
    pub vision_speed: Option<mav::VISION_SPEED_ESTIMATE_DATA>,
    pub odometry: Option<mav::ODOMETRY_DATA>,
}

/// Build the messages of one solution. `global` says whether the output frame is the
/// autopilot's origin (then GLOBAL_VISION_POSITION_ESTIMATE goes out too). The position
/// messages go out whenever the pose is usable. ODOMETRY: with a usable velocity always;
/// without one only in `local-ned` (PX4), its velocity NaN: PX4's `handle_message_odometry`
/// takes the pose and skips a velocity that is not all finite, while ArduPilot's
/// `handle_odometry` (the `local-frd` frame) would rotate a NaN velocity into its EKF, so there
/// ODOMETRY is left out.
pub fn outgoing(
    n: &NavSolution,
    pos_out_ned_m: [f32; 3],
    t_remote_us: u64,
    reset_counter: u8,
    velocity: Velocity,
    global: bool,
    odometry_frame: OdometryFrame,
) -> Outgoing {
    let [roll, pitch, yaw] = euler_rpy_rad(n.att_nb_wxyz);
    let [x, y, z] = pos_out_ned_m;
    let covariance = pose_covariance(n);
    let vision_position = mav::VISION_POSITION_ESTIMATE_DATA { usec: t_remote_us, x, y, z, roll, pitch, yaw, covariance, reset_counter };
    let global_vision_position = global.then_some(mav::GLOBAL_VISION_POSITION_ESTIMATE_DATA {
        usec: t_remote_us,
        x,
        y,
        z,
        roll,
        pitch,
        yaw,
        covariance,
        reset_counter,
    });
    let usable = velocity == Velocity::Usable;
    let [vn, ve, vd] = n.vel_ned_mps;
    let vision_speed = usable.then_some(mav::VISION_SPEED_ESTIMATE_DATA {
        usec: t_remote_us,
        x: vn,
        y: ve,
        z: vd,
        covariance: velocity_covariance_ned(n),
        reset_counter,
    });
    let pose_only = !usable && odometry_frame == OdometryFrame::LocalNed;
    let odometry = (usable || pose_only).then(|| {
        let v_b = if usable { body_frd_of(n.att_nb_wxyz, n.vel_ned_mps.map(f64::from)) } else { [f64::NAN; 3] };
        let mut velocity_covariance = velocity_covariance_body(n);
        if !usable {
            velocity_covariance = [f32::NAN; 21];
        }
        mav::ODOMETRY_DATA {
            time_usec: t_remote_us,
            x,
            y,
            z,
            q: n.att_nb_wxyz,
            vx: v_b[0] as f32,
            vy: v_b[1] as f32,
            vz: v_b[2] as f32,
            rollspeed: f32::NAN,
            pitchspeed: f32::NAN,
            yawspeed: f32::NAN,
            pose_covariance: covariance,
            velocity_covariance,
            frame_id: match odometry_frame {
                OdometryFrame::LocalFrd => mav::MavFrame::MAV_FRAME_LOCAL_FRD,
                OdometryFrame::LocalNed => mav::MavFrame::MAV_FRAME_LOCAL_NED,
            },
            child_frame_id: mav::MavFrame::MAV_FRAME_BODY_FRD,
            reset_counter,
            estimator_type: mav::MavEstimatorType::MAV_ESTIMATOR_TYPE_UNKNOWN,
            quality: quality_percent(n),
        }
    });
    Outgoing { vision_position, global_vision_position, vision_speed, odometry }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nav(yaw_rad: f32, vel_ned_mps: [f32; 3]) -> NavSolution {
        let h = yaw_rad / 2.0;
        NavSolution {
            t_us: 1_000_000,
            mode: NavMode::Aided,
            pos_ned_m: [10.0, -5.0, 3.0],
            vel_ned_mps,
            att_nb_wxyz: [h.cos(), 0.0, 0.0, h.sin()],
            sigma_pos_m: [0.5, 0.4, 0.02],
            sigma_vel_mps: [0.01, 0.02, 0.005],
            sigma_att_rad: [0.001, 0.002, 0.004],
            cov_ne_m2: 0.05,
        }
    }

    #[test]
    fn euler_of_a_pure_yaw_and_a_pure_roll() {
        let [r, p, y] = euler_rpy_rad(nav(1.0, [0.0; 3]).att_nb_wxyz);
        assert!(r.abs() < 1e-6 && p.abs() < 1e-6 && (y - 1.0).abs() < 1e-6);
        let h = 0.3f32 / 2.0;
        let [r, p, y] = euler_rpy_rad([h.cos(), h.sin(), 0.0, 0.0]);
        assert!((r - 0.3).abs() < 1e-6 && p.abs() < 1e-6 && y.abs() < 1e-6);
        // Heading west: yaw -90 deg, not 270.
        let [_, _, y] = euler_rpy_rad(nav(-core::f32::consts::FRAC_PI_2, [0.0; 3]).att_nb_wxyz);
        assert!((y + core::f32::consts::FRAC_PI_2).abs() < 1e-6);
    }

    #[test]
    fn body_velocity_of_a_vehicle_heading_east_moving_east_is_forward() {
        // Heading east (yaw +90 deg, FRD x towards east), moving east at 1 m/s and sinking at 0.1:
        // forward 1, right 0, down 0.1.
        let n = nav(core::f32::consts::FRAC_PI_2, [0.0, 1.0, 0.1]);
        let v = body_frd_of(n.att_nb_wxyz, n.vel_ned_mps.map(f64::from));
        assert!((v[0] - 1.0).abs() < 1e-6 && v[1].abs() < 1e-6 && (v[2] - 0.1).abs() < 1e-6, "{v:?}");
        // Moving north while heading east: the water comes from the left, velocity to the left (-y).
        let v = body_frd_of(n.att_nb_wxyz, [1.0, 0.0, 0.0]);
        assert!((v[1] + 1.0).abs() < 1e-6 && v[0].abs() < 1e-6, "{v:?}");
    }

    #[test]
    fn covariance_layout_is_the_upper_right_triangle_row_major() {
        assert_eq!(ut6(0, 0), 0);
        assert_eq!(ut6(0, 5), 5);
        assert_eq!(ut6(1, 1), 6);
        assert_eq!(ut6(2, 2), 11);
        assert_eq!(ut6(3, 3), 15);
        assert_eq!(ut6(5, 5), 20);
        let c = pose_covariance(&nav(0.0, [0.0; 3]));
        assert!((c[0] - 0.25).abs() < 1e-6 && (c[1] - 0.05).abs() < 1e-6 && (c[6] - 0.16).abs() < 1e-6);
        assert!((c[20] - 0.004 * 0.004).abs() < 1e-9);
        // Body velocity covariance heading east: the body x variance is the east variance.
        let cb = velocity_covariance_body(&nav(core::f32::consts::FRAC_PI_2, [0.0; 3]));
        assert!((cb[0] - 0.0004).abs() < 1e-7 && (cb[6] - 0.0001).abs() < 1e-7, "{cb:?}");
        assert!(cb[15].is_nan());
    }

    #[test]
    fn geodetic_round_trip_and_scale() {
        let o = Geodetic::checked(44.0, -2.0, 0.0).unwrap();
        let p = o.at_ned([100.0, -50.0, 3.0]);
        let back = o.ned_of(&p);
        for k in 0..3 {
            assert!((back[k] - [100.0, -50.0, 3.0][k]).abs() < 1e-6, "{back:?}");
        }
        // One arc-minute of latitude is about 1852 m.
        let q = Geodetic::checked(44.0 + 1.0 / 60.0, -2.0, 0.0).unwrap();
        assert!((o.ned_of(&q)[0] - 1852.0).abs() < 5.0);
        assert!(Geodetic::from_e7(0, 0, 0).is_none());
        assert!(Geodetic::checked(91.0, 0.0, 0.0).is_none());
        assert!(Geodetic::checked(f64::NAN, 0.0, 0.0).is_none());
    }

    #[test]
    fn no_velocity_while_aligning_or_too_uncertain_never_zeros() {
        let mut n = nav(0.3, [0.5, 0.2, 0.0]);
        assert_eq!(velocity_usable(&n, 0.1), Velocity::Usable);
        let out = outgoing(&n, n.pos_ned_m, 5, 0, Velocity::Usable, false, OdometryFrame::LocalFrd);
        let s = out.vision_speed.unwrap();
        assert_eq!((s.x, s.y), (0.5, 0.2));
        assert!(out.odometry.is_some() && out.global_vision_position.is_none());
        n.sigma_vel_mps = [0.3, 0.3, 0.1];
        assert_eq!(velocity_usable(&n, 0.1), Velocity::TooUncertain);
        n.mode = NavMode::Aligning;
        assert_eq!(velocity_usable(&n, 0.1), Velocity::NotYet);
        let out = outgoing(&n, n.pos_ned_m, 5, 0, Velocity::NotYet, true, OdometryFrame::LocalFrd);
        assert!(out.vision_speed.is_none() && out.odometry.is_none());
        assert!(out.global_vision_position.is_some());
        n.mode = NavMode::Aided;
        n.sigma_vel_mps = [f32::NAN, 0.0, 0.0];
        assert_eq!(velocity_usable(&n, 0.1), Velocity::TooUncertain);
        // PX4's frame: the pose still goes out in ODOMETRY, its velocity NaN (never zeros).
        let out = outgoing(&n, n.pos_ned_m, 5, 0, Velocity::TooUncertain, false, OdometryFrame::LocalNed);
        let o = out.odometry.expect("pose-only ODOMETRY for PX4");
        assert!(o.vx.is_nan() && o.vy.is_nan() && o.vz.is_nan() && o.velocity_covariance[0].is_nan());
        assert_eq!((o.x, o.y), (10.0, -5.0));
        assert!(out.vision_speed.is_none());
        let out = outgoing(&n, n.pos_ned_m, 5, 0, Velocity::Usable, false, OdometryFrame::LocalNed);
        assert!(out.odometry.unwrap().vx.is_finite());
    }

    #[test]
    fn quality_falls_with_the_position_sigma() {
        let mut n = nav(0.0, [0.0; 3]);
        n.sigma_pos_m = [0.0, 0.0, 0.0];
        assert_eq!(quality_percent(&n), 100);
        n.sigma_pos_m = [5.0, 5.0, 0.0];
        assert_eq!(quality_percent(&n), 50);
        n.mode = NavMode::Inertial;
        assert_eq!(quality_percent(&n), 10);
    }
}
