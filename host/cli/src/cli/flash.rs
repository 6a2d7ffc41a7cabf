//! `subnav flash` (the `probe` feature, on by default): write a firmware ELF to a board's flash with
//! the probe-rs library, reset it, and optionally stay attached to stream defmt + telemetry
//! (as `subnav attach`).
//!
//! Tested here: it builds (CI builds the feature). Not tested: a real probe and board.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use probe_rs::flashing::{DownloadOptions, ElfOptions, FlashProgress, ProgressEvent};

use super::Format;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Target chip as probe-rs names it, e.g. STM32F405RGTx.
    #[arg(long)]
    pub chip: String,
    /// The firmware ELF (`cargo xtask build --board stm32f4`).
    #[arg(long)]
    pub elf: PathBuf,
    /// After flashing, stay attached and stream logs and telemetry (see `subnav attach`).
    #[arg(long)]
    pub attach: bool,
    /// With --attach: also read telemetry from this serial port.
    #[arg(long)]
    pub serial: Option<String>,
    #[arg(long, default_value_t = 460_800)]
    pub baud: u32,
    /// With --attach: record to this file.
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// With --attach: stop after this many seconds.
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// With --attach: the head's solution to an autopilot (see `subnav attach --help`).
    #[command(flatten)]
    pub mavlink: super::mavlink::MavlinkArgs,
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    if !args.elf.exists() {
        bail!("{} does not exist: build the firmware first (`cargo xtask build --board stm32f4`)", args.elf.display());
    }
    let started = std::time::Instant::now();
    {
        let mut session = super::attach::open_session(&args.chip)?;
        let bar = super::record::progress_bar(0, "flashing");
        let progress = FlashProgress::new(|event| {
            if let ProgressEvent::Started(op) = &event {
                bar.set_message(format!("{op:?}"));
            }
        });
        let mut opts = DownloadOptions::default();
        opts.progress = progress;
        probe_rs::flashing::download_file_with_options(&mut session, &args.elf, probe_rs::flashing::ElfLoader(ElfOptions::default()), opts)
            .with_context(|| format!("flashing {} to {}", args.elf.display(), args.chip))?;
        bar.finish_and_clear();
        session.core(0).context("selecting core 0")?.reset().context("resetting the target after flashing")?;
    }
    let secs = started.elapsed().as_secs_f64();
    match format {
        Format::Text => eprintln!("flashed {} to {} in {secs:.1} s and reset it", args.elf.display(), args.chip),
        Format::Json => println!(
            "{}",
            serde_json::json!({"type": "flashed", "elf": args.elf.display().to_string(), "chip": args.chip, "seconds": secs})
        ),
    }
    if args.attach {
        let a = super::attach::Args {
            chip: args.chip,
            elf: args.elf,
            serial: args.serial,
            baud: args.baud,
            record: args.record,
            duration_s: args.duration_s,
            live: Default::default(),
            mavlink: args.mavlink,
        };
        return super::attach::run(a, format);
    }
    Ok(ExitCode::SUCCESS)
}
