//! subnav-base: what the host's methods and simulators share.
//!
//! - [`trajectory`]: the sensor-head dive's truth trajectory (descent and lawnmower survey).
//! - [`imu`]: IMU synthesis shared by every simulator: specific force and body rate from the
//!   truth, the lawnmower turn schedule, the IMU error model from a grade, the host `ImuSample`.
//! - [`sky`]: the polarized sky and water seen by the compass units (sensor grades from
//!   `subnav_core::head`).
//! - [`osoaa`]: the real field's departure from single scattering, from a table of OSOAA
//!   radiative-transfer fields (used by [`sky::SeaField`]).
//! - [`sea`]: the moving wind-driven sea surface (Elfouhaily spectrum, Cox-Munk slopes).
//! - [`so3`]: SO(3) helpers in f64 (exponential, logarithm, hat, Jacobians).
//! - [`chi2`]: the chi-square CDF and quantile for the gates.
//! - [`limits`]: size limits on what a file can make the host allocate (images, tables).
//! - [`wrap_pi`]: the one angle wrap (re-exported from `subnav_core::ukf`).
pub mod chi2;
pub mod imu;
pub mod limits;
pub mod osoaa;
pub mod sea;
pub mod sky;
pub mod so3;
pub mod trajectory;

pub use subnav_core::ukf::wrap_pi;
