//! `subnav fgo`: factor-graph INS/DVL/USBL navigation (`subnav_fgo`, spec 002).
//!
//! - `subnav fgo replay --input LOG --out OUT [--no-gating] [--realtime]`: process a JSON-lines sensor
//!   log (format in `subnav_fgo::log`); writes the batch-optimised nodes (or the real-time
//!   smoother's outputs with `--realtime`) as CSV, or JSON lines when OUT ends in `.json`/`.jsonl`.
//!   Columns: ENU position/velocity, body(FLU)->ENU quaternion, biases, and the NED/FRD position
//!   and attitude of the project convention. `--decisions FILE` writes every gating decision.
//! - `subnav fgo simulate --out LOG`: a simulated mission log (and `--truth CSV`).
//! - `subnav fgo monte-carlo --seeds 1..=100`: gated vs ungated vs the shared-UKF filter, latency.
//! - `subnav fgo pyfg --input FILE --out TRAJ.csv [--beacons known|unknown] [--no-gating]`: a
//!   range-aided 2-D problem in the PyFactorGraph text format (`subnav_fgo::pyfg`, e.g. GOATS):
//!   writes `key,x_m,y_m,theta_rad` per pose and the beacons to `TRAJ.beacons.csv` (both only once
//!   solved); prints the range residual statistics and how many ranges the gate inflated, and
//!   with `--truth PYFG` the APE after a rigid 2-D fit against that file's pose vertices.

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
        /// Fixed-lag window of the real-time smoother, seconds (> 0, at most a day).
        #[arg(long, default_value_t = 6.0, allow_hyphen_values = true, value_parser = args::f64_positive_upto(args::MAX_SIM_DURATION_S))]
        lag_s: f64,
        /// Confidence of the chi-square gate (in (0, 1): 1e-9..=0.999999999).
        #[arg(long, default_value_t = 0.99, allow_hyphen_values = true, value_parser = args::f64_in(1e-9..=0.999_999_999))]
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
    /// Range-aided 2-D navigation from a PyFactorGraph text file (SE2 odometry + ranges to beacons).
    Pyfg {
        /// Input .pyfg file (VERTEX_SE2, VERTEX_XY, EDGE_SE2, EDGE_RANGE lines).
        #[arg(long)]
        input: PathBuf,
        /// Output trajectory CSV: key,x_m,y_m,theta_rad. Beacons go to the same name with
        /// `.beacons.csv` in place of the extension.
        #[arg(long)]
        out: PathBuf,
        /// Beacons known (the file's VERTEX_XY positions, fixed) or unknown (estimated).
        #[arg(long, value_enum, default_value_t = BeaconsArg::Known)]
        beacons: BeaconsArg,
        /// Initial guess of the poses: the odometry composed from the first pose vertex, or the
        /// file's pose vertices.
        #[arg(long, value_enum, default_value_t = InitArg::Odometry)]
        init: InitArg,
        /// Disable the range gate (every range keeps its variance).
        #[arg(long)]
        no_gating: bool,
        /// The seed's fixed chi-square test instead of the adaptive one (for comparison).
        #[arg(long)]
        fixed_gate: bool,
        /// Confidence of the chi-square gate (in (0, 1): 1e-9..=0.999999999).
        #[arg(long, default_value_t = 0.99, allow_hyphen_values = true, value_parser = args::f64_in(1e-9..=0.999_999_999))]
        confidence: f64,
        /// Estimate a range bias per beacon (zero-mean prior, sigma 10 m).
        #[arg(long)]
        range_bias: bool,
        /// Multiply the file's odometry covariances by this (a DVL/INS noise model that is too tight).
        /// (> 0, at most 1e6)
        #[arg(long, default_value_t = 1.0, allow_hyphen_values = true, value_parser = args::f64_positive_upto(1e6))]
        odometry_cov_scale: f64,
        /// Scale the odometry and range noise to the data (robust variance components) before gating.
        #[arg(long)]
        adapt_noise: bool,
        /// A .pyfg file whose pose vertices are the reference trajectory (same keys): print the APE.
        #[arg(long)]
        truth: Option<PathBuf>,
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

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BeaconsArg {
    Known,
    Unknown,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum InitArg {
    Odometry,
    File,
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
    let mut w = BufWriter::new(subnav_link::output::AtomicFile::create(path)?);
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
    w.into_inner().map_err(|e| e.into_error())?.commit()?;
    Ok(())
}

fn beacons_path(out: &Path) -> PathBuf {
    let stem = out.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    out.with_file_name(format!("{stem}.beacons.csv"))
}

#[derive(Clone, Copy)]
struct PyfgOpts {
    beacons: BeaconsArg,
    init: InitArg,
    no_gating: bool,
    fixed_gate: bool,
    confidence: f64,
    range_bias: bool,
    adapt_noise: bool,
    odometry_cov_scale: f64,
}

fn run_pyfg(input: &Path, out: &Path, o: &PyfgOpts, truth: Option<&Path>, format: Format) -> Result<ExitCode> {
    let PyfgOpts { beacons, init, no_gating, fixed_gate, confidence, range_bias, adapt_noise, odometry_cov_scale } = *o;
    if !(odometry_cov_scale > 0.0 && odometry_cov_scale.is_finite()) {
        bail!("--odometry-cov-scale must be a finite number > 0");
    }
    use subnav_fgo::range2d::{Beacons, Graph2, Init, LmOptions2, RangeGate, ape_rigid_2d};
    let bpath = beacons_path(out);
    let mut inputs = vec![input];
    inputs.extend(truth);
    subnav_link::output::check_outputs(&[("--out", out), ("the beacons file", &bpath)], &inputs)?;
    if !(confidence > 0.0 && confidence < 1.0) {
        bail!("--confidence must be in (0, 1)");
    }
    let fg = subnav_fgo::pyfg::PyFg::read(input)?;
    // the reference, read before solving so that a bad file fails before anything is written
    let reference = match truth {
        Some(t) => {
            let r = subnav_fgo::pyfg::PyFg::read(t)?;
            let mut pos = Vec::with_capacity(fg.poses.len());
            for p in &fg.poses {
                let q = r.poses.iter().find(|q| q.name == p.name).with_context(|| format!("{}: no pose {}", t.display(), p.name))?;
                pos.push(q.guess.t());
            }
            Some(pos)
        }
        None => None,
    };
    let mode = if beacons == BeaconsArg::Known { Beacons::Known } else { Beacons::Unknown };
    let init = if init == InitArg::File { Init::File } else { Init::Odometry };
    let start = std::time::Instant::now();
    let mut g = Graph2::from_pyfg(&fg, mode, init).with_context(|| format!("setting up {}", input.display()))?;
    if range_bias {
        g = g.with_range_bias();
    }
    for o in &mut g.odometry {
        o.3 *= odometry_cov_scale;
    }
    let noise_scale = if adapt_noise { Some(g.adapt_noise(&LmOptions2::default(), 30)?) } else { None };
    let gate = RangeGate { enabled: !no_gating, confidence, adaptive: !fixed_gate, ..Default::default() };
    let (report, summary) = g.solve_gated(&gate, &LmOptions2::default()).with_context(|| format!("solving {}", input.display()))?;
    let solve_s = start.elapsed().as_secs_f64();
    let mut traj = String::from("key,x_m,y_m,theta_rad\n");
    for (v, p) in fg.poses.iter().zip(&g.poses) {
        traj += &format!("{},{},{},{}\n", v.name, p.x_m, p.y_m, p.theta_rad);
    }
    let mut bcsv = String::from("key,x_m,y_m,known\n");
    for (v, b) in fg.beacons.iter().zip(&g.beacons) {
        bcsv += &format!("{},{},{},{}\n", v.name, b.x, b.y, mode == Beacons::Known);
    }
    subnav_link::output::write_atomic(&bpath, bcsv.as_bytes())?;
    subnav_link::output::write_atomic(out, traj.as_bytes())?;
    let e = g.range_residuals_m();
    let mut abs: Vec<f64> = e.iter().map(|x| x.abs()).collect();
    abs.sort_by(|a, b| a.total_cmp(b));
    let pct = |q: f64| abs.get(((abs.len() as f64 - 1.0) * q).round() as usize).copied().unwrap_or(f64::NAN);
    let rms = (e.iter().map(|x| x * x).sum::<f64>() / e.len().max(1) as f64).sqrt();
    let ape = match &reference {
        Some(r) => Some(ape_rigid_2d(&g.poses.iter().map(|p| p.t()).collect::<Vec<_>>(), r)?),
        None => None,
    };
    // the odometry alone (dead reckoning from the first vertex), for comparison
    let ape_dr = match &reference {
        Some(r) => Some(ape_rigid_2d(&subnav_fgo::range2d::dead_reckoning(&fg)?.iter().map(|p| p.t()).collect::<Vec<_>>(), r)?),
        None => None,
    };
    let summary_json = serde_json::json!({
        "poses": g.poses.len(), "beacons": g.beacons.len(), "odometry": g.odometry.len(), "ranges": e.len(),
        "beacons_mode": format!("{beacons:?}").to_lowercase(), "gating": !no_gating, "adaptive_gate": !fixed_gate,
        "ranges_inflated": summary.inflated, "gate_rounds": summary.rounds, "gate_scale": summary.scale,
        "range_residual_m": {"rms": rms, "median_abs": pct(0.5), "p95_abs": pct(0.95), "max_abs": abs.last()},
        "lm_iterations": report.iterations, "initial_cost": report.initial_cost, "final_cost": report.final_cost,
        "solve_s": solve_s, "noise_scale": noise_scale, "odometry_cov_scale": odometry_cov_scale, "range_bias_m": g.range_bias_m, "ape_rmse_m": ape.map(|a| a.0), "ape_max_m": ape.map(|a| a.1),
        "dead_reckoning_ape_rmse_m": ape_dr.map(|a| a.0),
    });
    match format {
        Format::Json => println!("{summary_json}"),
        Format::Text => {
            println!("wrote {} and {}", out.display(), bpath.display());
            println!(
                "{} poses, {} beacons ({}), {} odometry, {} ranges; LM {} iterations, cost {:.6e} -> {:.6e}, {:.3} s",
                g.poses.len(),
                g.beacons.len(),
                format!("{beacons:?}").to_lowercase(),
                g.odometry.len(),
                e.len(),
                report.iterations,
                report.initial_cost,
                report.final_cost,
                solve_s
            );
            println!(
                "range residuals m: rms {rms:.3} median |e| {:.3} p95 |e| {:.3} max |e| {:.3}",
                pct(0.5),
                pct(0.95),
                abs.last().copied().unwrap_or(f64::NAN)
            );
            if no_gating {
                println!("gate off");
            } else {
                println!(
                    "gate ({}): {} of {} ranges inflated, {} rounds, residual scale {:.2}",
                    if fixed_gate { "fixed chi2" } else { "adaptive" },
                    summary.inflated,
                    e.len(),
                    summary.rounds,
                    summary.scale
                );
            }
            if let Some((so, sr)) = noise_scale {
                println!("noise adapted: odometry covariance x{so:.1}, range variance x{sr:.2}");
            }
            if let Some(b) = &g.range_bias_m {
                println!("range bias per beacon m: {}", b.iter().map(|x| format!("{x:.2}")).collect::<Vec<_>>().join(" "));
            }
            if let Some((rmse, max)) = ape {
                println!("APE after a rigid 2-D fit: rmse {rmse:.3} m, max {max:.3} m");
            }
            if let Some((rmse, max)) = ape_dr {
                println!("dead reckoning (odometry only), same fit: rmse {rmse:.3} m, max {max:.3} m");
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    match args.command {
        Sub::Pyfg { input, out, beacons, init, no_gating, fixed_gate, confidence, range_bias, adapt_noise, odometry_cov_scale, truth } => {
            let opts = PyfgOpts { beacons, init, no_gating, fixed_gate, confidence, range_bias, adapt_noise, odometry_cov_scale };
            run_pyfg(&input, &out, &opts, truth.as_deref(), format)
        }
        Sub::Simulate { out, truth, seed, duration_s, abnormal_fraction } => {
            if !(duration_s > 10.0 && duration_s.is_finite() && (0.0..1.0).contains(&abnormal_fraction)) {
                bail!("--duration-s must be > 10 and --abnormal-fraction in [0, 1)");
            }
            let outputs: Vec<(&str, &Path)> =
                [("--out", Some(out.as_path())), ("--truth", truth.as_deref())].into_iter().filter_map(|(f, p)| Some((f, p?))).collect();
            subnav_link::output::check_outputs(&outputs, &[])?;
            let sim = simulate(&SimConfig { seed, duration_s, abnormal_fraction, ..Default::default() });
            let mut log = Vec::new();
            sim.log.write(&mut log)?;
            subnav_link::output::write_atomic(&out, log)?;
            if let Some(t) = truth {
                let mut w = String::from("t_s,east_m,north_m,up_m\n");
                for (t, s) in sim.truth.t_s.iter().zip(&sim.truth.states) {
                    let p = s.nav.pos_enu_m;
                    w += &format!("{t},{},{},{}\n", p.x, p.y, p.z);
                }
                subnav_link::output::write_atomic(&t, w)?;
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
                subnav_link::output::write_atomic(&p, serde_json::to_vec_pretty(&s)?)?;
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
            let outputs: Vec<(&str, &Path)> = [("--out", Some(out.as_path())), ("--decisions", decisions.as_deref())]
                .into_iter()
                .filter_map(|(f, p)| Some((f, p?)))
                .collect();
            subnav_link::output::check_outputs(&outputs, &[&input])?;
            let f = File::open(&input).with_context(|| format!("cannot open {}", input.display()))?;
            let log = SensorLog::read(BufReader::new(f)).with_context(|| format!("reading {}", input.display()))?;
            let cfg = SmootherConfig {
                lag_s,
                gating: GatingConfig { enabled: !no_gating, confidence, ..Default::default() },
                ..Default::default()
            };
            let pb = bar((log.dvl.len() + log.usbl.len()) as u64, quiet, "smoothing");
            let res = smoother::run(&log, cfg, !realtime, |i, _| pb.set_position(i as u64))?;
            pb.finish_and_clear();
            write_estimates(&out, if realtime { &res.realtime } else { &res.batch })?;
            if let Some(d) = decisions {
                let mut w = Vec::new();
                for x in &res.gate_log.decisions {
                    serde_json::to_writer(&mut w, x)?;
                    writeln!(w)?;
                }
                subnav_link::output::write_atomic(&d, w)?;
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
