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
    /// --flash FILE` boots a head on it. Any other existing file is refused, untouched.
    #[arg(long, value_name = "FILE")]
    pub flash: PathBuf,
    /// Make a new erased image at --flash, replacing the file there.
    #[arg(long)]
    pub new_flash: bool,
    /// Manufacturing seed of the simulated head (its per-unit errors); omitted: the ideal head.
    #[arg(long)]
    pub build_seed: Option<u64>,
    /// Power-up seed of the session (turn-on biases, noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Run the QEMU board firmware (ELF) instead of the native application core.
    #[arg(long)]
    pub elf: Option<PathBuf>,
    /// Power-ups the IMU part of the sequence is run in (their turn-on biases average out of the
    /// stored bias; the first session also has the sky turns).
    #[arg(long, default_value_t = calibrate::IMU_POWER_UPS, value_parser = super::args::int_in(1u64..=100))]
    pub imu_power_ups: u64,
    /// Wall-clock limit of each QEMU session, s (1..=604800).
    #[arg(long, default_value_t = 1800, value_parser = super::args::int_in(1u64..=super::args::MAX_TIMEOUT_S))]
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

/// A refused flash image's error, with the flag that asks for a new image.
pub fn flash_hint(e: anyhow::Error, cmd: &str) -> anyhow::Error {
    if e.to_string().contains("not a flash image") {
        e.context(format!("--flash: `subnav {cmd} --new-flash` replaces the file with a new erased image"))
    } else {
        e.context("--flash")
    }
}

fn head(a: HeadArgs, format: Format) -> Result<ExitCode> {
    if let Some(elf) = &a.elf {
        // A bad ELF is refused before the flash image is made or opened.
        subnav_link::defmt_log::DefmtTable::from_elf_path(elf)?;
        subnav_link::output::refuse_input_as_output("--flash", &a.flash, &[elf])?;
    }
    let flash = calibrate::flash_file(&a.flash, a.new_flash).map_err(|e| flash_hint(e, "calibrate head"))?;
    let target = match a.elf {
        Some(elf) => Target::Qemu { elf, timeout: Duration::from_secs(a.timeout_s) },
        None => Target::Native,
    };
    let cal = calibrate::calibrate_with(&target, a.build_seed, a.seed, a.imu_power_ups, &flash)?;
    match format {
        Format::Json => {
            let recovery = a.build_seed.map(|s| calibrate::recovery_errors(&cal.records, s));
            let records: Vec<String> = cal.records.iter().map(describe).collect();
            println!("{}", serde_json::json!({ "records": records, "verified": true, "recovery": recovery }));
        }
        Format::Text => {
            println!(
                "recorded {} IMU and {} polarization samples in the first session ({} IMU power-ups); wrote and read back {} records into {}:",
                cal.recording.imu.len(),
                cal.recording.polarization.len(),
                a.imu_power_ups,
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

fn cell(f: &calibrate::HeadFigures) -> String {
    if f.compass_fixes == 0 {
        return format!("no fix ({} solves)", f.compass_no_fix);
    }
    format!("{:.3} / {:.3} / {:.2} ({})", f.compass_median_abs_deg, f.compass_rmse_inliers_deg, f.compass_rmse_deg, f.compass_outliers)
}

fn compare(a: CompareArgs, format: Format) -> Result<ExitCode> {
    let dive = subnav_sil::Scenario { duration_s: a.duration_s, ..subnav_sil::Scenario::default() };
    let mut rows: Vec<Comparison> = Vec::new();
    if format == Format::Text {
        println!(
            "compass heading error, deg: median / RMSE without fixes over {} deg off / RMSE of all fixes (fixes over {} deg off)",
            calibrate::OUTLIER_DEG,
            calibrate::OUTLIER_DEG
        );
        println!("| build seed | uncalibrated | calibrated | ideal | nav heading RMSE uncal. / cal. / ideal | AoP err | mounting err |");
        println!("|---:|---:|---:|---:|---:|---:|---:|");
    }
    for seed in a.seeds.range() {
        let c = calibrate::compare(seed, &dive)?;
        match format {
            Format::Json => println!("{}", serde_json::to_string(&c)?),
            Format::Text => println!(
                "| {} | {} | {} | {} | {:.3} / {:.3} / {:.3} | {:.4} | {:.4} |",
                c.build_seed,
                cell(&c.uncalibrated),
                cell(&c.calibrated),
                cell(&c.ideal),
                c.uncalibrated.heading_rmse_deg,
                c.calibrated.heading_rmse_deg,
                c.ideal.heading_rmse_deg,
                c.recovery.max_aop_deg,
                c.recovery.mounting_deg
            ),
        }
        rows.push(c);
    }
    // Pooled over the heads that have fixes: root of the mean squared per-head figure.
    let pooled = |pick: fn(&Comparison) -> calibrate::HeadFigures, g: fn(&calibrate::HeadFigures) -> f64| {
        let v: Vec<f64> = rows.iter().map(|c| g(&pick(c))).filter(|x| x.is_finite()).collect();
        ((v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt(), rows.len() - v.len())
    };
    let picks: [(&str, fn(&Comparison) -> calibrate::HeadFigures); 3] =
        [("uncalibrated", |c| c.uncalibrated), ("calibrated", |c| c.calibrated), ("ideal", |c| c.ideal)];
    let summary: Vec<(&str, (f64, usize), (f64, usize))> =
        picks.iter().map(|(name, f)| (*name, pooled(*f, |h| h.compass_rmse_inliers_deg), pooled(*f, |h| h.compass_rmse_deg))).collect();
    let ratio = summary[1].1.0 / summary[2].1.0;
    match format {
        Format::Json => {
            let s: Vec<_> = summary
                .iter()
                .map(|(n, inl, all)| serde_json::json!({ "head": n, "compass_rmse_inliers_deg": inl.0, "compass_rmse_deg": all.0, "heads_without_fix": inl.1 }))
                .collect();
            println!("{}", serde_json::json!({ "heads": rows.len(), "pooled": s, "calibrated_over_ideal_inliers": ratio }))
        }
        Format::Text => {
            println!();
            println!("pooled over {} heads (root mean square of the per-head RMSE):", rows.len());
            for (n, inl, all) in &summary {
                println!("  {n:<13} RMSE without outliers {:.3} deg, all fixes {:.3} deg, heads without a fix {}", inl.0, all.0, inl.1);
            }
            println!("  calibrated / ideal (without outliers) = {:.3} (goal <= 1.10)", ratio);
        }
    }
    Ok(ExitCode::SUCCESS)
}
