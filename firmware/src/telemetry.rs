//! Telemetry output: frames uplink messages and hands them to a board's byte sink.

use subnav_wire::{self as wire, MAX_UPLINK_FRAME, Uplink};

/// Where framed telemetry bytes go (a UART, an RTT channel, a test buffer).
pub trait TelemetrySink {
    /// Write a whole frame. Returns `false` if the sink could not take it (the frame is dropped
    /// and counted; the application never blocks on telemetry).
    fn write_frame(&mut self, frame: &[u8]) -> bool;
}

/// Frames messages into a fixed buffer and counts what could not be sent.
pub struct Telemetry {
    buf: [u8; MAX_UPLINK_FRAME],
    /// Messages sent / dropped since boot.
    pub sent: u32,
    pub dropped: u32,
}

impl Default for Telemetry {
    fn default() -> Self {
        Self::new()
    }
}

impl Telemetry {
    pub const fn new() -> Self {
        Self { buf: [0; MAX_UPLINK_FRAME], sent: 0, dropped: 0 }
    }

    pub fn send(&mut self, msg: &Uplink, sink: &mut impl TelemetrySink) {
        match wire::encode(msg, &mut self.buf) {
            Ok(frame) if sink.write_frame(frame) => self.sent = self.sent.wrapping_add(1),
            // Encoding cannot fail for a buffer of MAX_UPLINK_FRAME (tested in shared); a full
            // sink is counted and reported as a fault by the application.
            _ => self.dropped = self.dropped.wrapping_add(1),
        }
    }
}

#[cfg(test)]
impl TelemetrySink for std::vec::Vec<u8> {
    fn write_frame(&mut self, frame: &[u8]) -> bool {
        self.extend_from_slice(frame);
        true
    }
}
