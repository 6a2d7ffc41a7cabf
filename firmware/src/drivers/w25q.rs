//! Winbond W25Q16JV (2 MiB, 4 KiB sectors, 256-byte pages) SPI NOR flash: the sensor head's
//! persistent store.
//!
//! Written here: the maintained W25Q crates are either async-only on a concrete HAL or blocking
//! without the `embedded-storage` traits; what sequential-storage needs is small (read, page
//! program, sector erase, busy poll, the JEDEC identity check), so it sits on `SpiDevice` in
//! ~150 lines and implements `embedded_storage_async::nor_flash::{NorFlash,
//! MultiwriteNorFlash}` (NOR programming only clears bits, so a word may be programmed again
//! with fewer ones: what `MultiwriteNorFlash` promises). The futures complete at once: the SPI
//! is blocking.
//!
//! Transactions carry at most [`CHUNK`] data bytes (the QEMU bus bridge's operation size), so a
//! page program is split into chunks inside the page; a real bus does the same at a small cost.
//! Every program and erase is preceded by WRITE ENABLE and followed by polling BUSY in the
//! status register (bounded: [`BUSY_POLLS`]; a chip that stays busy is a timeout).

use embedded_hal::spi::{Operation, SpiDevice};
use embedded_storage_async::nor_flash::{ErrorType, MultiwriteNorFlash, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};

use super::Error;

/// JEDEC manufacturer (Winbond) and device id (W25Q16JV-IQ: memory type 0x40, capacity 0x15).
pub const JEDEC_ID: [u8; 3] = [0xEF, 0x40, 0x15];
pub const CAPACITY_BYTES: u32 = 2 * 1024 * 1024;
pub const SECTOR_BYTES: u32 = 4096;
pub const PAGE_BYTES: u32 = 256;
/// Data bytes per SPI transaction.
pub const CHUNK: usize = 32;
/// Status polls before a program or erase counts as hung (a sector erase takes up to 400 ms;
/// each poll is a 2-byte transaction, tens of microseconds).
pub const BUSY_POLLS: u32 = 200_000;

pub mod cmd {
    pub const WRITE_ENABLE: u8 = 0x06;
    pub const READ_STATUS1: u8 = 0x05;
    pub const READ_DATA: u8 = 0x03;
    pub const PAGE_PROGRAM: u8 = 0x02;
    pub const SECTOR_ERASE: u8 = 0x20;
    pub const JEDEC_ID: u8 = 0x9F;
    /// Status register 1: erase/write in progress.
    pub const STATUS_BUSY: u8 = 0x01;
    /// Status register 1: write enable latch.
    pub const STATUS_WEL: u8 = 0x02;
}

pub struct W25q<SPI> {
    spi: SPI,
}

impl<E: core::fmt::Debug> NorFlashError for Error<E> {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Error::InvalidInput => NorFlashErrorKind::OutOfBounds,
            _ => NorFlashErrorKind::Other,
        }
    }
}

fn addr(a: u32) -> [u8; 3] {
    let b = a.to_be_bytes();
    [b[1], b[2], b[3]]
}

impl<SPI: SpiDevice> W25q<SPI> {
    /// Take the bus and check the chip's identity.
    pub fn new(spi: SPI) -> Result<Self, Error<SPI::Error>> {
        let mut f = Self { spi };
        let id = f.jedec_id()?;
        if id != JEDEC_ID {
            return Err(Error::IdentityMismatch { expected: JEDEC_ID[2], found: id[2] });
        }
        Ok(f)
    }

    /// Give the bus back.
    pub fn destroy(self) -> SPI {
        self.spi
    }

    pub fn jedec_id(&mut self) -> Result<[u8; 3], Error<SPI::Error>> {
        let mut id = [0u8; 3];
        self.spi.transaction(&mut [Operation::Write(&[cmd::JEDEC_ID]), Operation::Read(&mut id)]).map_err(Error::Bus)?;
        Ok(id)
    }

    fn status(&mut self) -> Result<u8, Error<SPI::Error>> {
        let mut s = [0u8; 1];
        self.spi.transaction(&mut [Operation::Write(&[cmd::READ_STATUS1]), Operation::Read(&mut s)]).map_err(Error::Bus)?;
        Ok(s[0])
    }

    fn write_enable(&mut self) -> Result<(), Error<SPI::Error>> {
        self.spi.write(&[cmd::WRITE_ENABLE]).map_err(Error::Bus)?;
        if self.status()? & cmd::STATUS_WEL == 0 {
            // The latch did not set: the chip is write-protected or not listening.
            return Err(Error::NotReady);
        }
        Ok(())
    }

    fn wait_idle(&mut self) -> Result<(), Error<SPI::Error>> {
        for _ in 0..BUSY_POLLS {
            if self.status()? & cmd::STATUS_BUSY == 0 {
                return Ok(());
            }
        }
        Err(Error::NotReady)
    }

    pub fn read_blocking(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error<SPI::Error>> {
        if u64::from(offset) + bytes.len() as u64 > u64::from(CAPACITY_BYTES) {
            return Err(Error::InvalidInput);
        }
        let mut a = offset;
        for chunk in bytes.chunks_mut(CHUNK) {
            let [a2, a1, a0] = addr(a);
            self.spi.transaction(&mut [Operation::Write(&[cmd::READ_DATA, a2, a1, a0]), Operation::Read(chunk)]).map_err(Error::Bus)?;
            a = a.wrapping_add(chunk.len() as u32);
        }
        Ok(())
    }

    pub fn program_blocking(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error<SPI::Error>> {
        if u64::from(offset) + bytes.len() as u64 > u64::from(CAPACITY_BYTES) {
            return Err(Error::InvalidInput);
        }
        let mut a = offset;
        let mut rest = bytes;
        while !rest.is_empty() {
            // Never cross a page boundary (the chip would wrap inside the page).
            let to_page_end = (PAGE_BYTES - a % PAGE_BYTES) as usize;
            let n = rest.len().min(CHUNK).min(to_page_end);
            let (now, later) = rest.split_at(n);
            self.write_enable()?;
            let [a2, a1, a0] = addr(a);
            self.spi.transaction(&mut [Operation::Write(&[cmd::PAGE_PROGRAM, a2, a1, a0]), Operation::Write(now)]).map_err(Error::Bus)?;
            self.wait_idle()?;
            a = a.wrapping_add(n as u32);
            rest = later;
        }
        Ok(())
    }

    pub fn erase_blocking(&mut self, from: u32, to: u32) -> Result<(), Error<SPI::Error>> {
        if from % SECTOR_BYTES != 0 || to % SECTOR_BYTES != 0 || from > to || to > CAPACITY_BYTES {
            return Err(Error::InvalidInput);
        }
        let mut a = from;
        while a < to {
            self.write_enable()?;
            let [a2, a1, a0] = addr(a);
            self.spi.write(&[cmd::SECTOR_ERASE, a2, a1, a0]).map_err(Error::Bus)?;
            self.wait_idle()?;
            a += SECTOR_BYTES;
        }
        Ok(())
    }
}

impl<SPI: SpiDevice> ErrorType for W25q<SPI> {
    type Error = Error<SPI::Error>;
}

impl<SPI: SpiDevice> ReadNorFlash for W25q<SPI> {
    const READ_SIZE: usize = 1;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.read_blocking(offset, bytes)
    }

    fn capacity(&self) -> usize {
        CAPACITY_BYTES as usize
    }
}

impl<SPI: SpiDevice> NorFlash for W25q<SPI> {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = SECTOR_BYTES as usize;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.erase_blocking(from, to)
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        if offset as usize % Self::WRITE_SIZE != 0 || bytes.len() % Self::WRITE_SIZE != 0 {
            return Err(Error::InvalidInput);
        }
        self.program_blocking(offset, bytes)
    }
}

/// NOR programming only clears bits: programming a word again with a subset of its ones is
/// what the chip does natively.
impl<SPI: SpiDevice> MultiwriteNorFlash for W25q<SPI> {}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal_mock::eh1::spi::{Mock, Transaction};

    #[test]
    fn wrong_identity_is_refused_and_bus_returned() {
        let exp = [
            Transaction::transaction_start(),
            Transaction::write(cmd::JEDEC_ID),
            Transaction::read_vec(vec![0xEF, 0x40, 0x16]),
            Transaction::transaction_end(),
        ];
        let mut spi = Mock::new(&exp);
        match W25q::new(spi.clone()) {
            Err(Error::IdentityMismatch { expected: 0x15, found: 0x16 }) => {}
            other => panic!("expected an identity mismatch, got {:?}", other.err()),
        }
        spi.done();
    }

    #[test]
    fn program_splits_at_chunks_and_pages() {
        // 40 bytes at 250: 6 up to the page end, then 32, then 2.
        let wel = |v: &mut Vec<Transaction<u8>>| {
            v.push(Transaction::transaction_start());
            v.push(Transaction::write(cmd::WRITE_ENABLE));
            v.push(Transaction::transaction_end());
            v.push(Transaction::transaction_start());
            v.push(Transaction::write(cmd::READ_STATUS1));
            v.push(Transaction::read(cmd::STATUS_WEL));
            v.push(Transaction::transaction_end());
        };
        let idle = |v: &mut Vec<Transaction<u8>>| {
            v.push(Transaction::transaction_start());
            v.push(Transaction::write(cmd::READ_STATUS1));
            v.push(Transaction::read(0));
            v.push(Transaction::transaction_end());
        };
        let data: Vec<u8> = (0..40).collect();
        let mut exp = Vec::new();
        for (a, r) in [(250u32, 0..6usize), (256, 6..38), (288, 38..40)] {
            wel(&mut exp);
            exp.push(Transaction::transaction_start());
            exp.push(Transaction::write_vec(vec![cmd::PAGE_PROGRAM, 0, (a >> 8) as u8, a as u8]));
            exp.push(Transaction::write_vec(data[r].to_vec()));
            exp.push(Transaction::transaction_end());
            idle(&mut exp);
        }
        let mut spi = Mock::new(&exp);
        let mut f = W25q { spi: spi.clone() };
        f.program_blocking(250, &data).unwrap();
        spi.done();
    }

    #[test]
    fn out_of_range_and_misaligned_are_refused_without_bus_traffic() {
        let mut spi = Mock::new(&[]);
        let mut f = W25q { spi: spi.clone() };
        assert_eq!(f.erase_blocking(100, 4096), Err(Error::InvalidInput));
        assert_eq!(f.program_blocking(CAPACITY_BYTES - 1, &[0, 0]), Err(Error::InvalidInput));
        let mut b = [0u8; 4];
        assert_eq!(f.read_blocking(CAPACITY_BYTES, &mut b), Err(Error::InvalidInput));
        spi.done();
    }
}
