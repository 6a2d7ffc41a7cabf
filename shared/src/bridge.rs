//! Sensor-bus bridge for hardware-in-the-loop under QEMU.
//!
//! The QEMU board has no I2C/SPI sensors. Its bus implementation (embedded-hal 1.0 `I2c` and
//! `SpiDevice`) turns each transaction into a [`BusRequest`], sends it over a second UART to the
//! host, and blocks until the [`BusResponse`]. The host's register-level chip models answer *for
//! the firmware's timestamp* in the request, so a run is deterministic whatever the host's speed.
//!
//! Frames use the same COBS + CRC-32 framing as telemetry ([`crate::wire::frame`]). Payloads are
//! fixed-size arrays with a length (no heap, bounded frames).

use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

use crate::wire::max_frame_len;

/// Largest number of bytes in one bus operation.
pub const MAX_OP_BYTES: usize = 32;
/// Largest number of operations in one transaction.
pub const MAX_OPS: usize = 4;

/// Which bus (and, for SPI, which chip select) a transaction is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Bus {
    /// I2C bus `n`, 7-bit device address.
    I2c { bus: u8, address: u8 },
    /// SPI bus `n`, chip select `cs`.
    Spi { bus: u8, cs: u8 },
}

/// A byte buffer of up to [`MAX_OP_BYTES`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Bytes {
    pub len: u8,
    pub data: [u8; MAX_OP_BYTES],
}

impl Bytes {
    pub const EMPTY: Bytes = Bytes { len: 0, data: [0; MAX_OP_BYTES] };

    /// Copy `src`; `None` if it is longer than [`MAX_OP_BYTES`].
    pub fn from_slice(src: &[u8]) -> Option<Self> {
        let mut b = Self::EMPTY;
        b.data.get_mut(..src.len())?.copy_from_slice(src);
        b.len = u8::try_from(src.len()).ok()?;
        Some(b)
    }

    pub fn as_slice(&self) -> &[u8] {
        self.data.get(..usize::from(self.len)).unwrap_or(&[])
    }
}

/// One operation of a transaction. I2C: `Write` / `Read`. SPI: also `Transfer` (full duplex:
/// as many bytes are read as written).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Op {
    Write(Bytes),
    Read { len: u8 },
    Transfer(Bytes),
}

/// Firmware -> host.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BusRequest {
    /// Sequence number, echoed in the response.
    pub seq: u32,
    /// Firmware time of the transaction (µs since boot): the instant the chip models answer for.
    pub t_us: u64,
    pub bus: Bus,
    pub n_ops: u8,
    pub ops: [Op; MAX_OPS],
}

/// Why a transaction failed (what a real bus reports).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BusFault {
    /// No device acknowledged the address (or a data byte).
    Nack,
    /// The device held the bus too long.
    Timeout,
    /// Anything else (arbitration loss, overrun).
    Other,
}

/// Host -> firmware: the bytes read by each `Read` / `Transfer` op, concatenated in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BusResponse {
    pub seq: u32,
    pub result: Result<ReadData, BusFault>,
}

/// Read bytes of a transaction (up to `MAX_OPS * MAX_OP_BYTES`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ReadData {
    pub len: u8,
    #[serde(with = "big_array")]
    pub data: [u8; MAX_OPS * MAX_OP_BYTES],
}

impl ReadData {
    pub const EMPTY: ReadData = ReadData { len: 0, data: [0; MAX_OPS * MAX_OP_BYTES] };

    pub fn as_slice(&self) -> &[u8] {
        self.data.get(..usize::from(self.len)).unwrap_or(&[])
    }

    /// Append bytes; `false` if they do not fit.
    pub fn push(&mut self, bytes: &[u8]) -> bool {
        let start = usize::from(self.len);
        let Some(dst) = self.data.get_mut(start..start + bytes.len()) else { return false };
        dst.copy_from_slice(bytes);
        self.len += bytes.len() as u8;
        true
    }
}

/// serde for `[u8; 128]` (serde derives arrays only up to 32), as a fixed-length tuple.
mod big_array {
    use serde::de::{Error, SeqAccess, Visitor};
    use serde::ser::SerializeTuple;
    use serde::{Deserializer, Serializer};

    const N: usize = super::MAX_OPS * super::MAX_OP_BYTES;

    pub fn serialize<S: Serializer>(a: &[u8; N], s: S) -> Result<S::Ok, S::Error> {
        let mut t = s.serialize_tuple(N)?;
        for b in a {
            t.serialize_element(b)?;
        }
        t.end()
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<[u8; N], D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = [u8; N];
            fn expecting(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                write!(f, "{N} bytes")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<[u8; N], A::Error> {
                let mut out = [0u8; N];
                for (i, slot) in out.iter_mut().enumerate() {
                    *slot = seq.next_element()?.ok_or_else(|| A::Error::invalid_length(i, &self))?;
                }
                Ok(out)
            }
        }
        d.deserialize_tuple(N, V)
    }
}

/// Largest request / response frame on the bridge UART.
pub const MAX_REQUEST_FRAME: usize = max_frame_len(BusRequest::POSTCARD_MAX_SIZE);
pub const MAX_RESPONSE_FRAME: usize = max_frame_len(BusResponse::POSTCARD_MAX_SIZE);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::{decode_in_place, encode};

    #[test]
    fn request_and_response_roundtrip() {
        let mut ops = [Op::Read { len: 0 }; MAX_OPS];
        ops[0] = Op::Write(Bytes::from_slice(&[0x1f, 0x80]).unwrap());
        ops[1] = Op::Read { len: 14 };
        let req = BusRequest { seq: 7, t_us: 123_456, bus: Bus::Spi { bus: 0, cs: 1 }, n_ops: 2, ops };
        let mut buf = [0u8; MAX_REQUEST_FRAME];
        let f = encode(&req, &mut buf).unwrap();
        let n = f.len() - 1;
        assert_eq!(decode_in_place::<BusRequest>(&mut f[..n]).unwrap(), req);

        let mut data = ReadData::EMPTY;
        assert!(data.push(&[1, 2, 3]));
        assert!(!data.push(&[0; 200]));
        let resp = BusResponse { seq: 7, result: Ok(data) };
        let mut buf = [0u8; MAX_RESPONSE_FRAME];
        let f = encode(&resp, &mut buf).unwrap();
        let n = f.len() - 1;
        let back = decode_in_place::<BusResponse>(&mut f[..n]).unwrap();
        assert_eq!(back, resp);
        assert_eq!(back.result.unwrap().as_slice(), &[1, 2, 3]);
        let nack = BusResponse { seq: 8, result: Err(BusFault::Nack) };
        let f = encode(&nack, &mut buf).unwrap();
        let n = f.len() - 1;
        assert_eq!(decode_in_place::<BusResponse>(&mut f[..n]).unwrap(), nack);
    }

    #[test]
    fn oversized_payload_is_refused() {
        assert!(Bytes::from_slice(&[0u8; MAX_OP_BYTES + 1]).is_none());
        assert_eq!(Bytes::from_slice(&[9u8; MAX_OP_BYTES]).unwrap().as_slice(), &[9u8; MAX_OP_BYTES]);
    }
}
