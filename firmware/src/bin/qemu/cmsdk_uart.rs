//! Minimal blocking driver for the ARM CMSDK APB UART of mps2-an386 (no maintained crate
//! covers this QEMU-only peripheral; it is five registers).

use core::ptr::{read_volatile, write_volatile};

const DATA: usize = 0x00;
const STATE: usize = 0x04;
const CTRL: usize = 0x08;
const BAUDDIV: usize = 0x10;

const STATE_TX_FULL: u32 = 1 << 0;
#[allow(dead_code)]
const STATE_RX_FULL: u32 = 1 << 1;
const CTRL_TX_EN: u32 = 1 << 0;
const CTRL_RX_EN: u32 = 1 << 1;

#[allow(dead_code)] // the bench binary shares this file and only transmits
pub struct Uart {
    base: usize,
}

impl Uart {
    /// UART0 at 0x4000_4000, enabled for TX and RX.
    pub fn uart0() -> Self {
        Self::at(0x4000_4000)
    }

    /// UART1 at 0x4000_5000 (the sensor-bus bridge).
    #[allow(dead_code)]
    pub fn uart1() -> Self {
        Self::at(0x4000_5000)
    }

    fn at(base: usize) -> Self {
        let u = Self { base };
        // SAFETY: fixed, valid MMIO addresses of mps2-an386's UART0; only this owner touches them.
        unsafe {
            write_volatile((u.base + BAUDDIV) as *mut u32, 16);
            write_volatile((u.base + CTRL) as *mut u32, CTRL_TX_EN | CTRL_RX_EN);
        }
        u
    }

    fn reg(&self, off: usize) -> u32 {
        // SAFETY: see `uart0`.
        unsafe { read_volatile((self.base + off) as *const u32) }
    }

    pub fn write_all(&mut self, bytes: &[u8]) {
        for &b in bytes {
            while self.reg(STATE) & STATE_TX_FULL != 0 {}
            // SAFETY: see `uart0`.
            unsafe { write_volatile((self.base + DATA) as *mut u32, u32::from(b)) };
        }
    }

    /// One received byte, if waiting.
    #[allow(dead_code)]
    pub fn read_byte(&mut self) -> Option<u8> {
        (self.reg(STATE) & STATE_RX_FULL != 0).then(|| (self.reg(DATA) & 0xff) as u8)
    }

    /// Read the bytes that are waiting (the CMSDK UART holds one).
    #[allow(dead_code)]
    pub fn read_available(&mut self, buf: &mut [u8]) -> usize {
        let mut n = 0;
        for slot in buf.iter_mut() {
            if self.reg(STATE) & STATE_RX_FULL == 0 {
                break;
            }
            *slot = (self.reg(DATA) & 0xff) as u8;
            n += 1;
        }
        n
    }
}
