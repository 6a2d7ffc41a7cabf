//! The persistent store: one record per [`RecordKey`] in the head's NOR flash.
//!
//! [`FlashStore`] keeps the records with `sequential-storage`'s map (tweedegolf: wear-levelled
//! over the pages of its range, power-loss safe: an interrupted write leaves the previous value
//! readable, and the crate repairs a half-written page on the next operation), over the
//! [`W25q`](crate::drivers::w25q::W25q) driver. Each value is the record's stored form
//! ([`subnav_wire::encode_stored`]: format byte, postcard, CRC-32), so a record is checked
//! twice: by the map's item CRC and by its own, which also carries its layout version.
//!
//! Range: the first 32 KiB of the flash (8 sectors of 4 KiB). The map needs at least two
//! pages; eight give about 2,000 record writes per erase cycle of a sector (a record is
//! ~130 B), i.e. 10^8 configuration changes over the W25Q's 100,000 cycles.
//!
//! The application talks to the store only through [`RecordStore`], so the boards and tests
//! can give it no store ([`NoStore`]) or one that has failed.

use embedded_hal::spi::SpiDevice;
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::map::{MapConfig, MapStorage};
use subnav_wire::{FaultKind, MAX_STORED_RECORD, Record, RecordKey, StoredError, decode_stored, encode_stored};

use crate::drivers::BusErrorKind;
use crate::drivers::w25q::W25q;

/// Flash range of the map.
pub const STORE_RANGE: core::ops::Range<u32> = 0..32 * 1024;

/// Why a store operation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StoreError {
    /// This board has no store.
    Absent,
    /// The flash did not answer (the bus fault's kind).
    Bus(FaultKind),
    /// The store's structure is damaged beyond its own repair (erase it to recover).
    Corrupted,
    /// No room even after garbage collection (cannot happen with this key set; reported anyway).
    Full,
    /// The value stored under the key is not a valid record (damaged, another layout version,
    /// or another key's record).
    BadRecord(StoredError),
}

impl core::fmt::Display for StoreError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            StoreError::Absent => f.write_str("no persistent store on this board"),
            StoreError::Bus(k) => write!(f, "flash bus: {k}"),
            StoreError::Corrupted => f.write_str("store damaged beyond repair"),
            StoreError::Full => f.write_str("store full"),
            StoreError::BadRecord(e) => write!(f, "stored record unusable: {e}"),
        }
    }
}

impl StoreError {
    /// The fault kind reported for it.
    pub fn fault_kind(&self) -> FaultKind {
        match self {
            StoreError::Absent => FaultKind::BusOther,
            StoreError::Bus(k) => *k,
            StoreError::Corrupted | StoreError::BadRecord(_) => FaultKind::BadCrc,
            StoreError::Full => FaultKind::Overrun,
        }
    }
}

/// What the application needs from a store.
pub trait RecordStore {
    /// The record stored under `key`, `Ok(None)` when there is none.
    fn load(&mut self, key: RecordKey) -> Result<Option<Record>, StoreError>;
    /// Store `record` under its key (the old value stays readable until the new one is complete).
    fn save(&mut self, record: &Record) -> Result<(), StoreError>;
    /// Remove the record under `key`.
    fn erase(&mut self, key: RecordKey) -> Result<(), StoreError>;
    /// Erase the whole store.
    fn format(&mut self) -> Result<(), StoreError>;
    /// Whether the board has a store at all.
    fn present(&self) -> bool {
        true
    }
}

/// A board without a store: nothing loads, nothing saves.
pub struct NoStore;

impl RecordStore for NoStore {
    fn load(&mut self, _key: RecordKey) -> Result<Option<Record>, StoreError> {
        Err(StoreError::Absent)
    }
    fn save(&mut self, _record: &Record) -> Result<(), StoreError> {
        Err(StoreError::Absent)
    }
    fn erase(&mut self, _key: RecordKey) -> Result<(), StoreError> {
        Err(StoreError::Absent)
    }
    fn format(&mut self) -> Result<(), StoreError> {
        Err(StoreError::Absent)
    }
    fn present(&self) -> bool {
        false
    }
}

/// A store whose flash failed at boot (wrong chip, dead bus): every operation reports it.
pub struct FailedStore(pub FaultKind);

impl RecordStore for FailedStore {
    fn load(&mut self, _key: RecordKey) -> Result<Option<Record>, StoreError> {
        Err(StoreError::Bus(self.0))
    }
    fn save(&mut self, _record: &Record) -> Result<(), StoreError> {
        Err(StoreError::Bus(self.0))
    }
    fn erase(&mut self, _key: RecordKey) -> Result<(), StoreError> {
        Err(StoreError::Bus(self.0))
    }
    fn format(&mut self) -> Result<(), StoreError> {
        Err(StoreError::Bus(self.0))
    }
}

/// Buffer for one map item: key, value, rounded up to the flash word.
const ITEM_BUFFER: usize = (1 + MAX_STORED_RECORD + 8).div_ceil(4) * 4;

/// The records in a W25Q's first [`STORE_RANGE`] bytes.
/// The map's work buffer is a local of each operation, not a field: the store sits in the
/// board loop's frame, at the stack peak, and the operations run above it.
pub struct FlashStore<SPI: SpiDevice> {
    map: MapStorage<u8, W25q<SPI>, Cache<Uncached, Uncached, Uncached, u8>>,
}

fn map_error<E: BusErrorKind>(e: sequential_storage::Error<crate::drivers::Error<E>>) -> StoreError {
    match e {
        sequential_storage::Error::Storage { value, .. } => StoreError::Bus(value.fault_kind()),
        sequential_storage::Error::FullStorage => StoreError::Full,
        sequential_storage::Error::SerializationError(_) => StoreError::BadRecord(StoredError::Payload),
        _ => StoreError::Corrupted,
    }
}

impl<SPI: SpiDevice> FlashStore<SPI>
where
    SPI::Error: BusErrorKind,
{
    pub fn new(flash: W25q<SPI>) -> Self {
        Self { map: MapStorage::new(flash, const { MapConfig::new(STORE_RANGE) }, Cache::new_uncached()) }
    }

    /// Give the flash back.
    pub fn destroy(self) -> W25q<SPI> {
        self.map.destroy().0
    }
}

impl<SPI: SpiDevice> RecordStore for FlashStore<SPI>
where
    SPI::Error: BusErrorKind,
{
    fn load(&mut self, key: RecordKey) -> Result<Option<Record>, StoreError> {
        let id = key.id();
        let mut buf = [0u8; ITEM_BUFFER];
        let got = embassy_futures::block_on(self.map.fetch_item::<&[u8]>(&mut buf, &id)).map_err(map_error)?;
        let Some(bytes) = got else { return Ok(None) };
        let record = decode_stored(bytes).map_err(StoreError::BadRecord)?;
        if record.key() != key {
            return Err(StoreError::BadRecord(StoredError::Payload));
        }
        Ok(Some(record))
    }

    fn save(&mut self, record: &Record) -> Result<(), StoreError> {
        let mut stored = [0u8; MAX_STORED_RECORD];
        let bytes = encode_stored(record, &mut stored).map_err(StoreError::BadRecord)?;
        let id = record.key().id();
        let mut buf = [0u8; ITEM_BUFFER];
        embassy_futures::block_on(self.map.store_item(&mut buf, &id, &bytes)).map_err(map_error)
    }

    fn erase(&mut self, key: RecordKey) -> Result<(), StoreError> {
        let mut buf = [0u8; ITEM_BUFFER];
        embassy_futures::block_on(self.map.remove_item(&mut buf, &key.id())).map_err(map_error)
    }

    fn format(&mut self) -> Result<(), StoreError> {
        embassy_futures::block_on(self.map.erase_all()).map_err(map_error)
    }
}
