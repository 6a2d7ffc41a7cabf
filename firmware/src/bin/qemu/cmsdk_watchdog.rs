//! The ARM CMSDK APB watchdog of mps2-an386 (0x4000_8000, clocked by the 25 MHz system clock),
//! and the reset cause the board reports in `Boot`. No maintained crate covers this QEMU board's
//! peripheral; it is four registers.
//!
//! The counter counts down from `LOAD`. The first time it reaches zero it raises its interrupt,
//! which mps2-an386 wires to the NMI, and reloads; the second time, with the interrupt still
//! pending, it resets the machine (QEMU: `watchdog_perform_action`, a system reset unless
//! `-action watchdog=...` says otherwise). Feeding clears the interrupt and reloads the count.
//!
//! The board has no reset-cause register, so the cause is a word pair in RAM that survives a
//! reset: the watchdog's NMI writes `Watchdog` before the reset, the `Reboot` command writes
//! `Software` before `SYSRESETREQ`, and the next boot reads and clears it. Power-on RAM holds
//! no mark: `PowerOn`. Where: just above the 128 KiB the firmware's RAM budget uses
//! (`boards/mps2-an386.x`; the board's SSRAM is 4 MiB). Not a `.uninit` static: the linker puts
//! `.uninit` in the same ELF segment as `.bss`, and QEMU's loader zero-fills that whole segment
//! on every reset (its ROM blob: data, then zeros up to the segment's memory size).

use core::ptr::{read_volatile, write_volatile};

use subnav_wire::ResetCause;

const BASE: usize = 0x4000_8000;
const LOAD: usize = 0x000;
const CONTROL: usize = 0x008;
const INTCLR: usize = 0x00C;
const LOCK: usize = 0xC00;

const CONTROL_INTEN: u32 = 1 << 0;
const CONTROL_RESEN: u32 = 1 << 1;
const UNLOCK_KEY: u32 = 0x1ACC_E551;

/// Watchdog clock (the board's system clock), Hz.
pub const WDOG_CLK_HZ: u32 = 25_000_000;

pub struct Watchdog;

fn write(offset: usize, value: u32) {
    // SAFETY: fixed, valid MMIO address of mps2-an386's watchdog; only this module touches it.
    unsafe { write_volatile((BASE + offset) as *mut u32, value) }
}

impl Watchdog {
    /// Start it: the NMI after `period_ms` without a feed, the reset after twice that.
    pub fn start(period_ms: u32) -> Self {
        write(LOCK, UNLOCK_KEY);
        write(LOAD, (WDOG_CLK_HZ / 1000).saturating_mul(period_ms));
        write(INTCLR, 1);
        write(CONTROL, CONTROL_INTEN | CONTROL_RESEN);
        write(LOCK, 0);
        Watchdog
    }

    /// Clear the interrupt and reload the count.
    pub fn feed(&mut self) {
        write(LOCK, UNLOCK_KEY);
        write(INTCLR, 1);
        write(LOCK, 0);
    }
}

const MARK_MAGIC: u32 = 0x5EB0_07CA;

/// Two words past the end of the linker's RAM region (0x2000_0000 + 128 KiB).
const RESET_MARK: usize = 0x2002_0000;

fn code(cause: ResetCause) -> u32 {
    match cause {
        ResetCause::PowerOn => 0,
        ResetCause::Pin => 1,
        ResetCause::Brownout => 2,
        ResetCause::Software => 3,
        ResetCause::Watchdog => 4,
    }
}

/// Leave `cause` for the next boot (called just before a reset).
pub fn mark_next_reset(cause: ResetCause) {
    // SAFETY: board RAM outside every linker region, used by nothing else; it runs either in
    // the NMI, with the board loop stopped for good, or just before SYSRESETREQ.
    unsafe {
        let p = RESET_MARK as *mut u32;
        write_volatile(p, MARK_MAGIC);
        write_volatile(p.add(1), code(cause));
    }
}

/// Why this boot happened, and clear the mark (read once, at reset).
pub fn take_reset_cause() -> ResetCause {
    // SAFETY: as in `mark_next_reset`; read once at reset, before anything else runs.
    let (magic, c) = unsafe {
        let p = RESET_MARK as *mut u32;
        let v = (read_volatile(p), read_volatile(p.add(1)));
        write_volatile(p, 0);
        v
    };
    match (magic, c) {
        (MARK_MAGIC, 1) => ResetCause::Pin,
        (MARK_MAGIC, 2) => ResetCause::Brownout,
        (MARK_MAGIC, 3) => ResetCause::Software,
        (MARK_MAGIC, 4) => ResetCause::Watchdog,
        _ => ResetCause::PowerOn,
    }
}
