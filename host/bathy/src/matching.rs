//! Loop closure by terrain matching between two overlapping submaps (spec C2).
//!
//! Method (chosen over ICP because 2.5D grids make an exhaustive search cheap and immune to the
//! local minima ICP falls into when the dead-reckoning offset is tens of metres):
//! 1. exhaustive grid correlation over a window of horizontal shifts on a coarse grid; the cost
//!    is the variance of the depth difference over the overlap (the mean difference is a free
//!    vertical offset: tide, sound-speed and depth-sensor biases);
//! 2. Gauss-Newton refinement of (shift_n, shift_e, dz) on the fine grid with bilinear sampling
//!    (point-to-surface, the 2.5D form of point-to-plane ICP), giving a covariance.
//!
//! Gates, each reported as a rejection reason: too little overlap; too little relief (detrended
//! depth std) or too little DoN information; an ambiguous cost surface (the best cost is not
//! clearly below the best cost away from it: flat sand, a straight ridge); a poorly conditioned
//! Gauss-Newton information; a residual too large; refinement wandering off. Voting across
//! closures is in [`super::correction`].
//!
//! Result: `shift = e_b - e_a`, the difference of the navigation offsets of the two submaps
//! (a feature at true q appears at q + e in a map built with offset e).

use super::V2;
use super::grid::Grid;
use super::submap::grid_don;
use nalgebra::{Matrix2, Matrix3, Vector3};

#[derive(Debug, Clone, serde::Serialize)]
pub struct MatchConfig {
    pub coarse_factor: usize,
    pub min_overlap_cells: usize,
    pub min_relief_m: f64,
    pub min_mean_don: f64,
    pub max_peak_ratio: f64,
    /// Exclusion radius around the best shift when looking for the runner-up (m).
    pub peak_exclusion_m: f64,
    pub max_rms_m: f64,
    /// Minimum of the smaller eigenvalue of the GN information per overlap cell (1/m^2 scale).
    pub min_info_eig: f64,
    /// Floor on the closure's 1-sigma (non-rigid submaps, gridding).
    pub sigma_floor_m: f64,
    pub don_r1_cells: usize,
    pub don_r2_cells: usize,
}

impl Default for MatchConfig {
    fn default() -> Self {
        Self {
            coarse_factor: 2,
            min_overlap_cells: 300,
            min_relief_m: 0.3,
            min_mean_don: 0.004,
            max_peak_ratio: 0.5,
            peak_exclusion_m: 10.0,
            max_rms_m: 1.0,
            min_info_eig: 0.002,
            sigma_floor_m: 0.5,
            don_r1_cells: 1,
            don_r2_cells: 4,
        }
    }
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct MatchResult {
    /// e_b - e_a (north, east), metres.
    pub shift_n_m: f64,
    pub shift_e_m: f64,
    pub dz_m: f64,
    /// Covariance of the shift (m^2), row-major 2x2.
    pub cov: [f64; 4],
    pub rms_m: f64,
    pub overlap_cells: usize,
    pub peak_ratio: f64,
}

impl MatchResult {
    pub fn shift(&self) -> V2 {
        V2::new(self.shift_n_m, self.shift_e_m)
    }
    pub fn cov2(&self) -> Matrix2<f64> {
        Matrix2::new(self.cov[0], self.cov[1], self.cov[2], self.cov[3])
    }
}

#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub enum Rejection {
    NoOverlap { cells: usize },
    LowRelief { relief_m: f64 },
    LowInformation { mean_don: f64 },
    Ambiguous { peak_ratio: f64 },
    IllConditioned { min_eig: f64 },
    LargeResidual { rms_m: f64 },
    Diverged,
}

impl std::fmt::Display for Rejection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Rejection::NoOverlap { cells } => write!(f, "grids overlap in only {cells} cells (below min_overlap_cells)"),
            Rejection::LowRelief { relief_m } => write!(f, "terrain relief {relief_m:.3} m in the overlap is below min_relief_m"),
            Rejection::LowInformation { mean_don } => {
                write!(f, "mean difference of normals {mean_don:.4} in the overlap is below min_mean_don (flat terrain)")
            }
            Rejection::Ambiguous { peak_ratio } => {
                write!(f, "ambiguous match: best / runner-up cost ratio {peak_ratio:.3} is above max_peak_ratio")
            }
            Rejection::IllConditioned { min_eig } => {
                write!(f, "shift information ill-conditioned: smallest eigenvalue per cell {min_eig:.3e} is below min_info_eig")
            }
            Rejection::LargeResidual { rms_m } => write!(f, "residual RMS {rms_m:.3} m after alignment is above max_rms_m"),
            Rejection::Diverged => f.write_str("alignment diverged (no step, or moved more than two coarse cells from the coarse peak)"),
        }
    }
}

impl std::error::Error for Rejection {}

/// Cost over the overlap: (variance of b(p + t) - a(p), count), nearest-cell lookup.
fn coarse_cost(a: &Grid, b: &Grid, t: V2) -> (f64, usize) {
    let (mut s, mut s2, mut n) = (0.0, 0.0, 0usize);
    for r in 0..a.rows {
        for c in 0..a.cols {
            let va = a.data[r * a.cols + c];
            if !va.is_finite() {
                continue;
            }
            let (pn, pe) = a.centre(r, c);
            if let Some(k) = b.index_of(pn + t.x, pe + t.y) {
                let vb = b.data[k];
                if vb.is_finite() {
                    let d = vb - va;
                    s += d;
                    s2 += d * d;
                    n += 1;
                }
            }
        }
    }
    if n == 0 {
        return (f64::INFINITY, 0);
    }
    let m = s / n as f64;
    ((s2 / n as f64 - m * m).max(0.0), n)
}

/// Detrended depth std over the cells of `a` that overlap `b` at shift `t`, and mean DoN there.
fn overlap_relief(a: &Grid, b: &Grid, t: V2, cfg: &MatchConfig) -> (f64, f64) {
    let don = grid_don(a, cfg.don_r1_cells, cfg.don_r2_cells);
    let mut rows = vec![];
    let (mut dsum, mut dn) = (0.0, 0usize);
    for r in 0..a.rows {
        for c in 0..a.cols {
            let va = a.data[r * a.cols + c];
            if !va.is_finite() {
                continue;
            }
            let (pn, pe) = a.centre(r, c);
            if b.sample(pn + t.x, pe + t.y).is_some() {
                rows.push((pn, pe, va));
                let d = don[r * a.cols + c];
                if d.is_finite() {
                    dsum += d;
                    dn += 1;
                }
            }
        }
    }
    if rows.len() < 4 {
        return (0.0, 0.0);
    }
    // Least-squares plane fit, then the residual std.
    let (mn, me) = rows.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
    let (mn, me) = (mn / rows.len() as f64, me / rows.len() as f64);
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for &(n, e, d) in &rows {
        let v = Vector3::new(1.0, n - mn, e - me);
        ata += v * v.transpose();
        atb += v * d;
    }
    let Some(x) = ata.cholesky().map(|c| c.solve(&atb)) else { return (0.0, 0.0) };
    let var = rows.iter().map(|&(n, e, d)| (d - x[0] - x[1] * (n - mn) - x[2] * (e - me)).powi(2)).sum::<f64>() / rows.len() as f64;
    (var.sqrt(), if dn > 0 { dsum / dn as f64 } else { 0.0 })
}

/// Match submap grid `b` against `a` searching shifts within `radius_m` of `prior` (both grids
/// must share a cell size).
pub fn match_grids(a: &Grid, b: &Grid, prior: V2, radius_m: f64, cfg: &MatchConfig) -> Result<MatchResult, Rejection> {
    let f = cfg.coarse_factor.max(1);
    let (ac, bc) = (a.downsample(f), b.downsample(f));
    let step = ac.cell_m;
    let k = (radius_m / step).ceil() as i64;
    let mut costs = vec![];
    let mut max_n = 0;
    for i in -k..=k {
        for j in -k..=k {
            let t = prior + V2::new(i as f64 * step, j as f64 * step);
            if (t - prior).norm() > radius_m + 1e-9 {
                continue;
            }
            let (c, n) = coarse_cost(&ac, &bc, t);
            max_n = max_n.max(n);
            costs.push((t, c, n));
        }
    }
    let min_coarse = (cfg.min_overlap_cells / (f * f)).max(1);
    if max_n < min_coarse {
        return Err(Rejection::NoOverlap { cells: max_n * f * f });
    }
    let need = min_coarse.max(max_n / 2);
    let valid: Vec<&(V2, f64, usize)> = costs.iter().filter(|c| c.2 >= need).collect();
    let Some(best) = valid.iter().min_by(|x, y| x.1.total_cmp(&y.1)) else { return Err(Rejection::NoOverlap { cells: 0 }) };
    let second = valid.iter().filter(|c| (c.0 - best.0).norm() > cfg.peak_exclusion_m).map(|c| c.1).fold(f64::INFINITY, f64::min);
    let (relief, don) = overlap_relief(a, b, best.0, cfg);
    if relief < cfg.min_relief_m {
        return Err(Rejection::LowRelief { relief_m: relief });
    }
    if don < cfg.min_mean_don {
        return Err(Rejection::LowInformation { mean_don: don });
    }
    let peak_ratio = if second.is_finite() && second > 0.0 { best.1 / second } else { 1.0 };
    if peak_ratio > cfg.max_peak_ratio {
        return Err(Rejection::Ambiguous { peak_ratio });
    }
    // Gauss-Newton on the fine grids: r_p = b(p + t) - a(p) - dz.
    let mut t = best.0;
    let mut dz = 0.0;
    let mut last = None;
    for _ in 0..15 {
        let mut h = Matrix3::zeros();
        let mut g = Vector3::zeros();
        let (mut ss, mut n) = (0.0, 0usize);
        for r in 0..a.rows {
            for c in 0..a.cols {
                let va = a.data[r * a.cols + c];
                if !va.is_finite() {
                    continue;
                }
                let (pn, pe) = a.centre(r, c);
                if let Some((vb, dn, de)) = b.sample_grad(pn + t.x, pe + t.y) {
                    let res = vb - va - dz;
                    let j = Vector3::new(dn, de, -1.0);
                    h += j * j.transpose();
                    g += j * res;
                    ss += res * res;
                    n += 1;
                }
            }
        }
        if n < cfg.min_overlap_cells {
            return Err(Rejection::NoOverlap { cells: n });
        }
        let Some(ch) = h.cholesky() else { return Err(Rejection::IllConditioned { min_eig: 0.0 }) };
        let dx = ch.solve(&(-g));
        // Limit the step to one cell to stay in the basin.
        let lim = a.cell_m;
        let sn = dx[0].clamp(-lim, lim);
        let se = dx[1].clamp(-lim, lim);
        t += V2::new(sn, se);
        dz += dx[2];
        last = Some((h, ss, n));
        if sn.abs() < 1e-3 && se.abs() < 1e-3 {
            break;
        }
    }
    let Some((h, ss, n)) = last else { return Err(Rejection::Diverged) };
    if (t - best.0).norm() > 2.0 * step {
        return Err(Rejection::Diverged);
    }
    let rms = (ss / n as f64).sqrt();
    if rms > cfg.max_rms_m {
        return Err(Rejection::LargeResidual { rms_m: rms });
    }
    // Marginal information of the shift (Schur complement of dz), per overlap cell.
    let hsz = nalgebra::Vector2::new(h[(0, 2)], h[(1, 2)]);
    let hs = Matrix2::new(h[(0, 0)], h[(0, 1)], h[(1, 0)], h[(1, 1)]) - hsz * hsz.transpose() / h[(2, 2)];
    let eig = hs.symmetric_eigenvalues();
    let min_eig = eig.min() / n as f64;
    if !(min_eig >= cfg.min_info_eig) {
        return Err(Rejection::IllConditioned { min_eig });
    }
    // Covariance: residual variance times inverse information, inflated for the correlation of
    // neighbouring cells (x4) and floored.
    let var = (ss / n as f64).max(1e-6);
    let cov = hs.try_inverse().map(|m| m * var * 4.0).unwrap_or(Matrix2::identity() * 1e6);
    let cov = (cov + cov.transpose()) * 0.5 + Matrix2::identity() * cfg.sigma_floor_m.powi(2);
    Ok(MatchResult {
        shift_n_m: t.x,
        shift_e_m: t.y,
        dz_m: dz,
        cov: [cov[(0, 0)], cov[(0, 1)], cov[(1, 0)], cov[(1, 1)]],
        rms_m: rms,
        overlap_cells: n,
        peak_ratio,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Point;
    use crate::terrain::{TerrainConfig, generate};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// Two submaps cut from the same synthetic terrain: `a` built with offset 0, `b` with
    /// navigation offset `e_b` (features appear shifted by +e_b), both with depth noise.
    fn pair(flat: bool, e_b: V2, seed: u64) -> (Grid, Grid) {
        let mut tc = TerrainConfig::area((-150.0, 150.0), (-150.0, 150.0));
        tc.all_flat = flat;
        tc.cell_m = 0.5;
        let terr = generate(&tc, seed);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, 0.1).unwrap();
        let mut pts_a = vec![];
        let mut pts_b = vec![];
        for i in 0..160 {
            for j in 0..60 {
                // a: a north-south strip; b: an east-west strip crossing it.
                let (n, e) = (-80.0 + i as f64, -30.0 + j as f64);
                let d = terr.sample(n, e).unwrap() + noise.sample(&mut rng);
                pts_a.push(Point { north_m: n, east_m: e, depth_m: d });
                let (n2, e2) = (-30.0 + j as f64, -80.0 + i as f64);
                let d2 = terr.sample(n2, e2).unwrap() + noise.sample(&mut rng) + 0.7; // vertical bias
                pts_b.push(Point { north_m: n2 + e_b.x, east_m: e2 + e_b.y, depth_m: d2 });
            }
        }
        (Grid::from_points(&pts_a, 2.0, 2).unwrap(), Grid::from_points(&pts_b, 2.0, 2).unwrap())
    }

    #[test]
    fn grid_correlation_recovers_a_known_rigid_offset_on_synthetic_terrain() {
        for (seed, off) in [(1u64, V2::new(13.3, -7.6)), (2, V2::new(-21.8, 4.1)), (3, V2::new(0.9, 17.2))] {
            let (a, b) = pair(false, off, seed);
            let m = match_grids(&a, &b, V2::zeros(), 30.0, &MatchConfig::default()).expect("rugged terrain must match");
            let err = (m.shift() - off).norm();
            assert!(err < 0.3, "seed {seed}: shift {:?} vs {off:?} (err {err})", m.shift());
            assert!((m.dz_m - 0.7).abs() < 0.1, "dz {}", m.dz_m);
            let sd = m.cov2().trace().sqrt();
            assert!(sd < 2.0 && sd >= MatchConfig::default().sigma_floor_m);
        }
    }

    #[test]
    fn flat_sand_is_rejected_not_matched() {
        for seed in 0..4 {
            let (a, b) = pair(true, V2::new(9.0, -5.0), seed);
            let r = match_grids(&a, &b, V2::zeros(), 30.0, &MatchConfig::default());
            assert!(r.is_err(), "flat terrain produced a closure: {r:?}");
            // Even with the relief gates switched off, the ambiguity test alone rejects it.
            let cfg = MatchConfig { min_relief_m: 0.0, min_mean_don: 0.0, ..MatchConfig::default() };
            let r = match_grids(&a, &b, V2::zeros(), 30.0, &cfg);
            assert!(matches!(r, Err(Rejection::Ambiguous { .. })), "{r:?}");
        }
    }

    #[test]
    fn disjoint_submaps_report_no_overlap() {
        let (a, _) = pair(false, V2::zeros(), 1);
        let mut b = a.clone();
        b.north0_m += 1000.0;
        assert!(matches!(match_grids(&a, &b, V2::zeros(), 20.0, &MatchConfig::default()), Err(Rejection::NoOverlap { .. })));
    }
}
