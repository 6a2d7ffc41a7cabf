//! The memory that keeps the warm-start record across a reset (`subnav_firmware::estimator::warm`):
//! words of the board's SSRAM just above the reset-cause mark of `cmsdk_watchdog.rs`, outside every
//! linker region (`boards/mps2-an386.x` cuts RAM at 128 KiB; the board has 4 MiB), so QEMU's
//! loader does not zero them on a reset and nothing else uses them. Power-on contents are zeros
//! (QEMU) or noise (hardware): the record's header and CRC tell. The encoding, the checks and
//! the schedule are the library's; this is only where.

use subnav_firmware::estimator::warm::WARM_RECORD_BYTES;

/// 16 bytes above the reset mark (0x2002_0000, two words).
const WARM_RECORD: usize = 0x2002_0010;

/// The record's memory. Call once (the board loop owns it).
pub fn take() -> &'static mut [u8; WARM_RECORD_BYTES] {
    // SAFETY: board RAM outside every linker region (see the module doc), word aligned, used by
    // nothing else; taken once at boot, so this is the only reference.
    unsafe { &mut *(WARM_RECORD as *mut [u8; WARM_RECORD_BYTES]) }
}
