//! Subcommands of the `subnav` binary: one module each, with clap `Args` and
//! `run(args, format) -> anyhow::Result<ExitCode>`. A subcommand with several modes has one
//! nested subcommand per mode; `args` holds the value parsers they share (seeds, fault windows).

pub mod args;
#[cfg(feature = "probe")]
pub mod attach;
pub mod bathy;
pub mod calibrate;
pub mod compass;
pub mod decode;
pub mod export;
pub mod fgo;
pub mod filter;
#[cfg(feature = "probe")]
pub mod flash;
pub mod ice;
pub mod live;
pub mod lmnn;
pub mod map;
pub mod mavlink;
pub mod phasecorr;
pub mod print;
pub mod qemu;
pub mod record;
pub mod replay;
pub mod report;
pub mod run;
pub mod sim;
pub mod sun;

/// `--format`: human text or one JSON object per line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    Text,
    Json,
}
