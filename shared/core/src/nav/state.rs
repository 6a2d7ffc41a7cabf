//! The navigation state: the nominal (full) state integrated by the strapdown, and the layout of
//! the error state the UKF estimates.
//!
//! Error state (spec A4, in the local NED frame of [`subnav_wire::messages`] instead of geodetic
//! latitude/longitude/height: the sensor head works over a few km, where the flat-earth frame
//! loses nothing measurable against MEMS errors; earth rate is neglected for the same reason):
//!
//! | index | symbol  | meaning                                                        |
//! |-------|---------|----------------------------------------------------------------|
//! | 0..3  | phi     | attitude error, NED, rad: `R_true = Exp(phi) R_nominal`         |
//! | 3..6  | dv      | velocity error, NED, m/s                                       |
//! | 6..9  | dp      | position error, NED, m                                         |
//! | 9..12 | dbg     | gyro constant bias error, FRD, rad/s                           |
//! | 12..15| dba     | accelerometer bias error, FRD, m/s^2                           |
//! | 15..18| eps_r   | gyro first-order Markov drift, FRD, rad/s (18-state only)      |
//!
//! The attitude error is a rotation vector about the nominal attitude, so sigma points are
//! rotations `Exp(phi_i) R` and never leave SO(3) (USQUE-style); after every step the error mean
//! is folded into the nominal state and the error reset to zero.

use super::rotation::quat_from_rotation_vector;
use nalgebra::{SVector, UnitQuaternion, Vector3};

pub const ATT: usize = 0;
pub const VEL: usize = 3;
pub const POS: usize = 6;
pub const BG: usize = 9;
pub const BA: usize = 12;
pub const MARKOV: usize = 15;

/// Three components of an error vector starting at `i` (zero where out of range, so a 15-state
/// filter reads its absent Markov block as zero without a panic path).
pub fn seg<const N: usize>(x: &SVector<f32, N>, i: usize) -> Vector3<f32> {
    Vector3::new(x.get(i).copied().unwrap_or(0.0), x.get(i + 1).copied().unwrap_or(0.0), x.get(i + 2).copied().unwrap_or(0.0))
}

/// Write three components at `i` (ignored where out of range).
pub fn set_seg<const N: usize>(x: &mut SVector<f32, N>, i: usize, v: &Vector3<f32>) {
    for k in 0..3 {
        if let Some(e) = x.get_mut(i + k) {
            *e = v[k];
        }
    }
}

/// The nominal state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NominalState {
    /// Body (FRD) -> NED.
    pub att_nb: UnitQuaternion<f32>,
    pub vel_ned_mps: Vector3<f32>,
    pub pos_ned_m: Vector3<f32>,
    pub gyro_bias_radps: Vector3<f32>,
    pub accel_bias_mps2: Vector3<f32>,
    /// Gyro Markov drift (18-state only, else stays zero).
    pub gyro_markov_radps: Vector3<f32>,
}

impl NominalState {
    /// Level, at rest at the origin, no biases.
    pub const fn zero() -> Self {
        Self {
            att_nb: UnitQuaternion::new_unchecked(nalgebra::Quaternion::from_vector(nalgebra::Vector4::new(0.0, 0.0, 0.0, 1.0))),
            vel_ned_mps: Vector3::new(0.0, 0.0, 0.0),
            pos_ned_m: Vector3::new(0.0, 0.0, 0.0),
            gyro_bias_radps: Vector3::new(0.0, 0.0, 0.0),
            accel_bias_mps2: Vector3::new(0.0, 0.0, 0.0),
            gyro_markov_radps: Vector3::new(0.0, 0.0, 0.0),
        }
    }

    /// Fold an error-state mean into the nominal state.
    pub fn inject<const N: usize>(&mut self, dx: &SVector<f32, N>) {
        let phi = seg(dx, ATT);
        self.att_nb = quat_from_rotation_vector(&phi) * self.att_nb;
        self.att_nb.renormalize_fast();
        self.vel_ned_mps += seg(dx, VEL);
        self.pos_ned_m += seg(dx, POS);
        self.gyro_bias_radps += seg(dx, BG);
        self.accel_bias_mps2 += seg(dx, BA);
        if N >= MARKOV + 3 {
            self.gyro_markov_radps += seg(dx, MARKOV);
        }
    }

    /// Heading (yaw of the ZYX Euler angles), rad in (-pi, pi].
    pub fn yaw_rad(&self) -> f32 {
        yaw_of(&self.att_nb)
    }

    /// All components finite, by their sum (checked on every IMU sample): NaN and infinities
    /// propagate through it; finite parts whose sum overflows (components of ~1e37) count as
    /// not finite, which refuses the sample (no real state is near that).
    pub fn is_finite(&self) -> bool {
        let sum = |v: &[f32]| v.iter().fold(0.0f32, |a, b| a + b);
        (sum(self.att_nb.coords.as_slice())
            + sum(self.vel_ned_mps.as_slice())
            + sum(self.pos_ned_m.as_slice())
            + sum(self.gyro_bias_radps.as_slice())
            + sum(self.accel_bias_mps2.as_slice())
            + sum(self.gyro_markov_radps.as_slice()))
        .is_finite()
    }
}

/// Yaw of a body -> NED rotation: `atan2(R[1,0], R[0,0])`.
pub fn yaw_of(q: &UnitQuaternion<f32>) -> f32 {
    let (w, x, y, z) = (q.w, q.i, q.j, q.k);
    let r10 = 2.0 * (x * y + w * z);
    let r00 = 1.0 - 2.0 * (y * y + z * z);
    libm::atan2f(r10, r00)
}
