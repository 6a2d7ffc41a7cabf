//! subnav-wire: the wire protocol between the sensor head and the host, `no_std` and
//! allocation-free: message types ([`messages`]), framing ([`frame`]: postcard + CRC-32 + COBS)
//! and the sensor-bus bridge used under QEMU ([`bridge`]). Both sides use exactly this code.
//!
//! Frames and units are documented once, in [`messages`].
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]

pub mod bridge;
#[cfg(feature = "std")]
#[doc(hidden)]
pub mod error_check;
pub mod frame;
pub mod messages;
pub mod records;

pub use frame::{Decoded, FrameDecoder, FrameError, decode_in_place, encode, max_frame_len};
pub use messages::*;
pub use records::*;

use postcard::experimental::max_size::MaxSize;

/// Bumped on every incompatible change of the messages or framing.
pub const PROTOCOL_VERSION: u16 = 7;

/// FNV-1a 64 of the postcard-schema description of [`Uplink`] and [`Downlink`]. A unit test
/// recomputes it from the types, so a message change without a new fingerprint fails the tests.
pub const SCHEMA_FINGERPRINT: u64 = 0x8dd8_b566_5692_e828;

/// Largest uplink frame on the wire, including CRC, COBS overhead and delimiter.
pub const MAX_UPLINK_FRAME: usize = max_frame_len(Uplink::POSTCARD_MAX_SIZE);
/// Largest downlink frame on the wire, including CRC, COBS overhead and delimiter.
pub const MAX_DOWNLINK_FRAME: usize = max_frame_len(Downlink::POSTCARD_MAX_SIZE);

/// The boot message this build of the protocol sends.
pub const fn boot_message(
    board: Board,
    firmware_version: [u8; 3],
    t_us: u64,
    calibration: CalibrationInUse,
    reset_cause: ResetCause,
) -> Boot {
    Boot {
        protocol_version: PROTOCOL_VERSION,
        schema_fingerprint: SCHEMA_FINGERPRINT,
        firmware_version,
        board,
        t_us,
        calibration,
        reset_cause,
    }
}

/// Whether a peer's boot message speaks our protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compatibility {
    Compatible,
    VersionMismatch { ours: u16, theirs: u16 },
    SchemaMismatch { ours: u64, theirs: u64 },
}

impl Boot {
    pub fn compatibility(&self) -> Compatibility {
        if self.protocol_version != PROTOCOL_VERSION {
            Compatibility::VersionMismatch { ours: PROTOCOL_VERSION, theirs: self.protocol_version }
        } else if self.schema_fingerprint != SCHEMA_FINGERPRINT {
            Compatibility::SchemaMismatch { ours: SCHEMA_FINGERPRINT, theirs: self.schema_fingerprint }
        } else {
            Compatibility::Compatible
        }
    }
}

#[cfg(test)]
mod tests;
