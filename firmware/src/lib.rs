//! subnav sensor-head application core: HAL-agnostic and host-testable.
//!
//! Board binaries (`src/bin/*.rs`) own the hardware: clocks, UART, timers, buses. They call
//! [`App`] with the current time and the bytes they received, and send the frames it emits.
//! Everything here is `no_std`, allocation-free and panic-free on data paths.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]

pub mod app;
pub mod board_loop;
pub mod bus_bridge;
pub mod calibration;
pub mod config;
pub mod drivers;
pub mod estimator;
pub mod hal_bus;
pub mod head_suite;
pub mod log;
pub mod sensors;
pub mod store;
pub mod telemetry;
pub mod time;
pub mod uart_queue;

#[cfg(test)]
mod error_tests;

pub use app::App;
pub use config::AppConfig;
pub use telemetry::{Telemetry, TelemetrySink};

/// Firmware version reported in the boot message.
pub const FIRMWARE_VERSION: [u8; 3] = [0, 1, 0];
