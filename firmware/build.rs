//! Puts the selected board's `memory.x` on the linker search path (target builds only).
//! The STM32F405 layout is the top-level `memory.x`; the QEMU board uses
//! `firmware/boards/mps2-an386.x`, which mirrors the STM32F405 flash/RAM budget at the addresses
//! where mps2-an386 has memory, so a firmware that fits in QEMU fits on the chip.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").unwrap());
    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").unwrap());
    let src = if env::var_os("CARGO_FEATURE_BOARD_QEMU").is_some() {
        Some(manifest.join("boards/mps2-an386.x"))
    } else if env::var_os("CARGO_FEATURE_BOARD_STM32F4").is_some() {
        Some(manifest.join("../memory.x"))
    } else {
        None
    };
    if let Some(src) = src {
        fs::copy(&src, out.join("memory.x")).expect("copy memory.x");
        println!("cargo:rustc-link-search={}", out.display());
        println!("cargo:rerun-if-changed={}", src.display());
    }
    println!("cargo:rerun-if-changed=build.rs");
}
