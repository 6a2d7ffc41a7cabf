//! `subnav calibrate`: calibrate a (simulated) sensor head and write its calibrations to its
//! store over the downlink (`head`), or compare mis-built heads uncalibrated, calibrated and
//! ideal in the same dive (`compare`). The procedures are `subnav_sil::calibrate`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Result;
use subnav_sil::calibrate::{self, Comparison, Target};
use subnav_wire::Record;

use super::Format;

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(subcommand)]
    pub mode: Mode,
}

#[derive(clap::Subcommand, Debug)]
pub enum Mode {
    /// Record the calibration sequence on a simulated head (rig: six positions, turns, a sky
    /// spin), fit its polarization units and IMU, write them with SetRecord, verify the read-back.
    Head(HeadArgs),
    /// Mis-built heads (one per seed) in the same dive: compass heading RMSE uncalibrated,
    /// calibrated by this procedure and for the ideal head (native runs).
    Compare(CompareArgs),
}

#[derive(clap::Args, Debug)]
pub struct HeadArgs {
    /// The head's store (its W25Q flash image; created erased when missing). `subnav qemu
    /// --flash FILE` boots a head on it.
    #[arg(long, value_name = "FILE")]
    pub flash: PathBuf,
    /// Manufacturing seed of the simulated head (its per-unit errors); omitted: the ideal head.
    #[arg(long)]
    pub build_seed: Option<u64>,
    /// Power-up seed of the session (turn-on biases, noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Run the QEMU board firmware (ELF) instead of the native application core.
    #[arg(long)]
    pub elf: Option<PathBuf>,
    /// Wall-clock limit of each QEMU session, s.
    #[arg(long, default_value_t = 1800)]
    pub timeout_s: u64,
}

#[derive(clap::Args, Debug)]
pub struct CompareArgs {
    /// Manufacturing seeds of the heads (`N`, `A..B`, `A..=B`).
    #[arg(long, value_parser = super::args::parse_seeds, default_value = "1..=10")]
    pub seeds: super::args::Seeds,
    /// Length of the dive (the default scenario: survey at 10 m, DVL, fixes every 5 s), s.
    #[arg(long, default_value_t = 300.0, value_parser = super::args::f64_positive_upto(86_400.0))]
    pub duration_s: f64,
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    match args.mode {
        Mode::Head(a) => head(a, format),
        Mode::Compare(a) => compare(a, format),
    }
}

fn describe(r: &Record) -> String {
    match r {
        Record::Polarization(p) => format!(
            "unit {}: gain {:.4?} offset {:.1?} counts, polarizer {:.3?} deg, extinction {:.0?}",
            p.unit,
            p.gain,
            p.offset_counts,
            p.polarizer_rad.map(|a| a.to_degrees()),
            p.extinction_ratio
        ),
        Record::Imu(c) => format!(
            "IMU: gyro bias {:.5?} rad/s, accel bias {:.4?} m/s^2, gyro {:.5?}, accel {:.5?}, body from IMU {:.5?}",
            c.gyro_bias_radps, c.accel_bias_mps2, c.gyro_correction, c.accel_correction, c.body_from_imu_wxyz
        ),
        other => format!("{other:?}"),
    }
}

fn head(a: HeadArgs, format: Format) -> Result<ExitCode> {
    let flash = calibrate::flash_file(&a.flash)?;
    let target = match a.elf {
        Some(elf) => Target::Qemu { elf, timeout: Duration::from_secs(a.timeout_s) },
        None => Target::Native,
    };
    let cal = calibrate::calibrate(&target, a.build_seed, a.seed, &flash)?;
    match format {
        Format::Json => {
            let recovery = a.build_seed.map(|s| calibrate::recovery_errors(&cal.records, s));
            let records: Vec<String> = cal.records.iter().map(describe).collect();
            println!("{}", serde_json::json!({ "records": records, "verified": true, "recovery": recovery }));
        }
        Format::Text => {
            println!(
                "recorded {} IMU and {} polarization samples; wrote and read back {} records into {}:",
                cal.recording.imu.len(),
                cal.recording.polarization.len(),
                cal.records.len(),
                a.flash.display()
            );
            for r in &cal.records {
                println!("  {}", describe(r));
            }
            if let Some(s) = a.build_seed {
                let e = calibrate::recovery_errors(&cal.records, s);
                println!(
                    "against the simulated build {s}: gains within {:.3} % (common scale removed), angle of polarization within {:.4} deg, mounting {:.4} deg, accel scale {:.4} %",
                    100.0 * e.max_gain_rel,
                    e.max_aop_deg,
                    e.mounting_deg,
                    100.0 * e.max_accel_scale_rel
                );
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn compare(a: CompareArgs, format: Format) -> Result<ExitCode> {
    let dive = subnav_sil::Scenario { duration_s: a.duration_s, ..subnav_sil::Scenario::default() };
    let mut rows: Vec<Comparison> = Vec::new();
    if format == Format::Text {
        println!("| build seed | compass RMSE uncalibrated (deg) | calibrated | ideal | nav heading RMSE uncal. / cal. / ideal (deg) | AoP err (deg) | mounting err (deg) |");
        println!("|---:|---:|---:|---:|---:|---:|---:|");
    }
    for seed in a.seeds.range() {
        let c = calibrate::compare(seed, &dive)?;
        match format {
            Format::Json => println!("{}", serde_json::to_string(&c)?),
            Format::Text => println!(
                "| {} | {:.3} | {:.3} | {:.3} | {:.3} / {:.3} / {:.3} | {:.4} | {:.4} |",
                c.build_seed,
                c.uncalibrated.compass_rmse_deg,
                c.calibrated.compass_rmse_deg,
                c.ideal.compass_rmse_deg,
                c.uncalibrated.heading_rmse_deg,
                c.calibrated.heading_rmse_deg,
                c.ideal.heading_rmse_deg,
                c.recovery.max_aop_deg,
                c.recovery.mounting_deg
            ),
        }
        rows.push(c);
    }
    let n = rows.len().max(1) as f64;
    let rms = |f: fn(&Comparison) -> f64| (rows.iter().map(|c| f(c).powi(2)).sum::<f64>() / n).sqrt();
    let (u, c, i) = (rms(|r| r.uncalibrated.compass_rmse_deg), rms(|r| r.calibrated.compass_rmse_deg), rms(|r| r.ideal.compass_rmse_deg));
    match format {
        Format::Json => println!("{}", serde_json::json!({ "heads": rows.len(), "compass_rmse_deg": { "uncalibrated": u, "calibrated": c, "ideal": i }, "calibrated_over_ideal": c / i })),
        Format::Text => println!(
            "| all ({} heads, RMS) | {u:.3} | {c:.3} | {i:.3} | calibrated / ideal = {:.3} (goal <= 1.10) | | |",
            rows.len(),
            c / i
        ),
    }
    Ok(ExitCode::SUCCESS)
}
