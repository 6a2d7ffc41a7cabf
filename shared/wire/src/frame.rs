//! Framing: `COBS( postcard(message) || CRC-32(postcard(message)) ) || 0x00`.
//!
//! postcard encodes the message, the CRC-32 (ISO-HDLC, little endian, computed by the `crc`
//! crate through postcard's own CRC flavor) protects it, and postcard's COBS flavor removes
//! every zero so that `0x00` delimits frames. A receiver that joins a stream mid-frame, or sees
//! corrupted bytes, loses at most the frames that were touched: the next `0x00` resynchronises.

use crc::{CRC_32_ISO_HDLC, Crc};
use postcard::ser_flavors::{Cobs, Slice, crc::CrcModifier};
use serde::{Serialize, de::DeserializeOwned};

/// The CRC used on every frame.
pub const FRAME_CRC: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);
/// Bytes of CRC appended to each payload.
pub const CRC_LEN: usize = 4;
/// Frame delimiter.
pub const DELIMITER: u8 = 0x00;

/// Largest COBS encoding (including the trailing delimiter) of `payload_len` bytes.
pub const fn max_frame_len(payload_len: usize) -> usize {
    let n = payload_len + CRC_LEN;
    // COBS adds one byte per 254 bytes of input (at least one), plus the delimiter.
    n + n / 254 + 1 + 1
}

/// Why a frame could not be decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// The output buffer is too small for the encoded frame.
    BufferTooSmall,
    /// The frame is not valid COBS.
    Cobs,
    /// Too short to hold a CRC.
    TooShort,
    /// The CRC does not match the payload.
    Crc,
    /// The CRC matched but the payload is not a valid message (e.g. a newer protocol).
    Payload,
    /// The frame is longer than any valid frame (delimiter lost).
    Overlong,
}

impl core::fmt::Display for FrameError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            FrameError::BufferTooSmall => "output buffer too small for the encoded frame",
            FrameError::Cobs => "frame is not valid COBS",
            FrameError::TooShort => "frame too short to hold its 4-byte CRC-32",
            FrameError::Crc => "frame CRC-32 does not match its payload",
            FrameError::Payload => "frame CRC ok but the payload is not a valid message (different protocol version?)",
            FrameError::Overlong => "frame longer than the protocol's maximum (delimiter lost?)",
        })
    }
}

impl core::error::Error for FrameError {}

/// Encode `msg` as one frame into `buf`; returns the frame including the trailing `0x00`.
pub fn encode<'a, T: Serialize>(msg: &T, buf: &'a mut [u8]) -> Result<&'a mut [u8], FrameError> {
    let cobs = Cobs::try_new(Slice::new(buf)).map_err(|_| FrameError::BufferTooSmall)?;
    let digest = FRAME_CRC.digest();
    let flavor = CrcModifier::new(cobs, digest);
    postcard::serialize_with_flavor(msg, flavor).map_err(|_| FrameError::BufferTooSmall)
}

/// Decode one frame body (the bytes between delimiters, without the `0x00`), in place.
pub fn decode_in_place<T: DeserializeOwned>(frame: &mut [u8]) -> Result<T, FrameError> {
    let n = cobs::decode_in_place(frame).map_err(|_| FrameError::Cobs)?;
    let data = frame.get(..n).ok_or(FrameError::Cobs)?;
    if data.len() < CRC_LEN {
        return Err(FrameError::TooShort);
    }
    let (payload, crc_bytes) = data.split_at(data.len() - CRC_LEN);
    let mut crc = [0u8; CRC_LEN];
    crc.copy_from_slice(crc_bytes);
    if FRAME_CRC.checksum(payload) != u32::from_le_bytes(crc) {
        return Err(FrameError::Crc);
    }
    let (msg, rest) = postcard::take_from_bytes::<T>(payload).map_err(|_| FrameError::Payload)?;
    if !rest.is_empty() {
        return Err(FrameError::Payload);
    }
    Ok(msg)
}

/// What [`FrameDecoder::push`] produced for one input byte.
#[derive(Debug, PartialEq)]
pub enum Decoded<T> {
    /// More bytes are needed.
    Pending,
    /// A complete, valid message.
    Message(T),
    /// A complete frame that was corrupt; the decoder has resynchronised.
    Corrupt(FrameError),
}

/// Incremental stream decoder over a fixed buffer of `N` bytes (no heap).
///
/// Feed bytes in any chunking; every delimiter yields a message or a counted error, never a
/// panic. Empty frames (consecutive delimiters) are skipped silently: senders may use a leading
/// `0x00` to flush a receiver's partial frame.
pub struct FrameDecoder<const N: usize> {
    buf: [u8; N],
    len: usize,
    overflowed: bool,
    /// Valid messages decoded.
    pub frames_ok: u64,
    /// Corrupt frames seen.
    pub frames_bad: u64,
}

impl<const N: usize> Default for FrameDecoder<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> FrameDecoder<N> {
    pub const fn new() -> Self {
        Self { buf: [0; N], len: 0, overflowed: false, frames_ok: 0, frames_bad: 0 }
    }

    /// Bytes buffered in the current, unfinished frame.
    pub fn pending_len(&self) -> usize {
        self.len
    }

    /// Push one byte.
    pub fn push<T: DeserializeOwned>(&mut self, byte: u8) -> Decoded<T> {
        if byte != DELIMITER {
            match self.buf.get_mut(self.len) {
                Some(slot) => {
                    *slot = byte;
                    self.len += 1;
                }
                None => self.overflowed = true,
            }
            return Decoded::Pending;
        }
        let len = core::mem::replace(&mut self.len, 0);
        if core::mem::replace(&mut self.overflowed, false) {
            self.frames_bad += 1;
            return Decoded::Corrupt(FrameError::Overlong);
        }
        if len == 0 {
            return Decoded::Pending;
        }
        let Some(frame) = self.buf.get_mut(..len) else {
            self.frames_bad += 1;
            return Decoded::Corrupt(FrameError::Overlong);
        };
        match decode_in_place::<T>(frame) {
            Ok(m) => {
                self.frames_ok += 1;
                Decoded::Message(m)
            }
            Err(e) => {
                self.frames_bad += 1;
                Decoded::Corrupt(e)
            }
        }
    }
}

impl crate::Downlink {
    /// CRC-32 of the command's postcard encoding (not its sequence number): the sensor head's
    /// duplicate filter compares `(seq, digest)`, so a repeated frame is recognised and a
    /// different command that reuses a number (another sender) is not taken for it.
    pub fn command_digest(&self) -> u32 {
        use postcard::experimental::max_size::MaxSize;
        let mut buf = [0u8; crate::Command::POSTCARD_MAX_SIZE];
        match postcard::to_slice(&self.command, &mut buf) {
            Ok(bytes) => FRAME_CRC.checksum(bytes),
            Err(_) => 0,
        }
    }
}
