//! `subnav ice`: the under-ice odometry (`subnav_ice`). Either seeded simulated runs with
//! evaluation (`ice simulate --seeds 1..=10 [--ablations]`), or a recorded/written data
//! directory (`ice run --input DIR --out DIR`, format in `subnav_ice::data`).

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::UnitQuaternion;
use serde_json::json;

use super::Format;
use super::args::{self, Seeds};
use subnav_ice::data::Dataset;
use subnav_ice::eval::evaluate;
use subnav_ice::frontend::TrackerConfig;
use subnav_ice::montecarlo::{RPE_LENGTHS_M, RunResult, Variant, mean_max, run_seed};
use subnav_ice::odometry::{self, OdometryConfig};
use subnav_ice::sim::{SimConfig, simulate, write_stereo_images};
use subnav_ice::sonar;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: Sub,
}

#[derive(Debug, clap::Subcommand)]
pub enum Sub {
    /// Run the odometry on a data directory (imu.csv, tracks.csv or stereo images, depth.csv, ...).
    Run(RunArgs),
    /// Seeded simulated under-ice runs evaluated against the truth (drift, ATE, RPE, NEES).
    Simulate(SimulateArgs),
}

/// Switches of the odometry and its front end (both modes).
#[derive(Debug, clap::Args)]
pub struct Tuning {
    /// Odometry: do not use the imaging-sonar velocity.
    #[arg(long)]
    pub no_sonar: bool,
    /// Odometry: do not use the depth sensor.
    #[arg(long)]
    pub no_depth: bool,
    /// Odometry: no adaptive measurement noise.
    #[arg(long)]
    pub no_adaptive: bool,
    /// Front end: skip the dark-channel dehazing.
    #[arg(long)]
    pub no_dehaze: bool,
    /// Front end: do not undo the flat-port refraction (treat the image as a pinhole in water).
    #[arg(long)]
    pub no_refraction: bool,
}

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Data directory to run on (imu.csv, tracks.csv, depth.csv, ...; see `ice::data`).
    #[arg(long)]
    pub input: PathBuf,
    /// Output directory: trajectory.csv and metrics.json.
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub tuning: Tuning,
}

#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    /// Seeds of the runs: `N`, `A..B` (B exclusive) or `A..=B`.
    #[arg(long, default_value = "1", value_parser = args::parse_seeds)]
    pub seeds: Seeds,
    /// Output directory for results.json.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Path length of each simulated run, m (at most 10 km).
    #[arg(long, allow_hyphen_values = true, default_value_t = 500.0, value_parser = super::args::f64_positive_upto(10_000.0))]
    pub distance_m: f64,
    /// Also run the ablations (no sonar, no depth, no adaptivity, no FEJ, IMU-based augmentation
    /// only, IMU only).
    #[arg(long)]
    pub ablations: bool,
    /// Write the first seed's simulated data set to this directory (then usable with `ice run --input`).
    #[arg(long)]
    pub write: Option<PathBuf>,
    /// Stereo observations from rendered images through the FAST + KLT front end (slower: about
    /// 0.1 s per frame) instead of synthetic feature tracks. With --write, the images are written
    /// (stereo/*.png + stereo.csv) instead of tracks.csv.
    #[arg(long)]
    pub images: bool,
    /// The camera sees nothing (turbid water) for this many seconds, starting at
    /// --outage-start-s (so the sonar and depth carry the odometry).
    /// (0..=86400).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = args::f64_in(0.0..=args::MAX_SIM_DURATION_S))]
    pub outage_s: f64,
    /// Start of the vision outage, s (0..=86400).
    #[arg(long, default_value_t = 100.0, allow_hyphen_values = true, value_parser = args::f64_in(0.0..=args::MAX_SIM_DURATION_S))]
    pub outage_start_s: f64,
    #[command(flatten)]
    pub tuning: Tuning,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

impl Tuning {
    fn configs(&self) -> (OdometryConfig, TrackerConfig) {
        let mut base = OdometryConfig::default();
        base.use_sonar &= !self.no_sonar;
        base.use_depth &= !self.no_depth;
        base.adaptive &= !self.no_adaptive;
        let mut tracker = TrackerConfig::default();
        if self.no_dehaze {
            tracker.dehaze = None;
        }
        tracker.refraction &= !self.no_refraction;
        (base, tracker)
    }
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    match args.command {
        Sub::Run(a) => run_dir(a, format),
        Sub::Simulate(a) => simulate_runs(a, format),
    }
}

fn run_dir(args: RunArgs, format: Format) -> Result<ExitCode> {
    if let Some(out) = &args.out {
        subnav_link::output::refuse_dir_holding_input("--out", out, &[&args.input])?;
    }
    let (base, tracker) = args.tuning.configs();
    let dir = &args.input;
    let mut data = Dataset::read_dir(dir)?;
    data.track_images(tracker)?;
    let (est, stats) = odometry::run(&data, &base, &data.cam)?;
    if est.is_empty() {
        // "0 poses ... ATE 0.000 m" was printed as a success.
        bail!(
            "{}: no poses estimated ({} frames, {} features used, {} IMU samples): nothing to report",
            dir.display(),
            data.frames.len(),
            stats.features_used,
            data.imu.len()
        );
    }
    let metrics = (!data.truth.is_empty()).then(|| evaluate(&est, &data.truth, &RPE_LENGTHS_M));
    if let Some(out) = &args.out {
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        let mut s = String::from("t_s,qw,qx,qy,qz,x,y,z,sigma_x,sigma_y,sigma_z\n");
        for e in &est {
            let q = UnitQuaternion::from_matrix(&e.rot);
            let p = e.pos_w_m;
            let sd = |i: usize| e.cov[(3 + i, 3 + i)].max(0.0).sqrt();
            let _ = writeln!(s, "{:.6},{},{},{},{},{},{},{},{},{},{}", e.t_s, q.w, q.i, q.j, q.k, p.x, p.y, p.z, sd(0), sd(1), sd(2));
        }
        subnav_link::output::write_atomic(out.join("trajectory.csv"), s)?;
        subnav_link::output::write_atomic(
            out.join("metrics.json"),
            serde_json::to_string_pretty(&json!({"stats": stats, "frontend": data.frontend, "metrics": metrics}))?,
        )?;
    }
    match format {
        Format::Json => println!("{}", json!({"poses": est.len(), "stats": stats, "frontend": data.frontend, "metrics": metrics})),
        Format::Text => {
            println!(
                "{} poses; {} features used, {} gated; depth {} used; sonar {} used",
                est.len(),
                stats.features_used,
                stats.features_gated,
                stats.depth_used,
                stats.sonar_used
            );
            if let Some(f) = &data.frontend {
                println!(
                    "front end: {} frames, {:.1} observations per frame, {} features started, {} lost",
                    f.frames,
                    f.observations as f64 / f.frames.max(1) as f64,
                    f.started,
                    f.lost
                );
            }
            if let Some(m) = metrics {
                println!(
                    "drift {:.3} % of {:.1} m, ATE {:.3} m / {:.3} deg, NEES ori {:.2} pos {:.2}",
                    m.drift_pct, m.distance_m, m.ate_pos_m, m.ate_ori_deg, m.nees_ori, m.nees_pos
                );
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn simulate_runs(args: SimulateArgs, format: Format) -> Result<ExitCode> {
    let (base, tracker) = args.tuning.configs();
    let outage = (args.outage_s > 0.0).then_some((args.outage_start_s, args.outage_s));
    let sim_at = |seed: u64| SimConfig {
        seed,
        distance_m: args.distance_m,
        images: args.images,
        tracker,
        vision_outage: outage,
        ..SimConfig::default()
    };
    if args.distance_m.is_nan() || args.distance_m <= 0.0 {
        bail!("--distance-m must be > 0");
    }
    if !(args.outage_s >= 0.0 && args.outage_start_s.is_finite()) {
        bail!("--outage-s must be >= 0 and --outage-start-s finite");
    }
    let variants: Vec<Variant> = if args.ablations { Variant::ALL.to_vec() } else { vec![Variant::Full] };
    if let Some(dir) = &args.write {
        let sim = sim_at(args.seeds.first);
        let mut data = simulate(&SimConfig { images: false, ..sim });
        data.sonar_velocity = sonar::velocities(&data.sonar_frames, &base.sonar);
        if args.images {
            // The images stand in for the tracks: --input runs the front end on them.
            data.frames.clear();
            let _ = std::fs::remove_file(dir.join("tracks.csv"));
            write_stereo_images(&sim, &data.truth, dir)?;
        }
        data.write_dir(dir)?;
    }
    let pb = if args.quiet { ProgressBar::hidden() } else { ProgressBar::new(args.seeds.count) };
    if let Ok(style) = ProgressStyle::with_template("ice runs [{bar:40}] {pos}/{len} ({eta})") {
        pb.set_style(style.progress_chars("=> "));
    }
    let mut all: Vec<RunResult> = Vec::new();
    for seed in args.seeds.range() {
        all.extend(run_seed(&sim_at(seed), &base, &variants)?);
        pb.inc(1);
    }
    pb.finish_and_clear();
    let mut summary = Vec::new();
    for v in &variants {
        let rs: Vec<&RunResult> = all.iter().filter(|r| r.variant == *v).collect();
        let f = |g: &dyn Fn(&RunResult) -> f64| mean_max(rs.iter().map(|r| g(r)));
        let rpe = |k: usize| f(&|r: &RunResult| r.metrics.rpe_m.get(k).map_or(f64::NAN, |x| x.1));
        summary.push(json!({
            "variant": v.name(),
            "runs": rs.len(),
            "distance_m_mean": f(&|r| r.metrics.distance_m).0,
            "drift_pct": f(&|r| r.metrics.drift_pct),
            "ate_pos_m": f(&|r| r.metrics.ate_pos_m),
            "ate_ori_deg": f(&|r| r.metrics.ate_ori_deg),
            "rpe_50m_m": rpe(0),
            "rpe_100m_m": rpe(1),
            "nees_ori": f(&|r| r.metrics.nees_ori),
            "nees_pos": f(&|r| r.metrics.nees_pos),
            "observations_per_frame": f(&|r| r.frontend.map_or(f64::NAN, |s| s.observations as f64 / s.frames.max(1) as f64)),
        }));
    }
    if let Some(out) = &args.out {
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        subnav_link::output::write_atomic(
            out.join("results.json"),
            serde_json::to_string_pretty(&json!({"summary": summary, "runs": all}))?,
        )?;
    }
    match format {
        Format::Json => println!("{}", json!({ "summary": summary })),
        Format::Text => {
            let source = if args.images { "rendered stereo images, FAST + KLT front end" } else { "synthetic feature tracks" };
            let outage = outage.map_or(String::new(), |(a, d)| format!(", vision outage {d:.0} s from {a:.0} s"));
            println!(
                "{} seeded runs of {:.0} m, {source}{outage} (mean [max] over runs; n/a: no data, e.g. RPE over more than the track)",
                args.seeds.count, args.distance_m
            );
            println!(
                "{:<17} {:>16} {:>16} {:>14} {:>16} {:>16} {:>14} {:>14}",
                "variant", "drift %", "ATE m", "ATE deg", "RPE50 m", "RPE100 m", "NEES ori", "NEES pos"
            );
            for s in &summary {
                // A figure with nothing behind it (RPE over a length longer than the track) is
                // said to be so, not printed as NaN.
                let c = |k: &str| {
                    let a = &s[k];
                    match (a[0].as_f64().filter(|v| v.is_finite()), a[1].as_f64().filter(|v| v.is_finite())) {
                        (Some(mean), Some(max)) => format!("{mean:.3} [{max:.3}]"),
                        _ => "n/a".to_string(),
                    }
                };
                println!(
                    "{:<17} {:>16} {:>16} {:>14} {:>16} {:>16} {:>14} {:>14}",
                    s["variant"].as_str().unwrap_or(""),
                    c("drift_pct"),
                    c("ate_pos_m"),
                    c("ate_ori_deg"),
                    c("rpe_50m_m"),
                    c("rpe_100m_m"),
                    c("nees_ori"),
                    c("nees_pos")
                );
            }
            if args.images
                && let Some(s) = summary.first()
            {
                let a = &s["observations_per_frame"];
                println!(
                    "front end: {:.1} [{:.1}] stereo observations per frame",
                    a[0].as_f64().unwrap_or(f64::NAN),
                    a[1].as_f64().unwrap_or(f64::NAN)
                );
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}
