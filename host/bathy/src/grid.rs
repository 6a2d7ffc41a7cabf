//! Regular north/east grid of depths: mean-per-cell gridding of soundings, bilinear sampling,
//! and ESRI ASCII grid output (readable by GDAL/QGIS). Empty cells hold NaN.
//! Written here because the operations are a few lines each and the needed semantics (NaN =
//! empty, bilinear only over four valid cells) are specific; no crate would save code.

use super::Point;
use anyhow::{Context, Result, bail};
use std::io::Write;

#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    /// North coordinate of the centre of row 0 (the southernmost row).
    pub north0_m: f64,
    /// East coordinate of the centre of column 0 (westernmost).
    pub east0_m: f64,
    pub cell_m: f64,
    pub rows: usize,
    pub cols: usize,
    /// Row-major (row = north index), NaN = empty.
    pub data: Vec<f64>,
}

impl Grid {
    pub fn new_empty(north0_m: f64, east0_m: f64, cell_m: f64, rows: usize, cols: usize) -> Self {
        Self { north0_m, east0_m, cell_m, rows, cols, data: vec![f64::NAN; rows * cols] }
    }

    /// Grid covering all `points` (plus `margin_cells` empty cells around), each cell the mean
    /// depth of the points that fall in it. Returns `None` for no finite points.
    pub fn from_points(points: &[Point], cell_m: f64, margin_cells: usize) -> Option<Self> {
        let (mut nmin, mut nmax, mut emin, mut emax) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for p in points.iter().filter(|p| is_finite(p)) {
            nmin = nmin.min(p.north_m);
            nmax = nmax.max(p.north_m);
            emin = emin.min(p.east_m);
            emax = emax.max(p.east_m);
        }
        if nmin > nmax || !(cell_m > 0.0) {
            return None;
        }
        let m = margin_cells as f64 * cell_m;
        let n0 = ((nmin - m) / cell_m).floor() * cell_m + 0.5 * cell_m;
        let e0 = ((emin - m) / cell_m).floor() * cell_m + 0.5 * cell_m;
        let rows = ((nmax + m - n0) / cell_m).round() as usize + 1;
        let cols = ((emax + m - e0) / cell_m).round() as usize + 1;
        let mut g = Self::new_empty(n0, e0, cell_m, rows, cols);
        g.accumulate(points);
        Some(g)
    }

    /// Same geometry as `self`, filled with the mean of `points` per cell (points outside ignored).
    pub fn accumulate(&mut self, points: &[Point]) {
        let mut sum = vec![0.0; self.data.len()];
        let mut cnt = vec![0u32; self.data.len()];
        for p in points.iter().filter(|p| is_finite(p)) {
            if let Some(k) = self.index_of(p.north_m, p.east_m) {
                sum[k] += p.depth_m;
                cnt[k] += 1;
            }
        }
        let mut off = vec![(0.0, 0.0); self.data.len()];
        for p in points.iter().filter(|p| is_finite(p)) {
            if let Some(k) = self.index_of(p.north_m, p.east_m) {
                let (cn, ce) = self.centre(k / self.cols, k % self.cols);
                off[k].0 += p.north_m - cn;
                off[k].1 += p.east_m - ce;
            }
        }
        for k in 0..self.data.len() {
            self.data[k] = if cnt[k] > 0 { sum[k] / cnt[k] as f64 } else { f64::NAN };
            if cnt[k] > 0 {
                off[k].0 /= cnt[k] as f64;
                off[k].1 /= cnt[k] as f64;
            }
        }
        // The mean of a cell's points is the surface at the points' mean position, not at the
        // cell centre: move it to the centre with the local gradient (central differences),
        // which removes the first-order bias of uneven sampling (exact on planes).
        let raw = self.data.clone();
        let at = |r: isize, c: isize| -> f64 {
            if r < 0 || c < 0 || r as usize >= self.rows || c as usize >= self.cols {
                f64::NAN
            } else {
                raw[r as usize * self.cols + c as usize]
            }
        };
        for r in 0..self.rows as isize {
            for c in 0..self.cols as isize {
                let k = r as usize * self.cols + c as usize;
                if !raw[k].is_finite() {
                    continue;
                }
                let slope = |a: f64, m: f64, b: f64| -> f64 {
                    if a.is_finite() && b.is_finite() {
                        (b - a) / (2.0 * self.cell_m)
                    } else if b.is_finite() {
                        (b - m) / self.cell_m
                    } else if a.is_finite() {
                        (m - a) / self.cell_m
                    } else {
                        0.0
                    }
                };
                let gn = slope(at(r - 1, c), raw[k], at(r + 1, c));
                let ge = slope(at(r, c - 1), raw[k], at(r, c + 1));
                self.data[k] = raw[k] - gn * off[k].0 - ge * off[k].1;
            }
        }
    }

    pub fn index_of(&self, north_m: f64, east_m: f64) -> Option<usize> {
        let r = ((north_m - self.north0_m) / self.cell_m + 0.5).floor();
        let c = ((east_m - self.east0_m) / self.cell_m + 0.5).floor();
        if r < 0.0 || c < 0.0 || r >= self.rows as f64 || c >= self.cols as f64 || !r.is_finite() || !c.is_finite() {
            return None;
        }
        Some(r as usize * self.cols + c as usize)
    }

    pub fn centre(&self, row: usize, col: usize) -> (f64, f64) {
        (self.north0_m + row as f64 * self.cell_m, self.east0_m + col as f64 * self.cell_m)
    }

    pub fn get(&self, row: usize, col: usize) -> f64 {
        if row < self.rows && col < self.cols { self.data[row * self.cols + col] } else { f64::NAN }
    }

    /// Bilinear interpolation; `None` unless all four surrounding cells are valid.
    pub fn sample(&self, north_m: f64, east_m: f64) -> Option<f64> {
        let fr = (north_m - self.north0_m) / self.cell_m;
        let fc = (east_m - self.east0_m) / self.cell_m;
        if !(fr >= 0.0 && fc >= 0.0) {
            return None;
        }
        let (r, c) = (fr.floor() as usize, fc.floor() as usize);
        if r + 1 >= self.rows || c + 1 >= self.cols {
            // Exactly on the last row/column.
            if r < self.rows && c < self.cols && fr == r as f64 && fc == c as f64 {
                let v = self.get(r, c);
                return v.is_finite().then_some(v);
            }
            return None;
        }
        let (tr, tc) = (fr - r as f64, fc - c as f64);
        let v00 = self.get(r, c);
        let v01 = self.get(r, c + 1);
        let v10 = self.get(r + 1, c);
        let v11 = self.get(r + 1, c + 1);
        let v = (1.0 - tr) * ((1.0 - tc) * v00 + tc * v01) + tr * ((1.0 - tc) * v10 + tc * v11);
        v.is_finite().then_some(v)
    }

    /// Bilinear value and gradient (d/dnorth, d/deast).
    pub fn sample_grad(&self, north_m: f64, east_m: f64) -> Option<(f64, f64, f64)> {
        let fr = (north_m - self.north0_m) / self.cell_m;
        let fc = (east_m - self.east0_m) / self.cell_m;
        if !(fr >= 0.0 && fc >= 0.0) {
            return None;
        }
        let (r, c) = (fr.floor() as usize, fc.floor() as usize);
        if r + 1 >= self.rows || c + 1 >= self.cols {
            return None;
        }
        let (tr, tc) = (fr - r as f64, fc - c as f64);
        let v00 = self.get(r, c);
        let v01 = self.get(r, c + 1);
        let v10 = self.get(r + 1, c);
        let v11 = self.get(r + 1, c + 1);
        let v = (1.0 - tr) * ((1.0 - tc) * v00 + tc * v01) + tr * ((1.0 - tc) * v10 + tc * v11);
        let dn = ((1.0 - tc) * (v10 - v00) + tc * (v11 - v01)) / self.cell_m;
        let de = ((1.0 - tr) * (v01 - v00) + tr * (v11 - v10)) / self.cell_m;
        (v.is_finite() && dn.is_finite() && de.is_finite()).then_some((v, dn, de))
    }

    pub fn valid_count(&self) -> usize {
        self.data.iter().filter(|v| v.is_finite()).count()
    }

    /// Downsample by an integer factor (mean of valid cells in each block).
    pub fn downsample(&self, f: usize) -> Grid {
        let f = f.max(1);
        let rows = self.rows.div_ceil(f);
        let cols = self.cols.div_ceil(f);
        let cell = self.cell_m * f as f64;
        let off = 0.5 * (f as f64 - 1.0) * self.cell_m;
        let mut g = Grid::new_empty(self.north0_m + off, self.east0_m + off, cell, rows, cols);
        for r in 0..rows {
            for c in 0..cols {
                let (mut s, mut n) = (0.0, 0);
                for rr in r * f..((r + 1) * f).min(self.rows) {
                    for cc in c * f..((c + 1) * f).min(self.cols) {
                        let v = self.get(rr, cc);
                        if v.is_finite() {
                            s += v;
                            n += 1;
                        }
                    }
                }
                // Require at least half the block so that the coarse cell is representative.
                if n * 2 >= f * f {
                    g.data[r * cols + c] = s / n as f64;
                }
            }
        }
        g
    }

    /// ESRI ASCII grid (x = east, y = north; values = depth in metres, positive down). Errors
    /// name the file.
    pub fn write_esri_ascii(&self, path: &std::path::Path) -> Result<()> {
        self.write_esri_ascii_unnamed(path).with_context(|| format!("writing {}", path.display()))
    }

    fn write_esri_ascii_unnamed(&self, path: &std::path::Path) -> Result<()> {
        let f = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        let mut w = std::io::BufWriter::new(f);
        writeln!(w, "ncols {}", self.cols)?;
        writeln!(w, "nrows {}", self.rows)?;
        writeln!(w, "xllcenter {:.3}", self.east0_m)?;
        writeln!(w, "yllcenter {:.3}", self.north0_m)?;
        writeln!(w, "cellsize {:.3}", self.cell_m)?;
        writeln!(w, "NODATA_value -9999")?;
        for r in (0..self.rows).rev() {
            let mut line = String::with_capacity(self.cols * 9);
            for c in 0..self.cols {
                let v = self.get(r, c);
                if c > 0 {
                    line.push(' ');
                }
                if v.is_finite() {
                    line.push_str(&format!("{v:.3}"));
                } else {
                    line.push_str("-9999");
                }
            }
            writeln!(w, "{line}")?;
        }
        w.flush()?;
        Ok(())
    }

    /// Read an ESRI ASCII grid written by [`Grid::write_esri_ascii`] (centre or corner origin).
    pub fn read_esri_ascii(text: &str) -> Result<Grid> {
        let mut lines = text.lines();
        let mut hdr = std::collections::HashMap::new();
        for _ in 0..6 {
            let l = lines.next().context("ESRI grid: header shorter than 6 lines")?;
            let mut it = l.split_whitespace();
            let k = it.next().context("ESRI grid: empty header line")?.to_ascii_lowercase();
            let v: f64 = it.next().context("ESRI grid: header without value")?.parse().context("ESRI grid: bad header value")?;
            hdr.insert(k, v);
        }
        let get = |k: &str| hdr.get(k).copied().with_context(|| format!("ESRI grid: missing {k}"));
        let cols = get("ncols")? as usize;
        let rows = get("nrows")? as usize;
        let cell = get("cellsize")?;
        let nod = get("nodata_value")?;
        let (e0, n0) = match (hdr.get("xllcenter"), hdr.get("yllcenter")) {
            (Some(x), Some(y)) => (*x, *y),
            _ => (get("xllcorner")? + 0.5 * cell, get("yllcorner")? + 0.5 * cell),
        };
        let mut g = Grid::new_empty(n0, e0, cell, rows, cols);
        for r in (0..rows).rev() {
            let l = lines.next().context("ESRI grid: fewer data rows than nrows")?;
            let vals: Vec<&str> = l.split_whitespace().collect();
            if vals.len() != cols {
                bail!("ESRI grid: row has {} values, expected {cols}", vals.len());
            }
            for (c, s) in vals.iter().enumerate() {
                let v: f64 = s.parse().context("ESRI grid: bad value")?;
                g.data[r * cols + c] = if v == nod { f64::NAN } else { v };
            }
        }
        Ok(g)
    }
}

fn is_finite(p: &Point) -> bool {
    p.north_m.is_finite() && p.east_m.is_finite() && p.depth_m.is_finite()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(n: f64, e: f64) -> f64 {
        40.0 + 0.05 * n - 0.12 * e
    }

    #[test]
    fn gridding_symmetric_points_on_a_plane_is_exact() {
        // Four points placed symmetrically about each cell centre: the cell mean equals the plane
        // at the centre (linearity), for any plane.
        let cell = 2.0;
        let mut pts = vec![];
        for i in 0..20 {
            for j in 0..15 {
                let (cn, ce) = (i as f64 * cell + 1.0, j as f64 * cell + 1.0);
                for (dn, de) in [(-0.4, -0.3), (0.4, 0.3), (-0.4, 0.3), (0.4, -0.3)] {
                    pts.push(Point { north_m: cn + dn, east_m: ce + de, depth_m: plane(cn + dn, ce + de) });
                }
            }
        }
        let g = Grid::from_points(&pts, cell, 0).unwrap();
        assert_eq!((g.rows, g.cols), (20, 15));
        for r in 0..g.rows {
            for c in 0..g.cols {
                let (n, e) = g.centre(r, c);
                assert!((g.get(r, c) - plane(n, e)).abs() < 1e-9);
            }
        }
        // Bilinear interpolation reproduces a plane exactly anywhere inside.
        for (n, e) in [(3.3, 4.7), (20.0, 10.0), (37.9, 28.5)] {
            let v = g.sample(n, e).unwrap();
            assert!((v - plane(n, e)).abs() < 1e-9, "{v} vs {}", plane(n, e));
            let (_, dn, de) = g.sample_grad(n, e).unwrap();
            assert!((dn - 0.05).abs() < 1e-9 && (de + 0.12).abs() < 1e-9);
        }
        assert!(g.sample(-5.0, 3.0).is_none());
    }

    #[test]
    fn gridding_random_points_error_is_bounded_by_slope_times_half_cell() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let pts: Vec<Point> = (0..5000)
            .map(|_| {
                let (n, e) = (rng.random_range(0.0..50.0), rng.random_range(0.0..50.0));
                Point { north_m: n, east_m: e, depth_m: plane(n, e) }
            })
            .collect();
        let g = Grid::from_points(&pts, 2.5, 0).unwrap();
        let bound = (0.05f64.abs() + 0.12) * 2.5 / 2.0;
        for r in 0..g.rows {
            for c in 0..g.cols {
                let v = g.get(r, c);
                if v.is_finite() {
                    let (n, e) = g.centre(r, c);
                    assert!((v - plane(n, e)).abs() <= bound + 1e-12);
                }
            }
        }
    }

    #[test]
    fn esri_ascii_round_trip_and_nan_points_ignored() {
        let mut pts = vec![Point { north_m: f64::NAN, east_m: 0.0, depth_m: 1.0 }];
        for i in 0..10 {
            pts.push(Point { north_m: i as f64, east_m: (i * 2) as f64, depth_m: i as f64 * 0.5 });
        }
        let g = Grid::from_points(&pts, 1.0, 1).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("g.asc");
        g.write_esri_ascii(&p).unwrap();
        let back = Grid::read_esri_ascii(&std::fs::read_to_string(&p).unwrap()).unwrap();
        assert_eq!((back.rows, back.cols), (g.rows, g.cols));
        for (a, b) in g.data.iter().zip(&back.data) {
            assert!((a.is_nan() && b.is_nan()) || (a - b).abs() < 1e-3);
        }
        assert!(Grid::read_esri_ascii("ncols 2\nnrows x\n").is_err());
        assert!(Grid::from_points(&[], 1.0, 0).is_none());
    }
}
