//! Image enhancement steps of the stereo front end (D3): dark-channel-prior dehazing and the
//! flat-port refraction model. (The FAST + KLT tracker on rendered ice images is not built yet:
//! the back end runs on feature tracks from the simulator or a file, see `data`.)
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
    idx.sort_by(|&a, &b| dark.data[b].total_cmp(&dark.data[a]));
    let top = (n / 1000).max(1);
    let a = idx[..top].iter().map(|&i| img.data[i]).fold(1e-6, f64::max);
    let norm = Gray { rows: img.rows, cols: img.cols, data: img.data.iter().map(|v| v / a).collect() };
    let dn = dark_channel(&norm, radius);
    let data = img.data.iter().zip(&dn.data).map(|(&i, &d)| (i - a) / (1.0 - omega * d).max(t0) + a).collect();
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
