//! PNG figures with plotters: gridded bathymetry before/after correction with the tracks, and
//! histograms of the sounding position error. Text needs a TrueType font; one is looked up at
//! run time (DejaVu/Liberation paths or `SUBNAV_FONT`), and without one the figures are drawn
//! without captions and axis labels rather than failing.

use super::grid::Grid;
use super::{NavSample, V2};
use anyhow::{Result, anyhow};
use plotters::prelude::*;
use std::path::Path;

use subnav_base::plot::font_ok;

fn err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("plotting: {e:?}")
}

/// Colour map (depth -> colour), shallow = yellow, deep = dark blue (viridis-like, 5 stops).
fn colour(t: f64) -> RGBColor {
    let stops = [(68.0, 1.0, 84.0), (59.0, 82.0, 139.0), (33.0, 145.0, 140.0), (94.0, 201.0, 98.0), (253.0, 231.0, 37.0)];
    let t = (1.0 - t.clamp(0.0, 1.0)) * 4.0;
    let k = (t.floor() as usize).min(3);
    let f = t - k as f64;
    let (a, b) = (stops[k], stops[k + 1]);
    RGBColor((a.0 + f * (b.0 - a.0)) as u8, (a.1 + f * (b.1 - a.1)) as u8, (a.2 + f * (b.2 - a.2)) as u8)
}

/// Side-by-side maps (east right, north up), each a grid plus tracks (label, colour, poses).
pub fn maps(path: &Path, panels: &[(&str, &Grid, Vec<(&str, RGBColor, &[NavSample])>)]) -> Result<()> {
    let text = font_ok();
    let (w, h) = (720 * panels.len() as u32, 760);
    let root = BitMapBackend::new(path, (w, h)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let areas = root.split_evenly((1, panels.len()));
    // Common colour scale (5th..95th percentile of all depths).
    let mut all: Vec<f64> = panels.iter().flat_map(|p| p.1.data.iter().copied().filter(|v| v.is_finite())).collect();
    all.sort_by(f64::total_cmp);
    let (lo, hi) = if all.is_empty() { (0.0, 1.0) } else { (all[all.len() / 20], all[all.len() * 19 / 20]) };
    for (area, (title, g, tracks)) in areas.iter().zip(panels) {
        let (n0, e0) = (g.north0_m - 0.5 * g.cell_m, g.east0_m - 0.5 * g.cell_m);
        let (n1, e1) = (n0 + g.rows as f64 * g.cell_m, e0 + g.cols as f64 * g.cell_m);
        let mut b = ChartBuilder::on(area);
        b.margin(10);
        if text {
            b.caption(*title, ("sans-serif", 22)).x_label_area_size(40).y_label_area_size(55);
        }
        let mut chart = b.build_cartesian_2d(e0..e1, n0..n1).map_err(err)?;
        if text {
            chart.configure_mesh().disable_mesh().x_desc("east (m)").y_desc("north (m)").draw().map_err(err)?;
        }
        // Draw at most ~250 x 250 rectangles: downsample big grids.
        let f = (g.rows.max(g.cols) / 250).max(1);
        let gd: Grid = if f > 1 { g.downsample(f) } else { (*g).clone() };
        let hc = 0.5 * gd.cell_m;
        chart
            .draw_series((0..gd.rows).flat_map(|r| (0..gd.cols).map(move |c| (r, c))).filter_map(|(r, c)| {
                let v = gd.get(r, c);
                if !v.is_finite() {
                    return None;
                }
                let (n, e) = gd.centre(r, c);
                let col = colour((v - lo) / (hi - lo).max(1e-9));
                Some(Rectangle::new([(e - hc, n - hc), (e + hc, n + hc)], col.filled()))
            }))
            .map_err(err)?;
        for (label, col, nav) in tracks {
            let s = chart.draw_series(LineSeries::new(nav.iter().map(|n| (n.east_m, n.north_m)), col.stroke_width(2))).map_err(err)?;
            if text {
                let c = *col;
                s.label(*label).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2)));
            }
        }
        if text && !tracks.is_empty() {
            chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(err)?;
        }
    }
    root.present().map_err(err)?;
    Ok(())
}

/// One histogram panel per error set (label, errors in m), shared bins.
pub fn error_histograms(path: &Path, sets: &[(&str, &[f64])]) -> Result<()> {
    let text = font_ok();
    let root = BitMapBackend::new(path, (520 * sets.len() as u32, 420)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let areas = root.split_evenly((1, sets.len()));
    let mut all: Vec<f64> = sets.iter().flat_map(|s| s.1.iter().copied().filter(|v| v.is_finite())).collect();
    all.sort_by(f64::total_cmp);
    let xmax = all.get(all.len().saturating_sub(1) * 99 / 100).copied().unwrap_or(1.0).max(1e-3);
    let bins = 60usize;
    let bw = xmax / bins as f64;
    for (area, (label, v)) in areas.iter().zip(sets) {
        let mut counts = vec![0usize; bins];
        for x in v.iter().filter(|x| x.is_finite()) {
            let k = ((x / bw) as usize).min(bins - 1);
            counts[k] += 1;
        }
        let total = v.len().max(1) as f64;
        let ymax = counts.iter().map(|c| *c as f64 / total).fold(0.0, f64::max).max(1e-6) * 1.1;
        let mut b = ChartBuilder::on(area);
        b.margin(10);
        if text {
            let mean = v.iter().sum::<f64>() / total;
            b.caption(format!("{label}: mean {mean:.2} m"), ("sans-serif", 20)).x_label_area_size(40).y_label_area_size(55);
        }
        let mut chart = b.build_cartesian_2d(0.0..xmax, 0.0..ymax).map_err(err)?;
        if text {
            chart.configure_mesh().x_desc("sounding position error (m)").y_desc("fraction").draw().map_err(err)?;
        }
        chart
            .draw_series(
                counts
                    .iter()
                    .enumerate()
                    .map(|(k, c)| Rectangle::new([(k as f64 * bw, 0.0), ((k + 1) as f64 * bw, *c as f64 / total)], BLUE.mix(0.6).filled())),
            )
            .map_err(err)?;
    }
    root.present().map_err(err)?;
    Ok(())
}

/// Navigation error against time for several offset sets.
pub fn nav_error_over_time(path: &Path, t_s: &[f64], series: &[(&str, RGBColor, Vec<f64>)], keys_t: &[f64]) -> Result<()> {
    let text = font_ok();
    let root = BitMapBackend::new(path, (1000, 420)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let tmax = t_s.last().copied().unwrap_or(1.0).max(1.0);
    let ymax = series.iter().flat_map(|s| s.2.iter().copied()).fold(0.0, f64::max).max(1e-3) * 1.05;
    let mut b = ChartBuilder::on(&root);
    b.margin(10);
    if text {
        b.caption("horizontal navigation error", ("sans-serif", 20)).x_label_area_size(40).y_label_area_size(55);
    }
    let mut chart = b.build_cartesian_2d(0.0..tmax, 0.0..ymax).map_err(err)?;
    if text {
        chart.configure_mesh().x_desc("time (s)").y_desc("error (m)").draw().map_err(err)?;
    }
    for &t in keys_t {
        chart.draw_series(std::iter::once(PathElement::new(vec![(t, 0.0), (t, ymax * 0.03)], BLACK.mix(0.5)))).map_err(err)?;
    }
    for (label, col, v) in series {
        let s = chart.draw_series(LineSeries::new(t_s.iter().copied().zip(v.iter().copied()), col.stroke_width(2))).map_err(err)?;
        if text {
            let c = *col;
            s.label(*label).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2)));
        }
    }
    if text {
        chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(err)?;
    }
    root.present().map_err(err)?;
    Ok(())
}

/// Offsets as horizontal vectors, for callers that want norms.
pub fn norms(v: &[V2]) -> Vec<f64> {
    v.iter().map(|x| x.norm()).collect()
}
