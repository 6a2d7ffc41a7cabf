//! Uplink stream decoding with statistics: every intact frame is decoded, every corrupt one is
//! counted (and reported), and a boot message from an incompatible firmware is flagged.

use serde::Serialize;
use subnav_wire::{Compatibility, Decoded, FrameDecoder, FrameError, MAX_UPLINK_FRAME, Uplink};

/// One decoded item of the uplink stream.
#[derive(Debug, Clone, PartialEq)]
pub enum LinkEvent {
    Message(Uplink),
    Corrupt(FrameError),
    /// A boot message whose protocol version or schema differs from this host's.
    Incompatible(Compatibility),
}

/// Counts over a stream.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct LinkStats {
    pub bytes: u64,
    pub frames_ok: u64,
    pub frames_bad: u64,
    pub boots: u64,
    pub incompatible_boots: u64,
}

#[derive(Default)]
pub struct UplinkDecoder {
    frames: FrameDecoder<MAX_UPLINK_FRAME>,
    stats: LinkStats,
}

impl UplinkDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// Feed bytes; `on_event` gets every message, corrupt frame and compatibility warning.
    pub fn feed(&mut self, bytes: &[u8], mut on_event: impl FnMut(LinkEvent)) {
        self.stats.bytes += bytes.len() as u64;
        for &b in bytes {
            match self.frames.push::<Uplink>(b) {
                Decoded::Pending => {}
                Decoded::Corrupt(e) => {
                    self.stats.frames_bad += 1;
                    on_event(LinkEvent::Corrupt(e));
                }
                Decoded::Message(m) => {
                    self.stats.frames_ok += 1;
                    if let Uplink::Boot(boot) = &m {
                        self.stats.boots += 1;
                        let c = boot.compatibility();
                        if c != Compatibility::Compatible {
                            self.stats.incompatible_boots += 1;
                            on_event(LinkEvent::Incompatible(c));
                        }
                    }
                    on_event(LinkEvent::Message(m));
                }
            }
        }
    }

    /// Bytes of an unfinished frame at the end of the input (reported, not silently dropped).
    pub fn trailing_bytes(&self) -> usize {
        self.frames.pending_len()
    }
}

/// Human-readable explanation of an incompatibility.
pub fn describe(c: &Compatibility) -> String {
    match c {
        Compatibility::Compatible => "compatible".into(),
        Compatibility::VersionMismatch { ours, theirs } => format!(
            "firmware speaks protocol version {theirs}, this host speaks {ours}: messages after this boot may not decode; update the host or the firmware"
        ),
        Compatibility::SchemaMismatch { ours, theirs } => format!(
            "firmware message schema {theirs:#018x} differs from this host's {ours:#018x} (same protocol version): rebuild host and firmware from the same source"
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use subnav_wire::{self as wire, Board, CommandAck, boot_message};

    #[test]
    fn flags_an_incompatible_boot_and_keeps_decoding() {
        let mut bytes = vec![];
        let mut buf = [0u8; MAX_UPLINK_FRAME];
        let mut boot =
            boot_message(Board::QemuMps2An386, [0, 1, 0], 0, subnav_wire::CalibrationInUse::NO_STORE, subnav_wire::ResetCause::PowerOn);
        boot.protocol_version += 1;
        bytes.extend_from_slice(wire::encode(&Uplink::Boot(boot), &mut buf).unwrap());
        bytes.extend_from_slice(wire::encode(&Uplink::Ack(CommandAck { seq: 3, result: Ok(()) }), &mut buf).unwrap());
        let mut dec = UplinkDecoder::new();
        let mut events = vec![];
        dec.feed(&bytes, |e| events.push(e));
        assert!(matches!(events[0], LinkEvent::Incompatible(Compatibility::VersionMismatch { .. })));
        assert_eq!(events.len(), 3);
        assert_eq!(dec.stats().incompatible_boots, 1);
        assert_eq!(dec.stats().frames_ok, 2);
    }
}
