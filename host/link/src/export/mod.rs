//! Exporting a decoded recording: MCAP for Foxglove ([`mcap`]) and one CSV per message kind
//! ([`csv`]). Both work on a [`Session`](crate::record::session::Session).

pub mod csv;
pub mod mcap;
pub mod schema;
pub mod topics;

/// Which clock stamps exported messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum TimeBase {
    /// Host receive time (absolute, monotonic across sensor-head reboots).
    Host,
    /// Sensor-head time since boot (the firmware's `t_us`; deterministic for QEMU runs).
    /// Messages without their own time (acks, logs) take the latest sensor time seen before them.
    Sensor,
}
