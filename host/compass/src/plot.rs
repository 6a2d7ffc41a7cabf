//! The compass's figures (plotters; text with the font `subnav_base::plot` finds, none
//! without one): the operating envelope's panels (`subnav compass envelope --png`).

use std::path::Path;

use anyhow::{Result, bail};
use plotters::prelude::*;

use crate::envelope::{Cell, EnvelopeConfig};

/// Two rows of panels, one column per sunlit sky and turbidity: heading RMSE (log scale) and
/// the fraction within 2 reported sigma against wind, one line per depth. Skies without a
/// fix anywhere (overcast, twilight) are in the table only.
pub fn envelope_png(path: &Path, cells: &[Cell], cfg: &EnvelopeConfig) -> Result<()> {
    let text = subnav_base::plot::font_ok();
    let err = |e: &dyn std::fmt::Display| anyhow::anyhow!("plotting: {e}");
    let mut panels: Vec<(String, f64)> = Vec::new();
    for c in cells.iter().filter(|c| c.fixes > 0) {
        let key = (c.sky.clone(), c.turbidity);
        if !panels.contains(&key) {
            panels.push(key);
        }
    }
    if panels.is_empty() {
        bail!("no cell of the envelope has a fix: nothing to draw");
    }
    let w_max = cfg.winds_mps.iter().copied().fold(0.0, f64::max).max(1.0);
    let cols = [RGBColor(31, 119, 180), RGBColor(255, 127, 14), RGBColor(44, 160, 44), RGBColor(214, 39, 40), RGBColor(148, 103, 189)];
    let root = BitMapBackend::new(path, (420 * panels.len() as u32, 760)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let areas = root.split_evenly((2, panels.len()));
    for (j, (sky, turb)) in panels.iter().enumerate() {
        for row in 0..2 {
            let area = &areas[row * panels.len() + j];
            let mut b = ChartBuilder::on(area);
            b.margin(10).x_label_area_size(if text { 35 } else { 0 }).y_label_area_size(if text { 55 } else { 0 });
            if text {
                b.caption(format!("{sky}, turbidity {turb}"), ("sans-serif", 18));
            }
            let series = |d: f64| -> Vec<(f64, f64)> {
                cells
                    .iter()
                    .filter(|c| &c.sky == sky && c.turbidity == *turb && c.depth_m == d && c.fixes > 0)
                    .map(|c| (c.wind_mps, if row == 0 { c.rmse_deg.max(1e-3) } else { 100.0 * c.within_2_sigma }))
                    .collect()
            };
            if row == 0 {
                let mut ch = b.build_cartesian_2d(0.0..w_max, (0.02f64..20.0).log_scale()).map_err(|e| err(&e))?;
                if text {
                    ch.configure_mesh().x_desc("wind (m/s)").y_desc("heading RMSE (deg)").draw().map_err(|e| err(&e))?;
                }
                for (k, d) in cfg.depths_m.iter().enumerate() {
                    let col = cols[k % cols.len()];
                    let s = ch.draw_series(LineSeries::new(series(*d), col.stroke_width(2))).map_err(|e| err(&e))?;
                    if text {
                        s.label(format!("{d} m")).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], col.stroke_width(2)));
                    }
                }
                if text {
                    ch.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(|e| err(&e))?;
                }
            } else {
                let mut ch = b.build_cartesian_2d(0.0..w_max, 50.0f64..100.0).map_err(|e| err(&e))?;
                if text {
                    ch.configure_mesh().x_desc("wind (m/s)").y_desc("% within 2 reported sigma").draw().map_err(|e| err(&e))?;
                }
                ch.draw_series(LineSeries::new([(0.0, 95.4), (w_max, 95.4)], BLACK.mix(0.4))).map_err(|e| err(&e))?;
                for (k, d) in cfg.depths_m.iter().enumerate() {
                    let col = cols[k % cols.len()];
                    ch.draw_series(LineSeries::new(series(*d).into_iter().map(|(x, y)| (x, y.max(50.0))), col.stroke_width(2)))
                        .map_err(|e| err(&e))?;
                }
            }
        }
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}
