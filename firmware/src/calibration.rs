//! Range checks for stored and commanded records, and what each record becomes in the
//! estimator: a polarization [`UnitModel`], an [`ImuCorrection`], a DVL mounting.
//!
//! A record outside these ranges is refused (`Refusal::OutOfRange` / `NotFinite`) when it is
//! commanded, and left unused (defaults, with a `Store` fault) when it is read from flash. The
//! ranges are wide enough for any real unit of the head's parts (gains within a factor of 2,
//! polarizers within 10 deg of nominal, IMU scale within 20 %, misalignment below 0.1 rad) and
//! narrow enough that a record written for another head or damaged in a way the CRC missed
//! cannot take the filter somewhere absurd.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};
use subnav_core::compass::{ChannelCal, UnitModel};
use subnav_core::head;
use subnav_core::nav::dvl::DvlMounting;
use subnav_wire::{DvlMountingRecord, ImuCalibration, ImuSample, PolarizationCalibration, Record, Refusal, RunConfigRecord};

use crate::config::AppConfig;

const DEG: f32 = core::f32::consts::PI / 180.0;

fn finite(v: &[f32]) -> Result<(), Refusal> {
    if v.iter().all(|x| x.is_finite()) { Ok(()) } else { Err(Refusal::NotFinite) }
}

fn within(v: f32, lo: f32, hi: f32) -> Result<(), Refusal> {
    if (lo..=hi).contains(&v) { Ok(()) } else { Err(Refusal::OutOfRange) }
}

fn unit_quaternion(wxyz: [f32; 4]) -> Result<UnitQuaternion<f32>, Refusal> {
    finite(&wxyz)?;
    let [w, x, y, z] = wxyz;
    let q = Quaternion::new(w, x, y, z);
    within(q.norm(), 0.999, 1.001)?;
    Ok(UnitQuaternion::from_quaternion(q))
}

/// The upper-triangular matrix `[m00, m01, m02, m11, m12, m22]`.
fn matrix(m: [f32; 6]) -> Result<Matrix3<f32>, Refusal> {
    finite(&m)?;
    let [a, b, c, d, e, f] = m;
    for v in [a, d, f] {
        within(v, 0.8, 1.25)?;
    }
    for v in [b, c, e] {
        within(v, -0.1, 0.1)?;
    }
    Ok(Matrix3::new(a, b, c, 0.0, d, e, 0.0, 0.0, f))
}

/// The calibrated model of polarization unit `p.unit` (the head's geometry, the record's channels).
pub fn unit_model(p: &PolarizationCalibration) -> Result<UnitModel, Refusal> {
    let Some(geometry) = head::polarization_unit(usize::from(p.unit)) else { return Err(Refusal::OutOfRange) };
    let all: [&[f32; 4]; 4] = [&p.gain, &p.offset_counts, &p.polarizer_rad, &p.extinction_ratio];
    for v in all {
        finite(v)?;
    }
    let mut channels = geometry.channels;
    for (k, c) in channels.iter_mut().enumerate() {
        let (gain, offset, angle, er) = (p.gain[k], p.offset_counts[k], p.polarizer_rad[k], p.extinction_ratio[k]);
        within(gain, 0.5 * head::POLARIZATION_GAIN_COUNTS, 2.0 * head::POLARIZATION_GAIN_COUNTS)?;
        within(offset, -1000.0, 4000.0)?;
        within(angle - k as f32 * 45.0 * DEG, -10.0 * DEG, 10.0 * DEG)?;
        within(er, 2.0, 1.0e5)?;
        *c = ChannelCal { gain, offset_counts: offset, polarizer_rad: angle, extinction_ratio: er };
    }
    UnitModel::new(geometry.view_body, geometry.axis0_body, channels, geometry.noise).map_err(|_| Refusal::OutOfRange)
}

/// IMU correction: `body = R * M * (raw - b)` for the gyro and the accelerometer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuCorrection {
    gyro_bias_radps: Vector3<f32>,
    accel_bias_mps2: Vector3<f32>,
    gyro: Matrix3<f32>,
    accel: Matrix3<f32>,
}

impl ImuCorrection {
    pub fn new(c: &ImuCalibration) -> Result<Self, Refusal> {
        finite(&c.gyro_bias_radps)?;
        finite(&c.accel_bias_mps2)?;
        for v in c.gyro_bias_radps {
            within(v, -0.1, 0.1)?;
        }
        for v in c.accel_bias_mps2 {
            within(v, -2.0, 2.0)?;
        }
        let r = unit_quaternion(c.body_from_imu_wxyz)?.to_rotation_matrix().into_inner();
        Ok(Self {
            gyro_bias_radps: Vector3::from(c.gyro_bias_radps),
            accel_bias_mps2: Vector3::from(c.accel_bias_mps2),
            gyro: r * matrix(c.gyro_correction)?,
            accel: r * matrix(c.accel_correction)?,
        })
    }

    /// The sample in body axes with biases, scale and misalignment removed.
    pub fn apply(&self, s: &ImuSample) -> ImuSample {
        let g = self.gyro * (Vector3::from(s.gyro_radps) - self.gyro_bias_radps);
        let a = self.accel * (Vector3::from(s.accel_mps2) - self.accel_bias_mps2);
        ImuSample { t_us: s.t_us, gyro_radps: [g.x, g.y, g.z], accel_mps2: [a.x, a.y, a.z], temp_c: s.temp_c }
    }
}

/// DVL mounting and scale factor.
pub fn dvl_mounting(d: &DvlMountingRecord) -> Result<(DvlMounting, f32), Refusal> {
    finite(&d.lever_arm_body_m)?;
    finite(&[d.scale])?;
    for v in d.lever_arm_body_m {
        within(v, -5.0, 5.0)?;
    }
    within(d.scale, 0.8, 1.25)?;
    let m = DvlMounting { rot_body_from_dvl: unit_quaternion(d.body_from_dvl_wxyz)?, lever_arm_body_m: Vector3::from(d.lever_arm_body_m) };
    Ok((m, d.scale))
}

/// The run configuration a record describes (the same ranges as `SetConfig`).
pub fn run_config(r: &RunConfigRecord) -> Result<AppConfig, Refusal> {
    if !(1..=50).contains(&r.nav_rate_hz) {
        return Err(Refusal::OutOfRange);
    }
    finite(&[r.water_density_kgm3])?;
    within(r.water_density_kgm3, 990.0, 1050.0)?;
    let origin = match r.origin {
        None => None,
        Some(o) => {
            if !(o.lat_rad.is_finite() && o.lon_rad.is_finite() && o.alt_m.is_finite()) {
                return Err(Refusal::NotFinite);
            }
            if o.lat_rad.abs() > core::f64::consts::FRAC_PI_2
                || o.lon_rad.abs() > core::f64::consts::PI
                || !(-12_000.0..=10_000.0).contains(&o.alt_m)
            {
                return Err(Refusal::OutOfRange);
            }
            Some((o.lat_rad, o.lon_rad, o.alt_m))
        }
    };
    Ok(AppConfig { nav_rate_hz: r.nav_rate_hz, stream_raw: r.stream_raw, water_density_kgm3: r.water_density_kgm3, origin })
}

/// The record of a configuration (what `SetConfig` persists).
pub fn run_config_record(c: &AppConfig) -> RunConfigRecord {
    RunConfigRecord {
        nav_rate_hz: c.nav_rate_hz,
        stream_raw: c.stream_raw,
        water_density_kgm3: c.water_density_kgm3,
        origin: c.origin.map(|(lat_rad, lon_rad, alt_m)| subnav_wire::Origin { lat_rad, lon_rad, alt_m }),
    }
}

/// Whether a record is acceptable, without applying it.
pub fn check(r: &Record) -> Result<(), Refusal> {
    match r {
        Record::RunConfig(c) => run_config(c).map(|_| ()),
        Record::Polarization(p) => unit_model(p).map(|_| ()),
        Record::Imu(c) => ImuCorrection::new(c).map(|_| ()),
        Record::DvlMounting(d) => dvl_mounting(d).map(|_| ()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub fn nominal_polarization(unit: u8) -> PolarizationCalibration {
        PolarizationCalibration {
            unit,
            gain: [head::POLARIZATION_GAIN_COUNTS; 4],
            offset_counts: [head::POLARIZATION_OFFSET_COUNTS; 4],
            polarizer_rad: core::array::from_fn(|k| k as f32 * 45.0 * DEG),
            extinction_ratio: [head::POLARIZER_EXTINCTION_RATIO; 4],
        }
    }

    #[test]
    fn nominal_record_gives_the_nominal_model() {
        let m = unit_model(&nominal_polarization(2)).unwrap();
        let n = head::polarization_units()[2].unwrap();
        for (a, b) in m.channels.iter().zip(n.channels.iter()) {
            assert!((a.gain - b.gain).abs() < 1e-6 && (a.polarizer_rad - b.polarizer_rad).abs() < 1e-6);
        }
    }

    #[test]
    fn out_of_range_and_non_finite_values_are_refused() {
        let mut p = nominal_polarization(0);
        p.polarizer_rad[1] += 20.0 * DEG;
        assert_eq!(unit_model(&p), Err(Refusal::OutOfRange));
        let mut p = nominal_polarization(0);
        p.gain[3] = f32::NAN;
        assert_eq!(unit_model(&p), Err(Refusal::NotFinite));
        assert_eq!(unit_model(&nominal_polarization(9)), Err(Refusal::OutOfRange));
        let eye = [1.0, 0.0, 0.0, 1.0, 0.0, 1.0];
        let mut c = ImuCalibration {
            gyro_bias_radps: [0.0; 3],
            accel_bias_mps2: [0.0; 3],
            gyro_correction: eye,
            accel_correction: eye,
            body_from_imu_wxyz: [0.5, 0.5, 0.5, 0.5],
        };
        assert!(ImuCorrection::new(&c).is_ok());
        c.body_from_imu_wxyz = [2.0, 0.0, 0.0, 0.0];
        assert_eq!(ImuCorrection::new(&c), Err(Refusal::OutOfRange));
    }

    #[test]
    fn imu_correction_inverts_a_known_error() {
        // raw = S (true + bias... ) : build raw from a true rate with scale 1.1 on x, bias 0.01.
        let eye = [1.0, 0.0, 0.0, 1.0, 0.0, 1.0];
        let mut g = eye;
        g[0] = 1.0 / 1.1;
        let c = ImuCalibration {
            gyro_bias_radps: [0.01, 0.0, 0.0],
            accel_bias_mps2: [0.0; 3],
            gyro_correction: g,
            accel_correction: eye,
            body_from_imu_wxyz: [1.0, 0.0, 0.0, 0.0],
        };
        let k = ImuCorrection::new(&c).unwrap();
        let raw = ImuSample { t_us: 0, gyro_radps: [1.1 * 0.2 + 0.01, 0.0, 0.0], accel_mps2: [0.0, 0.0, -9.81], temp_c: 0.0 };
        let out = k.apply(&raw);
        assert!((out.gyro_radps[0] - 0.2).abs() < 1e-6);
    }
}
