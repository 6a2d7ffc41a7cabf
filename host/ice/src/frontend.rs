//! The stereo image front end (D3): dark-channel-prior dehazing, the flat-port refraction model,
//! and [`StereoTracker`]: FAST corners (imageproc) tracked with pyramidal KLT (the
//! `optical-flow-lk` crate, forward-backward checked) from frame to frame and matched left to
//! right, turned into stereo observations in normalized water-side coordinates for the MSCKF.
//! The back end also runs on feature tracks from a file (see `data`).
//!
//! Dehazing (He, Sun & Tang 2009) for a grey underwater image `I = J t + A (1 - t)`: the dark
//! channel is the local minimum over a `(2 radius + 1)^2` patch; the veiling light `A` is the
//! highest intensity among the pixels of the brightest 0.1 % of the dark channel; the transmission is
//! `t = 1 - omega dark(I / A)`, floored at `t0`; the scene `J = (I - A) / t + A`.
//!
//! Flat port: the camera looks through a flat window into water. A ray leaving the lens at angle
//! `theta_a` to the optical axis continues at `theta_w` with `sin theta_a = n sin theta_w` (thin
//! window, lens centre at the window: the single-viewpoint approximation). Normalized image
//! coordinates measured in air are mapped to the water-side ray's coordinates before the pinhole
//! stereo model is applied.

use image::GrayImage;
use optical_flow_lk::{TrackParams, TrackStatus, build_pyramid, calc_optical_flow_fb};

use super::camera::{StereoCamera, StereoObs};
use super::phasecorr::Gray;

/// Refractive index of sea water relative to air.
pub const N_SEAWATER: f64 = 1.34;

/// Local minimum over a square patch (clamped at the borders). Separable: rows then columns.
pub fn dark_channel(img: &Gray, radius: usize) -> Gray {
    let (r, c) = (img.rows, img.cols);
    let mut tmp = vec![0.0; r * c];
    for y in 0..r {
        for x in 0..c {
            let (lo, hi) = (x.saturating_sub(radius), (x + radius).min(c - 1));
            tmp[y * c + x] = img.data[y * c + lo..=y * c + hi].iter().copied().fold(f64::INFINITY, f64::min);
        }
    }
    let mut out = vec![0.0; r * c];
    for y in 0..r {
        let (lo, hi) = (y.saturating_sub(radius), (y + radius).min(r - 1));
        for x in 0..c {
            out[y * c + x] = (lo..=hi).map(|yy| tmp[yy * c + x]).fold(f64::INFINITY, f64::min);
        }
    }
    Gray { rows: r, cols: c, data: out }
}

/// Dark-channel-prior dehazing of a grey image. Returns the scene estimate and the veiling light.
pub fn dehaze(img: &Gray, radius: usize, omega: f64, t0: f64) -> (Gray, f64) {
    let dark = dark_channel(img, radius);
    let n = img.data.len();
    let mut idx: Vec<usize> = (0..n).collect();
    let top = (n / 1000).max(1).min(n);
    if top < n {
        idx.select_nth_unstable_by(top - 1, |&a, &b| dark.data[b].total_cmp(&dark.data[a]));
    }
    let a = idx[..top].iter().map(|&i| img.data[i]).fold(1e-6, f64::max);
    // dark(I / A) = dark(I) / A: the patch minimum commutes with a positive scale.
    let data = img.data.iter().zip(&dark.data).map(|(&i, &d)| (i - a) / (1.0 - omega * d / a).max(t0) + a).collect();
    (Gray { rows: img.rows, cols: img.cols, data }, a)
}

/// Air-side normalized coordinates -> water-side ray's normalized coordinates (flat port).
/// `None` beyond total internal reflection (not reachable from air into water, kept for safety).
pub fn refract_air_to_water(x: f64, y: f64, n: f64) -> Option<(f64, f64)> {
    let r = x.hypot(y);
    if r == 0.0 {
        return Some((0.0, 0.0));
    }
    let sin_a = r / (1.0 + r * r).sqrt();
    let sin_w = sin_a / n;
    if sin_w >= 1.0 {
        return None;
    }
    let rw = sin_w / (1.0 - sin_w * sin_w).sqrt();
    Some((x * rw / r, y * rw / r))
}

/// Inverse of [`refract_air_to_water`] (what a simulator uses to place a water ray on the sensor).
pub fn refract_water_to_air(x: f64, y: f64, n: f64) -> Option<(f64, f64)> {
    refract_air_to_water(x, y, 1.0 / n)
}

/// Parameters of the stereo tracker.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TrackerConfig {
    /// Features kept per frame (new FAST corners fill up to this).
    pub max_features: usize,
    /// FAST-9 intensity threshold (grey levels of the enhanced image).
    pub fast_threshold: u8,
    /// New corners are taken at most one per square bucket of this side, away from tracked ones.
    pub min_distance_px: u32,
    /// Corners closer than this to the border are not taken (the KLT window must fit).
    pub border_px: u32,
    pub pyramid_levels: usize,
    /// KLT window side (odd).
    pub window_px: usize,
    /// Forward-backward round trip allowed, px.
    pub fb_threshold_px: f32,
    /// Rectified stereo: the right match must lie on the same row within this, px.
    pub max_row_diff_px: f64,
    /// Disparity range accepted, px (right = left - disparity).
    pub disparity_px: (f64, f64),
    /// Dark-channel dehazing before detection and tracking (patch radius, omega, t0).
    pub dehaze: Option<(usize, f64, f64)>,
    /// Undo the flat port (off: air-side coordinates go to the pinhole model unchanged).
    pub refraction: bool,
    pub n_water: f64,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            max_features: 60,
            fast_threshold: 20,
            min_distance_px: 24,
            border_px: 16,
            pyramid_levels: 3,
            window_px: 21,
            fb_threshold_px: 0.5,
            max_row_diff_px: 1.0,
            disparity_px: (1.0, 120.0),
            dehaze: Some((7, 0.9, 0.2)),
            refraction: true,
            n_water: N_SEAWATER,
        }
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct FrontendStats {
    pub frames: usize,
    /// New features started (FAST corners that also matched in the right image).
    pub started: usize,
    /// Frame-to-frame KLT tracks continued / lost (out of view, flat, forward-backward failure).
    pub tracked: usize,
    pub lost: usize,
    /// Stereo matches rejected (no KLT match, off the row, disparity out of range).
    pub stereo_rejected: usize,
    /// Observations delivered (sum over frames).
    pub observations: usize,
}

/// FAST + KLT stereo tracker. Feed it the left and right image of each frame in time order.
pub struct StereoTracker {
    pub cfg: TrackerConfig,
    cam: StereoCamera,
    prev: Option<Vec<GrayImage>>,
    /// Tracked features in the previous left image: (id, pixel position).
    features: Vec<(u64, (f32, f32))>,
    next_id: u64,
    disparity_guess_px: f32,
    pub stats: FrontendStats,
}

fn to_gray(img: &GrayImage) -> Gray {
    Gray { rows: img.height() as usize, cols: img.width() as usize, data: img.as_raw().iter().map(|&v| f64::from(v) / 255.0).collect() }
}

fn to_u8(img: &Gray) -> GrayImage {
    let data = img.data.iter().map(|v| (v * 255.0).round().clamp(0.0, 255.0) as u8).collect();
    GrayImage::from_raw(img.cols as u32, img.rows as u32, data).unwrap_or_default()
}

impl StereoTracker {
    pub fn new(cam: StereoCamera, cfg: TrackerConfig) -> Self {
        let guess = (cam.focal_px * cam.baseline_m / 5.0) as f32;
        Self { cfg, cam, prev: None, features: Vec::new(), next_id: 0, disparity_guess_px: guess, stats: FrontendStats::default() }
    }

    /// The enhanced image the tracker works on (dehazed when configured).
    pub fn enhance(&self, img: &GrayImage) -> GrayImage {
        match self.cfg.dehaze {
            Some((radius, omega, t0)) if img.width() > 0 && img.height() > 0 => to_u8(&dehaze(&to_gray(img), radius, omega, t0).0),
            _ => img.clone(),
        }
    }

    /// Pixel -> normalized water-side coordinates (flat port undone when configured).
    pub fn normalize(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        let (cx, cy) = ((self.cam.width_px.round() - 1.0) / 2.0, (self.cam.height_px.round() - 1.0) / 2.0);
        let (x, y) = ((u - cx) / self.cam.focal_px, (v - cy) / self.cam.focal_px);
        if self.cfg.refraction { refract_air_to_water(x, y, self.cfg.n_water) } else { Some((x, y)) }
    }

    fn params(&self) -> TrackParams {
        TrackParams {
            window_size: self.cfg.window_px | 1,
            max_iterations: 30,
            min_eigen_threshold: optical_flow_lk::DEFAULT_MIN_EIGEN_THRESHOLD,
        }
    }

    /// One stereo frame: returns the observations `(feature id, [u_l, v_l, u_r, v_r])` in normalized
    /// water-side coordinates. Images of a size other than the camera's give no observations.
    pub fn process(&mut self, left: &GrayImage, right: &GrayImage) -> Vec<(u64, StereoObs)> {
        self.stats.frames += 1;
        let (w, h) = (self.cam.width_px.round() as u32, self.cam.height_px.round() as u32);
        if left.dimensions() != (w, h) || right.dimensions() != (w, h) || w < 2 * self.cfg.border_px + 8 || h < 2 * self.cfg.border_px + 8 {
            self.prev = None;
            self.features.clear();
            return Vec::new();
        }
        let levels = self.cfg.pyramid_levels.clamp(1, 6);
        let (lp, rp) = std::thread::scope(|s| {
            let r = s.spawn(|| build_pyramid(&self.enhance(right), levels));
            let l = build_pyramid(&self.enhance(left), levels);
            (l, r.join().unwrap_or_else(|_| build_pyramid(&self.enhance(right), levels)))
        });
        let params = self.params();
        let border = self.cfg.border_px as f32;
        let inside = |p: (f32, f32)| p.0 >= border && p.1 >= border && p.0 < w as f32 - border && p.1 < h as f32 - border;

        // 1. Frame to frame.
        let mut cur: Vec<(u64, (f32, f32))> = Vec::with_capacity(self.cfg.max_features);
        if let Some(prev) = &self.prev
            && !self.features.is_empty()
        {
            let pts: Vec<(f32, f32)> = self.features.iter().map(|f| f.1).collect();
            let res = calc_optical_flow_fb(prev, &lp, &pts, None, params, self.cfg.fb_threshold_px);
            for (f, r) in self.features.iter().zip(&res) {
                if r.status == TrackStatus::Tracked && inside(r.pos) {
                    cur.push((f.0, r.pos));
                } else {
                    self.stats.lost += 1;
                }
            }
            self.stats.tracked += cur.len();
        }
        let n_tracked = cur.len();

        // 2. New FAST corners where the image has no feature yet: best per bucket, best buckets first.
        if cur.len() < self.cfg.max_features {
            let cell = self.cfg.min_distance_px.max(4);
            let (gw, gh) = (w.div_ceil(cell) as usize, h.div_ceil(cell) as usize);
            let mut taken = vec![false; gw * gh];
            let bucket = |x: f32, y: f32| (y as usize / cell as usize).min(gh - 1) * gw + (x as usize / cell as usize).min(gw - 1);
            for &(_, p) in &cur {
                taken[bucket(p.0, p.1)] = true;
            }
            let mut best: Vec<Option<imageproc::corners::Corner>> = vec![None; gw * gh];
            for c in imageproc::corners::corners_fast9(&lp[0], self.cfg.fast_threshold) {
                if !inside((c.x as f32, c.y as f32)) {
                    continue;
                }
                let b = bucket(c.x as f32, c.y as f32);
                if !taken[b] && best[b].is_none_or(|o| c.score > o.score) {
                    best[b] = Some(c);
                }
            }
            let mut fresh: Vec<imageproc::corners::Corner> = best.into_iter().flatten().collect();
            fresh.sort_by(|a, b| b.score.total_cmp(&a.score));
            fresh.truncate(self.cfg.max_features - cur.len());
            for c in fresh {
                cur.push((u64::MAX, (c.x as f32, c.y as f32)));
            }
        }

        // 3. Left to right on the same row, seeded with the running disparity.
        let pts: Vec<(f32, f32)> = cur.iter().map(|f| f.1).collect();
        let pred: Vec<(f32, f32)> = pts.iter().map(|p| (p.0 - self.disparity_guess_px, p.1)).collect();
        let res =
            if pts.is_empty() { Vec::new() } else { calc_optical_flow_fb(&lp, &rp, &pts, Some(&pred), params, self.cfg.fb_threshold_px) };
        let mut out = Vec::with_capacity(cur.len());
        let mut kept = Vec::with_capacity(cur.len());
        let mut disparities = Vec::with_capacity(cur.len());
        for (k, ((id, pl), r)) in cur.into_iter().zip(&res).enumerate() {
            let disparity = f64::from(pl.0 - r.pos.0);
            let ok = r.status == TrackStatus::Tracked
                && f64::from((r.pos.1 - pl.1).abs()) <= self.cfg.max_row_diff_px
                && disparity >= self.cfg.disparity_px.0
                && disparity <= self.cfg.disparity_px.1;
            let obs = ok
                .then(|| self.normalize(f64::from(pl.0), f64::from(pl.1)).zip(self.normalize(f64::from(r.pos.0), f64::from(r.pos.1))))
                .flatten();
            let Some(((xl, yl), (xr, yr))) = obs else {
                if k < n_tracked {
                    self.stats.lost += 1;
                }
                self.stats.stereo_rejected += 1;
                continue;
            };
            let id = if id == u64::MAX {
                self.next_id += 1;
                self.stats.started += 1;
                self.next_id - 1
            } else {
                id
            };
            disparities.push(disparity as f32);
            kept.push((id, pl));
            out.push((id, StereoObs::new(xl, yl, xr, yr)));
        }
        if !disparities.is_empty() {
            disparities.sort_by(f32::total_cmp);
            self.disparity_guess_px = disparities[disparities.len() / 2];
        }
        self.features = kept;
        self.prev = Some(lp);
        self.stats.observations += out.len();
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn snell_hand_case() {
        // 30 deg in air: tan = 0.57735; sin 30 = 0.5 -> sin theta_w = 0.5 / 1.34 = 0.373134,
        // cos theta_w = sqrt(1 - 0.139229) = 0.927777, tan theta_w = 0.402181.
        let (xw, yw) = refract_air_to_water(30f64.to_radians().tan(), 0.0, N_SEAWATER).unwrap();
        assert!((xw - 0.402_181).abs() < 1e-5 && yw == 0.0, "{xw}");
        // Round trip, off-axis.
        let (a, b) = refract_air_to_water(0.3, -0.45, N_SEAWATER).unwrap();
        let (c, d) = refract_water_to_air(a, b, N_SEAWATER).unwrap();
        assert!((c - 0.3).abs() < 1e-12 && (d + 0.45).abs() < 1e-12);
        // Water narrows the field of view: the water-side ray is closer to the axis.
        assert!(a.hypot(b) < 0.3f64.hypot(0.45));
    }

    #[test]
    fn dehazing_recovers_a_scene_that_has_dark_pixels_everywhere() {
        // Scene: a pattern with a zero in every 3x3 block (the prior holds), haze t = 0.4, A = 0.8,
        // and open water (I = A) in the top 6 rows, where A is found.
        let (rows, cols) = (36, 30);
        let (t, a) = (0.4, 0.8);
        let scene: Vec<f64> = (0..rows * cols)
            .map(|i| if (i / cols) % 3 == 1 && (i % cols) % 3 == 1 { 0.0 } else { 0.2 + 0.6 * (((i * 37) % 11) as f64 / 10.0) })
            .collect();
        let hazy =
            Gray::new(rows, cols, (0..rows * cols).map(|i| if i / cols < 6 { a } else { scene[i] * t + a * (1.0 - t) }).collect()).unwrap();
        let (j, a_est) = dehaze(&hazy, 2, 1.0, 0.1);
        assert!((a_est - a).abs() < 1e-12, "veiling light {a_est}");
        // Pixels whose patch lies in the scene come back exactly (t is recovered exactly there).
        let mut worst: f64 = 0.0;
        for y in 9..rows - 3 {
            for x in 3..cols - 3 {
                worst = worst.max((j.at(y, x) - scene[y * cols + x]).abs());
            }
        }
        assert!(worst < 1e-9, "worst {worst}");
    }
}
