//! The head's run-time configuration: what downlink `SetConfig` changes (range-checked in
//! `app::commands`) and the stored `RunConfig` record holds (`calibration::run_config`). Its own
//! module so that `app` and `calibration` both use it without depending on each other.

/// Run-time configuration (changed by downlink `SetConfig`, range-checked).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AppConfig {
    pub nav_rate_hz: u8,
    pub stream_raw: bool,
    pub water_density_kgm3: f32,
    pub origin: Option<(f64, f64, f32)>,
}

impl Default for AppConfig {
    fn default() -> Self {
        Self { nav_rate_hz: 10, stream_raw: true, water_density_kgm3: 1025.0, origin: None }
    }
}
