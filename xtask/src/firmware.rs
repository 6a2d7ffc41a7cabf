//! Firmware builds for thumbv7em-none-eabihf with whichever toolchain this machine has.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, Result, bail};

use crate::{root, run, setup};

pub const TARGET: &str = "thumbv7em-none-eabihf";

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Board {
    Qemu,
    Stm32f4,
    /// The target benchmark binary (QEMU board glue), see `firmware/src/bin/qemu-bench`.
    QemuBench,
}

impl Board {
    pub fn bin(self) -> &'static str {
        match self {
            Board::Qemu => "qemu",
            Board::Stm32f4 => "stm32f4",
            Board::QemuBench => "qemu-bench",
        }
    }
    pub fn feature(self) -> &'static str {
        match self {
            Board::Qemu => "board-qemu",
            Board::Stm32f4 => "board-stm32f4",
            Board::QemuBench => "board-qemu",
        }
    }
}

pub fn boards(which: &str) -> Result<Vec<Board>> {
    Ok(match which {
        "qemu" => vec![Board::Qemu],
        "stm32f4" => vec![Board::Stm32f4],
        "all" => vec![Board::Qemu, Board::Stm32f4],
        other => bail!("unknown board {other:?} (qemu, stm32f4, all)"),
    })
}

pub enum Toolchain {
    /// rustup with the target installed: plain `cargo build --target`.
    Rustup,
    /// Debian rustc-web: `-Zbuild-std` from /usr/lib/rustlib/src and ld.lld.
    DebianBuildStd,
}

fn rustup_has_target() -> bool {
    Command::new("rustup")
        .args(["target", "list", "--installed"])
        .current_dir(root())
        .output()
        .map(|o| o.status.success() && String::from_utf8_lossy(&o.stdout).lines().any(|l| l.trim() == TARGET))
        .unwrap_or(false)
}

fn debian_ready() -> bool {
    Path::new("/usr/bin/rustc").exists()
        && Path::new("/usr/bin/cargo").exists()
        && Path::new("/usr/lib/rustlib/src/rust/library/core").exists()
        && which("ld.lld")
}

pub fn which(program: &str) -> bool {
    std::env::var_os("PATH").map(|paths| std::env::split_paths(&paths).any(|d| d.join(program).is_file())).unwrap_or(false)
}

impl Toolchain {
    pub fn detect() -> Result<Self> {
        if std::env::var_os("SUBNAV_FORCE_BUILD_STD").is_none() && rustup_has_target() {
            eprintln!("xtask: firmware toolchain: rustup with {TARGET}");
            return Ok(Toolchain::Rustup);
        }
        if !debian_ready() {
            eprintln!("xtask: {TARGET} is not installed in rustup; installing Debian's rustc-web toolchain");
            setup::apt_install(&["rustc-web", "cargo-web", "rust-web-src", "lld"])?;
        }
        if !debian_ready() {
            bail!(
                "no toolchain for {TARGET}: either `rustup target add {TARGET}`, or install Debian's \
                 rustc-web cargo-web rust-web-src lld (apt-get, as root)"
            );
        }
        eprintln!("xtask: firmware toolchain: Debian rustc-web with -Zbuild-std");
        Ok(Toolchain::DebianBuildStd)
    }

    /// Build one board (the `firmware` profile: size-optimised, fat LTO) and return the ELF path.
    pub fn build(&self, board: Board) -> Result<PathBuf> {
        let target_dir = root().join("target").join("firmware");
        let mut c = match self {
            Toolchain::Rustup => {
                let mut c = Command::new("cargo");
                c.env_remove("RUSTC").env_remove("CARGO");
                c.arg("build");
                c
            }
            Toolchain::DebianBuildStd => {
                let mut c = Command::new("/usr/bin/cargo");
                c.env("RUSTC", "/usr/bin/rustc").env("RUSTC_BOOTSTRAP", "1").env_remove("CARGO");
                // rustup's proxies must not be picked up by the Debian cargo.
                c.env_remove("RUSTUP_TOOLCHAIN").env_remove("RUSTDOC");
                c.args([
                    "build",
                    "-Zbuild-std=core,compiler_builtins",
                    "-Zbuild-std-features=compiler-builtins-mem",
                    "--config",
                    "target.thumbv7em-none-eabihf.linker=\"ld.lld\"",
                ]);
                c
            }
        };
        c.current_dir(root())
            .env("DEFMT_LOG", std::env::var("DEFMT_LOG").unwrap_or_else(|_| "info".into()))
            .args(["--profile", "firmware", "--target", TARGET, "-p", "subnav-firmware", "--bin", board.bin()])
            .args(["--features", board.feature()])
            .arg("--target-dir")
            .arg(&target_dir);
        run(&mut c).with_context(|| format!("building the {} firmware", board.bin()))?;
        // Each board is built with its own features; keep a copy of each ELF so that building
        // the other board does not invalidate the path we return.
        let elf = target_dir.join(TARGET).join("firmware").join(board.bin());
        let keep = target_dir.join(format!("subnav-{}.elf", board.bin()));
        std::fs::copy(&elf, &keep).with_context(|| format!("copying {}", elf.display()))?;
        Ok(keep)
    }
}
