//! `subnav attach` (the `probe` feature, on by default): attach to a running board through a debug
//! probe (probe-rs), stream its defmt logs from the RTT up-channel named `defmt` (and telemetry
//! from an up-channel named `telemetry`, if the firmware has one), optionally the telemetry UART
//! too (`--serial`), print them decoded and optionally record everything losslessly; with
//! `--foxglove` serve them live, with `--mavlink ENDPOINT` bridge the solution to an autopilot
//! (the one path of `record`/`qemu`: [`super::mavlink::start_reading`] and
//! [`super::mavlink::observe`]; nothing goes back to the head, so the autopilot's GPS is not
//! taken).
//!
//! Tested here: it builds (the `probe` feature is on by default), its options parse (unit test),
//! and the shared path from a decoded link event to the autopilot is tested
//! without a probe (`cli::mavlink` tests). Not tested: a real probe and board (none can be
//! attached on the build machines).

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use probe_rs::rtt::{Rtt, ScanRegion};
use probe_rs::{Permissions, probe::list::Lister};

use super::record::{LiveStatus, progress_bar};
use super::{Format, print};
use subnav_link::defmt_log::DefmtTable;
use subnav_link::record::{Meta, Stream, Writer};
use subnav_link::source::{Source, pump};
use subnav_link::uplink::UplinkDecoder;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Target chip as probe-rs names it, e.g. STM32F405RGTx.
    #[arg(long)]
    pub chip: String,
    /// The firmware ELF running on the board (defmt table and RTT control block address).
    #[arg(long)]
    pub elf: PathBuf,
    /// Also read telemetry from this serial port (the STM32 board's USART2).
    #[arg(long)]
    pub serial: Option<String>,
    #[arg(long, default_value_t = 460_800)]
    pub baud: u32,
    /// Record everything to this file.
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    pub duration_s: Option<f64>,
    #[command(flatten)]
    pub live: super::live::FoxgloveArgs,
    /// The head's solution to an autopilot as it streams (the autopilot's GPS is not sent back).
    #[command(flatten)]
    pub mavlink: super::mavlink::MavlinkArgs,
}

/// Open the first probe and attach to `chip`.
pub fn open_session(chip: &str) -> Result<probe_rs::Session> {
    let lister = Lister::new();
    let probes = lister.list_all();
    let info = probes.first().ok_or_else(|| anyhow!("no debug probe found: plug one in (and on Linux install probe-rs udev rules)"))?;
    let probe = info.open().with_context(|| format!("opening the probe {info:?} (permissions? udev rules?)"))?;
    probe
        .attach(chip, Permissions::default())
        .with_context(|| format!("attaching to {chip} (check the chip name with `probe-rs chip list` and the wiring)"))
}

enum In {
    Uplink(Vec<u8>),
    Defmt(Vec<u8>),
}

/// Stream RTT (and the serial port) until `duration_s` or the link ends; decode and print through
/// `on_text`, and record to `record` when given.
pub fn stream_rtt(
    chip: &str,
    elf: &Path,
    serial: Option<(String, u32)>,
    record: Option<&Path>,
    duration_s: Option<f64>,
    live: Option<&subnav_link::live_view::LiveView>,
    bridge: Option<&std::sync::Arc<subnav_mavlink::Bridge>>,
    mut on_text: impl FnMut(&str),
) -> Result<LiveStatus> {
    let elf_bytes = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let table = DefmtTable::from_elf(&elf_bytes)?;
    let cb = probe_rs::rtt::find_rtt_control_block_in_raw_file(&elf_bytes)
        .map_err(|e| anyhow!("reading {}: {e}", elf.display()))?
        .ok_or_else(|| anyhow!("{} has no _SEGGER_RTT symbol: is it built with defmt-rtt?", elf.display()))?;
    let mut session = open_session(chip)?;
    let mut core = session.core(0).context("selecting core 0")?;
    let mut rtt = Rtt::attach_region(&mut core, &ScanRegion::Exact(cb)).context("attaching to RTT (is the firmware running?)")?;

    let (tx, rx) = mpsc::channel::<In>();
    if let Some((path, baud)) = serial {
        let mut reader = Source::Serial { path, baud }.open()?;
        let tx = tx.clone();
        std::thread::spawn(move || {
            let _ = pump(reader.as_mut(), None, |b| b.is_empty() || tx.send(In::Uplink(b.to_vec())).is_ok());
        });
    }
    let mut writer = match record {
        Some(p) => {
            let mut meta = Meta::new(format!("probe {chip}"));
            meta.elf = Some(elf.display().to_string());
            Some(Writer::create(p, &meta)?)
        }
        None => None,
    };
    let mut logs = table.stream();
    let mut dec = UplinkDecoder::new();
    let mut status = LiveStatus::default();
    let bar = progress_bar(0, "attached");
    let started = Instant::now();
    let limit = duration_s.map(Duration::from_secs_f64);
    let mut buf = vec![0u8; 4096];
    while limit.is_none_or(|l| started.elapsed() < l) {
        let mut got_any = false;
        for ch in rtt.up_channels().iter_mut() {
            let n = ch.read(&mut core, &mut buf).context("reading RTT")?;
            if n == 0 {
                continue;
            }
            got_any = true;
            let data = buf.get(..n).unwrap_or_default().to_vec();
            match ch.name() {
                Some("defmt") => tx.send(In::Defmt(data)).ok(),
                Some("telemetry") => tx.send(In::Uplink(data)).ok(),
                _ => None,
            };
        }
        while let Ok(item) = rx.try_recv() {
            match item {
                In::Uplink(b) => {
                    if let Some(w) = writer.as_mut() {
                        w.chunk_now(Stream::Uplink, &b)?;
                    }
                    dec.feed(&b, |e| {
                        super::mavlink::observe(live, bridge, &e);
                        status.see(&e);
                        if let subnav_link::LinkEvent::Message(m) = &e {
                            on_text(&print::text(m));
                        }
                    });
                }
                In::Defmt(b) => {
                    status.defmt_bytes += b.len() as u64;
                    if let Some(w) = writer.as_mut() {
                        w.chunk_now(Stream::Defmt, &b)?;
                    }
                    logs.feed(&b, |l| {
                        super::live::log_line(live, &l);
                        on_text(&format!("log     {l}"))
                    });
                }
            }
        }
        status.link = dec.stats();
        status.seconds = started.elapsed().as_secs_f64();
        bar.set_message(status.line());
        if !got_any {
            std::thread::sleep(Duration::from_millis(10));
        }
    }
    bar.finish_and_clear();
    Ok(status)
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    if !args.elf.exists() {
        bail!("{} does not exist: build the firmware first (`cargo xtask build --board stm32f4`)", args.elf.display());
    }
    let serial = args.serial.clone().map(|s| (s, args.baud));
    let live = super::live::start(&args.live, subnav_link::export::TimeBase::Host)?;
    let bridge = super::mavlink::start_reading(&args.mavlink, None)?;
    let status =
        stream_rtt(&args.chip, &args.elf, serial, args.record.as_deref(), args.duration_s, live.as_ref(), bridge.as_ref(), |line| {
            if format == Format::Text {
                println!("{line}");
            }
        });
    super::live::finish(live);
    super::mavlink::finish(bridge, &args.mavlink.bridge)?;
    let status = status?;
    match format {
        Format::Text => eprintln!("{}", status.line()),
        Format::Json => println!("{}", serde_json::json!({"type": "summary", "status": status})),
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        attach: super::Args,
    }

    #[test]
    fn attach_takes_the_mavlink_options_of_the_other_live_commands() {
        let c = Cli::try_parse_from([
            "attach",
            "--chip",
            "STM32F405RGTx",
            "--elf",
            "fw.elf",
            "--mavlink",
            "udpout:127.0.0.1:14550",
            "--mavlink-system-id",
            "2",
            "--mavlink-odometry-frame",
            "local-ned",
        ])
        .unwrap();
        assert_eq!(c.attach.mavlink.mavlink.unwrap().to_string(), "udpout:127.0.0.1:14550");
        assert_eq!(c.attach.mavlink.bridge.mavlink_system_id, 2);
        assert!(Cli::try_parse_from(["attach", "--chip", "X", "--elf", "f", "--mavlink", "carrier-pigeon:1"]).is_err());
    }
}
