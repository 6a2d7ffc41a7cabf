//! Helpers for the end-to-end and peer tests.
//!
//! `cargo xtask test` builds the firmware, creates the peer venv, and exports:
//! - `SUBNAV_FIRMWARE_QEMU_ELF`: the QEMU board ELF,
//! - `SUBNAV_PEER_PYTHON`: a python with the peer libraries (`tests/peers/requirements.txt`).
//!
//! A test that needs one of them fails with an instruction when it is missing: a missing
//! capability is a failure, never a silent skip.

use std::path::PathBuf;

fn required_path(var: &str) -> PathBuf {
    match std::env::var_os(var) {
        Some(p) => PathBuf::from(p),
        None => panic!("{var} is not set: run the tests with `cargo xtask test` (it builds and sets it up)"),
    }
}

/// The firmware ELF for the QEMU board.
pub fn qemu_elf() -> PathBuf {
    required_path("SUBNAV_FIRMWARE_QEMU_ELF")
}

/// The python interpreter of the peer venv.
pub fn peer_python() -> PathBuf {
    required_path("SUBNAV_PEER_PYTHON")
}

/// Directory of the peer scripts (`tests/peers`).
pub fn peers_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("peers")
}
