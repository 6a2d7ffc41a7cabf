//! Telemetry link.
