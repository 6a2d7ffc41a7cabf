//! Subcommands of the `subnav` binary: one module each, with clap `Args` and
//! `run(args, format) -> anyhow::Result<ExitCode>`.

pub mod bathy;
pub mod compass;
pub mod decode;
pub mod fgo;
pub mod filter;
pub mod print;
pub mod qemu;
pub mod sun;
pub mod record;
pub mod export;
pub mod report;
#[cfg(feature = "probe")]
pub mod attach;
#[cfg(feature = "probe")]
pub mod flash;

/// `--format`: human text or one JSON object per line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    Text,
    Json,
}
