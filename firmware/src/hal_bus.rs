//! Any embedded-hal 1.0 I2C bus or SPI device as a sensor-head bus: the wrappers delegate every
//! transaction and turn the HAL's error into a [`HalBusError`], which knows its telemetry fault
//! kind (through the embedded-hal `ErrorKind`). The STM32 board wraps its peripherals in these;
//! the QEMU board uses `bus_bridge`, whose error already knows its kind.
//!
//! Why a wrapper: [`crate::drivers::BusErrorKind`] is this crate's trait, and a board binary may
//! not implement it for a HAL's error type (both foreign to the binary).

use embedded_hal::i2c::{self, I2c, Operation as I2cOp};
use embedded_hal::spi::{self, Operation as SpiOp, SpiDevice};
use subnav_wire::FaultKind;

use crate::drivers::BusErrorKind;

/// A HAL bus error reduced to what the sensor head reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HalBusError(pub FaultKind);

impl core::fmt::Display for HalBusError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "HAL bus transaction failed: {}", self.0)
    }
}

impl core::error::Error for HalBusError {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        Some(&self.0)
    }
}

impl BusErrorKind for HalBusError {
    fn fault_kind(&self) -> FaultKind {
        self.0
    }
}

impl i2c::Error for HalBusError {
    fn kind(&self) -> i2c::ErrorKind {
        match self.0 {
            FaultKind::BusNack => i2c::ErrorKind::NoAcknowledge(i2c::NoAcknowledgeSource::Unknown),
            _ => i2c::ErrorKind::Other,
        }
    }
}

/// For a board's UART wrapper (the DVL's), whose HAL error is foreign too.
impl embedded_io::Error for HalBusError {
    fn kind(&self) -> embedded_io::ErrorKind {
        embedded_io::ErrorKind::Other
    }
}

impl spi::Error for HalBusError {
    fn kind(&self) -> spi::ErrorKind {
        spi::ErrorKind::Other
    }
}

/// An I2C bus (or a shared-bus device such as embedded-hal-bus's `RefCellDevice`).
pub struct HalI2c<T>(pub T);

impl<T: I2c> i2c::ErrorType for HalI2c<T> {
    type Error = HalBusError;
}

impl<T: I2c> I2c for HalI2c<T> {
    fn transaction(&mut self, address: u8, operations: &mut [I2cOp<'_>]) -> Result<(), HalBusError> {
        self.0.transaction(address, operations).map_err(|e| HalBusError(crate::drivers::i2c_fault_kind(&e)))
    }
}

/// Either of two I2C buses behind one type: the head's eight polarization ADCs are one array of
/// bus handles while units 0-3 and 4-7 sit on different peripherals (`bus_map`), whose HAL
/// types differ (on the STM32 board I2C1 and I2C3).
pub enum HalI2cEither<A, B> {
    First(HalI2c<A>),
    Second(HalI2c<B>),
}

impl<A: I2c, B: I2c> i2c::ErrorType for HalI2cEither<A, B> {
    type Error = HalBusError;
}

impl<A: I2c, B: I2c> I2c for HalI2cEither<A, B> {
    fn transaction(&mut self, address: u8, operations: &mut [I2cOp<'_>]) -> Result<(), HalBusError> {
        match self {
            Self::First(bus) => bus.transaction(address, operations),
            Self::Second(bus) => bus.transaction(address, operations),
        }
    }
}

/// An SPI device (bus + chip select).
pub struct HalSpi<T>(pub T);

impl<T: SpiDevice> spi::ErrorType for HalSpi<T> {
    type Error = HalBusError;
}

impl<T: SpiDevice> SpiDevice for HalSpi<T> {
    fn transaction(&mut self, operations: &mut [SpiOp<'_, u8>]) -> Result<(), HalBusError> {
        self.0.transaction(operations).map_err(|e| {
            HalBusError(match spi::Error::kind(&e) {
                spi::ErrorKind::ChipSelectFault => FaultKind::BusNack,
                _ => FaultKind::BusOther,
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal_mock::eh1::i2c::{Mock as I2cMock, Transaction as I2cT};
    use embedded_hal_mock::eh1::spi::{Mock as SpiMock, Transaction as SpiT};

    #[test]
    fn i2c_transactions_pass_through_and_errors_keep_their_kind() {
        let expect =
            [I2cT::transaction_start(0x76), I2cT::write(0x76, vec![0xA0]), I2cT::read(0x76, vec![0x12, 0x34]), I2cT::transaction_end(0x76)];
        let mut bus = HalI2c(I2cMock::new(&expect));
        let mut buf = [0u8; 2];
        bus.write_read(0x76, &[0xA0], &mut buf).unwrap();
        assert_eq!(buf, [0x12, 0x34]);
        bus.0.done();
        // A HAL that NACKs / fails otherwise.
        struct Failing(i2c::ErrorKind);
        impl i2c::ErrorType for Failing {
            type Error = i2c::ErrorKind;
        }
        impl I2c for Failing {
            fn transaction(&mut self, _: u8, _: &mut [I2cOp<'_>]) -> Result<(), i2c::ErrorKind> {
                Err(self.0)
            }
        }
        let nack = HalI2c(Failing(i2c::ErrorKind::NoAcknowledge(i2c::NoAcknowledgeSource::Address))).write(0x48, &[1]).unwrap_err();
        assert_eq!(nack.fault_kind(), FaultKind::BusNack);
        let other = HalI2c(Failing(i2c::ErrorKind::ArbitrationLoss)).write(0x48, &[1]).unwrap_err();
        assert_eq!(other.fault_kind(), FaultKind::BusOther);
        // Either of two buses: each variant reaches its own bus.
        let mut second: HalI2cEither<Failing, I2cMock> = HalI2cEither::Second(HalI2c(I2cMock::new(&[
            I2cT::transaction_start(0x4A),
            I2cT::write(0x4A, vec![1]),
            I2cT::transaction_end(0x4A),
        ])));
        second.write(0x4A, &[1]).unwrap();
        if let HalI2cEither::Second(HalI2c(m)) = &mut second {
            m.done();
        }
        let mut first: HalI2cEither<Failing, I2cMock> = HalI2cEither::First(HalI2c(Failing(i2c::ErrorKind::ArbitrationLoss)));
        assert_eq!(first.write(0x48, &[1]).unwrap_err(), HalBusError(FaultKind::BusOther));
        assert_eq!(i2c::Error::kind(&HalBusError(FaultKind::BusNack)), i2c::ErrorKind::NoAcknowledge(i2c::NoAcknowledgeSource::Unknown));
    }

    #[test]
    fn spi_transactions_pass_through() {
        let expect = [SpiT::transaction_start(), SpiT::transfer_in_place(vec![0xF5, 0x00], vec![0x00, 0x47]), SpiT::transaction_end()];
        let mut dev = HalSpi(SpiMock::new(&expect));
        let mut buf = [0xF5, 0x00];
        dev.transfer_in_place(&mut buf).unwrap();
        assert_eq!(buf[1], 0x47);
        dev.0.done();
    }
}
