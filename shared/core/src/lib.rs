//! subnav-core: the `no_std`, allocation-free estimation core that the sensor-head firmware and
//! the host tools both use, so that no math is written twice. Messages and framing are in
//! `subnav-wire`.
//!
//! - [`ephemeris`]: solar position from UTC and place, accurate enough for a compass, on an f32 FPU.
//! - [`compass`]: polarization compass: photodiode counts -> Stokes -> sun vector -> heading.
//! - [`ukf`]: generic fixed-size (adaptive) unscented Kalman filter.
//! - [`nav`]: the sensor head's INS error-state navigation filter and its per-sensor updates.
//! - [`depth_adaptive`]: adaptive measurement noise with a forgetting factor (under-ice depth/sonar updates).
//! - [`head`]: the sensor head's configuration: rates, compass units, sensor grades (read by the
//!   firmware's default tuning and by the host simulator).
//!
//! Frames and units are documented once, in [`subnav_wire::messages`].
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]

pub mod compass;
pub mod depth_adaptive;
pub mod ephemeris;
pub mod head;
pub mod nav;
pub mod ukf;

#[cfg(test)]
mod error_tests;
