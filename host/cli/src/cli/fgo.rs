//! `subnav fgo`: factor-graph INS/DVL/USBL navigation (`subnav_fgo`, spec 002).
//!
//! - `subnav fgo replay --input LOG --out OUT [--no-gating] [--realtime]`: process a JSON-lines sensor
//!   log (format in `subnav_fgo::log`); writes the batch-optimised nodes (or the real-time
//!   smoother's outputs with `--realtime`) as CSV, or JSON lines when OUT ends in `.json`/`.jsonl`.
//!   Columns: ENU position/velocity, body(FLU)->ENU quaternion, biases, and the NED/FRD position
//!   and attitude of the project convention. `--decisions FILE` writes every gating decision.
//! - `subnav fgo simulate --out LOG`: a simulated mission log (and `--truth CSV`).
//! - `subnav fgo monte-carlo --seeds 1..=100`: gated vs ungated vs the shared-UKF filter, latency.

use std::fs::File;
use std::io::{BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};

use super::Format;
use super::args::{self, Seeds};
use subnav_fgo::gating::{GatingConfig, Sensor};
use subnav_fgo::log::SensorLog;
use subnav_fgo::montecarlo;
use subnav_fgo::sim::{SimConfig, simulate};
use subnav_fgo::smoother::{self, Estimate, SmootherConfig};
use subnav_fgo::state::{attitude_ned_frd_wxyz, enu_to_ned};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: Sub,
}

#[derive(Debug, clap::Subcommand)]
pub enum Sub {
    /// Process a JSON-lines sensor log; write the estimates (CSV, or JSON lines for .json/.jsonl).
    Replay {
        /// Sensor log (JSON lines).
        #[arg(long)]
        input: PathBuf,
        /// Output: `.json`/`.jsonl` gives JSON lines, anything else CSV.
        #[arg(long)]
        out: PathBuf,
        /// Disable the abnormal-observation test (every observation keeps its covariance).
        #[arg(long)]
        no_gating: bool,
        /// Write the real-time (fixed-lag) outputs instead of the batch-optimised nodes.
        #[arg(long)]
        realtime: bool,
        /// Fixed-lag window of the real-time smoother, seconds.
        #[arg(long, default_value_t = 6.0)]
        lag_s: f64,
        /// Confidence of the chi-square gate.
        #[arg(long, default_value_t = 0.99)]
        confidence: f64,
        /// Write every gating decision (JSON lines).
        #[arg(long)]
        decisions: Option<PathBuf>,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
    },
    /// Write a simulated AUV mission as a sensor log.
    Simulate {
        /// Output sensor log (JSON lines).
        #[arg(long)]
        out: PathBuf,
        /// Truth CSV at IMU rate (t_s, east, north, up).
        #[arg(long)]
        truth: Option<PathBuf>,
        /// Seed of the simulated mission.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Mission length, s (more than 10, at most a day).
        #[arg(long, allow_hyphen_values = true, default_value_t = 600.0, value_parser = args::f64_positive_upto(args::MAX_SIM_DURATION_S))]
        duration_s: f64,
        /// Fraction of DVL/USBL observations made abnormal.
        #[arg(long, default_value_t = 0.1)]
        abnormal_fraction: f64,
    },
    /// Seeded Monte Carlo: gated vs ungated graph vs shared-UKF filter; smoother latency.
    MonteCarlo {
        /// Seeds of the simulated missions: `N`, `A..B` (B exclusive) or `A..=B`.
        #[arg(long, default_value = "1..=100", value_parser = args::parse_seeds)]
        seeds: Seeds,
        /// Mission length, s (more than 10, at most a day).
        #[arg(long, allow_hyphen_values = true, default_value_t = 300.0, value_parser = args::f64_positive_upto(args::MAX_SIM_DURATION_S))]
        duration_s: f64,
        /// Fraction of DVL/USBL observations made abnormal.
        #[arg(long, default_value_t = 0.1)]
        abnormal_fraction: f64,
        /// Full results (per run) as JSON.
        #[arg(long)]
        out: Option<PathBuf>,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
    },
}

fn bar(len: u64, quiet: bool, what: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len);
    if let Ok(style) = ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} ({eta})") {
        pb.set_style(style.progress_chars("=> "));
    }
    pb.set_message(what.to_string());
    pb
}

fn is_json(p: &Path) -> bool {
    matches!(p.extension().and_then(|e| e.to_str()), Some("json" | "jsonl"))
}

fn write_estimates(path: &Path, est: &[Estimate]) -> Result<()> {
    let f = File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    let mut w = BufWriter::new(f);
    let json = is_json(path);
    if !json {
        writeln!(
            w,
            "t_s,east_m,north_m,up_m,ve_mps,vn_mps,vu_mps,qw,qx,qy,qz,bax,bay,baz,bgx,bgy,bgz,north_ned_m,east_ned_m,down_ned_m,qw_ned_frd,qx_ned_frd,qy_ned_frd,qz_ned_frd"
        )?;
    }
    for e in est {
        let n = &e.state.nav;
        let q = nalgebra::UnitQuaternion::from_matrix(&n.rot_enu_flu);
        let ned = enu_to_ned(&n.pos_enu_m);
        let qn = attitude_ned_frd_wxyz(&n.rot_enu_flu);
        let (ba, bg) = (e.state.bias.acc_mps2, e.state.bias.gyro_radps);
        if json {
            serde_json::to_writer(
                &mut w,
                &serde_json::json!({
                    "t_s": e.t_s, "pos_enu_m": [n.pos_enu_m.x, n.pos_enu_m.y, n.pos_enu_m.z],
                    "vel_enu_mps": [n.vel_enu_mps.x, n.vel_enu_mps.y, n.vel_enu_mps.z],
                    "q_enu_flu_wxyz": [q.w, q.i, q.j, q.k], "bias_acc_mps2": [ba.x, ba.y, ba.z],
                    "bias_gyro_radps": [bg.x, bg.y, bg.z], "pos_ned_m": [ned.x, ned.y, ned.z], "q_ned_frd_wxyz": qn,
                }),
            )?;
            writeln!(w)?;
        } else {
            writeln!(
                w,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                e.t_s,
                n.pos_enu_m.x,
                n.pos_enu_m.y,
                n.pos_enu_m.z,
                n.vel_enu_mps.x,
                n.vel_enu_mps.y,
                n.vel_enu_mps.z,
                q.w,
                q.i,
                q.j,
                q.k,
                ba.x,
                ba.y,
                ba.z,
                bg.x,
                bg.y,
                bg.z,
                ned.x,
                ned.y,
                ned.z,
                qn[0],
                qn[1],
                qn[2],
                qn[3]
            )?;
        }
    }
    w.flush()?;
    Ok(())
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    match args.command {
        Sub::Simulate { out, truth, seed, duration_s, abnormal_fraction } => {
            if !(duration_s > 10.0 && duration_s.is_finite() && (0.0..1.0).contains(&abnormal_fraction)) {
                bail!("--duration-s must be > 10 and --abnormal-fraction in [0, 1)");
            }
            let sim = simulate(&SimConfig { seed, duration_s, abnormal_fraction, ..Default::default() });
            let f = File::create(&out).with_context(|| format!("cannot create {}", out.display()))?;
            sim.log.write(BufWriter::new(f))?;
            if let Some(t) = truth {
                let mut w = BufWriter::new(File::create(&t).with_context(|| format!("cannot create {}", t.display()))?);
                writeln!(w, "t_s,east_m,north_m,up_m")?;
                for (t, s) in sim.truth.t_s.iter().zip(&sim.truth.states) {
                    let p = s.nav.pos_enu_m;
                    writeln!(w, "{t},{},{},{}", p.x, p.y, p.z)?;
                }
                w.flush()?;
            }
            match format {
                Format::Json => println!("{}", serde_json::to_string(&sim.stats)?),
                Format::Text => println!("wrote {} ({:?})", out.display(), sim.stats),
            }
            Ok(ExitCode::SUCCESS)
        }
        Sub::MonteCarlo { seeds, duration_s, abnormal_fraction, out, quiet } => {
            let (runs, first_seed) = (usize::try_from(seeds.count)?, seeds.first);
            if !(duration_s > 10.0 && duration_s.is_finite() && (0.0..1.0).contains(&abnormal_fraction)) {
                bail!("--duration-s must be > 10 and --abnormal-fraction in [0, 1)");
            }
            let pb = bar(runs as u64, quiet, "monte carlo");
            let base = SimConfig { duration_s, abnormal_fraction, ..Default::default() };
            let s = montecarlo::run_all(runs, first_seed, &base, |i| pb.set_position(i as u64))?;
            pb.finish_and_clear();
            if let Some(p) = out {
                let f = File::create(&p).with_context(|| format!("cannot create {}", p.display()))?;
                serde_json::to_writer_pretty(BufWriter::new(f), &s)?;
            }
            match format {
                Format::Json => {
                    let mut short = s.clone();
                    short.per_run.clear();
                    println!("{}", serde_json::to_string(&short)?);
                }
                Format::Text => {
                    let m = s.mean;
                    println!(
                        "{} runs x {:.0} s, {:.0} % abnormal DVL/USBL observations",
                        s.runs,
                        s.duration_s,
                        100.0 * s.abnormal_fraction
                    );
                    println!("position RMSE (mean over runs), m:");
                    println!(
                        "  batch graph  gated {:.3}  ungated {:.3}  -> {:.1} % lower",
                        m.batch_gated_m,
                        m.batch_ungated_m,
                        100.0 * s.reduction_batch
                    );
                    println!(
                        "  real time    gated {:.3}  ungated {:.3}  -> {:.1} % lower",
                        m.rt_gated_m,
                        m.rt_ungated_m,
                        100.0 * s.reduction_rt
                    );
                    println!("  shared UKF (gated, p=0.999) {:.3}", m.ukf_m);
                    println!("  gated batch better than ungated in {}/{} runs", s.runs_gated_better, s.runs);
                    println!(
                        "abnormal per run: injected DVL {:.1} USBL {:.1}; flagged DVL {:.1} USBL {:.1}",
                        m.abnormal_dvl_injected, m.abnormal_usbl_injected, m.flagged_dvl, m.flagged_usbl
                    );
                    for (name, l) in [("thread CPU time (one core)", s.cpu_ms), ("wall clock", s.latency_ms)] {
                        println!(
                            "smoother update latency, {name}, {} updates, ms: p50 {:.3} p90 {:.3} p99 {:.3} p99.9 {:.3} max {:.3} mean {:.3}",
                            s.updates, l.p50, l.p90, l.p99, l.p999, l.max, l.mean
                        );
                    }
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        Sub::Replay { input, out, no_gating, realtime, lag_s, confidence, decisions, quiet } => {
            subnav_link::output::refuse_input_as_output("--out", &out, &[&input])?;
            if let Some(d) = &decisions {
                subnav_link::output::refuse_input_as_output("--decisions", d, &[&input])?;
            }
            let f = File::open(&input).with_context(|| format!("cannot open {}", input.display()))?;
            let log = SensorLog::read(BufReader::new(f)).with_context(|| format!("reading {}", input.display()))?;
            let cfg = SmootherConfig { lag_s, gating: GatingConfig { enabled: !no_gating, confidence }, ..Default::default() };
            let pb = bar((log.dvl.len() + log.usbl.len()) as u64, quiet, "smoothing");
            let res = smoother::run(&log, cfg, !realtime, |i, _| pb.set_position(i as u64))?;
            pb.finish_and_clear();
            write_estimates(&out, if realtime { &res.realtime } else { &res.batch })?;
            if let Some(d) = decisions {
                let mut w = BufWriter::new(File::create(&d).with_context(|| format!("cannot create {}", d.display()))?);
                for x in &res.gate_log.decisions {
                    serde_json::to_writer(&mut w, x)?;
                    writeln!(w)?;
                }
                w.flush()?;
            }
            let lg = &res.gate_log;
            let summary = serde_json::json!({
                "nodes": res.batch.len(), "realtime_outputs": res.realtime.len(),
                "dvl_normal": lg.count(Sensor::Dvl, false), "dvl_abnormal": lg.count(Sensor::Dvl, true),
                "usbl_normal": lg.count(Sensor::Usbl, false), "usbl_abnormal": lg.count(Sensor::Usbl, true),
                "dropped_too_old": lg.dropped_too_old, "gating": !no_gating,
                "batch_iterations": res.batch_report.map(|r| r.iterations),
            });
            match format {
                Format::Json => println!("{summary}"),
                Format::Text => println!("wrote {}: {summary}", out.display()),
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}
