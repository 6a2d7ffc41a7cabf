//! `subnav record`: read telemetry live (TCP, e.g. QEMU's `-serial tcp::4444,server=on`; a
//! serial port; or, with the `probe` feature (default), the RTT up-channels of a board through a
//! debug probe) into a lossless recording, with a live one-line status: data rate, frames,
//! corrupt frames, telemetry the firmware reported dropped, and the latest fix.
//!
//! Every chunk is written to the file as it arrives (unbuffered), so stopping with Ctrl-C or
//! losing power loses nothing already received.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use serde_json::json;
use subnav_wire::{FaultKind, NavMode, Uplink};

use super::Format;
use subnav_link::record::{Meta, Stream, Writer};
use subnav_link::source::{Source, pump};
use subnav_link::uplink::{LinkEvent, LinkStats, UplinkDecoder};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output recording (e.g. dive.snrec). If it exists, the recording goes to the next free
    /// name of its series (dive.2.snrec, dive.3.snrec, ...): a recorder started again mid-dive
    /// never replaces what was recorded, and says what it missed.
    #[arg(long, short)]
    pub out: PathBuf,
    /// A TCP address to connect to, e.g. QEMU started with `-serial tcp::4444,server=on`.
    #[arg(long, conflicts_with_all = ["serial", "chip"])]
    pub tcp: Option<String>,
    /// A serial port, e.g. /dev/ttyUSB0.
    #[arg(long, conflicts_with = "chip")]
    pub serial: Option<String>,
    /// Serial baud rate (the STM32 board uses 460800).
    #[arg(long, default_value_t = 460_800)]
    pub baud: u32,
    /// Record RTT through a debug probe from this chip (e.g. STM32F405RGTx); needs a build with
    /// the `probe` feature (default) and `--elf`.
    #[arg(long)]
    pub chip: Option<String>,
    /// The firmware ELF: named in the recording so that its defmt stream can be decoded later
    /// (and needed to find the RTT control block with --chip).
    #[arg(long)]
    pub elf: Option<PathBuf>,
    /// Stop after this many seconds (default: until the source closes or Ctrl-C); at most a year.
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::f64_positive_upto(MAX_RECORD_S))]
    pub duration_s: Option<f64>,
    /// End with an error when the source sends nothing for this long, s (default: wait).
    #[arg(long, allow_hyphen_values = true, value_parser = super::args::f64_positive_upto(MAX_RECORD_S))]
    pub idle_timeout_s: Option<f64>,
    #[command(flatten)]
    pub live: super::live::FoxgloveArgs,
    /// The head's solution to an autopilot as it is recorded (the autopilot's GPS is not sent
    /// back: `record` only reads the link; `subnav mavlink --from tcp:..|serial:..` does).
    #[command(flatten)]
    pub mavlink: super::mavlink::MavlinkArgs,
}

/// Longest `--duration-s` of a live recording, s (a year).
pub const MAX_RECORD_S: f64 = 365.0 * 86_400.0;

/// A progress bar on stderr (hidden when stderr is not a terminal): `len` 0 = spinner.
pub fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let bar = if len == 0 { ProgressBar::new_spinner() } else { ProgressBar::new(len) };
    let style = if len == 0 {
        ProgressStyle::with_template("{spinner} {prefix} {msg} [{elapsed}]")
    } else {
        ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} {msg} [{elapsed}]")
    };
    if let Ok(s) = style {
        bar.set_style(s.progress_chars("=> "));
    }
    bar.set_prefix(what.to_string());
    bar.enable_steady_tick(Duration::from_millis(200));
    bar
}

/// What a live recording has seen so far (the status line and the final summary).
#[derive(Debug, Clone, Default, Serialize)]
pub struct LiveStatus {
    pub seconds: f64,
    pub link: LinkStats,
    /// Telemetry messages the firmware reported it could not send (Fault TelemetryDropped).
    pub dropped_by_firmware: u64,
    pub defmt_bytes: u64,
    pub latest_fix: Option<(u64, [f32; 3], String)>,
    /// The head's re-acquisitions so far (from its latest `Health`): heading, position.
    pub resets: (u32, u32),
}

impl LiveStatus {
    pub fn see(&mut self, e: &LinkEvent) {
        if let LinkEvent::Message(m) = e {
            match m {
                Uplink::Nav(n) if n.mode != NavMode::Uninitialised => {
                    self.latest_fix = Some((n.t_us, n.pos_ned_m, format!("{:?}", n.mode)))
                }
                Uplink::Fault(f) if f.kind == FaultKind::TelemetryDropped => self.dropped_by_firmware = u64::from(f.count),
                Uplink::Health(h) => self.resets = (h.heading_resets, h.position_resets),
                _ => {}
            }
        }
    }

    pub fn line(&self) -> String {
        let rate = if self.seconds > 0.0 { self.link.bytes as f64 / self.seconds } else { 0.0 };
        let fix = match &self.latest_fix {
            Some((t, p, mode)) => format!("fix t={:.1}s N {:.1} E {:.1} D {:.1} ({mode})", *t as f64 * 1e-6, p[0], p[1], p[2]),
            None => "no fix yet".into(),
        };
        let resets = match self.resets {
            (0, 0) => String::new(),
            (h, p) => format!(", RE-ACQUIRED heading x{h} position x{p}"),
        };
        format!(
            "{:.0} B/s, {} frames, {} corrupt, {} dropped by firmware, {}{resets}",
            rate, self.link.frames_ok, self.link.frames_bad, self.dropped_by_firmware, fix
        )
    }
}

pub fn run(mut args: Args, format: Format) -> Result<ExitCode> {
    let first = args.out.clone();
    let k = subnav_link::record::series(&first).len() + 1;
    args.out = subnav_link::record::series_member(&first, k);
    let previous = (k > 1).then(|| subnav_link::record::series_member(&first, k - 1));
    if let Some(p) = &previous {
        eprintln!("{} exists: recording to {} (nothing recorded is replaced)", p.display(), args.out.display());
    }
    if let Some(chip) = &args.chip {
        return record_rtt(&args, chip, format);
    }
    let source = match (&args.tcp, &args.serial) {
        (Some(t), _) => Source::Tcp(t.clone()),
        (_, Some(s)) => Source::Serial { path: s.clone(), baud: args.baud },
        _ => bail!(
            "say where the telemetry comes from: --tcp HOST:PORT, --serial DEVICE [--baud N], or --chip CHIP --elf ELF (probe builds)"
        ),
    };
    let mut meta = Meta::new(source.to_string());
    meta.elf = args.elf.as_ref().map(|p| p.display().to_string());
    meta.continues = previous.as_ref().and_then(|p| p.file_name()).map(|n| n.to_string_lossy().into_owned());
    if let Some(elf) = &args.elf {
        subnav_link::output::refuse_input_as_output("--out", &args.out, &[elf])?;
    }
    let mut reader = source.open()?;
    let live = super::live::start(&args.live, subnav_link::export::TimeBase::Host)?;
    let bridge = super::mavlink::start_reading(&args.mavlink, None)?;
    // Under a temporary name until the first data arrives: a source that fails or closes at
    // once leaves an old recording at --out untouched.
    let mut w = Writer::create_atomic(&args.out, &meta)?;
    let bar = progress_bar(0, "recording");
    let started = Instant::now();
    let mut dec = UplinkDecoder::new();
    let mut status = LiveStatus::default();
    let mut write_err = None;
    let limit = args.duration_s.map(Duration::from_secs_f64);
    let idle = args.idle_timeout_s.map(Duration::from_secs_f64);
    let result = pump(reader.as_mut(), idle, |bytes| {
        if bytes.is_empty() {
            // The source is quiet: only the time limit to check.
            return limit.is_none_or(|l| started.elapsed() < l);
        }
        if let Err(e) = w.chunk_now(Stream::Uplink, bytes).and_then(|()| w.publish()) {
            write_err = Some(e);
            return false;
        }
        let was_first = dec.stats().frames_ok == 0;
        dec.feed(bytes, |e| {
            super::mavlink::observe(live.as_ref(), bridge.as_ref(), &e);
            status.see(&e)
        });
        status.link = dec.stats();
        if was_first && status.link.frames_ok > 0 && status.link.joined_running_head {
            bar.suspend(|| eprintln!("{}", joined_note(previous.as_deref(), &status.link)));
        }
        status.seconds = started.elapsed().as_secs_f64();
        bar.set_message(status.line());
        limit.is_none_or(|l| started.elapsed() < l)
    });
    bar.finish_and_clear();
    super::live::finish(live);
    super::mavlink::finish(bridge, &args.mavlink.bridge)?;
    if let Some(e) = write_err {
        return Err(e);
    }
    status.seconds = started.elapsed().as_secs_f64();
    if w.chunks[usize::from(Stream::Uplink.code())] == 0 {
        result?;
        bail!("{source} sent no data in {:.1} s: nothing recorded, {} not written", status.seconds, args.out.display());
    }
    w.into_inner().commit()?;
    finish(&args, &status, format);
    result?;
    Ok(ExitCode::SUCCESS)
}

/// What a recorder that joined a running head missed: since the head's boot, or since the end
/// of the series' previous recording.
fn joined_note(previous: Option<&std::path::Path>, now: &LinkStats) -> String {
    let at = now.first_head_us.map_or(0.0, |t| t as f64 * 1e-6);
    match previous {
        Some(p) => format!("joined a running head at head time {at:.1} s: {}", subnav_link::record::continuation_note(p, now)),
        None => format!("joined a running head at head time {at:.1} s (no Boot seen): its first {at:.1} s are not recorded"),
    }
}

fn finish(args: &Args, status: &LiveStatus, format: Format) {
    match format {
        Format::Text => {
            eprintln!("recorded {} in {:.1} s: {}", args.out.display(), status.seconds, status.line());
            let note = status.link.coverage_note();
            if !note.is_empty() {
                eprintln!("coverage: {note}");
            }
        }
        Format::Json => println!("{}", json!({"type": "summary", "recording": args.out.display().to_string(), "status": status})),
    }
}

#[cfg(feature = "probe")]
fn record_rtt(args: &Args, chip: &str, format: Format) -> Result<ExitCode> {
    let Some(elf) = &args.elf else { bail!("--chip needs --elf (the RTT control block is found through the ELF's symbols)") };
    let live = super::live::start(&args.live, subnav_link::export::TimeBase::Host)?;
    let bridge = super::mavlink::start_reading(&args.mavlink, None)?;
    let status = super::attach::stream_rtt(chip, elf, None, Some(&args.out), args.duration_s, live.as_ref(), bridge.as_ref(), |_| {});
    super::live::finish(live);
    super::mavlink::finish(bridge, &args.mavlink.bridge)?;
    let status = status?;
    finish(args, &status, format);
    Ok(ExitCode::SUCCESS)
}

#[cfg(not(feature = "probe"))]
fn record_rtt(_args: &Args, _chip: &str, _format: Format) -> Result<ExitCode> {
    bail!(
        "this subnav was built without debug-probe support: rebuild with the default features (`cargo build -p subnav-host`, the `probe` feature) to record RTT with --chip"
    )
}
