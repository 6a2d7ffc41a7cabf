//! Mission report from a recording (and truth, when the dive was simulated): figures with
//! plotters ([`plot`]) and a Markdown + HTML page that links them, with error statistics when
//! truth exists.
//!
//! Truth comes from the recording's truth stream or a CSV `t_s,n_m,e_m,d_m,yaw_rad` (the format
//! `subnav filter simulate --truth` writes), in sensor-head seconds. Estimates are compared with
//! truth linearly interpolated to each navigation solution's time (yaw interpolated on the
//! circle); solutions outside the truth's time span are not scored.

pub mod dive;
pub mod plot;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde::Serialize;
use subnav_wire::{NavMode, Uplink};

use subnav_link::record::session::{Session, TruthRow};

/// Yaw (rad, from north, clockwise) of a body->NED quaternion `[w, x, y, z]`.
pub fn yaw_of(q: [f32; 4]) -> f64 {
    let [w, x, y, z] = q.map(f64::from);
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

/// Wrap an angle to (-pi, pi] (the one wrap, `subnav_core::ukf::wrap_pi`).
pub use subnav_core::ukf::wrap_pi as wrap;

/// One navigation solution as plotted.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct NavPoint {
    pub t_s: f64,
    pub pos_ned_m: [f64; 3],
    pub sigma_pos_m: [f64; 3],
    pub yaw_rad: f64,
    pub sigma_yaw_rad: f64,
    pub aided: bool,
}

/// Estimate minus truth at one navigation solution.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ErrPoint {
    pub t_s: f64,
    pub pos_err_ned_m: [f64; 3],
    pub yaw_err_rad: f64,
    pub truth_ned_m: [f64; 3],
    pub truth_yaw_rad: f64,
}

/// Health sample (NaN = no value yet).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct HealthPoint {
    pub t_s: f64,
    pub lambda: f64,
    /// Per aid source, in `subnav_wire::AidSource::ALL`'s order: the latest test ratio (NIS /
    /// gate: above 1 refused) and noise variance.
    pub test_ratio: [f64; 4],
    pub q_diag: [f64; 5],
    pub noise_var: [f64; 4],
    /// The IMU process-noise scale in use.
    pub imu_q_scale: f64,
    pub gate_rejects: u32,
    pub pd_repairs: u32,
}

/// A fault on the timeline.
#[derive(Debug, Clone, Serialize)]
pub struct FaultPoint {
    pub t_s: f64,
    /// `source/kind`, e.g. `Polarization{unit:2}/BusNack`.
    pub label: String,
    pub count: u32,
}

/// Error statistics (only when truth exists): the run's one scoring, `subnav_link::score`
/// (aided solutions; heading over the converged ones), the figures `subnav run` prints.
pub use subnav_link::score::Score as ErrorStats;

/// A loop closure the head accepted: where the map put the vehicle at that instant and where
/// the head's estimate was.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ClosurePoint {
    pub t_s: f64,
    /// The recognised node (north, east).
    pub node_ne_m: [f64; 2],
    pub estimate_ne_m: [f64; 2],
}

/// The data of a report.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ReportData {
    /// The topological map's nodes (north, east), when the map ran in the loop.
    pub map_nodes: Vec<[f64; 2]>,
    pub closures: Vec<ClosurePoint>,
    pub nav: Vec<NavPoint>,
    pub truth: Vec<TruthRow>,
    pub errors: Vec<ErrPoint>,
    pub health: Vec<HealthPoint>,
    pub faults: Vec<FaultPoint>,
    pub stats: Option<ErrorStats>,
    pub corrupt_frames: u64,
    pub frames_ok: u64,
    pub log_lines: usize,
    pub nav_uninitialised: usize,
}

fn f(x: f32) -> f64 {
    f64::from(x)
}

/// Truth at `t_s` by linear interpolation (None outside the truth's span).
pub fn truth_at(truth: &[TruthRow], t_s: f64) -> Option<([f64; 3], f64)> {
    let i = truth.partition_point(|r| r.t_s < t_s);
    let b = truth.get(i)?;
    if (b.t_s - t_s).abs() < 1e-9 {
        return Some((b.pos_ned_m, b.yaw_rad));
    }
    let a = truth.get(i.checked_sub(1)?)?;
    let u = (t_s - a.t_s) / (b.t_s - a.t_s);
    let p = [0, 1, 2].map(|k| a.pos_ned_m[k] + u * (b.pos_ned_m[k] - a.pos_ned_m[k]));
    Some((p, wrap(a.yaw_rad + u * wrap(b.yaw_rad - a.yaw_rad))))
}

impl ReportData {
    /// Collect what the report shows. `truth` overrides the recording's truth stream when given.
    pub fn from_session(s: &Session, truth: Option<Vec<TruthRow>>) -> Self {
        let mut d =
            ReportData { corrupt_frames: s.link.frames_bad, frames_ok: s.link.frames_ok, log_lines: s.logs.len(), ..Default::default() };
        let mut truth = truth.unwrap_or_else(|| s.truth.clone());
        truth.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
        d.truth = truth;
        for m in &s.messages {
            match &m.item {
                Uplink::Nav(n) => {
                    if n.mode == NavMode::Uninitialised {
                        d.nav_uninitialised += 1;
                        continue;
                    }
                    let p = NavPoint {
                        t_s: n.t_us as f64 * 1e-6,
                        pos_ned_m: n.pos_ned_m.map(f),
                        sigma_pos_m: n.sigma_pos_m.map(f),
                        yaw_rad: yaw_of(n.att_nb_wxyz),
                        sigma_yaw_rad: f(n.sigma_att_rad[2]),
                        aided: n.mode == NavMode::Aided,
                    };
                    if p.pos_ned_m.iter().chain(&[p.yaw_rad]).all(|v| v.is_finite()) {
                        d.nav.push(p);
                    }
                }
                Uplink::Health(h) => d.health.push(HealthPoint {
                    t_s: h.t_us as f64 * 1e-6,
                    lambda: f(h.lambda),
                    test_ratio: subnav_wire::AidSource::ALL.map(|s| f(h.aid.get(s).test_ratio)),
                    q_diag: h.q_diag.map(f),
                    noise_var: subnav_wire::AidSource::ALL.map(|s| f(h.aid.get(s).noise_var)),
                    imu_q_scale: f(h.imu_q_scale),
                    gate_rejects: h.gate_rejects,
                    pd_repairs: h.pd_repairs,
                }),
                Uplink::Fault(x) => d.faults.push(FaultPoint {
                    t_s: x.t_us as f64 * 1e-6,
                    label: format!("{:?}/{:?}", x.source, x.kind).replace(' ', ""),
                    count: x.count,
                }),
                _ => {}
            }
        }
        for n in &d.nav {
            if let Some((p, y)) = truth_at(&d.truth, n.t_s) {
                d.errors.push(ErrPoint {
                    t_s: n.t_s,
                    pos_err_ned_m: [0, 1, 2].map(|k| n.pos_ned_m[k] - p[k]),
                    yaw_err_rad: wrap(n.yaw_rad - y),
                    truth_ned_m: p,
                    truth_yaw_rad: y,
                });
            }
        }
        d.stats = Self::score(s, &d.truth);
        d
    }

    /// The scoring of `subnav run` (`subnav_link::score`) over the aided solutions inside the
    /// truth's span, the truth interpolated at each solution's time.
    fn score(s: &Session, truth: &[TruthRow]) -> Option<ErrorStats> {
        let mut scorer = subnav_link::score::Scorer::new();
        for m in &s.messages {
            if let Uplink::Nav(n) = &m.item
                && let Some((pos_ned_m, yaw_rad)) = truth_at(truth, n.t_us as f64 * 1e-6)
            {
                scorer.add(n, &subnav_link::score::Truth { pos_ned_m, yaw_rad });
            }
        }
        let score = scorer.score();
        (score.scored > 0).then_some(score)
    }
}

/// Output image formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
pub enum ImageFormat {
    Png,
    Svg,
    Both,
}

/// What `write` produced.
#[derive(Debug, Clone, Serialize)]
pub struct Written {
    pub figures: Vec<PathBuf>,
    pub markdown: PathBuf,
    pub html: PathBuf,
    pub stats: Option<ErrorStats>,
}

/// Write the figures, `report.md` and `report.html` into `dir`.
pub fn write(d: &ReportData, dir: &Path, images: ImageFormat, title: &str, mut progress: impl FnMut(&str)) -> Result<Written> {
    if d.nav.is_empty() && d.health.is_empty() && d.faults.is_empty() {
        bail!(
            "nothing to report: the recording has no initialised navigation solutions, health or fault messages ({} nav messages were Uninitialised); record a run with the estimator running",
            d.nav_uninitialised
        );
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let exts: &[&str] = match images {
        ImageFormat::Png => &["png"],
        ImageFormat::Svg => &["svg"],
        ImageFormat::Both => &["png", "svg"],
    };
    let mut figures = vec![];
    let mut sections: Vec<(&str, String, &str)> = vec![];
    for (name, caption, draw) in plot::FIGURES {
        progress(name);
        let mut drew = false;
        for ext in exts {
            let p = dir.join(format!("{name}.{ext}"));
            if draw(d, &p)? {
                figures.push(p);
                drew = true;
            }
        }
        if drew {
            sections.push((name, format!("{name}.{}", exts[0]), caption));
        }
    }
    let mut md = format!("# {title}\n\n");
    let _ = writeln!(
        md,
        "{} navigation solutions ({} before initialisation not shown), {} health, {} fault messages, {} log lines; {} frames decoded, {} corrupt.\n",
        d.nav.len(),
        d.nav_uninitialised,
        d.health.len(),
        d.faults.len(),
        d.log_lines,
        d.frames_ok,
        d.corrupt_frames
    );
    if !d.map_nodes.is_empty() {
        let _ = writeln!(
            md,
            "Map in the loop: {} nodes, {} loop closures accepted by the head (on the trajectory figure).\n",
            d.map_nodes.len(),
            d.closures.len()
        );
    }
    match &d.stats {
        Some(s) => {
            let at = |t: Option<f64>| t.map_or("-".to_string(), |t| format!("{t:.1} s"));
            let _ = writeln!(md, "## Errors against truth ({} aided solutions scored)\n", s.scored);
            let _ = writeln!(
                md,
                "Scored as `subnav run` scores (`subnav_link::score`): the {} aided solutions (from {}), the alignment before them left out; the heading over the {} of them whose yaw 1-sigma is at most {} deg (converged, from {}). The figures below show every initialised solution.\n",
                s.scored,
                at(s.first_aided_s),
                s.heading_converged_epochs,
                subnav_link::score::HEADING_CONVERGED_SIGMA_DEG,
                at(s.heading_converged_s)
            );
            let _ = writeln!(md, "| metric | value |\n|---|---:|");
            let _ = writeln!(md, "| horizontal RMS | {:.2} m |", s.horizontal_rms_err_m);
            let _ = writeln!(md, "| horizontal max | {:.2} m |", s.horizontal_max_err_m);
            let _ = writeln!(md, "| horizontal final | {:.2} m |", s.horizontal_final_err_m);
            let _ = writeln!(md, "| horizontal within 3 sigma (N and E) | {:.1} % |", 100.0 * s.within_3_sigma);
            let _ = writeln!(md, "| depth RMSE | {:.3} m |", s.depth_rmse_m);
            let _ = writeln!(md, "| heading RMSE (converged) | {:.3} deg |", s.heading_rmse_deg);
            let _ = writeln!(md, "| heading max (converged) | {:.3} deg |", s.heading_max_abs_err_deg);
            let _ = writeln!(md, "| heading within 3 sigma (converged) | {:.1} % |", 100.0 * s.heading_within_3_sigma);
            let _ = writeln!(md, "| heading RMSE (all aided) | {:.2} deg |\n", s.heading_rmse_all_aided_deg);
        }
        None => {
            md.push_str("No truth: error statistics need a simulated dive's truth (`--truth`, or a truth stream in the recording).\n\n")
        }
    }
    for (name, file, caption) in &sections {
        let _ = writeln!(md, "## {name}\n\n{caption}\n\n![{name}]({file})\n");
    }
    let markdown = dir.join("report.md");
    subnav_link::output::write_atomic(&markdown, md.as_bytes())?;
    let html = dir.join("report.html");
    subnav_link::output::write_atomic(&html, to_html(&md).as_bytes())?;
    Ok(Written { figures, markdown, html, stats: d.stats })
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// The Markdown page as HTML (only the constructs `write` produces: headings, tables, images,
/// paragraphs).
fn to_html(md: &str) -> String {
    let mut h = String::from(
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>subnav report</title><style>body{font-family:sans-serif;max-width:1000px;margin:auto}img{max-width:100%}table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 8px}</style></head><body>\n",
    );
    let mut in_table = false;
    for line in md.lines() {
        if line.starts_with('|') {
            if line.starts_with("|---") {
                continue;
            }
            if !in_table {
                h.push_str("<table>\n");
                in_table = true;
            }
            let cells: Vec<String> = line.trim_matches('|').split('|').map(|c| format!("<td>{}</td>", esc(c.trim()))).collect();
            let _ = writeln!(h, "<tr>{}</tr>", cells.join(""));
            continue;
        }
        if in_table {
            h.push_str("</table>\n");
            in_table = false;
        }
        if let Some(t) = line.strip_prefix("## ") {
            let _ = writeln!(h, "<h2>{}</h2>", esc(t));
        } else if let Some(t) = line.strip_prefix("# ") {
            let _ = writeln!(h, "<h1>{}</h1>", esc(t));
        } else if let Some(rest) = line.strip_prefix("![") {
            let (alt, src) = rest.split_once("](").unwrap_or((rest, ""));
            let _ = writeln!(h, "<img alt=\"{}\" src=\"{}\">", esc(alt), esc(src.trim_end_matches(')')));
        } else if !line.trim().is_empty() {
            let _ = writeln!(h, "<p>{}</p>", esc(line));
        }
    }
    if in_table {
        h.push_str("</table>\n");
    }
    h.push_str("</body></html>\n");
    h
}
