//! subnav-base: what the host's methods and simulators share.
//!
//! - [`trajectory`]: the truth trajectory and IMU synthesis of the simulators.
//! - [`sky`]: the polarized sky and water seen by the compass units (sensor grades from
//!   `subnav_core::head`).
//! - [`so3`]: SO(3) helpers in f64 (exponential, logarithm, hat, Jacobians).
//! - [`chi2`]: the chi-square CDF and quantile for the gates.
pub mod chi2;
pub mod sky;
pub mod so3;
pub mod trajectory;
