//! Winbond W25Q16JV SPI NOR flash (2 MiB): the sensor head's persistent store.
//!
//! What the silicon does: READ DATA (0x03) streams from any address; PAGE PROGRAM (0x02) ANDs
//! its bytes into the addressed page (wrapping inside the 256-byte page, only clearing bits),
//! applied when chip select rises and only after WRITE ENABLE (0x06); SECTOR ERASE (0x20) sets a
//! 4 KiB sector to 0xFF, likewise; READ STATUS 1 (0x05) shows BUSY and WEL; JEDEC ID (0x9F).
//! Programs and erases complete at once (BUSY reads 0): the firmware's busy poll is exercised by
//! its unit tests, not here.
//!
//! Persistence: [`W25qModel::with_file`] keeps the contents in a file (created erased when
//! missing), written through on every program and erase, so a QEMU head keeps its store across
//! runs, and a killed run leaves exactly what the chip had.
//!
//! Power loss: [`PowerCut`] stops the chip inside its `at_operation`-th program or erase (counting
//! from 0 since the model was made): a program has only a random prefix of its bytes written and
//! one byte half-programmed (a random subset of its cleared bits); an erase leaves a random
//! prefix of the sector erased and the next 16 bytes with random bits set. After the cut the chip
//! is dead (every transaction times out), as the firmware would see it while the supply falls.

use std::fs::File;
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{BusFault, BusFaults, SpiChip};

pub const CAPACITY_BYTES: usize = 2 * 1024 * 1024;
pub const SECTOR_BYTES: usize = 4096;
pub const PAGE_BYTES: usize = 256;
pub const JEDEC_ID: [u8; 3] = [0xEF, 0x40, 0x15];
/// Bytes at the start of the chip the head's store uses (the firmware's `store::STORE_RANGE`);
/// an image is erased (0xFF) beyond them.
pub const STORE_BYTES: usize = subnav_firmware::store::STORE_RANGE.end as usize;

/// A flash image file's metadata: a regular file of exactly [`CAPACITY_BYTES`] (checked before
/// anything is read: `/dev/zero` or a 4 GB file is never read).
fn image_size_ok(path: &Path, md: &std::fs::Metadata) -> anyhow::Result<()> {
    if !md.is_file() {
        anyhow::bail!(
            "flash image {}: not a regular file (a device, a FIFO or a directory); a flash image is a file of {CAPACITY_BYTES} bytes",
            path.display()
        );
    }
    if md.len() != CAPACITY_BYTES as u64 {
        anyhow::bail!(
            "flash image {}: {} bytes, expected exactly {CAPACITY_BYTES} (a W25Q16JV image): not a flash image, left untouched; give a new path (created erased) or ask for a new image to replace it",
            path.display(),
            md.len()
        );
    }
    Ok(())
}

/// Whether `mem` (read from `path`) has the form of a flash image: [`CAPACITY_BYTES`] long and
/// erased beyond the store's [`STORE_BYTES`] (the head writes nothing there).
pub fn check_image(path: &Path, mem: &[u8]) -> anyhow::Result<()> {
    if mem.len() != CAPACITY_BYTES {
        anyhow::bail!("flash image {}: {} bytes, expected exactly {CAPACITY_BYTES}", path.display(), mem.len());
    }
    if let Some(at) = mem[STORE_BYTES..].iter().position(|&b| b != 0xFF) {
        anyhow::bail!(
            "flash image {}: byte {} (beyond the store's first {STORE_BYTES} bytes) is 0x{:02X}, expected erased 0xFF: not a flash image, left untouched",
            path.display(),
            STORE_BYTES + at,
            mem[STORE_BYTES + at]
        );
    }
    Ok(())
}

/// Where the power fails.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PowerCut {
    /// The program or erase (0-based count) during which power fails.
    pub at_operation: u64,
    /// Seeds how much of that operation completes.
    pub seed: u64,
    /// Set once the cut has happened.
    pub happened: bool,
    /// The cut hit an erase (else a program).
    pub in_erase: bool,
}

/// Operations served since the model was made.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FlashCounters {
    pub programs: u64,
    pub erases: u64,
    pub reads: u64,
    /// Programs and erases refused for a missing WRITE ENABLE.
    pub refused_writes: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    Command,
    Address { cmd: u8, got: usize, addr: u32 },
    Data { cmd: u8, addr: u32, pos: usize },
    Ignore,
}

/// One chip shared by several runs in a process (a head's flash across reboots): each run
/// attaches a clone; the contents are the same chip's.
#[derive(Clone, Default)]
pub struct SharedFlash(pub std::sync::Arc<std::sync::Mutex<W25qModel>>);

impl SharedFlash {
    fn chip(&self) -> std::sync::MutexGuard<'_, W25qModel> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl SpiChip for SharedFlash {
    fn begin(&mut self, t_us: u64) -> Result<(), BusFault> {
        self.chip().begin(t_us)
    }
    fn transfer(&mut self, t_us: u64, write: &[u8], read: &mut [u8]) -> Result<(), BusFault> {
        self.chip().transfer(t_us, write, read)
    }
    fn end(&mut self, t_us: u64) {
        self.chip().end(t_us)
    }
}

pub struct W25qModel {
    mem: Vec<u8>,
    /// The image file and its path (for messages).
    file: Option<(File, std::path::PathBuf)>,
    phase: Phase,
    /// Bytes of the page program being clocked in.
    program: Vec<u8>,
    wel: bool,
    dead: bool,
    pub faults: BusFaults,
    pub power_cut: Option<PowerCut>,
    pub counters: FlashCounters,
    /// Operation numbers (as `PowerCut::at_operation` counts them) of the erases served.
    pub erase_operations: Vec<u64>,
}

impl Default for W25qModel {
    fn default() -> Self {
        Self::new()
    }
}

impl W25qModel {
    /// An erased chip in memory.
    pub fn new() -> Self {
        Self::from_contents(vec![0xFF; CAPACITY_BYTES])
    }

    /// A chip holding `mem` (e.g. what a power-cut chip left).
    pub fn from_contents(mut mem: Vec<u8>) -> Self {
        mem.resize(CAPACITY_BYTES, 0xFF);
        Self {
            mem,
            file: None,
            phase: Phase::Command,
            program: Vec::new(),
            wel: false,
            dead: false,
            faults: BusFaults::default(),
            power_cut: None,
            counters: FlashCounters::default(),
            erase_operations: Vec::new(),
        }
    }

    /// A chip whose contents live in `path`: an existing flash image ([`check_image`]: a regular
    /// file of exactly [`CAPACITY_BYTES`], erased beyond the store's [`STORE_BYTES`]), or a new
    /// erased one when nothing is at `path`. Any other file, a device or a directory is refused
    /// before it is read or written. Errors name the file.
    pub fn with_file(path: &Path) -> anyhow::Result<Self> {
        use anyhow::Context as _;
        match std::fs::metadata(path) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Self::new_file(path),
            Err(e) => Err(e).with_context(|| format!("flash image {}: cannot read", path.display())),
            Ok(md) => {
                image_size_ok(path, &md)?;
                let mut f = std::fs::OpenOptions::new()
                    .read(true)
                    .write(true)
                    .open(path)
                    .with_context(|| format!("flash image {}: cannot open", path.display()))?;
                let mut mem = Vec::with_capacity(CAPACITY_BYTES);
                (&mut f)
                    .take(CAPACITY_BYTES as u64 + 1)
                    .read_to_end(&mut mem)
                    .with_context(|| format!("flash image {}: cannot read", path.display()))?;
                check_image(path, &mem)?;
                let mut m = Self::from_contents(mem);
                m.file = Some((f, path.to_path_buf()));
                Ok(m)
            }
        }
    }

    /// A new erased image at `path`, replacing a regular file there (a device, a FIFO or a
    /// directory is refused).
    pub fn new_file(path: &Path) -> anyhow::Result<Self> {
        use anyhow::Context as _;
        if let Ok(md) = std::fs::metadata(path)
            && !md.is_file()
        {
            anyhow::bail!("flash image {}: not a regular file (a device, a FIFO or a directory); give a file path", path.display());
        }
        let mem = vec![0xFF; CAPACITY_BYTES];
        let mut f = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(path)
            .with_context(|| format!("flash image {}: cannot create", path.display()))?;
        f.write_all(&mem).with_context(|| format!("flash image {}: cannot write", path.display()))?;
        let mut m = Self::from_contents(mem);
        m.file = Some((f, path.to_path_buf()));
        Ok(m)
    }

    pub fn contents(&self) -> &[u8] {
        &self.mem
    }

    pub fn is_dead(&self) -> bool {
        self.dead
    }

    fn persist(&mut self, start: usize, len: usize) {
        if let (Some((f, path)), Some(bytes)) = (self.file.as_mut(), self.mem.get(start..start + len)) {
            // A write error leaves the image stale; the in-memory chip is still right. Reported
            // once on stderr rather than failing the bus (a real chip does not know about files).
            if let Err(e) = f.seek(SeekFrom::Start(start as u64)).and_then(|_| f.write_all(bytes)) {
                eprintln!("w25q model: could not write the flash image {}: {e}", path.display());
                self.file = None;
            }
        }
    }

    /// Whether this operation is the one the power fails in; counts it.
    fn cut_now(&mut self) -> Option<ChaCha8Rng> {
        let n = self.counters.programs + self.counters.erases;
        match self.power_cut.as_mut() {
            Some(c) if !c.happened && c.at_operation == n => {
                c.happened = true;
                Some(ChaCha8Rng::seed_from_u64(c.seed))
            }
            _ => None,
        }
    }

    fn do_program(&mut self, addr: u32) {
        let cut = self.cut_now();
        self.counters.programs += 1;
        let page = (addr as usize) & !(PAGE_BYTES - 1);
        let mut off = (addr as usize) % PAGE_BYTES;
        let data = std::mem::take(&mut self.program);
        let n = data.len();
        let mut cut = cut;
        let done = match cut.as_mut() {
            Some(rng) => rng.random_range(0..=n),
            None => n,
        };
        for (i, b) in data.iter().enumerate() {
            let Some(cell) = self.mem.get_mut(page + off) else { break };
            if i < done {
                *cell &= *b;
            } else if i == done {
                if let Some(rng) = cut.as_mut() {
                    // Half-programmed: some of the bits that should clear did.
                    let clear = !*b & rng.random::<u8>();
                    *cell &= !clear;
                }
                break;
            }
            off = (off + 1) % PAGE_BYTES;
        }
        self.persist(page, PAGE_BYTES);
        if cut.is_some() {
            self.dead = true;
        }
    }

    fn do_erase(&mut self, addr: u32) {
        self.erase_operations.push(self.counters.programs + self.counters.erases);
        let mut cut = self.cut_now();
        if let (Some(_), Some(c)) = (&cut, self.power_cut.as_mut()) {
            c.in_erase = true;
        }
        self.counters.erases += 1;
        let start = (addr as usize) & !(SECTOR_BYTES - 1);
        let done = match cut.as_mut() {
            Some(rng) => rng.random_range(0..=SECTOR_BYTES),
            None => SECTOR_BYTES,
        };
        if let Some(s) = self.mem.get_mut(start..start + SECTOR_BYTES) {
            for (i, cell) in s.iter_mut().enumerate() {
                if i < done {
                    *cell = 0xFF;
                } else if i < done + 16 {
                    if let Some(rng) = cut.as_mut() {
                        *cell |= rng.random::<u8>();
                    }
                }
            }
        }
        self.persist(start, SECTOR_BYTES);
        if cut.is_some() {
            self.dead = true;
        }
    }

    fn status(&self) -> u8 {
        if self.wel { 0x02 } else { 0x00 }
    }
}

impl SpiChip for W25qModel {
    fn begin(&mut self, t_us: u64) -> Result<(), BusFault> {
        if self.dead {
            return Err(BusFault::Timeout);
        }
        self.faults.check(t_us)?;
        self.phase = Phase::Command;
        self.program.clear();
        Ok(())
    }

    fn transfer(&mut self, _t_us: u64, write: &[u8], read: &mut [u8]) -> Result<(), BusFault> {
        if self.dead {
            return Err(BusFault::Timeout);
        }
        let n = write.len().max(read.len());
        for i in 0..n {
            let mosi = write.get(i).copied().unwrap_or(0);
            let mut miso = 0xFF;
            self.phase = match self.phase {
                Phase::Command => match mosi {
                    0x03 | 0x02 | 0x20 => Phase::Address { cmd: mosi, got: 0, addr: 0 },
                    0x05 | 0x9F => Phase::Data { cmd: mosi, addr: 0, pos: 0 },
                    0x06 => {
                        self.wel = true;
                        Phase::Ignore
                    }
                    0x04 => {
                        self.wel = false;
                        Phase::Ignore
                    }
                    _ => Phase::Ignore,
                },
                Phase::Address { cmd, got, addr } => {
                    let addr = (addr << 8) | u32::from(mosi);
                    if got + 1 == 3 {
                        Phase::Data { cmd, addr: addr % CAPACITY_BYTES as u32, pos: 0 }
                    } else {
                        Phase::Address { cmd, got: got + 1, addr }
                    }
                }
                Phase::Data { cmd, addr, pos } => {
                    match cmd {
                        0x03 => {
                            miso = self.mem.get((addr as usize + pos) % CAPACITY_BYTES).copied().unwrap_or(0xFF);
                            self.counters.reads += 1;
                        }
                        0x05 => miso = self.status(),
                        0x9F => miso = JEDEC_ID.get(pos).copied().unwrap_or(0xFF),
                        0x02 => {
                            if self.program.len() < PAGE_BYTES {
                                self.program.push(mosi);
                            }
                        }
                        _ => {}
                    }
                    Phase::Data { cmd, addr, pos: pos + 1 }
                }
                Phase::Ignore => Phase::Ignore,
            };
            if let Some(r) = read.get_mut(i) {
                *r = miso;
            }
        }
        Ok(())
    }

    fn end(&mut self, _t_us: u64) {
        if self.dead {
            return;
        }
        if let Phase::Data { cmd: cmd @ (0x02 | 0x20), addr, .. } = self.phase {
            if self.wel {
                if cmd == 0x02 { self.do_program(addr) } else { self.do_erase(addr) }
            } else {
                self.counters.refused_writes += 1;
            }
            self.wel = false;
        }
        self.phase = Phase::Command;
    }
}

/// An embedded-hal `SpiDevice` straight onto one chip model (no bridge, no time): for tests
/// that run a driver against its model in-process.
pub struct DirectSpi<'a, C: SpiChip> {
    pub chip: &'a mut C,
    pub t_us: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DirectSpiError(pub BusFault);

impl embedded_hal::spi::Error for DirectSpiError {
    fn kind(&self) -> embedded_hal::spi::ErrorKind {
        embedded_hal::spi::ErrorKind::Other
    }
}

impl subnav_firmware::drivers::BusErrorKind for DirectSpiError {
    fn fault_kind(&self) -> subnav_wire::FaultKind {
        match self.0 {
            BusFault::Nack => subnav_wire::FaultKind::BusNack,
            BusFault::Timeout => subnav_wire::FaultKind::BusTimeout,
            BusFault::Other => subnav_wire::FaultKind::BusOther,
        }
    }
}

impl<C: SpiChip> embedded_hal::spi::ErrorType for DirectSpi<'_, C> {
    type Error = DirectSpiError;
}

impl<C: SpiChip> embedded_hal::spi::SpiDevice for DirectSpi<'_, C> {
    fn transaction(&mut self, ops: &mut [embedded_hal::spi::Operation<'_, u8>]) -> Result<(), DirectSpiError> {
        use embedded_hal::spi::Operation;
        let t = self.t_us;
        self.chip.begin(t).map_err(DirectSpiError)?;
        let r = ops.iter_mut().try_for_each(|op| match op {
            Operation::Write(w) => self.chip.transfer(t, w, &mut []),
            Operation::Read(r) => self.chip.transfer(t, &[], r),
            Operation::Transfer(r, w) => self.chip.transfer(t, w, r),
            Operation::TransferInPlace(b) => {
                let w = b.to_vec();
                self.chip.transfer(t, &w, b)
            }
            Operation::DelayNs(_) => Ok(()),
        });
        self.chip.end(t);
        r.map_err(DirectSpiError)
    }
}

#[cfg(test)]
mod image_tests {
    use super::*;

    /// `calibrate head --flash FILE` and `qemu --flash FILE` took any file up to 2 MiB as an
    /// image (a 9-byte note grew to 2 MiB, a recording was rewritten) and read `/dev/zero`
    /// until out of memory: other files are refused and left byte for byte.
    fn refusal(r: anyhow::Result<W25qModel>) -> String {
        match r {
            Ok(_) => panic!("taken as a flash image"),
            Err(e) => format!("{e:#}"),
        }
    }

    #[test]
    fn only_a_flash_image_is_taken_as_one() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let note = d.join("note.txt");
        std::fs::write(&note, b"my notes\n").unwrap();
        let e = refusal(W25qModel::with_file(&note));
        assert!(e.contains("note.txt") && e.contains("9 bytes") && e.contains("2097152"), "{e}");
        assert_eq!(std::fs::read(&note).unwrap(), b"my notes\n");
        // The right size, but not erased beyond the store.
        let text: Vec<u8> = b"0123456789abcdef".iter().copied().cycle().take(CAPACITY_BYTES).collect();
        let big = d.join("big.bin");
        std::fs::write(&big, &text).unwrap();
        let e = refusal(W25qModel::with_file(&big));
        assert!(e.contains("big.bin") && e.contains("expected erased"), "{e}");
        assert_eq!(std::fs::read(&big).unwrap(), text);
        for p in [Path::new("/dev/zero"), d] {
            let e = refusal(W25qModel::with_file(p));
            assert!(e.contains("not a regular file"), "{e}");
            assert!(W25qModel::new_file(p).is_err());
        }
        // A missing file is made erased; it is then an image, reopened with its contents.
        let img = d.join("head.flash");
        let mut m = W25qModel::with_file(&img).unwrap();
        m.mem[5] = 0x12;
        m.persist(0, 16);
        drop(m);
        assert_eq!(std::fs::metadata(&img).unwrap().len(), CAPACITY_BYTES as u64);
        assert_eq!(W25qModel::with_file(&img).unwrap().contents()[5], 0x12);
        // Asked for, a new image replaces a file.
        let m = W25qModel::new_file(&note).unwrap();
        assert!(m.contents().iter().all(|&b| b == 0xFF));
        assert!(W25qModel::with_file(&note).is_ok());
    }
}
