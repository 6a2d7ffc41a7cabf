//! Seafloor scene renderer: polarization mosaics of a procedurally textured seafloor seen by a
//! downward camera through the water column.
//!
//! - Seafloor albedo: the floor is cut into square cells; each cell shows one of a few motifs
//!   (blobs and ripples, chosen by a hash of the cell), so distant places look alike and
//!   recognition from appearance alone is ambiguous; a weak world-fixed noise and a slow
//!   brightness trend make every place slightly different.
//! - Light: the seafloor is Lambertian (unpolarized) under the downwelling irradiance
//!   `E_t exp(-K_d z_floor)`, attenuated by `exp(-c range)` on the way to the camera; the water
//!   between camera and floor adds the polarized path radiance of [`subnav_base::sky::Field`]
//!   (single Rayleigh/particle scattering of the refracted sun plus the unpolarized multiple
//!   scattering), truncated at the floor by the factor `1 - exp(-c range)` (the field itself
//!   integrates to infinity). AoP and DoLP therefore follow the sky (sun position, heading) and
//!   DoLP drops over bright patches.
//! - Camera: pinhole, square pixels, rows along the body x (forward) axis, columns along body y
//!   (right); polarizer angles are measured from the column axis. Shot noise (full well
//!   `full_well_e`), read noise, 12-bit ADC, stored as 16-bit mosaics (IMX250MZR layout).
//!
//! Not modelled: roll/pitch, shadows, vignetting, the optical blur of the water.

use nalgebra::Vector3;
use rand::Rng;
use rand_distr::{Distribution, Normal};

use crate::polar_image::Mosaic;
use crate::polar_image::mosaic::mosaic_from_stokes;
use subnav_base::sky::{Field, Water, stokes};

/// Scene and camera parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneConfig {
    /// Seafloor depth (m).
    pub floor_depth_m: f64,
    /// Texture cell size (m) and number of motifs (look-alike places share a motif).
    pub cell_m: f64,
    pub motifs: u32,
    /// Amplitude of the world-unique texture on top of the motif (0..1 of albedo range).
    pub unique_amp: f64,
    pub seed: u64,
    /// Image size (px, even) and full field of view (rad).
    pub size_px: usize,
    pub fov_rad: f64,
    /// Sensor: electrons at full scale, read noise (e-), ADC bits.
    pub full_well_e: f64,
    pub read_noise_e: f64,
    pub adc_bits: u32,
    /// Exposure: radiance that maps to full scale.
    pub full_scale_radiance: f64,
}

impl Default for SceneConfig {
    fn default() -> Self {
        SceneConfig {
            floor_depth_m: 14.0,
            cell_m: 6.0,
            motifs: 4,
            unique_amp: 0.15,
            seed: 7,
            size_px: 48,
            fov_rad: 70f64.to_radians(),
            full_well_e: 10_000.0,
            read_noise_e: 5.0,
            adc_bits: 12,
            full_scale_radiance: 0.0, // 0 = set from the scene at construction
        }
    }
}

/// Coastal water: more scattering than [`Water::clear`], so the path radiance matters at a few
/// metres of range.
pub fn coastal_water() -> Water {
    Water { c_per_m: 0.25, b_per_m: 0.15, kd_per_m: 0.12, ..Water::clear() }
}

fn hash(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

fn unit(h: u64) -> f64 {
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth value noise on a lattice of spacing 1 (bilinear with smoothstep).
fn value_noise(seed: u64, x: f64, y: f64) -> f64 {
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let v = |i: i64, j: i64| unit(hash(seed ^ hash((i as u64).wrapping_mul(0x1000_0000_01B3) ^ (j as u64))));
    let (i, j) = (x0 as i64, y0 as i64);
    let a = v(i, j) + (v(i + 1, j) - v(i, j)) * s(fx);
    let b = v(i, j + 1) + (v(i + 1, j + 1) - v(i, j + 1)) * s(fx);
    a + (b - a) * s(fy)
}

/// A motif: a few Gaussian blobs and a ripple field in cell coordinates (0..1).
#[derive(Debug, Clone)]
struct Motif {
    blobs: Vec<(f64, f64, f64, f64)>, // (u, v, radius, amplitude)
    ripple_dir: f64,
    ripple_k: f64,
    ripple_amp: f64,
}

impl Motif {
    fn new(seed: u64) -> Self {
        let mut h = hash(seed);
        let mut next = || {
            h = hash(h);
            unit(h)
        };
        let n = 2 + (next() * 3.0) as usize;
        let blobs = (0..n).map(|_| (0.15 + 0.7 * next(), 0.15 + 0.7 * next(), 0.06 + 0.12 * next(), 0.5 * (next() - 0.3))).collect();
        Motif { blobs, ripple_dir: next() * std::f64::consts::PI, ripple_k: 8.0 + 10.0 * next(), ripple_amp: 0.1 * next() }
    }

    fn value(&self, u: f64, v: f64) -> f64 {
        let mut a = 0.0;
        for &(bu, bv, r, amp) in &self.blobs {
            let d2 = (u - bu).powi(2) + (v - bv).powi(2);
            a += amp * (-d2 / (2.0 * r * r)).exp();
        }
        let (c, s) = (self.ripple_dir.cos(), self.ripple_dir.sin());
        a + self.ripple_amp * (self.ripple_k * (c * u + s * v) * std::f64::consts::TAU / 4.0).sin()
    }
}

/// The seafloor and the light field at the camera depth.
pub struct Scene {
    pub cfg: SceneConfig,
    motifs: Vec<Motif>,
    field: Field,
    sun_ned: Vector3<f64>,
    water: Water,
    camera_depth_m: f64,
    full_scale: f64,
}

impl Scene {
    /// `sun_ned`: unit vector toward the sun in air; `camera_depth_m` the survey depth.
    pub fn new<R: Rng>(cfg: SceneConfig, water: Water, sun_ned: Vector3<f64>, camera_depth_m: f64, rng: &mut R) -> Self {
        let motifs = (0..cfg.motifs.max(1)).map(|m| Motif::new(cfg.seed.wrapping_mul(31).wrapping_add(m as u64))).collect();
        let field = Field::new(sun_ned, water, camera_depth_m, rng);
        let mut sc = Scene { cfg, motifs, field, sun_ned, water, camera_depth_m, full_scale: 1.0 };
        sc.full_scale = if cfg.full_scale_radiance > 0.0 {
            cfg.full_scale_radiance
        } else {
            // Expose so that an albedo-0.6 floor straight below is at ~80 % of full scale.
            let s = sc.radiance_stokes(Vector3::new(0.0, 0.0, 1.0), Vector3::new(0.0, 1.0, 0.0), 0.6);
            s[0] / 0.8
        };
        sc
    }

    pub fn sun_ned(&self) -> Vector3<f64> {
        self.sun_ned
    }

    /// Motif index of the cell containing (north, east).
    pub fn motif_at(&self, n_m: f64, e_m: f64) -> usize {
        let (i, j) = ((n_m / self.cfg.cell_m).floor() as i64, (e_m / self.cfg.cell_m).floor() as i64);
        (hash(self.cfg.seed ^ hash((i as u64) << 32 ^ (j as u64 & 0xFFFF_FFFF))) % self.motifs.len() as u64) as usize
    }

    /// Seafloor albedo at (north, east) metres.
    pub fn albedo(&self, n_m: f64, e_m: f64) -> f64 {
        let cell = self.cfg.cell_m;
        let (u, v) = ((n_m / cell).rem_euclid(1.0), (e_m / cell).rem_euclid(1.0));
        let m = &self.motifs[self.motif_at(n_m, e_m)];
        let unique = value_noise(self.cfg.seed ^ 0xABCD, n_m / 1.5, e_m / 1.5) - 0.5;
        let trend = 0.05 * (n_m / 40.0).sin() * (e_m / 55.0).cos();
        (0.3 + m.value(u, v) + self.cfg.unique_amp * unique + trend).clamp(0.03, 0.9)
    }

    /// Stokes (S0, S1, S2) reaching the camera along look direction `d` (unit, NED, from the
    /// camera toward the floor), in the frame (a, d x a), for an albedo `alb` at the hit point.
    fn radiance_stokes(&self, d: Vector3<f64>, a_axis: Vector3<f64>, alb: f64) -> [f64; 3] {
        let alt = (self.cfg.floor_depth_m - self.camera_depth_m).max(0.1);
        let range = alt / d.z.max(1e-3);
        let w = &self.water;
        let c_path = self.field.radiance(d) * (1.0 - (-w.c_per_m * range).exp());
        let a = (a_axis - d * a_axis.dot(&d)).normalize();
        let b = d.cross(&a);
        let [p0, p1, p2] = stokes(&c_path, &a, &b);
        // Downwelling irradiance at the floor (relative to the transmitted irradiance used by the field).
        let mu = self.field.refracted_sun_ned().map_or(1.0, |s| (-s.z).max(0.05));
        let e_floor = mu * (-w.kd_per_m * self.cfg.floor_depth_m).exp();
        let reflected = alb * e_floor / std::f64::consts::PI * (-w.c_per_m * range).exp();
        [p0 + reflected, p1, p2]
    }

    /// Render the mosaic seen from (north, east) at heading `yaw_rad` (camera at the survey
    /// depth, looking down), with sensor noise from `rng`.
    pub fn render<R: Rng>(&self, n_m: f64, e_m: f64, yaw_rad: f64, rng: &mut R) -> Mosaic {
        let npx = self.cfg.size_px.max(4) & !1;
        let f = (npx as f64 / 2.0) / (self.cfg.fov_rad / 2.0).tan();
        let c0 = (npx as f64 - 1.0) / 2.0;
        let alt = (self.cfg.floor_depth_m - self.camera_depth_m).max(0.1);
        let (cy, sy) = (yaw_rad.cos(), yaw_rad.sin());
        let rot = |x: f64, y: f64, z: f64| Vector3::new(cy * x - sy * y, sy * x + cy * y, z);
        let a_axis = rot(0.0, 1.0, 0.0); // image column axis = body right
        let fs = self.full_scale;
        let gain_e = self.cfg.full_well_e;
        let levels = ((1u64 << self.cfg.adc_bits.clamp(1, 16)) - 1) as f64;
        let read = Normal::new(0.0, self.cfg.read_noise_e.max(0.0)).unwrap_or(Normal::new(0.0, 0.0).expect("zero sigma"));
        let mut m = mosaic_from_stokes(npx, npx, 16, |r, c| {
            // Row 0 is forward (top of the image), columns to the right.
            let d = rot((c0 - r as f64) / f, (c as f64 - c0) / f, 1.0).normalize();
            let t = alt / d.z;
            let alb = self.albedo(n_m + t * d.x, e_m + t * d.y);
            let s = self.radiance_stokes(d, a_axis, alb);
            [s[0] / fs, s[1] / fs, s[2] / fs]
        });
        for v in m.plane.data.iter_mut() {
            let e = (*v * gain_e).max(0.0);
            let shot = if e > 0.0 { Normal::new(e, e.sqrt()).map_or(e, |n| n.sample(rng)) } else { 0.0 };
            let counts = ((shot + read.sample(rng)) / gain_e * levels).round().clamp(0.0, levels);
            *v = counts / levels;
        }
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::polar_image::{demosaic, stokes as stokes_img};
    use rand::SeedableRng;

    fn sun() -> Vector3<f64> {
        let (el, az) = (50f64.to_radians(), 150f64.to_radians());
        Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), -el.sin())
    }

    #[test]
    fn images_are_polarized_and_darker_floor_is_more_polarized() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let sc = Scene::new(SceneConfig::default(), coastal_water(), sun(), 10.0, &mut rng);
        let st = stokes_img(&demosaic(&sc.render(3.0, 4.0, 0.3, &mut rng)));
        let mean_dolp = st.dolp.data.iter().sum::<f64>() / st.dolp.data.len() as f64;
        assert!(mean_dolp > 0.02 && mean_dolp < 0.8, "DoLP {mean_dolp}");
        // Same place, dark vs bright floor directly below.
        let dark = sc.radiance_stokes(Vector3::z(), Vector3::y(), 0.05);
        let bright = sc.radiance_stokes(Vector3::z(), Vector3::y(), 0.6);
        let dolp = |s: [f64; 3]| (s[1] * s[1] + s[2] * s[2]).sqrt() / s[0];
        assert!(dolp(dark) > dolp(bright));
    }

    #[test]
    fn look_alike_cells_exist() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let sc = Scene::new(SceneConfig::default(), coastal_water(), sun(), 10.0, &mut rng);
        let mut counts = [0usize; 4];
        for i in 0..10 {
            for j in 0..10 {
                counts[sc.motif_at(i as f64 * 6.0 + 1.0, j as f64 * 6.0 + 1.0)] += 1;
            }
        }
        assert!(counts.iter().all(|&c| c >= 10), "{counts:?}");
    }
}
