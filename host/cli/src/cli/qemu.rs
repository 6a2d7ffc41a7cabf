//! `subnav qemu`: boot a firmware ELF in QEMU (mps2-an386), print its decoded telemetry and
//! defmt logs live, and exit with the firmware's exit status.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Result;

use super::{Format, print};
use subnav_link::qemu::{self, QemuConfig, QemuEvent};
use subnav_link::record::tap::QemuRecorder;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The QEMU board firmware ELF (`cargo xtask build --board qemu` prints where it is).
    #[arg(long)]
    pub elf: PathBuf,
    /// Firmware time to run before the board exits, ms (0 = until the firmware stops itself; at most a day).
    #[arg(long, allow_hyphen_values = true, default_value_t = 5_000, value_parser = super::args::int_in(0u64..=86_400_000))]
    pub run_ms: u64,
    /// Wall-clock limit, seconds, connecting included (1..=604800, a week).
    #[arg(long, default_value_t = 120, value_parser = super::args::int_in(1u64..=super::args::MAX_TIMEOUT_S))]
    pub timeout_s: u64,
    /// Write a lossless recording (uplink, defmt and downlink bytes with host receive times) to
    /// this file; `subnav decode --file`, `export` and `report` read it.
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// QEMU executable.
    #[arg(long, default_value = "qemu-system-arm")]
    pub qemu: PathBuf,
    /// QEMU -icount shift (virtual ns per instruction = 2^shift; 0..=10, QEMU's range).
    #[arg(long, default_value_t = 3, value_parser = super::args::int_in(0u8..=10))]
    pub icount_shift: u8,
    /// Run without the simulated sensors (every bus transaction is NACKed).
    #[arg(long)]
    pub no_sensors: bool,
    /// Keep the head's store (its W25Q flash) in this file: configuration and calibrations
    /// survive across runs (created erased when missing). Default: an erased flash in memory.
    /// Any other existing file is refused, untouched.
    #[arg(long, value_name = "FILE")]
    pub flash: Option<PathBuf>,
    /// Make a new erased image at --flash, replacing the file there.
    #[arg(long, requires = "flash")]
    pub new_flash: bool,
    /// Seed of the simulated dive (default scenario: survey at 10 m, Bay of Biscay, June morning).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[command(flatten)]
    pub live: super::live::FoxgloveArgs,
    /// The head's solution to an autopilot (the autopilot's GPS is not sent back under QEMU).
    #[command(flatten)]
    pub mavlink: super::mavlink::MavlinkArgs,
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    // Before any output or the flash image is touched: the ELF, the outputs.
    subnav_link::defmt_log::DefmtTable::from_elf_path(&args.elf)?;
    let outputs: Vec<(&str, &std::path::Path)> = [
        ("--record", args.record.as_deref()),
        ("--flash", args.flash.as_deref()),
        ("--mavlink-summary", args.mavlink.bridge.mavlink_summary.as_deref()),
    ]
    .into_iter()
    .filter_map(|(f, p)| Some((f, p?)))
    .collect();
    subnav_link::output::check_outputs(&outputs, &[&args.elf])?;
    let mut cfg = QemuConfig::new(&args.elf);
    cfg.qemu = args.qemu;
    cfg.run_ms = (args.run_ms > 0).then_some(args.run_ms);
    cfg.timeout = Duration::from_secs(args.timeout_s);
    cfg.icount_shift = args.icount_shift;
    let recorder = args.record.as_ref().map(|p| QemuRecorder::start(&mut cfg, p)).transpose()?;
    let scenario = subnav_sil::Scenario { seed: args.seed, duration_s: (args.run_ms as f64 / 1000.0).max(1.0), ..Default::default() };
    let bus: Box<dyn qemu::BusHandler> = if args.no_sensors {
        Box::new(qemu::NothingAttached)
    } else {
        cfg.board_args = scenario.board_args();
        let head = subnav_sil::SimHead::new(&scenario);
        match &args.flash {
            Some(p) => {
                use subnav_sil::chips::w25q::W25qModel;
                let chip = if args.new_flash { W25qModel::new_file(p) } else { W25qModel::with_file(p) };
                Box::new(head.with_flash(chip.map_err(|e| super::calibrate::flash_hint(e, "qemu"))?))
            }
            None => Box::new(head),
        }
    };
    let live = super::live::start(&args.live, subnav_link::export::TimeBase::Host)?;
    // With the simulated sensors, the viewer also gets the truth.
    let feed = live.as_ref().filter(|_| !args.no_sensors).map(|l| super::live::SimFeed::new(l, &scenario));
    let origin = if args.no_sensors { None } else { super::mavlink::scenario_origin(&scenario) };
    let bridge = super::mavlink::start_reading(&args.mavlink, origin)?;
    let outcome = qemu::run_with_bus(&cfg, bus, |event, _| match event {
        QemuEvent::Link(e) => {
            if let subnav_link::LinkEvent::Message(m) = &e {
                super::mavlink::on_uplink(bridge.as_ref(), m);
            }
            match (&e, &feed) {
                (subnav_link::LinkEvent::Message(m), Some(f)) => f.on_uplink(subnav_link::record::now_unix_us(), m, None),
                _ => super::live::link_event(live.as_ref(), &e),
            }
            print::event(&e, format)
        }
        QemuEvent::Log(l) => {
            super::live::log_line(live.as_ref(), &l);
            print::log(&l, format)
        }
    })
    .map(|(o, _)| o);
    drop(feed);
    super::live::finish(live);
    super::mavlink::finish(bridge, &args.mavlink.bridge)?;
    cfg.raw_tap = None;
    if let Some(r) = recorder {
        r.finish()?;
    }
    let outcome = outcome?;
    print::summary(&outcome.link, 0, format);
    if !outcome.stderr.trim().is_empty() {
        eprintln!("qemu: {}", outcome.stderr.trim());
    }
    if outcome.timed_out {
        eprintln!("error: the firmware did not exit within {} s; QEMU was stopped", args.timeout_s);
        return Ok(ExitCode::FAILURE);
    }
    match outcome.exit_code {
        Some(0) => Ok(ExitCode::SUCCESS),
        code => {
            eprintln!("error: the firmware exited with failure (QEMU exit code {code:?})");
            Ok(ExitCode::FAILURE)
        }
    }
}
