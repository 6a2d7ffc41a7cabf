//! Sensor drivers on embedded-hal 1.0 (blocking), one module per chip.
//!
//! | module | chip | bus | crate |
//! |---|---|---|---|
//! | [`icm42688`] | TDK ICM-42688-P 6-axis IMU | SPI (`SpiDevice`) | written here: no maintained embedded-hal 1.0 crate gives register-level range/ODR control, data-ready and saturation reporting without heap |
//! | [`ads1115`] | 8 x TI ADS1115 16-bit ADCs (polarization photodiodes) | I2C 0x48..0x4B on two buses | `ads1x1x` 0.3 (eldruin) for the chip; this module only schedules the 32 single-shot conversions |
//! | [`dvl_a50`] | Water Linked DVL-A50 Doppler velocity log | UART (`embedded_io` `Read + ReadReady`, `Write` for commands) | written here: Water Linked's serial protocol (`wrz` / `wrs` sentences, CRC-8) has no no_std crate |
//! | [`w25q`] | Winbond W25Q16JV 2 MiB NOR flash (the persistent store) | SPI (`SpiDevice`), CS 1 | written here: see the module doc |
//! | [`ms5837`] | TE MS5837-30BA pressure (Blue Robotics Bar30) | I2C 0x76 | written here: no maintained no_std embedded-hal 1.0 crate does the PROM CRC-4 check and the datasheet's second-order compensation |
//!
//! Style (eldruin's drivers): each driver owns its bus handle (share one bus between several
//! devices with `embedded-hal-bus` or the QEMU bridge's per-device handles) and gives it back with
//! `destroy()`. Errors wrap the bus error: [`Error::Bus`] for a NACK / timeout / bus fault, and
//! chip-level failures as their own variants. [`Error::fault_kind`] maps an error to the
//! telemetry [`FaultKind`].
//!
//! Axes: every driver reports in the chip's own axes. The sensor head mounts the IMU with its
//! axes equal to the body FRD axes (`subnav_wire` conventions); a different mounting is
//! a rotation the application applies, not the driver.
//!
//! Time: drivers never read a clock. Where the chip needs time (ICM-42688-P reset, MS5837
//! conversions, ADS1115 conversions) they either take a `DelayNs` (blocking calls) or offer a
//! start / poll pair that the scheduler drives with its own time (non-blocking calls), so one
//! slow conversion never stalls the IMU task.

pub mod ads1115;
pub mod dvl_a50;
pub mod icm42688;
pub mod ms5837;
pub mod w25q;

use subnav_wire::FaultKind;

/// A driver error: the bus failed, or the chip answered something the driver cannot use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Error<E> {
    /// The bus transaction failed (NACK, timeout, arbitration loss...). Carries the bus error.
    Bus(E),
    /// The identity register did not hold the expected value (wrong chip, or a dead bus reading
    /// 0x00 / 0xFF).
    IdentityMismatch { expected: u8, found: u8 },
    /// The calibration PROM failed its CRC-4 check.
    BadCrc { expected: u8, computed: u8 },
    /// The chip has no valid result yet (conversion not finished, sensor not powered up, or a
    /// conversion that never completed within the polling budget).
    NotReady,
    /// An argument or a reading outside what the chip supports.
    InvalidInput,
    /// A serial sentence that is not one of the protocol's (framing, fields, numbers, or a line
    /// too long for the driver's buffer).
    Malformed,
}

/// The bus error is shown with `Debug` (embedded-hal bus errors need not implement `Display`).
impl<E: core::fmt::Debug> core::fmt::Display for Error<E> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Error::Bus(e) => write!(f, "bus transaction failed: {e:?}"),
            Error::IdentityMismatch { expected, found } => {
                write!(f, "identity register reads {found:#04x}, expected {expected:#04x} (wrong chip or dead bus)")
            }
            Error::BadCrc { expected, computed } => {
                write!(f, "calibration PROM CRC-4 mismatch: stored {expected:#x}, computed {computed:#x}")
            }
            Error::NotReady => f.write_str("chip has no valid result yet (conversion not finished or not powered up)"),
            Error::InvalidInput => f.write_str("argument or reading outside what the chip supports"),
            Error::Malformed => f.write_str("serial sentence not in the protocol (framing, fields, numbers or an overlong line)"),
        }
    }
}

impl<E: core::fmt::Debug> core::error::Error for Error<E> {}

/// How a bus error maps to a telemetry fault kind. Implemented for the bus error types the
/// sensor head uses; [`Error::fault_kind`] uses it.
pub trait BusErrorKind {
    fn fault_kind(&self) -> FaultKind;
}

impl BusErrorKind for crate::bus_bridge::BridgeError {
    fn fault_kind(&self) -> FaultKind {
        use subnav_wire::bridge::BusFault;
        match self.0 {
            BusFault::Nack => FaultKind::BusNack,
            BusFault::Timeout => FaultKind::BusTimeout,
            BusFault::Other => FaultKind::BusOther,
        }
    }
}

/// No bus at all (a board without the instrument): never fails.
impl BusErrorKind for core::convert::Infallible {
    fn fault_kind(&self) -> FaultKind {
        match *self {}
    }
}

/// Map any embedded-hal I2C error through its [`embedded_hal::i2c::ErrorKind`].
pub fn i2c_fault_kind<E: embedded_hal::i2c::Error>(e: &E) -> FaultKind {
    match e.kind() {
        embedded_hal::i2c::ErrorKind::NoAcknowledge(_) => FaultKind::BusNack,
        _ => FaultKind::BusOther,
    }
}

/// Map any `embedded_io` (UART) error through its [`embedded_io::ErrorKind`].
pub fn uart_fault_kind<E: embedded_io::Error>(e: &E) -> FaultKind {
    match e.kind() {
        embedded_io::ErrorKind::TimedOut => FaultKind::BusTimeout,
        _ => FaultKind::BusOther,
    }
}

impl<E: BusErrorKind> Error<E> {
    /// The telemetry fault kind for this error.
    pub fn fault_kind(&self) -> FaultKind {
        match self {
            Error::Bus(e) => e.fault_kind(),
            Error::IdentityMismatch { .. } => FaultKind::IdentityMismatch,
            Error::BadCrc { .. } => FaultKind::BadCrc,
            Error::NotReady => FaultKind::BusTimeout,
            Error::InvalidInput => FaultKind::NonFinite,
            Error::Malformed => FaultKind::Malformed,
        }
    }
}

impl<E> Error<E> {
    /// Map the bus error type (e.g. to erase it before storing the error).
    pub fn map_bus<F>(self, f: impl FnOnce(E) -> F) -> Error<F> {
        match self {
            Error::Bus(e) => Error::Bus(f(e)),
            Error::IdentityMismatch { expected, found } => Error::IdentityMismatch { expected, found },
            Error::BadCrc { expected, computed } => Error::BadCrc { expected, computed },
            Error::NotReady => Error::NotReady,
            Error::InvalidInput => Error::InvalidInput,
            Error::Malformed => Error::Malformed,
        }
    }
}

/// Detects a stuck channel: the same raw value `limit` times in a row. Real sensor noise makes
/// long runs of identical 16-bit samples practically impossible (when the noise is at least
/// about one LSB), so a long run means a frozen register or a dead signal chain.
#[derive(Debug, Clone, Copy)]
pub struct StuckDetector<const N: usize> {
    last: [i32; N],
    run: [u16; N],
    limit: u16,
}

impl<const N: usize> StuckDetector<N> {
    /// `limit`: identical consecutive samples that count as stuck (>= 2).
    pub const fn new(limit: u16) -> Self {
        Self { last: [i32::MIN; N], run: [0; N], limit: if limit < 2 { 2 } else { limit } }
    }

    /// Feed one sample of every channel; returns a bit mask of the channels that are stuck now.
    pub fn update(&mut self, raw: [i32; N]) -> u32 {
        let mut mask = 0u32;
        for (i, ((v, last), run)) in raw.iter().zip(self.last.iter_mut()).zip(self.run.iter_mut()).enumerate() {
            if *v == *last {
                *run = run.saturating_add(1);
            } else {
                *run = 1;
                *last = *v;
            }
            if *run >= self.limit && i < 32 {
                mask |= 1 << i;
            }
        }
        mask
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stuck_detector_flags_only_long_identical_runs() {
        let mut d = StuckDetector::<2>::new(3);
        assert_eq!(d.update([1, 5]), 0);
        assert_eq!(d.update([1, 6]), 0);
        assert_eq!(d.update([1, 7]), 0b01);
        assert_eq!(d.update([2, 7]), 0);
        assert_eq!(d.update([2, 7]), 0b10);
        assert_eq!(d.update([2, 7]), 0b11);
    }

    #[test]
    fn bridge_errors_map_to_fault_kinds() {
        use crate::bus_bridge::BridgeError;
        use subnav_wire::bridge::BusFault;
        assert_eq!(Error::Bus(BridgeError(BusFault::Nack)).fault_kind(), FaultKind::BusNack);
        assert_eq!(Error::Bus(BridgeError(BusFault::Timeout)).fault_kind(), FaultKind::BusTimeout);
        assert_eq!(Error::<BridgeError>::BadCrc { expected: 1, computed: 2 }.fault_kind(), FaultKind::BadCrc);
        assert_eq!(Error::<BridgeError>::IdentityMismatch { expected: 0x47, found: 0 }.fault_kind(), FaultKind::IdentityMismatch);
    }
}
