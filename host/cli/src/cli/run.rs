//! `subnav run`: run a dive scenario (from `subnav sim`) with the firmware in the loop, under
//! QEMU (`--elf`, the reference: the board binary with its buses bridged to the simulated chips)
//! or natively (`--native`: the same application core compiled for the host, ~20x faster);
//! record the telemetry and the truth, and print heading and position error statistics.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};

use super::Format;
use subnav_sil::Scenario;
use subnav_sil::dive::{DiveOptions, DiveResult, evaluate, run_dive, truth_csv};
use subnav_sil::sil::run_native;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Scenario JSON (`subnav sim --out`).
    pub scenario: PathBuf,
    /// The QEMU board firmware ELF (`cargo xtask build` puts it in target/firmware/subnav-qemu.elf).
    #[arg(long, required_unless_present = "native", conflicts_with = "native")]
    pub elf: Option<PathBuf>,
    /// Run the firmware's application core natively instead of under QEMU.
    #[arg(long)]
    pub native: bool,
    /// Write the telemetry recording here (`subnav export` / `report` read it).
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Write the truth here (CSV `t_s,n_m,e_m,d_m,yaw_rad` at 10 Hz, for `subnav report --truth`).
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Wall-clock limit for a QEMU run, s.
    #[arg(long, default_value_t = 1800)]
    pub timeout_s: u64,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Run the scenario once per seed (`N`, `A..B`, `A..=B`; native only) and print one line
    /// per seed and the mean of each figure.
    #[arg(long, value_parser = super::args::parse_seeds, requires = "native", conflicts_with_all = ["record", "truth"])]
    pub seeds: Option<super::args::Seeds>,
}

fn load(path: &PathBuf) -> Result<Scenario> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading the scenario {}", path.display()))?;
    let sc: Scenario = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a scenario (write one with `subnav sim --out {}`)", path.display(), path.display()))?;
    sc.validate().with_context(|| format!("the scenario {}", path.display()))?;
    Ok(sc)
}

/// `--seeds`: one native run per seed, a line each, then the means.
fn run_seeds(sc: &Scenario, seeds: &super::args::Seeds, format: Format) -> Result<ExitCode> {
    let mut rows = Vec::new();
    if format == Format::Text {
        println!("seed  horiz RMS m  final m  max m  final % dist  within 3 sigma %  heading RMSE deg");
    }
    let mut ok = true;
    for seed in seeds.range() {
        let sc = Scenario { seed, ..sc.clone() };
        let run = run_native(&sc, None);
        let r = evaluate(&sc, &run.messages, Some(0), run.corrupt_frames, run.bus_transactions);
        ok &= r.nonfinite_values == 0;
        if format == Format::Text {
            println!(
                "{seed:>4}  {:>11.2}  {:>7.2}  {:>5.2}  {:>12.3}  {:>16.1}  {:>16.3}",
                r.horizontal_rms_err_m,
                r.horizontal_final_err_m,
                r.horizontal_max_err_m,
                r.final_err_pct_of_distance,
                100.0 * r.within_3_sigma,
                r.heading_rmse_deg
            );
        }
        rows.push((seed, r));
    }
    let n = rows.len().max(1) as f64;
    let mean = |f: &dyn Fn(&DiveResult) -> f64| rows.iter().map(|(_, r)| f(r)).sum::<f64>() / n;
    let means = serde_json::json!({
        "horizontal_rms_err_m": mean(&|r| r.horizontal_rms_err_m),
        "horizontal_final_err_m": mean(&|r| r.horizontal_final_err_m),
        "horizontal_max_err_m": mean(&|r| r.horizontal_max_err_m),
        "final_err_pct_of_distance": mean(&|r| r.final_err_pct_of_distance),
        "within_3_sigma": mean(&|r| r.within_3_sigma),
        "heading_rmse_deg": mean(&|r| r.heading_rmse_deg),
    });
    match format {
        Format::Json => {
            let runs: Vec<_> = rows.iter().map(|(s, r)| serde_json::json!({"seed": s, "result": r})).collect();
            println!("{}", serde_json::json!({"runs": runs, "mean": means}));
        }
        Format::Text => println!(
            "mean  {:>11.2}  {:>7.2}  {:>5.2}  {:>12.3}  {:>16.1}  {:>16.3}",
            means["horizontal_rms_err_m"].as_f64().unwrap_or(f64::NAN),
            means["horizontal_final_err_m"].as_f64().unwrap_or(f64::NAN),
            means["horizontal_max_err_m"].as_f64().unwrap_or(f64::NAN),
            means["final_err_pct_of_distance"].as_f64().unwrap_or(f64::NAN),
            100.0 * means["within_3_sigma"].as_f64().unwrap_or(f64::NAN),
            means["heading_rmse_deg"].as_f64().unwrap_or(f64::NAN),
        ),
    }
    if !ok {
        eprintln!("error: a run produced non-finite estimates");
    }
    Ok(if ok { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    let inputs: Vec<&std::path::Path> = std::iter::once(args.scenario.as_path()).chain(args.elf.as_deref()).collect();
    for (flag, out) in [("--record", &args.record), ("--truth", &args.truth)] {
        if let Some(p) = out {
            subnav_link::output::refuse_input_as_output(flag, p, &inputs)?;
        }
    }
    let sc = load(&args.scenario)?;
    if let Some(seeds) = &args.seeds {
        return run_seeds(&sc, seeds, format);
    }
    let pb = if args.quiet || format == Format::Json { ProgressBar::hidden() } else { ProgressBar::new(sc.duration_s.ceil() as u64) };
    if let Ok(style) = ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} s ({eta})") {
        pb.set_style(style.progress_chars("=> "));
    }
    pb.set_message(if args.native { "native dive" } else { "QEMU dive" });
    let progress = |t: f64| pb.set_position(t as u64);
    let result: DiveResult = if args.native {
        let run = run_native(&sc, Some(&progress));
        if let Some(p) = &args.record {
            run.write_recording(p, &sc).with_context(|| format!("writing the recording {}", p.display()))?;
        }
        evaluate(&sc, &run.messages, Some(0), run.corrupt_frames, run.bus_transactions)
    } else {
        let elf = args.elf.as_ref().context("--elf is required without --native")?;
        if !elf.exists() {
            bail!("{} does not exist: build it with `cargo xtask build` (or use --native)", elf.display());
        }
        let opts =
            DiveOptions { record: args.record.as_deref(), timeout: Some(Duration::from_secs(args.timeout_s)), progress: Some(&progress) };
        run_dive(elf, &sc, &opts)?
    };
    pb.finish_and_clear();
    if let Some(p) = &args.truth {
        std::fs::write(p, truth_csv(&sc, 0.1)).with_context(|| format!("writing the truth {}", p.display()))?;
    }
    match format {
        Format::Json => println!("{}", serde_json::to_string(&result)?),
        Format::Text => print_summary(&result),
    }
    let ok = result.exit_code == Some(0) && result.nonfinite_values == 0;
    if !ok {
        eprintln!(
            "error: the firmware failed (exit {:?}) or produced non-finite estimates ({})",
            result.exit_code, result.nonfinite_values
        );
    }
    Ok(if ok { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

fn print_summary(r: &DiveResult) {
    println!("navigation messages   {} ({} aided, first at {:?} s)", r.nav_messages, r.aided_messages, r.first_aided_s);
    println!(
        "heading               RMSE {:.3} deg, max {:.3} deg, {:.1} % within 3 sigma (converged from {:?} s; all aided: RMSE {:.2} deg)",
        r.heading_rmse_deg,
        r.heading_max_abs_err_deg,
        100.0 * r.heading_within_3_sigma,
        r.heading_converged_s,
        r.heading_rmse_all_aided_deg
    );
    println!(
        "horizontal position   RMS {:.2} m, final {:.2} m ({:.3} % of {:.0} m travelled), max {:.2} m, {:.1} % within 3 sigma",
        r.horizontal_rms_err_m,
        r.horizontal_final_err_m,
        r.final_err_pct_of_distance,
        r.distance_m,
        r.horizontal_max_err_m,
        100.0 * r.within_3_sigma
    );
    println!("depth                 RMSE {:.3} m (raw sensor {:.4} m)", r.depth_rmse_m, r.raw_depth_rmse_m);
    println!("compass alone         {} fixes, {} without, RMSE {:.2} deg", r.compass_fixes, r.compass_no_fix, r.compass_rmse_deg);
    println!("bus transactions      {}  corrupt frames {}  non-finite values {}", r.bus_transactions, r.corrupt_frames, r.nonfinite_values);
    for (source, kind, count) in &r.faults {
        println!("fault                 {source} {kind} x{count}");
    }
}
