//! Synthetic seafloor: fractal (fBm of value noise) relief plus ridges, rocks, and patches of flat
//! sand where terrain matching must fail. The value noise is a few lines written here so that
//! every octave is seeded from the survey seed and evaluated in f64 (the `noise` crate's
//! generators are seeded by u32 and would add a dependency for 20 lines).

use super::grid::Grid;
use rand::{Rng, SeedableRng};

#[derive(Debug, Clone, serde::Serialize)]
pub struct TerrainConfig {
    pub north_min_m: f64,
    pub north_max_m: f64,
    pub east_min_m: f64,
    pub east_max_m: f64,
    pub cell_m: f64,
    pub base_depth_m: f64,
    /// Standard deviation-like amplitude of the fractal relief at its longest wavelength.
    pub fractal_amp_m: f64,
    pub fractal_wavelength_m: f64,
    pub octaves: u32,
    pub ridges: usize,
    pub rocks: usize,
    /// Flat sand patches: (centre north, centre east, radius) in metres.
    pub flat_patches: Vec<(f64, f64, f64)>,
    /// Make the whole seafloor flat sand (for the false-closure test).
    pub all_flat: bool,
}

impl TerrainConfig {
    pub fn area(north: (f64, f64), east: (f64, f64)) -> Self {
        Self {
            north_min_m: north.0,
            north_max_m: north.1,
            east_min_m: east.0,
            east_max_m: east.1,
            cell_m: 1.0,
            base_depth_m: 60.0,
            fractal_amp_m: 6.0,
            fractal_wavelength_m: 320.0,
            octaves: 7,
            ridges: 4,
            rocks: 300,
            flat_patches: vec![],
            all_flat: false,
        }
    }
}

fn hash2(seed: u64, i: i64, j: i64) -> f64 {
    // splitmix64 of the lattice coordinates -> uniform in [-1, 1).
    let mut z = seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

fn value_noise(seed: u64, x: f64, y: f64) -> f64 {
    let (i, j) = (x.floor(), y.floor());
    let (fx, fy) = (x - i, y - j);
    let s = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
    let (sx, sy) = (s(fx), s(fy));
    let (i, j) = (i as i64, j as i64);
    let a = hash2(seed, i, j);
    let b = hash2(seed, i + 1, j);
    let c = hash2(seed, i, j + 1);
    let d = hash2(seed, i + 1, j + 1);
    (a + (b - a) * sx) + ((c + (d - c) * sx) - (a + (b - a) * sx)) * sy
}

/// Generate the seafloor depth grid (positive down) for `seed`.
pub fn generate(cfg: &TerrainConfig, seed: u64) -> Grid {
    let rows = ((cfg.north_max_m - cfg.north_min_m) / cfg.cell_m).ceil() as usize + 1;
    let cols = ((cfg.east_max_m - cfg.east_min_m) / cfg.cell_m).ceil() as usize + 1;
    let mut g = Grid::new_empty(cfg.north_min_m, cfg.east_min_m, cfg.cell_m, rows, cols);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x7E44_A1B2);
    // Ridges: straight lines with a Gaussian cross profile.
    let ridges: Vec<(f64, f64, f64, f64, f64)> = (0..cfg.ridges)
        .map(|_| {
            let n = rng.random_range(cfg.north_min_m..cfg.north_max_m);
            let e = rng.random_range(cfg.east_min_m..cfg.east_max_m);
            let ang: f64 = rng.random_range(0.0..std::f64::consts::PI);
            let h = rng.random_range(3.0..8.0) * if rng.random_bool(0.7) { 1.0 } else { -1.0 };
            let w = rng.random_range(12.0..35.0);
            (n, e, ang, h, w)
        })
        .collect();
    let rocks: Vec<(f64, f64, f64, f64)> = (0..cfg.rocks)
        .map(|_| {
            (
                rng.random_range(cfg.north_min_m..cfg.north_max_m),
                rng.random_range(cfg.east_min_m..cfg.east_max_m),
                rng.random_range(0.5..2.5),
                rng.random_range(1.5..5.0),
            )
        })
        .collect();
    let oct_seeds: Vec<u64> = (0..cfg.octaves).map(|_| rng.random()).collect();
    for r in 0..rows {
        for c in 0..cols {
            let (n, e) = g.centre(r, c);
            let mut h = 0.0;
            let (mut amp, mut wl) = (cfg.fractal_amp_m, cfg.fractal_wavelength_m);
            for s in &oct_seeds {
                h += amp * value_noise(*s, n / wl, e / wl);
                amp *= 0.5;
                wl *= 0.5;
            }
            for &(rn, re, ang, rh, w) in &ridges {
                let d = -(n - rn) * ang.sin() + (e - re) * ang.cos();
                h += rh * (-0.5 * (d / w).powi(2)).exp();
            }
            g.data[r * cols + c] = h;
        }
    }
    // Rocks: stamped over their own footprint only.
    for &(kn, ke, kh, kr) in &rocks {
        let r0 = (((kn - 4.0 * kr - g.north0_m) / g.cell_m).floor().max(0.0)) as usize;
        let r1 = (((kn + 4.0 * kr - g.north0_m) / g.cell_m).ceil().max(0.0) as usize).min(rows.saturating_sub(1));
        let c0 = (((ke - 4.0 * kr - g.east0_m) / g.cell_m).floor().max(0.0)) as usize;
        let c1 = (((ke + 4.0 * kr - g.east0_m) / g.cell_m).ceil().max(0.0) as usize).min(cols.saturating_sub(1));
        for r in r0..=r1 {
            for c in c0..=c1 {
                let (n, e) = g.centre(r, c);
                let d2 = (n - kn).powi(2) + (e - ke).powi(2);
                g.data[r * cols + c] += kh * (-0.5 * d2 / (kr * kr)).exp();
            }
        }
    }
    for r in 0..rows {
        for c in 0..cols {
            let (n, e) = g.centre(r, c);
            let mut h = g.data[r * cols + c];
            // Flat sand: blend to a constant level inside the patches.
            let mut flat_w: f64 = if cfg.all_flat { 1.0 } else { 0.0 };
            for &(pn, pe, pr) in &cfg.flat_patches {
                let d = ((n - pn).powi(2) + (e - pe).powi(2)).sqrt();
                let w = ((pr - d) / 40.0 + 0.5).clamp(0.0, 1.0);
                flat_w = flat_w.max(w * w * (3.0 - 2.0 * w));
            }
            h *= 1.0 - flat_w;
            // Depth positive down: relief raises the seafloor.
            g.data[r * cols + c] = cfg.base_depth_m - h;
        }
    }
    g
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn value_noise_is_continuous_and_bounded() {
        for k in 0..1000 {
            let x = k as f64 * 0.0137;
            let v = value_noise(7, x, 0.3 * x);
            assert!((-1.0..=1.0).contains(&v));
            let v2 = value_noise(7, x + 1e-7, 0.3 * x);
            assert!((v - v2).abs() < 1e-5);
        }
    }

    #[test]
    fn flat_config_gives_constant_depth_and_relief_otherwise() {
        let mut cfg = TerrainConfig::area((0.0, 100.0), (0.0, 100.0));
        cfg.rocks = 20;
        let g = generate(&cfg, 1);
        let (mn, mx) = g.data.iter().fold((f64::MAX, f64::MIN), |a, v| (a.0.min(*v), a.1.max(*v)));
        assert!(mx - mn > 1.0, "relief {}", mx - mn);
        cfg.all_flat = true;
        let g = generate(&cfg, 1);
        assert!(g.data.iter().all(|v| (*v - 60.0).abs() < 1e-12));
    }
}
