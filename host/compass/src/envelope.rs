//! The compass's operating envelope: the moving-sea Monte Carlo ([`crate::montecarlo`] with a
//! [`SeaRun`]) over depth x wind x turbidity x sky, one cell each, and its Markdown table.

use std::collections::BTreeMap;

use serde::Serialize;
use subnav_base::sky::SkyKind;

use crate::montecarlo::{self, McConfig, SeaRun};

#[derive(Debug, Clone)]
pub struct EnvelopeConfig {
    pub depths_m: Vec<f64>,
    pub winds_mps: Vec<f64>,
    pub turbidities: Vec<f64>,
    pub skies: Vec<SkyKind>,
    /// Scored attempts per cell (sessions of [`SeaRun::scored`]).
    pub draws_per_cell: usize,
    pub units: usize,
    pub seed: u64,
}

impl Default for EnvelopeConfig {
    fn default() -> Self {
        EnvelopeConfig {
            depths_m: vec![2.0, 5.0, 10.0, 20.0, 40.0],
            winds_mps: vec![0.0, 3.0, 6.0, 9.0, 12.0],
            turbidities: vec![1.0, 3.0],
            skies: SkyKind::ALL.to_vec(),
            draws_per_cell: 100,
            units: subnav_core::head::POLARIZATION_UNITS,
            seed: 1,
        }
    }
}

/// One cell of the envelope.
#[derive(Debug, Clone, Serialize)]
pub struct Cell {
    pub depth_m: f64,
    pub wind_mps: f64,
    pub turbidity: f64,
    pub sky: String,
    pub draws: usize,
    pub fixes: usize,
    pub rmse_deg: f64,
    pub within_2_sigma: f64,
    pub rms_reported_sigma_deg: f64,
    pub no_fix: BTreeMap<String, usize>,
}

impl Cell {
    pub fn fix_rate(&self) -> f64 {
        self.fixes as f64 / self.draws.max(1) as f64
    }
}

/// Runs every cell; `progress(done, total)` after each.
pub fn run(cfg: &EnvelopeConfig, mut progress: impl FnMut(usize, usize)) -> Vec<Cell> {
    let total = cfg.depths_m.len() * cfg.winds_mps.len() * cfg.turbidities.len() * cfg.skies.len();
    let mut out = Vec::with_capacity(total);
    let mut i = 0u64;
    for &sky in &cfg.skies {
        for &turbidity in &cfg.turbidities {
            for &depth_m in &cfg.depths_m {
                for &wind in &cfg.winds_mps {
                    i += 1;
                    let mc = McConfig {
                        draws: cfg.draws_per_cell,
                        depth_m,
                        units: cfg.units,
                        water: montecarlo::turbid_water(turbidity),
                        seed: cfg.seed.wrapping_mul(1_000_003).wrapping_add(i),
                        sea: Some(SeaRun::new(wind, sky)),
                        ..McConfig::default()
                    };
                    let r = montecarlo::run(&mc);
                    out.push(Cell {
                        depth_m,
                        wind_mps: wind,
                        turbidity,
                        sky: sky.name().to_string(),
                        draws: r.draws,
                        fixes: r.fixes,
                        rmse_deg: r.rmse_deg,
                        within_2_sigma: r.within_2_sigma,
                        rms_reported_sigma_deg: r.rms_reported_sigma_deg,
                        no_fix: r.no_fix,
                    });
                    progress(out.len(), total);
                }
            }
        }
    }
    out
}

/// The table behind the figure (Markdown): one row per sky, turbidity and depth; per wind the
/// RMSE, the fraction within 2 reported sigma and the fix rate; cells without a fix give the
/// most frequent reason.
pub fn markdown_table(cells: &[Cell], winds: &[f64]) -> String {
    let mut s = String::from("| sky | turbidity | depth (m) |");
    for w in winds {
        s += &format!(" {w} m/s |");
    }
    s += "\n|---|---:|---:|";
    for _ in winds {
        s += "---|";
    }
    s += "\n";
    let mut rows: Vec<(String, f64, f64)> = Vec::new();
    for c in cells {
        let key = (c.sky.clone(), c.turbidity, c.depth_m);
        if !rows.contains(&key) {
            rows.push(key);
        }
    }
    for (sky, turb, depth) in rows {
        s += &format!("| {sky} | {turb} | {depth} |");
        for w in winds {
            let cell = cells.iter().find(|c| c.sky == sky && c.turbidity == turb && c.depth_m == depth && c.wind_mps == *w);
            s += &match cell {
                Some(c) if c.fixes > 0 => {
                    format!(" {:.2} deg, {:.0} % in 2σ, {:.0} % fixes |", c.rmse_deg, 100.0 * c.within_2_sigma, 100.0 * c.fix_rate())
                }
                Some(c) => {
                    let why = c.no_fix.iter().max_by_key(|(_, n)| **n).map_or("-", |(k, _)| k.as_str());
                    format!(" no fix ({why}) |")
                }
                None => " |".to_string(),
            };
        }
        s += "\n";
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A two-cell envelope: more wind, larger error; the table has every cell.
    #[test]
    fn small_envelope() {
        let cfg = EnvelopeConfig {
            depths_m: vec![5.0],
            winds_mps: vec![0.0, 10.0],
            turbidities: vec![1.0],
            skies: vec![SkyKind::Clear],
            draws_per_cell: 20,
            ..EnvelopeConfig::default()
        };
        let mut calls = 0;
        let cells = run(&cfg, |_, _| calls += 1);
        assert_eq!((cells.len(), calls), (2, 2));
        assert!(cells[1].rmse_deg > cells[0].rmse_deg, "{cells:?}");
        let t = markdown_table(&cells, &cfg.winds_mps);
        assert!(t.contains("| clear | 1 | 5 |") && t.contains("10 m/s"), "{t}");
    }
}
