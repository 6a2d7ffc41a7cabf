//! Puts the selected board's `memory.x` on the linker search path (target builds only).
//! The top-level `memory.x` includes `board-memory.x`, which this script copies from
//! `firmware/boards/<board>.x`: `stm32f405.x`, or `mps2-an386.x` for QEMU, which mirrors the
//! STM32F405 flash/RAM budget at the addresses where mps2-an386 has memory, so a firmware that
//! fits in QEMU fits on the chip.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").unwrap());
    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").unwrap());
    let src = if env::var_os("CARGO_FEATURE_BOARD_QEMU").is_some() {
        Some(manifest.join("boards/mps2-an386.x"))
    } else if env::var_os("CARGO_FEATURE_BOARD_STM32F4").is_some() {
        Some(manifest.join("boards/stm32f405.x"))
    } else {
        None
    };
    if let Some(src) = src {
        fs::copy(&src, out.join("board-memory.x")).expect("copy board memory layout");
        println!("cargo:rustc-link-search={}", out.display());
        println!("cargo:rerun-if-changed={}", src.display());
    }
    println!("cargo:rerun-if-changed=build.rs");
}
