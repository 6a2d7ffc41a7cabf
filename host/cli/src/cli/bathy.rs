//! `subnav bathy`: bathymetric graph SLAM (spec 003) on CSV soundings + navigation, or on
//! seeded simulated surveys with evaluation against the truth.
//!
//! ```text
//! subnav bathy run --soundings soundings.csv --nav nav.csv --out DIR
//! subnav bathy simulate --seeds 0..20 --out DIR [--format json]
//! ```
//! CSV formats: see `bathy::io`. Outputs in DIR: `trajectory_corrected.csv`,
//! `bathymetry_dead_reckoning.asc`, `bathymetry_corrected.asc` (ESRI ASCII grids, depth m),
//! `map_before_after.png`, `closures.json`; for simulations also `error_histograms.png`,
//! `nav_error.png`, `evaluation.json` (per seed and pooled).

use super::Format;
use super::args::{self, Seeds};
use anyhow::{Context, Result, bail};
use plotters::style::RGBColor;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;
use subnav_bathy::pipeline::{self, ErrorStats, Evaluation, PipelineConfig, PipelineOutput};
use subnav_bathy::sim::{self, SimConfig};
use subnav_bathy::{Survey, V2, io, plot};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: Sub,
}

#[derive(Debug, clap::Subcommand)]
pub enum Sub {
    /// Graph SLAM on CSV soundings and navigation; writes the corrected trajectory and grids.
    Run(RunArgs),
    /// Seeded simulated surveys: graph SLAM evaluated against the truth (pooled statistics).
    Simulate(SimulateArgs),
}

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Soundings CSV (t_s,beam_angle_rad,range_m).
    #[arg(long)]
    pub soundings: PathBuf,
    /// Navigation CSV (t_s,north_m,east_m,depth_m,heading_rad[,vel_sigma_mps]).
    #[arg(long)]
    pub nav: PathBuf,
    /// Output directory (created).
    #[arg(long)]
    pub out: PathBuf,
    /// Survey altitude for submap/matching scales, m (0..=12000; default: estimated from
    /// near-nadir beams).
    #[arg(long, allow_hyphen_values = true, value_parser = args::f64_positive_upto(12_000.0))]
    pub altitude_m: Option<f64>,
    /// Skip PNG figures.
    #[arg(long)]
    pub no_plots: bool,
}

#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    /// Seeds of the simulated surveys: `N`, `A..B` (B exclusive) or `A..=B`.
    #[arg(long, default_value = "0", value_parser = args::parse_seeds)]
    pub seeds: Seeds,
    /// Use the small (few-minute) survey instead of the one-hour survey.
    #[arg(long)]
    pub small: bool,
    /// Output directory (created).
    #[arg(long)]
    pub out: PathBuf,
    /// Skip PNG figures.
    #[arg(long)]
    pub no_plots: bool,
    /// Also write the first seed's survey as CSV (soundings.csv, nav.csv, truth_nav.csv) to show
    /// the input format of `bathy run`.
    #[arg(long)]
    pub export_csv: bool,
}

/// Median of `range * cos(angle)` over beams within 15 deg of nadir.
fn estimate_altitude(s: &Survey) -> Option<f64> {
    let mut v: Vec<f64> = s
        .pings
        .iter()
        .flat_map(|p| p.beams.iter())
        .filter(|b| b.angle_rad.abs() < 15f64.to_radians())
        .map(|b| b.range_m * b.angle_rad.cos())
        .collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

fn write_outputs(
    dir: &Path,
    survey: &Survey,
    out: &PipelineOutput,
    cfg: &PipelineConfig,
    plots: bool,
    truth: Option<&[subnav_bathy::NavSample]>,
) -> Result<()> {
    let corr = pipeline::corrected_nav(&survey.nav, &out.offsets_spring);
    io::write_nav(&dir.join("trajectory_corrected.csv"), &corr)?;
    let g0 = pipeline::bathymetry(survey, None, cfg.grid_cell_m).context("no soundings to grid")?;
    let g1 = pipeline::bathymetry(survey, Some(&out.offsets_spring), cfg.grid_cell_m).context("no soundings to grid")?;
    g0.write_esri_ascii(&dir.join("bathymetry_dead_reckoning.asc"))?;
    g1.write_esri_ascii(&dir.join("bathymetry_corrected.asc"))?;
    subnav_link::output::write_atomic(dir.join("closures.json"), serde_json::to_string_pretty(&out.attempts)?)?;
    if plots {
        let red = RGBColor(220, 30, 30);
        let white = RGBColor(255, 255, 255);
        let mut left = vec![("dead reckoning", red, survey.nav.as_slice())];
        let mut right = vec![("corrected (spring)", RGBColor(255, 140, 0), corr.as_slice())];
        if let Some(t) = truth {
            left.push(("truth", white, t));
            right.push(("truth", white, t));
        }
        let p = dir.join("map_before_after.png");
        plot::maps(&p, &[("before: dead reckoning", &g0, left), ("after: graph SLAM + spring", &g1, right)])
            .with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}

#[derive(serde::Serialize)]
struct Pooled {
    seeds: Vec<u64>,
    dead_reckoning: ErrorStats,
    uniform: ErrorStats,
    spring: ErrorStats,
    spring_dr_only: ErrorStats,
    mean_reduction_uniform_pct: f64,
    median_reduction_uniform_pct: f64,
    mean_reduction_spring_pct: f64,
    median_reduction_spring_pct: f64,
    spring_vs_uniform_mean_pct: f64,
    spring_vs_uniform_median_pct: f64,
    seeds_spring_beats_uniform_mean: usize,
    min_seed_mean_reduction_spring_pct: f64,
    crossline_mean_abs_dr_m: f64,
    crossline_mean_abs_uniform_m: f64,
    crossline_mean_abs_spring_m: f64,
    crossline_rms_dr_m: f64,
    crossline_rms_spring_m: f64,
    closures_kept: usize,
    closures_kept_false: usize,
    closures_matched_false: usize,
    closures_rejected_relief_or_info: usize,
    closures_rejected_ambiguous: usize,
    closure_error_mean_m: f64,
    survey_duration_mean_s: f64,
    processing_mean_s: f64,
    speedup_vs_real_time: f64,
}

fn pct(a: f64, b: f64) -> f64 {
    if a > 0.0 { 100.0 * (a - b) / a } else { 0.0 }
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    match args.command {
        Sub::Run(a) => run_csv(a, format),
        Sub::Simulate(a) => simulate(a, format),
    }
}

fn run_csv(args: RunArgs, format: Format) -> Result<ExitCode> {
    subnav_link::output::refuse_dir_holding_input("--out", &args.out, &[&args.soundings, &args.nav])?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let survey = io::read_survey(&args.soundings, &args.nav)?;
    let alt = match args.altitude_m {
        Some(a) => a,
        None => estimate_altitude(&survey).context("cannot estimate the altitude (no near-nadir beams); pass --altitude-m")?,
    };
    if !(alt.is_finite() && alt > 0.0) {
        bail!("altitude must be positive, got {alt}");
    }
    let cfg = PipelineConfig::for_altitude(alt);
    let out = pipeline::run(&survey, &cfg)?;
    write_outputs(&args.out, &survey, &out, &cfg, !args.no_plots, None)?;
    let kept = out.attempts.iter().filter(|a| a.kept).count();
    let max_off = out.offsets_spring.iter().map(|o| o.norm()).fold(0.0, f64::max);
    match format {
        Format::Json => println!(
            "{}",
            serde_json::json!({"pings": survey.pings.len(), "submaps": out.submaps.len(), "closures_attempted": out.attempts.len(),
                "closures_kept": kept, "max_correction_m": max_off, "timing": out.timing, "out": args.out})
        ),
        Format::Text => println!(
            "{} pings, {} submaps, {} closures attempted, {} kept; largest correction {:.2} m; {:.2} s; outputs in {}",
            survey.pings.len(),
            out.submaps.len(),
            out.attempts.len(),
            kept,
            max_off,
            out.timing.total_s,
            args.out.display()
        ),
    }
    Ok(ExitCode::SUCCESS)
}

fn simulate(args: SimulateArgs, format: Format) -> Result<ExitCode> {
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let seeds = args.seeds.range();
    let mut evals: Vec<(u64, Evaluation)> = vec![];
    let mut pooled: [Vec<f32>; 4] = Default::default();
    for seed in seeds.clone() {
        let scfg = if args.small { SimConfig::small(3, 320.0, 140.0) } else { SimConfig::one_hour(seed) };
        let t0 = Instant::now();
        let sim = sim::simulate(&scfg, seed);
        let sim_s = t0.elapsed().as_secs_f64();
        let cfg = PipelineConfig::for_altitude(scfg.altitude_m);
        let out = pipeline::run(&sim.survey, &cfg)?;
        let ev = pipeline::evaluate(&sim, &out, &cfg);
        let sets: [Option<&[V2]>; 4] = [None, Some(&out.offsets_uniform), Some(&out.offsets_spring), Some(&out.offsets_spring_dr_only)];
        for (p, o) in pooled.iter_mut().zip(sets) {
            p.extend(pipeline::sounding_errors(&sim, o).into_iter().map(|x| x as f32));
        }
        if format == Format::Text {
            eprintln!(
                "seed {seed}: {} pings, sim {sim_s:.1} s, slam {:.2} s; sounding error mean DR {:.2} / uniform {:.2} / spring {:.2} m; closures kept {} (false {})",
                ev.pings,
                ev.timing.total_s,
                ev.dead_reckoning.sounding_error.mean_m,
                ev.uniform.sounding_error.mean_m,
                ev.spring.sounding_error.mean_m,
                ev.closures.kept,
                ev.closures.kept_false
            );
        }
        if seed == seeds.start {
            let dir = &args.out;
            write_outputs(dir, &sim.survey, &out, &cfg, !args.no_plots, Some(&sim.truth_nav))?;
            io::write_nav(&dir.join("truth_nav.csv"), &sim.truth_nav)?;
            if args.export_csv {
                io::write_nav(&dir.join("nav.csv"), &sim.survey.nav)?;
                io::write_soundings(&dir.join("soundings.csv"), &sim.survey.pings)?;
            }
            if !args.no_plots {
                let e: Vec<Vec<f64>> = sets.iter().take(3).map(|o| pipeline::sounding_errors(&sim, *o)).collect();
                let p = dir.join("error_histograms.png");
                plot::error_histograms(&p, &[("dead reckoning", &e[0]), ("uniform", &e[1]), ("spring", &e[2])])
                    .with_context(|| format!("writing {}", p.display()))?;
                let t: Vec<f64> = sim.survey.nav.iter().map(|n| n.t_s).collect();
                let err_of = |o: Option<&[V2]>| -> Vec<f64> {
                    sim.survey
                        .nav
                        .iter()
                        .zip(&sim.truth_nav)
                        .enumerate()
                        .map(|(i, (n, tr))| {
                            let d = o.map_or(V2::zeros(), |o| o[i]);
                            ((n.north_m - d.x - tr.north_m).powi(2) + (n.east_m - d.y - tr.east_m).powi(2)).sqrt()
                        })
                        .collect()
                };
                let keys_t: Vec<f64> = out.keys.iter().map(|k| t[*k]).collect();
                plot::nav_error_over_time(
                    &dir.join("nav_error.png"),
                    &t,
                    &[
                        ("dead reckoning", RGBColor(220, 30, 30), err_of(None)),
                        ("uniform", RGBColor(30, 30, 220), err_of(Some(&out.offsets_uniform))),
                        ("spring", RGBColor(0, 150, 0), err_of(Some(&out.offsets_spring))),
                    ],
                    &keys_t,
                )
                .with_context(|| format!("writing {}", dir.join("nav_error.png").display()))?;
            }
        }
        evals.push((seed, ev));
    }
    let stats: Vec<ErrorStats> = pooled.iter().map(|v| ErrorStats::of(v.iter().map(|x| *x as f64).collect())).collect();
    let n = evals.len() as f64;
    let avg = |f: &dyn Fn(&Evaluation) -> f64| evals.iter().map(|(_, e)| f(e)).sum::<f64>() / n;
    let kept_err: Vec<f64> = evals.iter().map(|(_, e)| e.closures.kept_error.mean_m * e.closures.kept as f64).collect();
    let kept: usize = evals.iter().map(|(_, e)| e.closures.kept).sum();
    let p = Pooled {
        seeds: seeds.clone().collect(),
        mean_reduction_uniform_pct: pct(stats[0].mean_m, stats[1].mean_m),
        median_reduction_uniform_pct: pct(stats[0].median_m, stats[1].median_m),
        mean_reduction_spring_pct: pct(stats[0].mean_m, stats[2].mean_m),
        median_reduction_spring_pct: pct(stats[0].median_m, stats[2].median_m),
        spring_vs_uniform_mean_pct: pct(stats[1].mean_m, stats[2].mean_m),
        spring_vs_uniform_median_pct: pct(stats[1].median_m, stats[2].median_m),
        seeds_spring_beats_uniform_mean: evals
            .iter()
            .filter(|(_, e)| e.spring.sounding_error.mean_m < e.uniform.sounding_error.mean_m)
            .count(),
        min_seed_mean_reduction_spring_pct: evals
            .iter()
            .map(|(_, e)| pct(e.dead_reckoning.sounding_error.mean_m, e.spring.sounding_error.mean_m))
            .fold(f64::INFINITY, f64::min),
        crossline_mean_abs_dr_m: avg(&|e| e.dead_reckoning.crossline.mean_abs_m),
        crossline_mean_abs_uniform_m: avg(&|e| e.uniform.crossline.mean_abs_m),
        crossline_mean_abs_spring_m: avg(&|e| e.spring.crossline.mean_abs_m),
        crossline_rms_dr_m: avg(&|e| e.dead_reckoning.crossline.rms_m),
        crossline_rms_spring_m: avg(&|e| e.spring.crossline.rms_m),
        closures_kept: kept,
        closures_kept_false: evals.iter().map(|(_, e)| e.closures.kept_false).sum(),
        closures_matched_false: evals.iter().map(|(_, e)| e.closures.matched_false).sum(),
        closures_rejected_relief_or_info: evals.iter().map(|(_, e)| e.closures.rejected_no_relief_or_info).sum(),
        closures_rejected_ambiguous: evals.iter().map(|(_, e)| e.closures.rejected_ambiguous).sum(),
        closure_error_mean_m: if kept > 0 { kept_err.iter().sum::<f64>() / kept as f64 } else { f64::NAN },
        survey_duration_mean_s: avg(&|e| e.duration_s),
        processing_mean_s: avg(&|e| e.timing.total_s),
        speedup_vs_real_time: avg(&|e| e.duration_s) / avg(&|e| e.timing.total_s).max(1e-9),
        dead_reckoning: stats[0].clone(),
        uniform: stats[1].clone(),
        spring: stats[2].clone(),
        spring_dr_only: stats[3].clone(),
    };
    let per_seed: Vec<serde_json::Value> = evals.iter().map(|(s, e)| serde_json::json!({"seed": s, "evaluation": e})).collect();
    let doc = serde_json::json!({"pooled": p, "per_seed": per_seed});
    subnav_link::output::write_atomic(args.out.join("evaluation.json"), serde_json::to_string_pretty(&doc)?)?;
    match format {
        Format::Json => println!("{}", serde_json::to_string(&serde_json::json!({"pooled": p}))?),
        Format::Text => {
            println!("{} surveys (seeds {:?}), pooled over {} soundings", evals.len(), seeds, p.dead_reckoning.count);
            println!("{:<16} {:>10} {:>10} {:>10}", "method", "mean (m)", "median (m)", "p95 (m)");
            for (name, s) in [
                ("dead reckoning", &p.dead_reckoning),
                ("uniform", &p.uniform),
                ("spring", &p.spring),
                ("spring (DR only)", &p.spring_dr_only),
            ] {
                println!("{name:<16} {:>10.3} {:>10.3} {:>10.3}", s.mean_m, s.median_m, s.p95_m);
            }
            println!(
                "reduction vs DR: uniform {:.2} % mean / {:.2} % median; spring {:.2} % / {:.2} %; spring vs uniform {:.2} % / {:.2} %",
                p.mean_reduction_uniform_pct,
                p.median_reduction_uniform_pct,
                p.mean_reduction_spring_pct,
                p.median_reduction_spring_pct,
                p.spring_vs_uniform_mean_pct,
                p.spring_vs_uniform_median_pct
            );
            println!(
                "crossline |dz| mean: DR {:.3} m, uniform {:.3} m, spring {:.3} m; closures kept {} ({} > 5 m off), closure error mean {:.2} m",
                p.crossline_mean_abs_dr_m,
                p.crossline_mean_abs_uniform_m,
                p.crossline_mean_abs_spring_m,
                p.closures_kept,
                p.closures_kept_false,
                p.closure_error_mean_m
            );
            println!(
                "survey {:.0} s, processing {:.2} s: {:.0}x real time",
                p.survey_duration_mean_s, p.processing_mean_s, p.speedup_vs_real_time
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}
