//! A mis-built sensor head: the manufacturing errors of one unit, drawn from its build seed
//! ([`crate::Scenario::build_seed`]), that `subnav calibrate` has to find.
//!
//! Polarization channel `k` of unit `u` (the model of `subnav_core::compass::unit`): gain
//! nominal x (1 +- 5 %), dark offset nominal +- 50 counts, polarizer angle nominal +- 2 deg,
//! extinction ratio log-uniform in 100..1000 (nominal 500). IMU (the model of
//! `subnav_wire::records::ImuCalibration`, inverted): `raw = N (R_imu_body x_body) + b`, with
//! `N` upper triangular (scale 1 +- 2 % on the diagonal, non-orthogonality +- 3 mrad above it),
//! a repeatable bias (gyro +- 0.3 deg/s, accelerometer +- 0.15 m/s^2) on top of the run-to-run
//! turn-on bias every head has, and the IMU board turned in the housing by up to 2 deg about
//! each axis. All uniform unless said otherwise; the ideal head (no build seed) has none of it.

use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use subnav_core::compass::{CHANNELS, ChannelCal};
use subnav_core::head;

/// Largest manufacturing errors (the half-widths of the uniform draws).
pub const GAIN_REL: f64 = 0.05;
pub const OFFSET_COUNTS: f64 = 50.0;
pub const POLARIZER_DEG: f64 = 2.0;
pub const EXTINCTION_RATIO_RANGE: (f64, f64) = (100.0, 1000.0);
pub const IMU_SCALE_REL: f64 = 0.02;
pub const IMU_NON_ORTHOGONALITY_RAD: f64 = 3e-3;
pub const GYRO_BIAS_RADPS: f64 = 0.3 * std::f64::consts::PI / 180.0;
pub const ACCEL_BIAS_MPS2: f64 = 0.15;
pub const MOUNTING_DEG: f64 = 2.0;

/// One inertial sensor's (gyro or accelerometer) repeatable errors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisErrors {
    /// Scale and non-orthogonality (upper triangular).
    pub n: Matrix3<f64>,
    pub bias: Vector3<f64>,
}

/// The manufacturing errors of one head.
#[derive(Debug, Clone, PartialEq)]
pub struct BuildErrors {
    /// True channel calibration of each polarization unit.
    pub polarization: Vec<[ChannelCal; CHANNELS]>,
    pub gyro: AxisErrors,
    pub accel: AxisErrors,
    /// Rotation body (housing) axes -> IMU axes.
    pub imu_from_body: Rotation3<f64>,
}

fn sym<R: Rng>(rng: &mut R, half: f64) -> f64 {
    rng.random_range(-half..=half)
}

fn axis_errors<R: Rng>(rng: &mut R, bias: f64) -> AxisErrors {
    let mut n = Matrix3::identity();
    for k in 0..3 {
        n[(k, k)] += sym(rng, IMU_SCALE_REL);
    }
    for (r, c) in [(0, 1), (0, 2), (1, 2)] {
        n[(r, c)] = sym(rng, IMU_NON_ORTHOGONALITY_RAD);
    }
    AxisErrors { n, bias: Vector3::from_fn(|_, _| sym(rng, bias)) }
}

impl BuildErrors {
    /// The errors of the head built with `seed`.
    pub fn draw(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xB111_D000);
        let (lo, hi) = (EXTINCTION_RATIO_RANGE.0.ln(), EXTINCTION_RATIO_RANGE.1.ln());
        let polarization = head::polarization_units()
            .into_iter()
            .flatten()
            .map(|u| {
                u.channels.map(|c| ChannelCal {
                    gain: (f64::from(c.gain) * (1.0 + sym(&mut rng, GAIN_REL))) as f32,
                    offset_counts: (f64::from(c.offset_counts) + sym(&mut rng, OFFSET_COUNTS)) as f32,
                    polarizer_rad: (f64::from(c.polarizer_rad) + sym(&mut rng, POLARIZER_DEG).to_radians()) as f32,
                    extinction_ratio: rng.random_range(lo..=hi).exp() as f32,
                })
            })
            .collect();
        let gyro = axis_errors(&mut rng, GYRO_BIAS_RADPS);
        let accel = axis_errors(&mut rng, ACCEL_BIAS_MPS2);
        let m = MOUNTING_DEG.to_radians();
        let imu_from_body = Rotation3::from_euler_angles(sym(&mut rng, m), sym(&mut rng, m), sym(&mut rng, m));
        BuildErrors { polarization, gyro, accel, imu_from_body }
    }

    /// What the IMU senses (its own axes, scale, non-orthogonality and repeatable bias) of a
    /// body rate and specific force: `(gyro, accel)`.
    pub fn sense(&self, gyro_body: &Vector3<f64>, f_body: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
        let r = self.imu_from_body;
        (self.gyro.n * (r * gyro_body) + self.gyro.bias, self.accel.n * (r * f_body) + self.accel.bias)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_are_within_their_bounds_and_differ_per_seed() {
        let nominal = head::polarization_units();
        for seed in 0..20 {
            let b = BuildErrors::draw(seed);
            assert_eq!(b.polarization.len(), head::POLARIZATION_UNITS);
            for (u, chans) in b.polarization.iter().enumerate() {
                let n = nominal[u].unwrap().channels;
                for (c, n) in chans.iter().zip(n) {
                    assert!((c.gain / n.gain - 1.0).abs() <= GAIN_REL as f32 + 1e-6);
                    assert!((c.offset_counts - n.offset_counts).abs() <= OFFSET_COUNTS as f32 + 1e-3);
                    assert!((c.polarizer_rad - n.polarizer_rad).abs() <= (POLARIZER_DEG as f32).to_radians() + 1e-6);
                    assert!((99.9..=1000.1).contains(&c.extinction_ratio));
                }
            }
            assert!(b.imu_from_body.angle() <= 3f64.sqrt() * MOUNTING_DEG.to_radians() + 1e-9);
            assert_eq!(b.accel.n[(1, 0)], 0.0);
        }
        assert_ne!(BuildErrors::draw(1), BuildErrors::draw(2));
        assert_eq!(BuildErrors::draw(3), BuildErrors::draw(3));
    }
}
