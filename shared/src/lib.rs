//! subnav-shared: the `no_std`, allocation-free core that the sensor-head firmware and the host
//! tools both use, so that no math and no message definition is written twice.
//!
//! - [`wire`]: telemetry and command messages, postcard + CRC-32 + COBS framing.
//! - [`bridge`]: sensor-bus transactions carried to the host's chip models under QEMU.
//! - [`ephemeris`]: solar position from UTC and place, accurate enough for a compass, on an f32 FPU.
//! - [`compass`]: polarization compass: photodiode counts -> Stokes -> sun vector -> heading.
//! - [`ukf`]: generic fixed-size (adaptive) unscented Kalman filter.
//! - [`nav`]: the sensor head's INS error-state navigation filter and its per-sensor updates.
//! - [`depth_adaptive`]: adaptive measurement noise with a forgetting factor (under-ice depth/sonar updates).
//! - [`head`]: the sensor head's configuration: rates, compass units, sensor grades (read by the
//!   firmware's default tuning and by the host simulator).
//!
//! Frames and units are documented once, in [`wire::messages`].
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]

pub mod bridge;
pub mod compass;
pub mod depth_adaptive;
pub mod ephemeris;
pub mod head;
pub mod nav;
pub mod ukf;
pub mod wire;
