//! Stereo images of the ice underside for the image front end: a textured ice surface at
//! `z = sim::ice_z(x, y)` seen from below through a flat port, in hazy water.
//!
//! - Texture: seeded value noise at three scales (0.6 m, 0.2 m, 0.07 m), so the image has blobs
//!   and saddles for FAST and smooth gradients for KLT at 4-6 m range.
//! - Flat port: every pixel's air-side ray is bent into the water with the same single-viewpoint
//!   model the front end inverts ([`super::frontend::refract_air_to_water`]); the per-pixel
//!   water rays are computed once per camera.
//! - Water: `I = J t + A (1 - t)` with transmission `t = exp(-beta r)` over the in-water range `r`
//!   (which grows off-axis), veiling light `A`, then Gaussian sensor noise and 8-bit quantization.
//!
//! Pixel convention: pixel `(u, v)` (column, row) has its centre at `u`, `v`; normalized air
//! coordinates are `x = (u - (w - 1) / 2) / f`, `y = (v - (h - 1) / 2) / f`.

use image::GrayImage;
use nalgebra::{Matrix3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use super::camera::StereoCamera;
use super::frontend::{N_SEAWATER, refract_air_to_water};
use super::sim::ice_z;

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct WaterConfig {
    /// Attenuation coefficient, 1/m.
    pub beta_per_m: f64,
    /// Veiling light (backscatter) level in [0, 1].
    pub veiling: f64,
    /// Sensor noise, 1 sigma in [0, 1] units (before 8-bit quantization).
    pub noise: f64,
    /// Refractive index of the water relative to the air in the housing.
    pub n_water: f64,
}

impl Default for WaterConfig {
    fn default() -> Self {
        Self { beta_per_m: 0.2, veiling: 0.75, noise: 0.006, n_water: N_SEAWATER }
    }
}

fn hash2(x: i64, y: i64, salt: u64) -> f64 {
    let mut z = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F) ^ salt;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
}

fn value_noise(x: f64, y: f64, scale_m: f64, salt: u64) -> f64 {
    let (u, v) = (x / scale_m, y / scale_m);
    let (i, j) = (u.floor(), v.floor());
    let (fu, fv) = (u - i, v - j);
    let (su, sv) = (fu * fu * (3.0 - 2.0 * fu), fv * fv * (3.0 - 2.0 * fv));
    let (i, j) = (i as i64, j as i64);
    let a = hash2(i, j, salt) * (1.0 - su) + hash2(i + 1, j, salt) * su;
    let b = hash2(i, j + 1, salt) * (1.0 - su) + hash2(i + 1, j + 1, salt) * su;
    a * (1.0 - sv) + b * sv
}

/// Ice underside albedo in [0, 1] at a horizontal position (seeded).
pub fn ice_albedo(x: f64, y: f64, seed: u64) -> f64 {
    let s = seed.wrapping_mul(0xA24B_AED4_963E_E407);
    let v = 0.3 * value_noise(x, y, 0.6, s ^ 1) + 0.45 * value_noise(x, y, 0.2, s ^ 2) + 0.25 * value_noise(x, y, 0.07, s ^ 3);
    // Stretch the mid-tones: the sum of value noises bunches around 0.5.
    (0.5 + 1.6 * (v - 0.5)).clamp(0.0, 1.0)
}

/// Where a world ray `o + t d` (t > 0) meets the ice underside, by fixed-point iteration on the
/// surface height (the relief's slopes are small, 3 steps reach sub-millimetre). `None` if the
/// ray does not go up.
pub fn intersect_ice(o: &Vector3<f64>, d: &Vector3<f64>) -> Option<(f64, Vector3<f64>)> {
    intersect_ice_from(o, d, None, 4)
}

/// [`intersect_ice`] starting from ray parameter `t_start` (a neighbouring pixel's, which is
/// already within millimetres) instead of the `z = 0` plane, with `iterations` steps.
fn intersect_ice_from(o: &Vector3<f64>, d: &Vector3<f64>, t_start: Option<f64>, iterations: usize) -> Option<(f64, Vector3<f64>)> {
    if d.z > -1e-6 {
        return None;
    }
    let mut t = t_start.unwrap_or((0.0 - o.z) / d.z);
    for _ in 0..iterations {
        let p = o + d * t;
        t = (ice_z(p.x, p.y) - o.z) / d.z;
    }
    (t > 0.0).then(|| (t, o + d * t))
}

/// Renders stereo pairs for one camera and water model; the per-pixel water-side rays are
/// computed once.
pub struct StereoRenderer {
    pub cam: StereoCamera,
    pub water: WaterConfig,
    pub seed: u64,
    /// Water-side ray (camera frame, z = 1) per pixel, row-major; `None` past the port's limit.
    rays: Vec<Option<Vector3<f64>>>,
    width: u32,
    height: u32,
}

impl StereoRenderer {
    pub fn new(cam: StereoCamera, water: WaterConfig, seed: u64) -> Self {
        let (w, h) = (cam.width_px.round().max(1.0) as u32, cam.height_px.round().max(1.0) as u32);
        let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
        let mut rays = Vec::with_capacity((w * h) as usize);
        for v in 0..h {
            for u in 0..w {
                let (xa, ya) = ((u as f64 - cx) / cam.focal_px, (v as f64 - cy) / cam.focal_px);
                rays.push(refract_air_to_water(xa, ya, water.n_water).map(|(x, y)| Vector3::new(x, y, 1.0)));
            }
        }
        Self { cam, water, seed, rays, width: w, height: h }
    }

    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Render the left and right image of the body pose `(rot_wb, pos_wb)` on two threads; the
    /// sensor noise is seeded by `noise_seed` (and the side), so the result does not depend on
    /// the scheduling.
    pub fn render_pair(&self, rot_wb: &Matrix3<f64>, pos_wb: &Vector3<f64>, noise_seed: u64) -> (GrayImage, GrayImage) {
        std::thread::scope(|s| {
            let right = s.spawn(|| self.render(rot_wb, pos_wb, true, &mut ChaCha8Rng::seed_from_u64(noise_seed ^ 0x5EED_0001)));
            let left = self.render(rot_wb, pos_wb, false, &mut ChaCha8Rng::seed_from_u64(noise_seed));
            let right = right
                .join()
                .unwrap_or_else(|_| self.render(rot_wb, pos_wb, true, &mut ChaCha8Rng::seed_from_u64(noise_seed ^ 0x5EED_0001)));
            (left, right)
        })
    }

    /// Render the left (`right = false`) or right camera of the body pose `(rot_wb, pos_wb)`.
    pub fn render<R: Rng>(&self, rot_wb: &Matrix3<f64>, pos_wb: &Vector3<f64>, right: bool, rng: &mut R) -> GrayImage {
        let pose = self.cam.cam_pose(rot_wb, pos_wb);
        let rot_wc = pose.rot_cw.transpose();
        let origin = if right { pose.pos_wc + rot_wc * Vector3::new(self.cam.baseline_m, 0.0, 0.0) } else { pose.pos_wc };
        let noise = Normal::new(0.0, self.water.noise.max(0.0)).unwrap_or(Normal::new(0.0, 0.0).expect("valid"));
        let a = self.water.veiling;
        let mut img = GrayImage::new(self.width, self.height);
        let mut warm: Option<f64> = None;
        for (k, (px, ray)) in img.as_mut().iter_mut().zip(&self.rays).enumerate() {
            if k % self.width as usize == 0 {
                warm = None;
            }
            let hit = ray.map(|r| rot_wc * r).and_then(|d| {
                let (t, p) = intersect_ice_from(&origin, &d, warm, if warm.is_some() { 2 } else { 5 })?;
                Some((t, t * d.norm(), p))
            });
            warm = hit.map(|h| h.0);
            let i = match hit.map(|h| (h.1, h.2)) {
                Some((range, p)) => {
                    let t = (-self.water.beta_per_m * range).exp();
                    ice_albedo(p.x, p.y, self.seed) * t + a * (1.0 - t)
                }
                None => a,
            };
            *px = ((i + noise.sample(rng)) * 255.0).round().clamp(0.0, 255.0) as u8;
        }
        img
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ray_meets_the_surface() {
        let o = Vector3::new(3.0, -2.0, 5.0);
        let d = Vector3::new(0.3, 0.2, -1.0);
        let (t, p) = intersect_ice(&o, &d).unwrap();
        assert!((p.z - ice_z(p.x, p.y)).abs() < 1e-6, "{p}");
        assert!((p - (o + d * t)).norm() < 1e-12);
        assert!(intersect_ice(&o, &Vector3::new(0.0, 0.0, 1.0)).is_none());
    }

    #[test]
    fn centre_pixel_sees_the_ice_above_the_camera_with_haze() {
        // Level vehicle: the optical axis points straight up, so the centre pixel (for an odd
        // size) sees the ice point right above the left camera, through `range` of water.
        let cam = StereoCamera { width_px: 41.0, height_px: 31.0, ..StereoCamera::default() };
        let water = WaterConfig { noise: 0.0, ..WaterConfig::default() };
        let r = StereoRenderer::new(cam, water, 5);
        let pos = Vector3::new(1.0, 2.0, 5.0);
        let img = r.render_pair(&Matrix3::identity(), &pos, 0).0;
        let c = pos + cam.pos_bc_m;
        let top = ice_z(c.x, c.y);
        let t = (-water.beta_per_m * (c.z - top)).exp();
        let want = ice_albedo(c.x, c.y, 5) * t + water.veiling * (1.0 - t);
        let got = img.get_pixel(20, 15).0[0] as f64 / 255.0;
        assert!((got - want).abs() <= 0.5 / 255.0 + 1e-9, "{got} vs {want}");
    }
}
