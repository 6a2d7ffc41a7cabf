//! `subnav map`: topological mapping with polarization images and AUKF-SLAM (spec A3, A5).
//!
//! - `simulate`: a seeded survey with revisits over the rendered seafloor; prints the recognition
//!   precision/recall and the drift with loop-closure fixes vs dead reckoning; writes the map
//!   (JSON, GraphML), a plot of the graph over the trajectory, the position fixes as downlink
//!   frames, and optionally the mosaics (`--images`, `<t_us>.png`) with a navigation log
//!   (`nav.csv`: dead-reckoned `t_s,north_m,east_m,down_m`) that `build` reads.
//! - `build`: the same mapper on real data: a navigation source (a subnav recording, whose
//!   navigation solutions are used, or a CSV `t_s,north_m,east_m[,down_m]`) and a directory of 8/16-bit
//!   IMX250MZR mosaics named by sensor-head time in microseconds (`<t_us>.png`).
//!
//! Outputs in `--out-dir`: `map.json`, `map.graphml`, `map.png`, `fixes.bin` (COBS frames of
//! `Downlink` `PositionFix` commands, ready for the downlink; this command does not send them).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};

use super::Format;
use subnav_topo::export;
use subnav_topo::polar_image::{Mosaic, demosaic, features, stokes};
use subnav_topo::survey::{self, Frame, SurveyConfig, SurveyResult};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: Sub,
}

#[derive(Debug, clap::Subcommand)]
pub enum Sub {
    /// Simulated survey with revisits: build the map, report recognition and drift figures.
    Simulate {
        /// Laps of the racetrack survey (the second and later laps revisit the first).
        #[arg(long, default_value_t = 3.0)]
        laps: f64,
        /// Seed of the simulated survey.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Appearance-only association (no Mahalanobis position gate), for comparison.
        #[arg(long)]
        no_gate: bool,
        /// Output directory for the map, plot and fixes.
        #[arg(long)]
        out_dir: Option<PathBuf>,
        /// Also write every frame's mosaic (`<t_us>.png`) and `nav.csv` here.
        #[arg(long)]
        images: Option<PathBuf>,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
    },
    /// Build a map from a navigation source and a directory of mosaics.
    Build {
        /// A subnav recording (navigation solutions) or a CSV `t_s,north_m,east_m`.
        #[arg(long)]
        nav: PathBuf,
        /// Directory of mosaics named `<t_us>.png`.
        #[arg(long)]
        images: PathBuf,
        /// Output directory for the map, plot and fixes.
        #[arg(long)]
        out_dir: Option<PathBuf>,
        /// LMNN training time (s after the first image); default: half of the images' span.
        #[arg(long)]
        train_after_s: Option<f64>,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
    },
}

fn bar(quiet: bool, what: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(1000);
    if let Ok(style) = ProgressStyle::with_template("{msg} [{bar:40}] {percent}% ({eta})") {
        pb.set_style(style.progress_chars("=> "));
    }
    pb.set_message(what.to_string());
    pb
}

fn write_outputs(dir: &Path, res: &SurveyResult) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    subnav_link::output::write_atomic(dir.join("map.json"), export::to_json(&res.map, Some(&res.report))?)?;
    subnav_link::output::write_atomic(dir.join("map.graphml"), export::to_graphml(&res.map))?;
    let png = dir.join("map.png");
    export::plot(&png, &res.map, &res.track).with_context(|| format!("writing {}", png.display()))?;
    subnav_link::output::write_atomic(dir.join("fixes.bin"), res.fix_frames.concat())?;
    Ok(())
}

fn print_report(res: &SurveyResult, format: Format, with_truth: bool) {
    let r = &res.report;
    match format {
        Format::Json => println!("{}", serde_json::to_string(r).unwrap_or_default()),
        Format::Text => {
            println!(
                "{:.0} s, {} nodes ({} created, {} merged), {} position fixes",
                r.duration_s, r.nodes, r.nodes_created, r.merges, r.fixes
            );
            if with_truth {
                println!(
                    "recognition: precision {:.1} % ({}/{}), recall {:.1} % ({}/{} opportunities); appearance only: {}/{} correct",
                    r.precision * 100.0,
                    r.correct_recognitions,
                    r.recognitions,
                    r.recall * 100.0,
                    r.recalled_opportunities,
                    r.opportunities,
                    r.appearance_correct,
                    r.appearance_matches
                );
                println!(
                    "drift at the end: {:.2} m with loop-closure fixes, {:.2} m dead reckoning (max over the last lap {:.2} / {:.2} m)",
                    r.final_drift_slam_m, r.final_drift_dr_m, r.max_drift_last_lap_slam_m, r.max_drift_last_lap_dr_m
                );
                println!("estimated current: [{:.3}, {:.3}] m/s", r.estimated_current_mps[0], r.estimated_current_mps[1]);
            } else {
                println!("{} recognitions", r.recognitions);
            }
        }
    }
}

/// Navigation positions (t_s, [north, east, down]), sorted by time; down is NaN when unknown.
fn read_nav(path: &Path) -> Result<Vec<(f64, [f64; 3])>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let mut out = Vec::new();
    if subnav_link::record::is_recording(&bytes) {
        let loaded = subnav_link::record::reader::read_bytes(&bytes).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let session = subnav_link::record::session::Session::decode(&loaded, None);
        let data = subnav_report::ReportData::from_session(&session, None);
        out.extend(data.nav.iter().map(|n| (n.t_s, n.pos_ned_m)));
    } else {
        let text = String::from_utf8(bytes).with_context(|| format!("{} is neither a recording nor a text CSV", path.display()))?;
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') || (i == 0 && line.starts_with("t_s")) {
                continue;
            }
            let v: Vec<f64> = line
                .split(',')
                .map(|c| c.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .with_context(|| format!("{} line {}", path.display(), i + 1))?;
            if v.len() < 3 || v.len() > 4 || v.iter().any(|x| !x.is_finite()) {
                bail!("{} line {}: expected t_s,north_m,east_m[,down_m]", path.display(), i + 1);
            }
            out.push((v[0], [v[1], v[2], v.get(3).copied().unwrap_or(f64::NAN)]));
        }
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    if out.len() < 2 {
        bail!("{}: fewer than two navigation positions", path.display());
    }
    Ok(out)
}

fn nav_at(nav: &[(f64, [f64; 3])], t: f64) -> [f64; 3] {
    let i = nav.partition_point(|p| p.0 < t);
    if i == 0 {
        return nav[0].1;
    }
    if i >= nav.len() {
        return nav[nav.len() - 1].1;
    }
    let (a, b) = (nav[i - 1], nav[i]);
    let u = if b.0 > a.0 { (t - a.0) / (b.0 - a.0) } else { 0.0 };
    [0, 1, 2].map(|k| a.1[k] + u * (b.1[k] - a.1[k]))
}

/// How far outside the navigation's time span an image may be and still get its position (s).
const NAV_MARGIN_S: f64 = 1.0;

/// Frames from a navigation log and a directory of `<t_us>.png` mosaics. Unreadable images are
/// reported and skipped (their frame still carries the displacement).
fn frames_from_dir(nav: &[(f64, [f64; 3])], dir: &Path, warn: &mut dyn FnMut(String)) -> Result<(Vec<Frame>, [f64; 2])> {
    let mut imgs: Vec<(u64, PathBuf)> = Vec::new();
    for e in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let p = e?.path();
        if p.extension().and_then(|x| x.to_str()) != Some("png") {
            continue;
        }
        match p.file_stem().and_then(|s| s.to_str()).and_then(|s| s.parse::<u64>().ok()) {
            Some(t) => imgs.push((t, p)),
            None => warn(format!("skipping {}: not named <t_us>.png", p.display())),
        }
    }
    imgs.sort();
    if imgs.is_empty() {
        bail!("no <t_us>.png mosaics in {}", dir.display());
    }
    // Images outside the navigation's time span have no position: skipped (never clamped to
    // the span's ends), and said so; none inside is an error naming both spans.
    let (n0, n1) = (nav.first().map_or(0.0, |p| p.0), nav.last().map_or(0.0, |p| p.0));
    let (i0, i1) = (imgs[0].0 as f64 * 1e-6, imgs[imgs.len() - 1].0 as f64 * 1e-6);
    let total = imgs.len();
    imgs.retain(|(t, _)| (n0 - NAV_MARGIN_S..=n1 + NAV_MARGIN_S).contains(&(*t as f64 * 1e-6)));
    if imgs.is_empty() {
        bail!(
            "none of the {total} images in {} (times {i0:.3} to {i1:.3} s) falls within the navigation's time span ({n0:.3} to {n1:.3} s): the image names must be sensor-head time in microseconds",
            dir.display()
        );
    }
    if imgs.len() < total {
        warn(format!(
            "{} of {total} images in {} are outside the navigation's time span ({n0:.3} to {n1:.3} s) and were skipped",
            total - imgs.len(),
            dir.display()
        ));
    }
    let start = nav_at(nav, imgs[0].0 as f64 * 1e-6);
    let mut prev = start;
    let mut frames = Vec::with_capacity(imgs.len());
    for (t_us, p) in &imgs {
        let t = *t_us as f64 * 1e-6;
        let pos = nav_at(nav, t);
        let f = match Mosaic::read_png(p) {
            Ok(m) => Some(features(&stokes(&demosaic(&m)))),
            Err(e) => {
                warn(format!("skipping image: {e:#}"));
                None
            }
        };
        let depth_m = pos[2].is_finite().then_some(pos[2]);
        frames.push(Frame { t_s: t, dx_m: [pos[0] - prev[0], pos[1] - prev[1]], features: f, truth_ned_m: None, depth_m });
        prev = pos;
    }
    Ok((frames, [start[0], start[1]]))
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    match args.command {
        Sub::Simulate { laps, seed, no_gate, out_dir, images, quiet } => {
            if !(laps > 0.0 && laps <= 50.0) {
                bail!("--laps must be in (0, 50]");
            }
            let cfg = SurveyConfig { laps, seed, position_gate: !no_gate, ..SurveyConfig::default() };
            let pb = bar(quiet, "survey");
            let mut nav_csv = String::from("t_s,north_m,east_m,down_m\n");
            let depth = cfg.track.depth_m;
            if let Some(d) = &images {
                std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
            }
            let res = survey::run_with_frames(&cfg, &mut |f| pb.set_position((f * 1000.0) as u64), &mut |t, m, dr| {
                if let Some(d) = &images {
                    m.write_png(&d.join(format!("{}.png", (t * 1e6).round() as u64)))?;
                    nav_csv.push_str(&format!("{t},{},{},{depth}\n", dr[0], dr[1]));
                }
                Ok(())
            })?;
            pb.finish_and_clear();
            if let Some(d) = &images {
                subnav_link::output::write_atomic(d.join("nav.csv"), nav_csv)?;
            }
            if let Some(d) = &out_dir {
                write_outputs(d, &res)?;
            }
            print_report(&res, format, true);
            Ok(ExitCode::SUCCESS)
        }
        Sub::Build { nav, images, out_dir, train_after_s, quiet } => {
            if let Some(d) = &out_dir {
                subnav_link::output::refuse_dir_holding_input("--out-dir", d, &[&nav, &images])?;
            }
            let navs = read_nav(&nav)?;
            let (frames, start) = frames_from_dir(&navs, &images, &mut |w| eprintln!("warning: {w}"))?;
            let span = frames.last().map_or(0.0, |f| f.t_s) - frames.first().map_or(0.0, |f| f.t_s);
            if let Some(t) = train_after_s.filter(|t| !(t.is_finite() && *t >= 0.0 && *t <= span)) {
                bail!("--train-after-s {t}: must be in [0, {span:.3}] s (the images' span after the first image)");
            }
            let cfg = SurveyConfig { train_after_s: train_after_s.unwrap_or(span / 2.0), ..SurveyConfig::default() };
            let pb = bar(quiet, "mapping");
            let res = survey::build(&cfg, start, &frames, &mut |f| pb.set_position((f * 1000.0) as u64))?;
            pb.finish_and_clear();
            if let Some(d) = &out_dir {
                write_outputs(d, &res)?;
            }
            print_report(&res, format, false);
            Ok(ExitCode::SUCCESS)
        }
    }
}
