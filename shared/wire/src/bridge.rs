//! Sensor-bus bridge for hardware-in-the-loop under QEMU.
//!
//! The QEMU board has no I2C/SPI/UART sensors. Its bus implementation (embedded-hal 1.0 `I2c` and
//! `SpiDevice`) turns each transaction into a [`BusRequest`], sends it over a second UART to the
//! host, and blocks until the [`BusResponse`]. The host's register-level chip models answer *for
//! the firmware's timestamp* in the request, so a run is deterministic whatever the host's speed.
//!
//! Frames use the same COBS + CRC-32 framing as telemetry ([`crate::frame`]). Payloads are
//! fixed-size arrays with a length in memory (no heap, bounded frames) and only their used bytes
//! on the wire (postcard byte strings: a varint length and the bytes): a 2-byte register read is
//! a ~20-byte frame, not the ~300 bytes the full arrays would take, which matters because the
//! M4 encodes, CRCs and COBS-stuffs every frame.

use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

use crate::max_frame_len;

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
    /// UART `port` (a serial instrument such as the DVL). `Op::Read { len }` asks for up to
    /// `len` bytes: the response holds the bytes fully received by the request's time (possibly
    /// none); `Op::Write` sends bytes at that time.
    Uart { port: u8 },
    /// Digital output `pin` (e.g. a camera's trigger line): `Op::Write` of one byte, 0 = low,
    /// anything else = high, at the request's time.
    Gpio { pin: u8 },
}

/// A byte buffer of up to [`MAX_OP_BYTES`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
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

impl core::fmt::Display for BusFault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            BusFault::Nack => "bus NACK: no device acknowledged the address or a data byte",
            BusFault::Timeout => "bus timeout: the device held the bus too long",
            BusFault::Other => "bus error (arbitration loss, overrun or other)",
        })
    }
}

impl core::error::Error for BusFault {}

/// Host -> firmware: the bytes read by each `Read` / `Transfer` op, concatenated in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BusResponse {
    pub seq: u32,
    pub result: Result<ReadData, BusFault>,
}

/// Read bytes of a transaction (up to `MAX_OPS * MAX_OP_BYTES`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ReadData {
    pub len: u8,
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

/// serde as a byte string of the used bytes (`len` of them), for [`Bytes`] and [`ReadData`].
macro_rules! bounded_bytes_serde {
    ($ty:ident, $n:expr) => {
        impl Serialize for $ty {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_bytes(self.data.get(..usize::from(self.len)).unwrap_or(&[]))
            }
        }

        impl<'de> Deserialize<'de> for $ty {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                struct V;
                impl<'de> serde::de::Visitor<'de> for V {
                    type Value = $ty;
                    fn expecting(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                        write!(f, "at most {} bytes", $n)
                    }
                    fn visit_bytes<E: serde::de::Error>(self, v: &[u8]) -> Result<$ty, E> {
                        let mut out = $ty { len: 0, data: [0; $n] };
                        let dst = out.data.get_mut(..v.len()).ok_or_else(|| E::invalid_length(v.len(), &self))?;
                        dst.copy_from_slice(v);
                        out.len = u8::try_from(v.len()).map_err(|_| E::invalid_length(v.len(), &self))?;
                        Ok(out)
                    }
                    fn visit_borrowed_bytes<E: serde::de::Error>(self, v: &'de [u8]) -> Result<$ty, E> {
                        self.visit_bytes(v)
                    }
                }
                d.deserialize_bytes(V)
            }
        }

        impl MaxSize for $ty {
            // varint length (1 byte up to 127, 2 up to 16383) + the bytes
            const POSTCARD_MAX_SIZE: usize = if $n < 128 { 1 } else { 2 } + $n;
        }
    };
}

bounded_bytes_serde!(Bytes, MAX_OP_BYTES);
bounded_bytes_serde!(ReadData, MAX_OPS * MAX_OP_BYTES);

/// Largest request / response frame on the bridge UART.
pub const MAX_REQUEST_FRAME: usize = max_frame_len(BusRequest::POSTCARD_MAX_SIZE);
pub const MAX_RESPONSE_FRAME: usize = max_frame_len(BusResponse::POSTCARD_MAX_SIZE);

/// The sensor head's bus map, once: which chip sits on which bridge bus, for the QEMU board,
/// the host-native board (`subnav-sil`) and the simulated chips alike (the STM32 board maps
/// bridge bus `n` to its own peripherals: I2C 0 = I2C1, I2C 1 = I2C3, SPI 0 = SPI1 for the IMU
/// and SPI2 for the flash, UART 0 = USART3; `firmware/src/bin/stm32f4.rs`).
pub mod bus_map {
    /// (SPI bus, chip select) of the ICM-42688-P IMU.
    pub const IMU_SPI: (u8, u8) = (0, 0);
    /// (SPI bus, chip select) of the W25Q16JV store flash.
    pub const FLASH_SPI: (u8, u8) = (0, 1);
    /// (I2C bus, address) of polarization unit `u`'s ADS1115. The chip has four addresses
    /// (ADDR pin to GND, VDD, SDA, SCL), so eight units take two buses, four on each.
    pub const POLARIZATION_ADC_I2C: [(u8, u8); 8] =
        [(0, 0x48), (0, 0x49), (0, 0x4A), (0, 0x4B), (1, 0x48), (1, 0x49), (1, 0x4A), (1, 0x4B)];
    /// (I2C bus, address) of the MS5837-30BA depth sensor.
    pub const DEPTH_I2C: (u8, u8) = (0, 0x76);
    /// UART of the DVL-A50.
    pub const DVL_UART: u8 = 0;
    /// UART of the acoustic modem that brings position fixes (the simulated dives).
    pub const MODEM_UART: u8 = 1;
    /// Digital output of the camera's trigger line.
    pub const CAMERA_TRIGGER_GPIO: u8 = 0;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{decode_in_place, encode};

    #[test]
    fn no_two_chips_share_a_bus_address() {
        use bus_map::*;
        let mut i2c = [DEPTH_I2C; 9];
        i2c[..8].copy_from_slice(&POLARIZATION_ADC_I2C);
        i2c.sort_unstable();
        assert!(i2c.windows(2).all(|w| w[0] != w[1]), "two I2C chips on one bus and address");
        assert_ne!(IMU_SPI, FLASH_SPI);
        assert_ne!(DVL_UART, MODEM_UART);
    }

    #[test]
    fn frames_carry_only_the_used_bytes_and_full_ones_still_fit() {
        let mut ops = [Op::Read { len: 0 }; MAX_OPS];
        ops[0] = Op::Write(Bytes::from_slice(&[0x1f]).unwrap());
        ops[1] = Op::Read { len: 2 };
        let req = BusRequest { seq: 7, t_us: 123_456_789, bus: Bus::I2c { bus: 0, address: 0x76 }, n_ops: 2, ops };
        let mut buf = [0u8; MAX_REQUEST_FRAME];
        let small = encode(&req, &mut buf).unwrap().len();
        assert!(small <= 24, "a register read request is {small} bytes");
        let mut data = ReadData::EMPTY;
        assert!(data.push(&[0xAB, 0xCD]));
        let mut rbuf = [0u8; MAX_RESPONSE_FRAME];
        let small = encode(&BusResponse { seq: 7, result: Ok(data) }, &mut rbuf).unwrap().len();
        assert!(small <= 16, "a 2-byte response is {small} bytes");
        // Full-size payloads fit the maximum frames and round-trip.
        let full = [Op::Transfer(Bytes::from_slice(&[0xA5; MAX_OP_BYTES]).unwrap()); MAX_OPS];
        let req = BusRequest { seq: u32::MAX, t_us: u64::MAX, bus: Bus::Spi { bus: 255, cs: 255 }, n_ops: MAX_OPS as u8, ops: full };
        let f = encode(&req, &mut buf).unwrap();
        let n = f.len() - 1;
        assert_eq!(decode_in_place::<BusRequest>(&mut f[..n]).unwrap(), req);
        let mut data = ReadData::EMPTY;
        assert!(data.push(&[0x5A; MAX_OPS * MAX_OP_BYTES]));
        let resp = BusResponse { seq: u32::MAX, result: Ok(data) };
        let f = encode(&resp, &mut rbuf).unwrap();
        let n = f.len() - 1;
        assert_eq!(decode_in_place::<BusResponse>(&mut f[..n]).unwrap(), resp);
    }

    #[test]
    fn an_oversized_byte_string_is_an_error_not_a_panic() {
        // postcard body of a BusResponse: seq varint, Ok variant 0, then a 200-byte string.
        let mut body = [0u8; 210];
        body[0] = 7; // seq
        body[1] = 0; // Ok
        body[2] = 100; // fits: the layout is right
        assert!(postcard::from_bytes::<BusResponse>(&body).is_ok());
        body[2] = 0xC8; // varint 200 = 0xC8 0x01: does not fit
        body[3] = 0x01;
        assert!(postcard::from_bytes::<BusResponse>(&body).is_err());
        let mut req_body = [0u8; 64];
        // seq, t_us, bus I2c{0, 0x48}, n_ops 1, op Write with a 40-byte string
        req_body[..6].copy_from_slice(&[1, 1, 0, 0, 0x48, 1]);
        req_body[6] = 0; // Op::Write
        req_body[7] = 30; // fits: the layout is right
        assert!(postcard::from_bytes::<BusRequest>(&req_body).is_ok());
        req_body[7] = 40; // does not fit
        assert!(postcard::from_bytes::<BusRequest>(&req_body).is_err());
    }

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
