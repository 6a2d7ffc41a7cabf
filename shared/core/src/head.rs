//! The sensor head's configuration in one named place: task rates, the polarization units'
//! geometry and nominal calibration, and the sensor grades (noise densities, bias stabilities).
//! The firmware's default filter tuning and the host simulator both read these, so changing a
//! grade changes both. (To evaluate a mis-tuned filter, the simulator scales its own copy.)
//!
//! Sources: ICM-42688-P datasheet (rate noise 0.0028 dps/sqrt(Hz), accel noise 70 ug/sqrt(Hz));
//! MS5837-30BA datasheet (resolution 0.2 mbar at OSR 8192). Bias random walks and the photodiode
//! front end are our assumptions for a small MEMS head and are marked so.

use nalgebra::UnitQuaternion;

use crate::compass::{CompassConfig, NoiseModel, UnitModel, unit::ring_geometry};
use crate::nav::NavConfig;

/// Task rates (Hz).
pub const IMU_RATE_HZ: u32 = 200;
pub const POLARIZATION_RATE_HZ: u32 = 10;
pub const DEPTH_RATE_HZ: u32 = 10;
/// Camera trigger rate (the downward polarization camera the host's topological map uses).
pub const CAMERA_RATE_HZ: u32 = 2;

/// Polarization units on the head: a ring around the body z axis, looking slightly up, 45 deg
/// apart. Eight, not four: the real light field departs from single scattering in a pattern
/// mirror-symmetric about the solar plane, and eight units evenly spaced cancel most of what
/// the departure table leaves (clear water, sun 60 deg from the zenith, 5 m: 0.16 deg heading
/// RMSE against 0.55 with four; docs/PERFORMANCE.md, "The compass in an independent light
/// field"). Hardware: eight ADS1115 on two I2C buses (`subnav_wire::bridge::bus_map`).
pub const POLARIZATION_UNITS: usize = 8;
/// Elevation of each unit's viewing direction above the body's horizontal plane: 15 deg keeps
/// the view outside the Snell window (which reaches ~48.6 deg from the zenith), where the light
/// is scattered sunlight with a clean single-scattering e-vector.
pub const POLARIZATION_UNIT_ELEVATION_RAD: f32 = 15.0 * core::f32::consts::PI / 180.0;
/// Nominal photodiode calibration: gain (counts per count of the exposure-normalised radiance),
/// dark offset (counts), polarizer extinction ratio.
pub const POLARIZATION_GAIN_COUNTS: f32 = 1.0;
pub const POLARIZATION_OFFSET_COUNTS: f32 = 300.0;
pub const POLARIZER_EXTINCTION_RATIO: f32 = 500.0;
/// Auto-exposure target: counts of the brightest unit's S0.
pub const POLARIZATION_EXPOSURE_COUNTS: f32 = 20_000.0;

/// IMU grade (continuous-time noise densities and random walks).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuGrade {
    /// Gyro angle random walk (rad/s/sqrt(Hz) = rad/sqrt(s)).
    pub gyro_arw: f32,
    /// Gyro bias random walk (rad/s/sqrt(s)) (assumed).
    pub gyro_bias_rw: f32,
    /// Gyro turn-on bias 1-sigma (rad/s) (assumed).
    pub gyro_bias_sigma: f32,
    /// Accelerometer velocity random walk (m/s^2/sqrt(Hz)).
    pub accel_vrw: f32,
    /// Accelerometer bias random walk (m/s^2/sqrt(s)) (assumed).
    pub accel_bias_rw: f32,
    /// Accelerometer turn-on bias 1-sigma (m/s^2) (assumed).
    pub accel_bias_sigma: f32,
}

/// TDK ICM-42688-P (datasheet noise densities; bias figures assumed).
pub const IMU_ICM42688P: ImuGrade = ImuGrade {
    gyro_arw: 0.0028 * core::f32::consts::PI / 180.0,
    gyro_bias_rw: 2e-5,
    gyro_bias_sigma: 0.5 * core::f32::consts::PI / 180.0,
    accel_vrw: 70e-6 * 9.806_65,
    accel_bias_rw: 1e-4,
    accel_bias_sigma: 0.02,
};

/// Pressure / depth sensor grade.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthGrade {
    /// 1-sigma pressure noise per reading (Pa).
    pub pressure_sigma_pa: f32,
}

/// TE MS5837-30BA at OSR 8192: 0.2 mbar resolution.
pub const DEPTH_MS5837_30BA: DepthGrade = DepthGrade { pressure_sigma_pa: 20.0 };

/// Photodiode front end (assumed: photodiode + transimpedance amplifier + ADS1115).
pub const PHOTODIODE_NOISE: NoiseModel = NoiseModel { read_sigma_counts: 3.0, electrons_per_count: 100.0, saturation_counts: 32_000 };

/// The polarization units with nominal calibration.
pub fn polarization_units() -> [Option<UnitModel>; POLARIZATION_UNITS] {
    core::array::from_fn(polarization_unit)
}

/// Unit `i` with nominal calibration (`None` past the last unit): one model, not the eight
/// (the firmware's boot path applies stored calibrations one unit at a time).
pub fn polarization_unit(i: usize) -> Option<UnitModel> {
    if i >= POLARIZATION_UNITS {
        return None;
    }
    let (view, axis0) = polarization_unit_geometry(i);
    UnitModel::nominal(view, axis0, POLARIZATION_GAIN_COUNTS, POLARIZATION_OFFSET_COUNTS, POLARIZER_EXTINCTION_RATIO, PHOTODIODE_NOISE).ok()
}

/// Unit `i`'s viewing direction and polarizer reference axis (body FRD unit vectors).
pub fn polarization_unit_geometry(i: usize) -> ([f32; 3], [f32; 3]) {
    ring_geometry(i, POLARIZATION_UNITS, POLARIZATION_UNIT_ELEVATION_RAD)
}

/// The AoP departure of the real field from single scattering, times DoLP (rad): the
/// solver's model-error term (`SolverConfig::model_aop_dolp_rad`). 0.002 rad is 0.2 deg at
/// DoLP 0.55 (clear water, sun 30 deg) and 1 deg at DoLP 0.11 (turbid, 20 m); the residual
/// chi-square inflates the rest. Chosen against the OSOAA reference fields (docs/PERFORMANCE.md,
/// "The compass in an independent light field"): with it every case's fixes are within 2
/// reported sigma, and the solves the chi-square used to refuse are kept (0.005 gave the same).
pub const COMPASS_MODEL_AOP_DOLP_RAD: f32 = 0.002;

/// The compass settings of the head, measured against the OSOAA fields (docs/PERFORMANCE.md,
/// "The compass in an independent light field"): the model departure (above), the azimuth
/// re-fitted at the ephemeris's elevation with the real field's expected AoP departure
/// subtracted (`compass::departure::OSOAA_CLEAR`, 104 f32 of flash). In the real field the
/// pure single-scattering solver ([`compass_config_single_scattering`]) refuses most solves
/// with a low sun and is overconfident in the rest.
pub fn compass_config() -> CompassConfig {
    let mut c = CompassConfig::default();
    c.solver.model_aop_dolp_rad = COMPASS_MODEL_AOP_DOLP_RAD;
    c.solver.chi2_inflation_power = 0.5;
    c.azimuth_at_known_elevation = true;
    c.aop_departure = Some(&crate::compass::departure::OSOAA_CLEAR);
    c
}

/// The solver of single scattering alone (no model departure, no table, the sun's elevation
/// free): the head's compass before issue 35, kept for comparisons and for fields that are
/// single scattering by construction (the synthetic tests).
pub fn compass_config_single_scattering() -> CompassConfig {
    CompassConfig::default()
}

/// Where the DVL sits: its axes turned 45 deg (yaw, about body z) against the body axes, as
/// the A50 is often mounted to clear a hull's keel line, and its transducer 0.30 m aft of and
/// 0.12 m below the IMU. The simulator's DVL uses the same nominal mounting plus a small
/// misalignment drawn per unit that the filter is not told.
pub fn dvl_mounting() -> crate::nav::dvl::DvlMounting {
    crate::nav::dvl::DvlMounting {
        rot_body_from_dvl: UnitQuaternion::from_euler_angles(0.0, 0.0, core::f32::consts::FRAC_PI_4),
        lever_arm_body_m: nalgebra::Vector3::new(-0.30, 0.0, 0.12),
    }
}

/// The DVL noise the filter assumes per axis, from a report's figure of merit `fom_mps` and the
/// measured speed: `sqrt(max(fom, floor)^2 + (fraction * speed)^2)`. The speed-proportional
/// part stands for what a figure of merit does not contain: the unit's scale-factor error and
/// the mounting misalignment (both of order 0.3 %, i.e. 3 mm/s at 1 m/s, and constant, not
/// white); the floor covers the DVL's optimistic figure of merit near the bottom.
pub const DVL_SIGMA_FLOOR_MPS: f32 = 0.01;
pub const DVL_SIGMA_SPEED_FRACTION: f32 = 0.01;

pub fn dvl_sigma_mps(fom_mps: f32, vel_mps: [f32; 3]) -> f32 {
    let floor = fom_mps.max(DVL_SIGMA_FLOOR_MPS);
    let speed2 = vel_mps.iter().map(|v| v * v).sum::<f32>();
    libm::sqrtf(floor * floor + DVL_SIGMA_SPEED_FRACTION * DVL_SIGMA_SPEED_FRACTION * speed2)
}

/// The noise a DVL report gets when it sends its own covariance (DVL axes, row-major): that
/// covariance, its diagonal floored at `DVL_SIGMA_FLOOR_MPS`, plus the model error no DVL
/// reports (residual scale and alignment, `DVL_SIGMA_SPEED_FRACTION` of the speed): the same
/// terms as [`dvl_sigma_mps`]. A non-finite entry stays as it is (`f32::max` would turn a NaN
/// into the floor): the filter refuses and counts such a report.
pub fn dvl_covariance_m2ps2(c: [f32; 9], vel_mps: [f32; 3]) -> [f32; 9] {
    let speed2: f32 = vel_mps.iter().map(|v| v * v).sum();
    let model = DVL_SIGMA_SPEED_FRACTION * DVL_SIGMA_SPEED_FRACTION * speed2;
    let floor = DVL_SIGMA_FLOOR_MPS * DVL_SIGMA_FLOOR_MPS;
    let mut r = c;
    for k in [0, 4, 8] {
        if r[k].is_finite() {
            r[k] = r[k].max(floor) + model;
        }
    }
    r
}

/// The navigation filter's default tuning, from the grades above.
pub fn nav_config() -> NavConfig {
    let mut cfg = NavConfig::default();
    cfg.imu_rate_hz = IMU_RATE_HZ as f32;
    // UKF predict at 10 Hz: the compass and depth updates (10 Hz) flush a partial interval
    // anyway; 20 Hz cost 1.7 M instructions a second more on the M4F for the same accuracy
    // (docs/PERFORMANCE.md, "Cost on the target").
    cfg.cov_decimation = 20;
    // Horizontal position model error, m/sqrt(s): what the 15 states leave out of a DVL-aided
    // dead reckoning (the compass's slowly varying heading error, the DVL's residual scale and
    // alignment, the coast between reports). With the generic 0.005 the one-hour every-fault
    // dive's position error sat at 3-4 reported sigma for minutes under USBL and DVL (mean
    // horizontal NEES 4.8 for 2 dof); with 0.03 it is 2.3 and 99.9 % of the samples are within
    // 3 sigma (docs/RELIABILITY.md, "The closed loop under every fault").
    cfg.pos_rw = 0.03;
    cfg.gyro_arw = IMU_ICM42688P.gyro_arw;
    cfg.gyro_bias_rw = IMU_ICM42688P.gyro_bias_rw;
    cfg.accel_vrw = IMU_ICM42688P.accel_vrw;
    cfg.accel_bias_rw = IMU_ICM42688P.accel_bias_rw;
    cfg.init_sigma_gyro_bias = IMU_ICM42688P.gyro_bias_sigma;
    cfg.init_sigma_accel_bias = IMU_ICM42688P.accel_bias_sigma;
    // The IMU's noise is the datasheet's typical figure: a unit that is noisier (a bad part,
    // vibration from the thrusters) widens the filter instead of starving it at the gates
    // (`crate::ukf::adapt::NisQScale`).
    cfg.imu_q_adapt = crate::ukf::QScaleConfig::on();
    // Position fixes are gated on the full innovation covariance: the state part capped at a
    // multiple of the fix's own noise refused every clean fix of a filter whose position was
    // honestly uncertain (KITTI through the estimator: fixes of 0.26 m every 10 s against a 50-m
    // predicted sigma, 3 of 4 refused, 138 km off; docs/PERFORMANCE.md, "Never lost"). A fix that
    // disagrees with an uncertain filter cannot be told from a good one; a run of refused fixes
    // that agree resets the position (the estimator's position aid).
    cfg.position.gate_state_max = f32::INFINITY;
    cfg
}

/// Roll and pitch (rad) from a mean specific force at rest (body FRD: level reads [0, 0, -g]).
pub fn level_from_accel(f: [f32; 3]) -> (f32, f32) {
    let roll = libm::atan2f(-f[1], -f[2]);
    let pitch = libm::atan2f(f[0], libm::sqrtf(f[1] * f[1] + f[2] * f[2]));
    (roll, pitch)
}

/// Body -> NED attitude from roll, pitch, yaw (rad, ZYX).
pub fn attitude(roll: f32, pitch: f32, yaw: f32) -> UnitQuaternion<f32> {
    UnitQuaternion::from_euler_angles(roll, pitch, yaw)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_are_valid_and_look_up() {
        for u in polarization_units() {
            let u = u.expect("nominal unit model");
            assert!(u.view_body[2] < -0.2, "units look up (body z is down)");
        }
        let init = crate::nav::NavInit {
            t_us: 0,
            att_nb: attitude(0.0, 0.0, 0.0),
            vel_ned_mps: nalgebra::Vector3::zeros(),
            pos_ned_m: nalgebra::Vector3::zeros(),
        };
        assert!(crate::nav::NavFilter15::new(nav_config(), init).is_ok(), "default tuning must be a valid config");
    }

    #[test]
    fn level_from_accel_recovers_tilt() {
        let q = attitude(0.1, -0.2, 1.0);
        // specific force at rest: f_b = R_bn^T (-g_n), g_n = [0, 0, g]
        let f = q.inverse() * nalgebra::Vector3::new(0.0, 0.0, -9.81);
        let (r, p) = level_from_accel([f.x, f.y, f.z]);
        assert!((r - 0.1).abs() < 1e-5 && (p + 0.2).abs() < 1e-5, "{r} {p}");
    }
}
