//! The sensor head's navigation filter (spec A4/A5): an INS error-state UKF.
//!
//! - [`state`]: nominal state and error-state layout (15 states, or 18 with Markov gyro drift).
//! - [`strapdown`]: IMU-rate integration and the error transition used by the UKF predict.
//! - one file per aiding sensor: [`heading`] (polarization compass), [`depth`], [`velocity`]
//!   (body frame), [`dvl`] (DVL velocity with mounting rotation and lever arm), [`position`]
//!   (position fix with covariance from the host).
//! - [`history`]: the fixed-size past of the nominal state, for fusing position and velocity
//!   measurements at their own (past) time of validity.
//! - [`health`]: the `FilterHealth` telemetry message.
//!
//! Use from a firmware app:
//! ```
//! use subnav_core::nav::{NavConfig, NavFilter15, NavInit};
//! use subnav_wire::messages::ImuSample;
//! # use nalgebra::{UnitQuaternion, Vector3};
//! let init = NavInit { t_us: 0, att_nb: UnitQuaternion::identity(), vel_ned_mps: Vector3::zeros(), pos_ned_m: Vector3::zeros() };
//! let mut nav = NavFilter15::new(NavConfig::default().adaptive(), init).unwrap();
//! for k in 0..100u64 {
//!     let imu = ImuSample { t_us: k * 10_000, gyro_radps: [0.0; 3], accel_mps2: [0.0, 0.0, -9.81], temp_c: 20.0 };
//!     nav.propagate(&imu).unwrap();
//! }
//! nav.update_depth(1_000_000, 0.0, None).unwrap();
//! let _solution = nav.solution();
//! let _health = nav.health();
//! ```

pub mod depth;
pub mod dvl;
mod filter;
pub mod heading;
pub mod health;
pub mod history;
pub mod position;
pub mod rotation;
pub mod state;
pub mod strapdown;
pub mod velocity;

pub use filter::{
    KIND_DEPTH, KIND_HEADING, KIND_POSITION, KIND_VELOCITY, NavConfig, NavError, NavFilter, NavFilter15, NavFilter18, NavInit, SensorConfig,
};
pub use state::NominalState;

#[cfg(test)]
mod delay_tests;
#[cfg(test)]
mod refusal_tests;
#[cfg(test)]
mod tests;
