//! Every error type of the firmware crate: a non-empty message per variant, different from the
//! others, and usable as `&dyn core::error::Error`.

use embedded_hal::i2c::ErrorKind;
use subnav_wire::bridge::BusFault;
use subnav_wire::error_check::assert_distinct_messages;
use subnav_wire::{FaultKind, FaultSource};

use crate::bus_bridge::BridgeError;
use crate::drivers::Error;
use crate::hal_bus::HalBusError;
use crate::sensors::SensorFault;

#[test]
fn bus_errors() {
    let bridge = [BridgeError(BusFault::Nack), BridgeError(BusFault::Timeout), BridgeError(BusFault::Other)];
    let refs: Vec<&dyn core::error::Error> = bridge.iter().map(|e| e as &dyn core::error::Error).collect();
    assert_distinct_messages("BridgeError", &refs);
    let source = core::error::Error::source(&bridge[0]).map(|s| s.to_string());
    assert_eq!(source, Some(BusFault::Nack.to_string()));

    let hal = [HalBusError(FaultKind::BusNack), HalBusError(FaultKind::BusTimeout), HalBusError(FaultKind::BusOther)];
    let refs: Vec<&dyn core::error::Error> = hal.iter().map(|e| e as &dyn core::error::Error).collect();
    assert_distinct_messages("HalBusError", &refs);
}

#[test]
fn driver_error() {
    let all: [Error<ErrorKind>; 6] = [
        Error::Bus(ErrorKind::Bus),
        Error::IdentityMismatch { expected: 0x47, found: 0x6f },
        Error::BadCrc { expected: 9, computed: 3 },
        Error::NotReady,
        Error::InvalidInput,
        Error::Malformed,
    ];
    let refs: Vec<&dyn core::error::Error> = all.iter().map(|e| e as &dyn core::error::Error).collect();
    assert_distinct_messages("drivers::Error", &refs);
    // The register values are in the message.
    let id = all[1].to_string();
    assert!(id.contains("0x6f") && id.contains("0x47"), "{id}");
    let crc = all[2].to_string();
    assert!(crc.contains("0x9") && crc.contains("0x3"), "{crc}");
    // The bus error is named.
    assert!(all[0].to_string().contains("Bus"), "{}", all[0]);
    // Works with the bridge's error as the bus error, too.
    let e: Error<BridgeError> = Error::Bus(BridgeError(BusFault::Timeout));
    assert!(e.to_string().contains("Timeout"), "{e}");
}

#[test]
fn sensor_fault() {
    let faults = [
        SensorFault { source: FaultSource::Imu, kind: FaultKind::BusTimeout },
        SensorFault { source: FaultSource::Polarization { unit: 2 }, kind: FaultKind::BusTimeout },
        SensorFault { source: FaultSource::Polarization { unit: 2 }, kind: FaultKind::Occluded },
        SensorFault { source: FaultSource::Depth, kind: FaultKind::BadCrc },
    ];
    let refs: Vec<&dyn core::error::Error> = faults.iter().map(|e| e as &dyn core::error::Error).collect();
    assert_distinct_messages("SensorFault", &refs);
    assert!(faults[1].to_string().contains("unit 2"), "{}", faults[1]);
}
