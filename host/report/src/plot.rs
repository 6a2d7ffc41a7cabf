//! The report's figures with plotters, PNG (bitmap backend) or SVG by file extension. PNG text
//! needs a TrueType font, looked up at run time (`SUBNAV_FONT`, then DejaVu/Liberation paths);
//! without one, figures are drawn without text rather than failing (plotters measures SVG text
//! with the same font, so SVG needs it too: without one, the SVG backend failed every figure).
//!
//! A figure is drawn under a temporary name beside its target (`.NAME.tmp-PID.EXT`: the
//! backend picks the format by extension) and renamed on success, so a failed draw (a full
//! disk) leaves neither a truncated figure nor a temporary file.

use std::ops::Range;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow};
use plotters::coord::Shift;
use plotters::prelude::*;

use super::ReportData;

type Draw = fn(&ReportData, &Path) -> Result<bool>;

/// (file stem, caption, drawing function); a function returns false when it has nothing to draw.
pub const FIGURES: [(&str, &str, Draw); 5] = [
    (
        "trajectory",
        "Horizontal track, north up: estimate (blue) and truth (black); with the map in the loop, its nodes (grey) and the loop closures the head accepted (red: from the head's estimate at the image's time to the node it recognised).",
        trajectory,
    ),
    ("heading", "Heading estimate and truth (top); heading error with its 3-sigma bound (bottom, when truth exists).", heading),
    ("position_error", "Position error per NED axis with the 3-sigma bounds (3-sigma alone without truth).", position_error),
    ("health", "Filter health: fading factor lambda, NIS per update kind, process (Q) and measurement (R) noise diagonals.", health),
    ("faults", "Sensor and link faults over time (one row per source/kind).", faults),
];

pub use subnav_base::plot::font_ok;

fn err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("plotting: {e}")
}

/// The temporary name a figure is drawn under: beside it, hidden, same extension.
fn temp_beside(path: &Path) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let ext = path.extension().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{stem}.tmp-{}.{ext}", std::process::id()))
}

/// Rename the drawn temporary to the figure's name, or remove it after a failed draw.
fn finish_figure(path: &Path, tmp: &Path, drawn: Result<()>) -> Result<()> {
    match drawn {
        Ok(()) => std::fs::rename(tmp, path).with_context(|| format!("moving the figure into place as {}", path.display())),
        Err(e) => {
            let _ = std::fs::remove_file(tmp);
            Err(e.context(format!("drawing {}", path.display())))
        }
    }
}

/// Run `f` on a PNG or SVG drawing area chosen by the file extension.
macro_rules! with_area {
    ($path:expr, $size:expr, $f:expr) => {{
        let path: &Path = $path;
        let tmp = temp_beside(path);
        let is_svg = path.extension().is_some_and(|e| e == "svg");
        let text = font_ok();
        let drawn: Result<()> = if is_svg {
            let root = SVGBackend::new(&tmp, $size).into_drawing_area();
            $f(&root, text).and_then(|()| root.present().map_err(err))
        } else {
            let root = BitMapBackend::new(&tmp, $size).into_drawing_area();
            $f(&root, text).and_then(|()| root.present().map_err(err))
        };
        finish_figure(path, &tmp, drawn)?;
        Ok(true)
    }};
}

fn range(vals: impl Iterator<Item = f64>, pad: f64) -> Range<f64> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in vals.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return 0.0..1.0;
    }
    let span = (hi - lo).max(1e-6);
    (lo - pad * span)..(hi + pad * span)
}

fn time_range(d: &ReportData) -> Range<f64> {
    range(d.nav.iter().map(|p| p.t_s).chain(d.health.iter().map(|h| h.t_s)).chain(d.faults.iter().map(|f| f.t_s)), 0.0)
}

/// A line chart of several series over time in `area`.
fn series_chart<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    text: bool,
    title: &str,
    y_label: &str,
    x: Range<f64>,
    series: &[(&str, RGBColor, Vec<(f64, f64)>)],
    log_y: bool,
) -> Result<()> {
    let all = series.iter().flat_map(|s| s.2.iter().map(|p| p.1)).filter(|v| !log_y || *v > 0.0);
    let mut b = ChartBuilder::on(area);
    b.margin(8).x_label_area_size(if text { 30 } else { 0 }).y_label_area_size(if text { 60 } else { 0 });
    if text {
        b.caption(title, ("sans-serif", 18));
    }
    if log_y {
        let r = range(all, 0.0);
        let (lo, hi) = (r.start.max(1e-12), r.end.max(r.start.max(1e-12) * 10.0));
        let mut c = b.build_cartesian_2d(x, (lo * 0.5..hi * 2.0).log_scale()).map_err(err)?;
        c.configure_mesh().x_desc("t (s)").y_desc(y_label).y_label_formatter(&|v: &f64| format!("{v:.0e}")).draw().map_err(err)?;
        for (name, col, pts) in series {
            let s = c
                .draw_series(LineSeries::new(pts.iter().copied().filter(|p| p.1 > 0.0 && p.1.is_finite()), col.stroke_width(2)))
                .map_err(err)?;
            if text {
                let col = *col;
                s.label(*name).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], col.stroke_width(2)));
            }
        }
        if text {
            c.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(err)?;
        }
    } else {
        let mut c = b.build_cartesian_2d(x, range(all, 0.08)).map_err(err)?;
        let mut m = c.configure_mesh();
        m.x_desc("t (s)").y_desc(y_label).draw().map_err(err)?;
        for (name, col, pts) in series {
            let s = c.draw_series(LineSeries::new(pts.iter().copied().filter(|p| p.1.is_finite()), col.stroke_width(2))).map_err(err)?;
            if text {
                let col = *col;
                s.label(*name).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], col.stroke_width(2)));
            }
        }
        if text {
            c.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(err)?;
        }
    }
    Ok(())
}

const EST: RGBColor = RGBColor(31, 119, 180);
const BOUND: RGBColor = RGBColor(214, 39, 40);
const COLS: [RGBColor; 5] =
    [RGBColor(31, 119, 180), RGBColor(255, 127, 14), RGBColor(44, 160, 44), RGBColor(148, 103, 189), RGBColor(140, 86, 75)];

fn trajectory(d: &ReportData, path: &Path) -> Result<bool> {
    if d.nav.is_empty() {
        return Ok(false);
    }
    with_area!(path, (900, 800), |root: &DrawingArea<_, Shift>, text: bool| -> Result<()> {
        root.fill(&WHITE).map_err(err)?;
        let east = d.nav.iter().map(|p| p.pos_ned_m[1]).chain(d.truth.iter().map(|t| t.pos_ned_m[1]));
        let north = d.nav.iter().map(|p| p.pos_ned_m[0]).chain(d.truth.iter().map(|t| t.pos_ned_m[0]));
        let (xr, yr) = (range(east, 0.05), range(north, 0.05));
        // Equal scale on both axes.
        let half = ((xr.end - xr.start).max(yr.end - yr.start)) / 2.0;
        let (cx, cy) = ((xr.start + xr.end) / 2.0, (yr.start + yr.end) / 2.0);
        let mut b = ChartBuilder::on(root);
        b.margin(10).x_label_area_size(if text { 40 } else { 0 }).y_label_area_size(if text { 60 } else { 0 });
        if text {
            b.caption("Trajectory (NED, north up)", ("sans-serif", 22));
        }
        let mut c = b.build_cartesian_2d(cx - half..cx + half, cy - half..cy + half).map_err(err)?;
        c.configure_mesh().x_desc("east (m)").y_desc("north (m)").draw().map_err(err)?;
        if !d.truth.is_empty() {
            let s = c
                .draw_series(LineSeries::new(d.truth.iter().map(|t| (t.pos_ned_m[1], t.pos_ned_m[0])), BLACK.stroke_width(2)))
                .map_err(err)?;
            if text {
                s.label("truth").legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.stroke_width(2)));
            }
        }
        let s = c.draw_series(LineSeries::new(d.nav.iter().map(|p| (p.pos_ned_m[1], p.pos_ned_m[0])), EST.stroke_width(2))).map_err(err)?;
        if text {
            s.label("estimate").legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], EST.stroke_width(2)));
        }
        if !d.map_nodes.is_empty() {
            let node = RGBColor(120, 120, 120);
            let s = c.draw_series(d.map_nodes.iter().map(|n| Circle::new((n[1], n[0]), 3, node.filled()))).map_err(err)?;
            if text {
                s.label(format!("map nodes ({})", d.map_nodes.len())).legend(move |(x, y)| Circle::new((x + 8, y), 3, node.filled()));
            }
        }
        if !d.closures.is_empty() {
            let red = RGBColor(220, 30, 30);
            let s = c
                .draw_series(d.closures.iter().map(|k| {
                    PathElement::new(vec![(k.estimate_ne_m[1], k.estimate_ne_m[0]), (k.node_ne_m[1], k.node_ne_m[0])], red.stroke_width(2))
                }))
                .map_err(err)?;
            if text {
                s.label(format!("accepted loop closures ({})", d.closures.len()))
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], red.stroke_width(2)));
            }
            c.draw_series(d.closures.iter().map(|k| Circle::new((k.node_ne_m[1], k.node_ne_m[0]), 3, red.filled()))).map_err(err)?;
        }
        if let (Some(a), Some(z)) = (d.nav.first(), d.nav.last()) {
            c.draw_series([
                Circle::new((a.pos_ned_m[1], a.pos_ned_m[0]), 6, GREEN.filled()),
                Circle::new((z.pos_ned_m[1], z.pos_ned_m[0]), 6, BOUND.filled()),
            ])
            .map_err(err)?;
        }
        if text {
            c.configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(err)?;
        }
        Ok(())
    })
}

fn heading(d: &ReportData, path: &Path) -> Result<bool> {
    if d.nav.is_empty() {
        return Ok(false);
    }
    let x = time_range(d);
    with_area!(path, (1000, 700), |root: &DrawingArea<_, Shift>, text: bool| -> Result<()> {
        root.fill(&WHITE).map_err(err)?;
        let (top, bottom) = root.split_vertically(350);
        let mut s = vec![("estimate", EST, d.nav.iter().map(|p| (p.t_s, p.yaw_rad.to_degrees())).collect::<Vec<_>>())];
        if !d.truth.is_empty() {
            s.push(("truth", BLACK.into(), d.truth.iter().map(|t| (t.t_s, t.yaw_rad.to_degrees())).collect()));
        }
        series_chart(&top, text, "Heading", "heading (deg)", x.clone(), &s, false)?;
        let sig: Vec<(f64, f64)> = d.nav.iter().map(|p| (p.t_s, 3.0 * p.sigma_yaw_rad.to_degrees())).collect();
        let mut s = vec![("+3 sigma", BOUND, sig.clone()), ("-3 sigma", BOUND, sig.iter().map(|p| (p.0, -p.1)).collect())];
        if !d.errors.is_empty() {
            s.insert(0, ("error", EST, d.errors.iter().map(|e| (e.t_s, e.yaw_err_rad.to_degrees())).collect()));
        }
        let title = if d.errors.is_empty() { "Heading 3-sigma (no truth)" } else { "Heading error" };
        series_chart(&bottom, text, title, "deg", x, &s, false)
    })
}

fn position_error(d: &ReportData, path: &Path) -> Result<bool> {
    if d.nav.is_empty() {
        return Ok(false);
    }
    let x = time_range(d);
    with_area!(path, (1000, 900), |root: &DrawingArea<_, Shift>, text: bool| -> Result<()> {
        root.fill(&WHITE).map_err(err)?;
        for (k, area) in root.split_evenly((3, 1)).iter().enumerate() {
            let axis = ["north", "east", "down"][k];
            let sig: Vec<(f64, f64)> = d.nav.iter().map(|p| (p.t_s, 3.0 * p.sigma_pos_m[k])).collect();
            let mut s = vec![("+3 sigma", BOUND, sig.clone()), ("-3 sigma", BOUND, sig.iter().map(|p| (p.0, -p.1)).collect())];
            if !d.errors.is_empty() {
                s.insert(0, ("error", EST, d.errors.iter().map(|e| (e.t_s, e.pos_err_ned_m[k])).collect()));
            }
            series_chart(area, text, &format!("{axis} position error"), "m", x.clone(), &s, false)?;
        }
        Ok(())
    })
}

fn health(d: &ReportData, path: &Path) -> Result<bool> {
    if d.health.is_empty() {
        return Ok(false);
    }
    let x = time_range(d);
    with_area!(path, (1000, 1000), |root: &DrawingArea<_, Shift>, text: bool| -> Result<()> {
        root.fill(&WHITE).map_err(err)?;
        let areas = root.split_evenly((4, 1));
        let pts = |f: &dyn Fn(&super::HealthPoint) -> f64| d.health.iter().map(|h| (h.t_s, f(h))).collect::<Vec<_>>();
        series_chart(&areas[0], text, "Fading factor lambda", "lambda", x.clone(), &[("lambda", EST, pts(&|h| h.lambda))], false)?;
        let names = subnav_wire::AidSource::ALL.map(|s| s.name());
        let ratio: Vec<_> = (0..4).map(|k| (names[k], COLS[k], pts(&|h| h.test_ratio[k]))).collect();
        series_chart(&areas[1], text, "Test ratio per aid source (NIS / gate; above 1 refused)", "test ratio", x.clone(), &ratio, true)?;
        let qn = ["attitude", "velocity", "position", "gyro bias", "accel bias"];
        let q: Vec<_> = (0..5).map(|k| (qn[k], COLS[k], pts(&|h| h.q_diag[k]))).collect();
        series_chart(&areas[2], text, "Process noise Q (mean diagonal per group)", "Q", x.clone(), &q, true)?;
        let r: Vec<_> = (0..4).map(|k| (names[k], COLS[k], pts(&|h| h.noise_var[k]))).collect();
        series_chart(&areas[3], text, "Measurement noise R", "R", x, &r, true)
    })
}

fn faults(d: &ReportData, path: &Path) -> Result<bool> {
    let mut labels: Vec<&str> = d.faults.iter().map(|f| f.label.as_str()).collect();
    labels.sort_unstable();
    labels.dedup();
    let x = time_range(d);
    let rows = labels.len().max(1);
    with_area!(path, (1000, (160 + 40 * rows) as u32), |root: &DrawingArea<_, Shift>, text: bool| -> Result<()> {
        root.fill(&WHITE).map_err(err)?;
        let mut b = ChartBuilder::on(root);
        b.margin(10).x_label_area_size(if text { 35 } else { 0 }).y_label_area_size(if text { 260 } else { 0 });
        if text {
            b.caption(if labels.is_empty() { "Faults: none" } else { "Faults" }, ("sans-serif", 20));
        }
        let mut c = b.build_cartesian_2d(x, -0.5..(rows as f64 - 0.5)).map_err(err)?;
        let lab = labels.clone();
        c.configure_mesh()
            .x_desc("t (s)")
            .y_labels(rows)
            .y_label_formatter(&move |v: &f64| lab.get(v.round().max(0.0) as usize).map(|s| s.to_string()).unwrap_or_default())
            .draw()
            .map_err(err)?;
        c.draw_series(d.faults.iter().filter_map(|f| {
            let row = labels.iter().position(|l| *l == f.label)?;
            Some(Cross::new((f.t_s, row as f64), 6, BOUND.stroke_width(2)))
        }))
        .map_err(err)?;
        Ok(())
    })
}
