//! The sensor-bus bridge's byte link under QEMU: two host named pipes opened through
//! semihosting (`SYS_OPEN`, `SYS_WRITE`, `SYS_READ`).
//!
//! Why not a second UART: QEMU hands a CMSDK UART one received byte per main-loop round trip,
//! which makes each bus transaction cost milliseconds of wall time and lets the virtual clock run
//! while the firmware polls. A semihosting call is synchronous: the vCPU stops until the host
//! answers, so with `-icount` no virtual time passes during a transaction and the run is
//! deterministic (CPU load included) and fast.

use subnav_firmware::bus_bridge::ByteLink;

const SYS_OPEN: usize = 0x01;
const SYS_WRITE: usize = 0x05;
const SYS_READ: usize = 0x06;
/// `fopen` modes of the semihosting spec.
const MODE_RB: usize = 1;
const MODE_WB: usize = 5;

fn open(path: &[u8], mode: usize) -> Option<usize> {
    // The path must be NUL-terminated for the host.
    let mut name = [0u8; 200];
    let dst = name.get_mut(..path.len())?;
    dst.copy_from_slice(path);
    let block = [name.as_ptr() as usize, mode, path.len()];
    // SAFETY: semihosting call with a valid parameter block and NUL-terminated name.
    let fd = unsafe { cortex_m_semihosting::syscall1(SYS_OPEN, block.as_ptr() as usize) };
    (fd as isize >= 0).then_some(fd)
}

pub struct SemihostPipe {
    tx: usize,
    rx: usize,
    buf: [u8; 256],
    pos: usize,
    len: usize,
    /// The host closed the pipe or a call failed: every read now returns nothing.
    pub broken: bool,
}

impl SemihostPipe {
    /// Open the request pipe (we write) and the response pipe (we read), in that order.
    pub fn open(req_path: &[u8], resp_path: &[u8]) -> Option<Self> {
        let tx = open(req_path, MODE_WB)?;
        let rx = open(resp_path, MODE_RB)?;
        Some(Self { tx, rx, buf: [0; 256], pos: 0, len: 0, broken: false })
    }
}

impl ByteLink for SemihostPipe {
    fn write_all(&mut self, bytes: &[u8]) {
        if self.broken {
            return;
        }
        let block = [self.tx, bytes.as_ptr() as usize, bytes.len()];
        // SAFETY: valid parameter block; the host reads `len` bytes from our buffer.
        let not_written = unsafe { cortex_m_semihosting::syscall1(SYS_WRITE, block.as_ptr() as usize) };
        if not_written != 0 {
            self.broken = true;
        }
    }

    fn read_byte(&mut self) -> Option<u8> {
        if self.pos >= self.len {
            if self.broken {
                return None;
            }
            let block = [self.rx, self.buf.as_mut_ptr() as usize, self.buf.len()];
            // SAFETY: valid parameter block; the host writes at most `len` bytes into our buffer.
            // Blocks until the host has written something (a pipe read returns what is there).
            let not_read = unsafe { cortex_m_semihosting::syscall1(SYS_READ, block.as_ptr() as usize) };
            let got = self.buf.len().saturating_sub(not_read);
            if got == 0 || not_read > self.buf.len() {
                self.broken = true;
                return None;
            }
            self.pos = 0;
            self.len = got;
        }
        let b = self.buf.get(self.pos).copied();
        self.pos += 1;
        b
    }
}
