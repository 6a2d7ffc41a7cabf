//! The feature vector of one polarization image (spec A3: "intensity, DoLP and AoP statistics of
//! the scene"), plus texture. A downward camera revisits a place at another heading, so most
//! features are invariant to image rotation (global statistics, ring means around the image
//! centre, structure-tensor anisotropy); the AoP direction itself rotates with heading and the
//! sky, so it enters only as its concentration and as cos/sin of twice its mean, which LMNN can
//! weigh down if it does not help. Intensity features are relative (divided by the mean) except
//! the log mean, so a brighter or darker pass over the same place still matches.
//!
//! | # | name | what |
//! |---|------|------|
//! | 0 | `log_s0_mean` | log mean intensity |
//! | 1 | `s0_cv` | intensity std / mean |
//! | 2-4 | `s0_p10`, `s0_p50`, `s0_p90` | intensity quantiles / mean |
//! | 5 | `grad_energy` | mean gradient magnitude / mean |
//! | 6 | `anisotropy` | structure-tensor coherence (lambda1 - lambda2) / (lambda1 + lambda2) |
//! | 7-9 | `ring_inner`, `ring_mid`, `ring_outer` | mean intensity in 3 rings around the centre / mean |
//! | 10-13 | `dolp_mean`, `dolp_std`, `dolp_p10`, `dolp_p90` | DoLP statistics |
//! | 14 | `dolp_s0_corr` | correlation of DoLP and intensity over the image |
//! | 15 | `aop_concentration` | DoLP-weighted resultant length of exp(2i AoP) |
//! | 16-17 | `aop_cos2`, `aop_sin2` | cos/sin of twice the mean AoP |
//! | 18 | `bright_fraction` | fraction of pixels brighter than mean + std |
//! | 19 | `laplacian_energy` | mean absolute Laplacian / mean (fine texture) |

use super::stokes::StokesImage;

pub const N_FEATURES: usize = 20;

pub const FEATURE_NAMES: [&str; N_FEATURES] = [
    "log_s0_mean",
    "s0_cv",
    "s0_p10",
    "s0_p50",
    "s0_p90",
    "grad_energy",
    "anisotropy",
    "ring_inner",
    "ring_mid",
    "ring_outer",
    "dolp_mean",
    "dolp_std",
    "dolp_p10",
    "dolp_p90",
    "dolp_s0_corr",
    "aop_concentration",
    "aop_cos2",
    "aop_sin2",
    "bright_fraction",
    "laplacian_energy",
];

fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len().max(1) as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n;
    (m, var.sqrt())
}

fn quantiles(v: &[f64], qs: &[f64]) -> Vec<f64> {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    qs.iter().map(|q| s.get(((s.len().saturating_sub(1)) as f64 * q).round() as usize).copied().unwrap_or(0.0)).collect()
}

/// The feature vector of a Stokes image (any size >= 3x3). Non-finite inputs give non-finite
/// features; callers check (the map refuses them).
pub fn features(st: &StokesImage) -> [f64; N_FEATURES] {
    let (w, h) = (st.s0.width, st.s0.height);
    let s0 = &st.s0.data;
    let (m, sd) = mean_std(s0);
    let inv = if m.abs() > 1e-300 { 1.0 / m } else { 0.0 };
    let q = quantiles(s0, &[0.1, 0.5, 0.9]);
    // Gradients, structure tensor and Laplacian on the interior.
    let (mut g_sum, mut jxx, mut jyy, mut jxy, mut lap, mut cnt) = (0.0, 0.0, 0.0, 0.0, 0.0, 0usize);
    for r in 1..h.saturating_sub(1) {
        for c in 1..w.saturating_sub(1) {
            let gx = 0.5 * (st.s0.at(r, c + 1) - st.s0.at(r, c - 1));
            let gy = 0.5 * (st.s0.at(r + 1, c) - st.s0.at(r - 1, c));
            g_sum += (gx * gx + gy * gy).sqrt();
            jxx += gx * gx;
            jyy += gy * gy;
            jxy += gx * gy;
            lap += (st.s0.at(r, c + 1) + st.s0.at(r, c - 1) + st.s0.at(r + 1, c) + st.s0.at(r - 1, c) - 4.0 * st.s0.at(r, c)).abs();
            cnt += 1;
        }
    }
    let cnt = cnt.max(1) as f64;
    let tr = jxx + jyy;
    let aniso = if tr > 0.0 { ((jxx - jyy).powi(2) + 4.0 * jxy * jxy).sqrt() / tr } else { 0.0 };
    // Rings around the centre, radius normalised by the half-diagonal... of the inscribed circle.
    let (cr, cc) = ((h as f64 - 1.0) / 2.0, (w as f64 - 1.0) / 2.0);
    let rmax = cr.min(cc).max(1.0);
    let mut rings = [(0.0, 0usize); 3];
    for r in 0..h {
        for c in 0..w {
            let rho = ((r as f64 - cr).powi(2) + (c as f64 - cc).powi(2)).sqrt() / rmax;
            let k = if rho < 1.0 / 3.0 {
                0
            } else if rho < 2.0 / 3.0 {
                1
            } else if rho <= 1.0 {
                2
            } else {
                continue;
            };
            rings[k].0 += st.s0.at(r, c);
            rings[k].1 += 1;
        }
    }
    let ring = |k: usize| rings[k].0 / rings[k].1.max(1) as f64 * inv;
    let dolp = &st.dolp.data;
    let (dm, dsd) = mean_std(dolp);
    let dq = quantiles(dolp, &[0.1, 0.9]);
    let cov = s0.iter().zip(dolp).map(|(a, b)| (a - m) * (b - dm)).sum::<f64>() / s0.len().max(1) as f64;
    let corr = if sd > 0.0 && dsd > 0.0 { cov / (sd * dsd) } else { 0.0 };
    let (mut ac, mut as_, mut wsum) = (0.0, 0.0, 0.0);
    for (a, d) in st.aop_rad.data.iter().zip(dolp) {
        ac += d * (2.0 * a).cos();
        as_ += d * (2.0 * a).sin();
        wsum += d;
    }
    let conc = if wsum > 0.0 { (ac * ac + as_ * as_).sqrt() / wsum } else { 0.0 };
    let ang = as_.atan2(ac);
    let bright = s0.iter().filter(|&&v| v > m + sd).count() as f64 / s0.len().max(1) as f64;
    [
        m.max(1e-12).ln(),
        sd * inv,
        q[0] * inv,
        q[1] * inv,
        q[2] * inv,
        g_sum / cnt * inv,
        aniso,
        ring(0),
        ring(1),
        ring(2),
        dm,
        dsd,
        dq[0],
        dq[1],
        corr,
        conc,
        ang.cos(),
        ang.sin(),
        bright,
        lap / cnt * inv,
    ]
}
