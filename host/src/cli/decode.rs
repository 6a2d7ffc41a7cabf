//! `subnav decode`: decode telemetry from a recording, a TCP socket or a serial port; optionally
//! decode a defmt log stream against the firmware ELF. Corrupt frames are counted and reported;
//! decoding goes on.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Result, bail};

use super::{Format, print};
use crate::link::defmt_log::DefmtTable;
use crate::link::source::{Source, pump};
use crate::link::uplink::UplinkDecoder;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// A recorded telemetry file (raw uplink bytes, e.g. from `subnav qemu --record`).
    #[arg(long, conflicts_with_all = ["tcp", "serial"])]
    pub file: Option<PathBuf>,
    /// A TCP address to connect to, e.g. QEMU started with `-serial tcp::4444,server=on`.
    #[arg(long, conflicts_with = "serial")]
    pub tcp: Option<String>,
    /// A serial port, e.g. /dev/ttyUSB0.
    #[arg(long)]
    pub serial: Option<String>,
    /// Serial baud rate (the STM32 board uses 460800).
    #[arg(long, default_value_t = 460_800)]
    pub baud: u32,
    /// Firmware ELF, for decoding defmt logs given with --defmt.
    #[arg(long, requires = "defmt")]
    pub elf: Option<PathBuf>,
    /// A recorded defmt byte stream (QEMU semihosting stdout or an RTT capture).
    #[arg(long, requires = "elf")]
    pub defmt: Option<PathBuf>,
    /// Print only the summary.
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    if let (Some(elf), Some(defmt)) = (&args.elf, &args.defmt) {
        let table = DefmtTable::from_elf_path(elf)?;
        let mut stream = table.stream();
        let bytes = std::fs::read(defmt).map_err(|e| anyhow::anyhow!("reading {}: {e}", defmt.display()))?;
        stream.feed(&bytes, |l| {
            if !args.quiet {
                print::log(&l, format)
            }
        });
        if stream.malformed > 0 {
            eprintln!("warning: {} malformed defmt frames skipped", stream.malformed);
        }
    }
    let source = match (&args.file, &args.tcp, &args.serial) {
        (Some(f), _, _) => Source::File(f.clone()),
        (_, Some(t), _) => Source::Tcp(t.clone()),
        (_, _, Some(s)) => Source::Serial { path: s.clone(), baud: args.baud },
        _ if args.defmt.is_some() => return Ok(ExitCode::SUCCESS),
        _ => bail!("say where the telemetry comes from: --file PATH, --tcp HOST:PORT or --serial DEVICE"),
    };
    let mut reader = source.open()?;
    let mut dec = UplinkDecoder::new();
    let quiet = args.quiet;
    let result = pump(reader.as_mut(), |bytes| {
        dec.feed(bytes, |e| {
            if !quiet {
                print::event(&e, format)
            }
        });
        true
    });
    print::summary(&dec.stats(), dec.trailing_bytes(), format);
    result?;
    Ok(ExitCode::SUCCESS)
}
