//! `subnav decode`: decode telemetry from a recording, a TCP socket or a serial port; optionally
//! decode a defmt log stream against the firmware ELF. Corrupt frames are counted and reported;
//! decoding goes on.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Result, bail};

use super::{Format, print};
use subnav_link::defmt_log::DefmtTable;
use subnav_link::source::{Source, pump};
use subnav_link::uplink::UplinkDecoder;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// A recording (`subnav record`, `subnav qemu --record`) or a file of raw uplink bytes.
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
    /// Firmware ELF, for decoding defmt logs (given with --defmt, or in a recording; a
    /// recording names its ELF, used when this is not given).
    #[arg(long)]
    pub elf: Option<PathBuf>,
    /// A recorded defmt byte stream (QEMU semihosting stdout or an RTT capture).
    #[arg(long, requires = "elf")]
    pub defmt: Option<PathBuf>,
    /// Print only the summary.
    #[arg(long)]
    pub quiet: bool,
    /// A live source (--tcp, --serial) that sends nothing for this long ends the decode with an
    /// error, s.
    #[arg(long, allow_hyphen_values = true, default_value_t = 60.0, value_parser = super::args::f64_positive_upto(1e6))]
    pub idle_timeout_s: f64,
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    if let Some(f) = &args.file {
        let mut head = [0u8; 8];
        let mut file = std::fs::File::open(f).map_err(|e| anyhow::anyhow!("opening {}: {e}", f.display()))?;
        let n = std::io::Read::read(&mut file, &mut head).map_err(|e| anyhow::anyhow!("reading {}: {e}", f.display()))?;
        if n == 0 {
            bail!("{} is empty: neither a recording nor uplink bytes", f.display());
        }
        if subnav_link::record::looks_like_recording(&head[..n]) {
            return run_recording(f, &args, format);
        }
    }
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
    let idle = std::time::Duration::from_secs_f64(args.idle_timeout_s);
    let result = pump(reader.as_mut(), Some(idle), |bytes| {
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

/// Decode a recording: uplink messages and (with the ELF) defmt log lines in arrival order;
/// damaged regions of the file are reported and skipped.
fn run_recording(path: &std::path::Path, args: &Args, format: Format) -> Result<ExitCode> {
    use subnav_link::record::{Item, Reader, Stream};
    let bytes = std::fs::read(path).map_err(|e| anyhow::anyhow!("reading {}: {e}", path.display()))?;
    let mut reader = Reader::open(&bytes).map_err(|e| anyhow::anyhow!("reading the recording {}: {e}", path.display()))?;
    if let Some(e) = &reader.header_error {
        eprintln!("warning: {}: {e}; its metadata (source, ELF) is lost, the chunks after it are read", path.display());
    }
    let elf = args.elf.clone().or_else(|| reader.meta.elf.as_ref().map(PathBuf::from).filter(|p| p.exists()));
    let table = elf
        .as_ref()
        .map(|e| DefmtTable::from_elf_path(e))
        .transpose()
        .map_err(|e| if args.elf.is_some() { e } else { e.context(format!("the ELF named in the header of {}", path.display())) })?;
    let mut logs = table.as_ref().map(|t| t.stream());
    let mut dec = UplinkDecoder::new();
    let (mut defmt_bytes, mut damaged) = (0u64, 0u64);
    let quiet = args.quiet;
    for item in reader.by_ref() {
        match item {
            Item::Chunk(c) => match c.stream {
                Stream::Uplink => dec.feed(&c.data, |e| {
                    if !quiet {
                        print::event(&e, format)
                    }
                }),
                Stream::Defmt => {
                    defmt_bytes += c.data.len() as u64;
                    if let Some(l) = logs.as_mut() {
                        l.feed(&c.data, |line| {
                            if !quiet {
                                print::log(&line, format)
                            }
                        });
                    }
                }
                Stream::Downlink | Stream::Truth => {}
            },
            Item::Damage(d) => {
                damaged += 1;
                eprintln!("warning: damaged recording region at byte {} ({} bytes skipped): {}", d.offset, d.len, d.reason);
            }
        }
    }
    if defmt_bytes > 0 && logs.is_none() {
        eprintln!("note: {defmt_bytes} defmt log bytes not decoded: give the firmware ELF with --elf");
    }
    if let Some(l) = &logs {
        if l.malformed > 0 {
            eprintln!("warning: {} malformed defmt frames skipped", l.malformed);
        }
    }
    if damaged > 0 {
        eprintln!("warning: {damaged} damaged region(s) in the recording were skipped");
    }
    print::summary(&dec.stats(), dec.trailing_bytes(), format);
    if let Some(name) = reader.meta.continues.as_deref() {
        // The next of a series (a host restarted mid-dive): how much of the head's time is in
        // neither recording.
        let before = path.with_file_name(name);
        let note = format!("continues {}", subnav_link::record::continuation_note(&before, &dec.stats()));
        if format == Format::Text {
            eprintln!("series: {note}");
        } else {
            println!("{}", serde_json::json!({"type": "series", "continues": before.display().to_string(), "note": note}));
        }
    }
    Ok(ExitCode::SUCCESS)
}
