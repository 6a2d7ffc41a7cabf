//! Submaps (spec C1): the path is cut into pieces by path length and by terrain information,
//! measured with the difference of normals (DoN = (n(r1) - n(r2)) / 2, r1 < r2). A submap is
//! closed once it holds enough information (cumulative swath DoN >= `info_target`, but at least
//! `min_len_m` of path) or at `max_len_m`. Each submap keeps its soundings gridded in the
//! dead-reckoning frame and a keyframe (its middle ping).

use super::grid::Grid;
use super::{Point, V2};

#[derive(Debug, Clone, serde::Serialize)]
pub struct SubmapConfig {
    pub cell_m: f64,
    pub min_len_m: f64,
    pub max_len_m: f64,
    /// Cumulative per-swath mean DoN (sum over pings) that closes a submap early.
    pub info_target: f64,
    pub r1_m: f64,
    pub r2_m: f64,
}

impl SubmapConfig {
    /// Defaults scaled by the survey altitude (swath ~10x altitude).
    pub fn for_altitude(alt_m: f64) -> Self {
        Self {
            cell_m: (alt_m / 10.0).max(0.5),
            min_len_m: 4.0 * alt_m,
            max_len_m: 10.0 * alt_m,
            info_target: 4.0,
            r1_m: alt_m / 10.0,
            r2_m: alt_m / 2.5,
        }
    }
}

#[derive(Debug, Clone)]
pub struct Submap {
    pub first_ping: usize,
    /// Inclusive.
    pub last_ping: usize,
    pub key_ping: usize,
    pub key_dr: V2,
    pub path_len_m: f64,
    /// Cumulative swath DoN of the submap.
    pub info: f64,
    /// Soundings gridded in the dead-reckoning frame.
    pub grid: Grid,
}

/// Unit normal (in the profile plane) of a line with slope `s`.
fn normal2(s: f64) -> (f64, f64) {
    let k = (1.0 + s * s).sqrt();
    (-s / k, 1.0 / k)
}

/// DoN of a 1-D profile (x sorted ascending) at each sample: the normals of the chords joining
/// the profile at x-r and x+r, for r1 and r2; NaN where the chord leaves the profile.
pub fn profile_don(x: &[f64], d: &[f64], r1: f64, r2: f64) -> Vec<f64> {
    let interp = |q: f64| -> Option<f64> {
        if x.is_empty() || q < x[0] || q > x[x.len() - 1] {
            return None;
        }
        let k = x.partition_point(|v| *v < q);
        if k == 0 {
            return Some(d[0]);
        }
        let (x0, x1) = (x[k - 1], x[k]);
        if x1 - x0 <= 0.0 {
            return Some(d[k]);
        }
        Some(d[k - 1] + (d[k] - d[k - 1]) * (q - x0) / (x1 - x0))
    };
    x.iter()
        .map(|&xi| {
            let s = |r: f64| Some((interp(xi + r)? - interp(xi - r)?) / (2.0 * r));
            match (s(r1), s(r2)) {
                (Some(a), Some(b)) => {
                    let (n1, n2) = (normal2(a), normal2(b));
                    0.5 * ((n1.0 - n2.0).powi(2) + (n1.1 - n2.1).powi(2)).sqrt()
                }
                _ => f64::NAN,
            }
        })
        .collect()
}

/// Mean DoN of one swath given its beams' across-track offsets and depths.
pub fn swath_info(across_m: &[f64], depth_m: &[f64], r1: f64, r2: f64) -> f64 {
    let mut idx: Vec<usize> = (0..across_m.len()).filter(|&k| across_m[k].is_finite() && depth_m[k].is_finite()).collect();
    idx.sort_by(|a, b| across_m[*a].total_cmp(&across_m[*b]));
    let x: Vec<f64> = idx.iter().map(|&k| across_m[k]).collect();
    let d: Vec<f64> = idx.iter().map(|&k| depth_m[k]).collect();
    let v: Vec<f64> = profile_don(&x, &d, r1, r2).into_iter().filter(|v| v.is_finite()).collect();
    if v.is_empty() { 0.0 } else { v.iter().sum::<f64>() / v.len() as f64 }
}

/// DoN magnitude of a grid at each cell (3-D normals from chords at r1 and r2 cells along north
/// and east); NaN where a chord end is empty.
pub fn grid_don(g: &Grid, r1_cells: usize, r2_cells: usize) -> Vec<f64> {
    let mut out = vec![f64::NAN; g.data.len()];
    let normal = |r: usize, c: usize, k: usize| -> Option<[f64; 3]> {
        if r < k || c < k {
            return None;
        }
        let sn = (g.get(r + k, c) - g.get(r - k, c)) / (2.0 * k as f64 * g.cell_m);
        let se = (g.get(r, c + k) - g.get(r, c - k)) / (2.0 * k as f64 * g.cell_m);
        if !(sn.is_finite() && se.is_finite()) {
            return None;
        }
        let m = (1.0 + sn * sn + se * se).sqrt();
        Some([-sn / m, -se / m, 1.0 / m])
    };
    for r in 0..g.rows {
        for c in 0..g.cols {
            if let (Some(a), Some(b)) = (normal(r, c, r1_cells), normal(r, c, r2_cells)) {
                out[r * g.cols + c] = 0.5 * ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
            }
        }
    }
    out
}

/// Per-ping swath information (mean profile DoN); `points[i]` are ping i's soundings and
/// `pos[i]`/`heading[i]` its pose.
pub fn ping_info(points: &[Vec<Point>], pos: &[V2], heading: &[f64], cfg: &SubmapConfig) -> Vec<f64> {
    points
        .iter()
        .zip(pos)
        .zip(heading)
        .map(|((pts, p), h)| {
            let stbd = V2::new(-h.sin(), h.cos());
            let across: Vec<f64> = pts.iter().map(|q| (V2::new(q.north_m, q.east_m) - p).dot(&stbd)).collect();
            let depth: Vec<f64> = pts.iter().map(|q| q.depth_m).collect();
            swath_info(&across, &depth, cfg.r1_m, cfg.r2_m)
        })
        .collect()
}

/// Cut the survey into submaps. `points` are the dead-reckoned soundings per ping.
pub fn build(points: &[Vec<Point>], pos: &[V2], heading: &[f64], cfg: &SubmapConfig) -> Vec<Submap> {
    let info = ping_info(points, pos, heading, cfg);
    let mut out = vec![];
    let mut start = 0usize;
    let (mut len, mut acc) = (0.0, 0.0);
    let n = points.len();
    for i in 0..n {
        if i > start {
            len += (pos[i] - pos[i - 1]).norm();
        }
        acc += info[i];
        let close = i + 1 == n || len >= cfg.max_len_m || (len >= cfg.min_len_m && acc >= cfg.info_target);
        if close {
            // Keyframe: the ping at half the path length.
            let mut k = start;
            let mut l = 0.0;
            while k < i && l < 0.5 * len {
                l += (pos[k + 1] - pos[k]).norm();
                k += 1;
            }
            let pts: Vec<Point> = points[start..=i].iter().flatten().copied().collect();
            if let Some(grid) = Grid::from_points(&pts, cfg.cell_m, 2) {
                out.push(Submap { first_ping: start, last_ping: i, key_ping: k, key_dr: pos[k], path_len_m: len, info: acc, grid });
            }
            start = i + 1;
            len = 0.0;
            acc = 0.0;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn don_is_zero_on_planes_and_analytic_on_a_sinusoid() {
        let x: Vec<f64> = (0..400).map(|i| i as f64 * 0.25).collect();
        let plane: Vec<f64> = x.iter().map(|v| 3.0 + 0.4 * v).collect();
        assert!(profile_don(&x, &plane, 1.0, 4.0).iter().filter(|v| v.is_finite()).all(|v| v.abs() < 1e-12));
        // d = A sin(k x): chord slope at radius r is A k cos(k x) sin(k r)/(k r).
        let (a, k) = (2.0, 0.3);
        let d: Vec<f64> = x.iter().map(|v| a * (k * v).sin()).collect();
        let (r1, r2) = (1.0, 4.0);
        let don = profile_don(&x, &d, r1, r2);
        let mut checked = 0;
        for (i, &xi) in x.iter().enumerate() {
            if !don[i].is_finite() {
                continue;
            }
            let s1 = a * (k * xi).cos() * (k * r1).sin() / r1;
            let s2 = a * (k * xi).cos() * (k * r2).sin() / r2;
            let (n1, n2) = (normal2(s1), normal2(s2));
            let want = 0.5 * ((n1.0 - n2.0).powi(2) + (n1.1 - n2.1).powi(2)).sqrt();
            // Linear interpolation between 0.25 m samples: small error only.
            assert!((don[i] - want).abs() < 2e-3, "x {xi}: {} vs {want}", don[i]);
            checked += 1;
        }
        assert!(checked > 300);
        // 2-D: plane -> 0, rough -> > 0.
        let mut g = Grid::new_empty(0.0, 0.0, 1.0, 30, 30);
        for r in 0..30 {
            for c in 0..30 {
                g.data[r * 30 + c] = 10.0 + 0.2 * r as f64 - 0.1 * c as f64;
            }
        }
        assert!(grid_don(&g, 1, 4).iter().filter(|v| v.is_finite()).all(|v| v.abs() < 1e-12));
        for r in 0..30 {
            for c in 0..30 {
                g.data[r * 30 + c] += ((r * 7 + c * 3) as f64).sin();
            }
        }
        let m: Vec<f64> = grid_don(&g, 1, 4).into_iter().filter(|v| v.is_finite()).collect();
        assert!(m.iter().sum::<f64>() / m.len() as f64 > 0.05);
    }

    #[test]
    fn submaps_cover_every_ping_once_and_rugged_terrain_gives_shorter_submaps() {
        // A straight track; the swath is flat for the first half, rugged for the second.
        let n = 400;
        let pos: Vec<V2> = (0..n).map(|i| V2::new(i as f64, 0.0)).collect();
        let heading = vec![0.0; n];
        let points: Vec<Vec<Point>> = (0..n)
            .map(|i| {
                (-40..=40)
                    .map(|k| {
                        let e = k as f64;
                        let rough = if i >= n / 2 { 2.0 * (0.7 * e).sin() * (0.3 * i as f64).cos() } else { 0.0 };
                        Point { north_m: i as f64, east_m: e, depth_m: 30.0 + rough }
                    })
                    .collect()
            })
            .collect();
        let cfg = SubmapConfig { cell_m: 1.0, min_len_m: 20.0, max_len_m: 80.0, info_target: 4.0, r1_m: 1.0, r2_m: 4.0 };
        let maps = build(&points, &pos, &heading, &cfg);
        let mut next = 0;
        for m in &maps {
            assert_eq!(m.first_ping, next);
            assert!(m.key_ping >= m.first_ping && m.key_ping <= m.last_ping);
            next = m.last_ping + 1;
        }
        assert_eq!(next, n);
        let flat: Vec<f64> = maps.iter().filter(|m| m.last_ping < n / 2).map(|m| m.path_len_m).collect();
        let rough: Vec<f64> = maps.iter().filter(|m| m.first_ping > n / 2).map(|m| m.path_len_m).collect();
        assert!(flat.iter().all(|l| *l >= 79.0), "{flat:?}");
        assert!(rough.iter().all(|l| *l < 79.0), "{rough:?}");
    }
}
