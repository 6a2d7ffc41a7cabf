//! Weak data association between consecutive swaths (spec C3). Consecutive multibeam swaths do
//! not overlap, so the terrain seen by the last `history` swaths is extrapolated forward (per
//! across-track position, a straight-line fit of depth against along-track distance) to the
//! soundings of the next swath. The residuals give the likelihood p(X_{i+1} | X_i, u_i) of the
//! dead-reckoned step: linearised, r = -g . delta, with g the extrapolated terrain gradient and
//! delta the step error, so the association carries an information matrix J = sum g g^T / s^2
//! on the step (s^2 = extrapolation variance + sounding noise). The spring model uses J as
//! extra stiffness of that step.

use super::{NavSample, Point, V2};
use nalgebra::Matrix2;

#[derive(Debug, Clone, serde::Serialize)]
pub struct AssocConfig {
    pub history: usize,
    pub min_soundings: usize,
    /// Floor on the per-sounding prediction sigma (m): sounding noise.
    pub sigma_floor_m: f64,
}

impl Default for AssocConfig {
    fn default() -> Self {
        Self { history: 4, min_soundings: 10, sigma_floor_m: 0.15 }
    }
}

#[derive(Debug, Clone, Copy)]
pub struct StepAssociation {
    /// Mean log-likelihood per sounding of the dead-reckoned step (Gaussian, up to a constant).
    pub mean_ln_p: f64,
    /// Information on the step error (north, east), 1/m^2.
    pub info: Matrix2<f64>,
    /// Least-squares estimate of the step error (north, east) where observable (minimum norm).
    pub delta: V2,
    pub soundings: usize,
}

struct Profile {
    /// (across, along, depth), sorted by across.
    s: Vec<(f64, f64, f64)>,
}

impl Profile {
    fn at(&self, c: f64) -> Option<(f64, f64, f64)> {
        let s = &self.s;
        if s.len() < 2 || c < s[0].0 || c > s[s.len() - 1].0 {
            return None;
        }
        let k = s.partition_point(|v| v.0 < c).clamp(1, s.len() - 1);
        let (p, q) = (s[k - 1], s[k]);
        let w = if q.0 > p.0 { (c - p.0) / (q.0 - p.0) } else { 0.0 };
        // Keep interpolation local: no bridging of gaps wider than 10 m.
        if q.0 - p.0 > 10.0 {
            return None;
        }
        let slope = if q.0 > p.0 { (q.2 - p.2) / (q.0 - p.0) } else { 0.0 };
        Some((p.1 + w * (q.1 - p.1), p.2 + w * (q.2 - p.2), slope))
    }
}

fn profile(points: &[Point], o: V2, f: V2, s: V2) -> Profile {
    let mut v: Vec<(f64, f64, f64)> = points
        .iter()
        .filter(|p| p.north_m.is_finite() && p.east_m.is_finite() && p.depth_m.is_finite())
        .map(|p| {
            let d = V2::new(p.north_m, p.east_m) - o;
            (d.dot(&s), d.dot(&f), p.depth_m)
        })
        .collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    Profile { s: v }
}

/// Association of every step: `out[i]` is about the step (i-1 -> i); `None` where it cannot be
/// formed (first pings, too few soundings).
pub fn associate(points: &[Vec<Point>], nav: &[NavSample], cfg: &AssocConfig) -> Vec<Option<StepAssociation>> {
    let k = cfg.history.max(2);
    (0..points.len().min(nav.len())).map(|i| if i < k { None } else { associate_step(points, nav, i, k, cfg) }).collect()
}

fn associate_step(points: &[Vec<Point>], nav: &[NavSample], i: usize, k: usize, cfg: &AssocConfig) -> Option<StepAssociation> {
    let n = &nav[i];
    let o = V2::new(n.north_m, n.east_m);
    let f = V2::new(n.heading_rad.cos(), n.heading_rad.sin());
    let s = V2::new(-n.heading_rad.sin(), n.heading_rad.cos());
    let hist: Vec<Profile> = (i - k..i).map(|m| profile(&points[m], o, f, s)).collect();
    let cur = profile(&points[i], o, f, s);
    let mut info = Matrix2::zeros();
    let mut grad_r = nalgebra::Vector2::zeros();
    let (mut ll, mut cnt) = (0.0, 0usize);
    let floor2 = cfg.sigma_floor_m.powi(2);
    for &(c, a, d) in &cur.s {
        let samples: Vec<(f64, f64, f64)> = hist.iter().filter_map(|p| p.at(c)).collect();
        if samples.len() < 3 {
            continue;
        }
        // Straight-line fit d = alpha + beta * along over the history.
        let m = samples.len() as f64;
        let (sa, sd) = samples.iter().fold((0.0, 0.0), |x, v| (x.0 + v.0, x.1 + v.1));
        let (ma, md) = (sa / m, sd / m);
        let saa: f64 = samples.iter().map(|v| (v.0 - ma).powi(2)).sum();
        if saa < 1e-6 {
            continue;
        }
        let beta = samples.iter().map(|v| (v.0 - ma) * (v.1 - md)).sum::<f64>() / saa;
        let alpha = md - beta * ma;
        let fit_var = samples.iter().map(|v| (v.1 - alpha - beta * v.0).powi(2)).sum::<f64>() / (m - 2.0).max(1.0);
        // Prediction variance of the extrapolated line at `a`.
        let pred_var = fit_var * (1.0 + 1.0 / m + (a - ma).powi(2) / saa) + floor2;
        let pred = alpha + beta * a;
        let across_slope = samples.iter().map(|v| v.2).sum::<f64>() / m;
        let r = d - pred;
        // Gradient of the predicted terrain in the (along, across) frame, rotated to NED.
        let g = f * beta + s * across_slope;
        info += g * g.transpose() / pred_var;
        grad_r += g * r / pred_var;
        ll += -0.5 * r * r / pred_var;
        cnt += 1;
    }
    if cnt < cfg.min_soundings {
        return None;
    }
    // r = -g . delta  =>  delta = -J^+ sum g r / s^2 (pseudo-inverse: unobservable directions 0).
    let eig = info.symmetric_eigen();
    let mut pinv = Matrix2::zeros();
    let tol = eig.eigenvalues.max() * 1e-6;
    for j in 0..2 {
        let l = eig.eigenvalues[j];
        if l > tol && l > 0.0 {
            let v = eig.eigenvectors.column(j);
            pinv += v * v.transpose() / l;
        }
    }
    let delta = -(pinv * grad_r);
    Some(StepAssociation { mean_ln_p: ll / cnt as f64, info: (info + info.transpose()) * 0.5, delta, soundings: cnt })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Swaths over a sloping plane; the last one is placed with a step error `delta`.
    fn plane_swaths(delta: V2) -> (Vec<Vec<Point>>, Vec<NavSample>) {
        let depth = |n: f64, e: f64| 30.0 + 0.08 * n - 0.15 * e;
        let mut pts = vec![];
        let mut nav = vec![];
        for i in 0..6 {
            let (tn, te) = (2.0 * i as f64, 0.0);
            let (dn, de) = if i == 5 { (tn + delta.x, te + delta.y) } else { (tn, te) };
            nav.push(NavSample { t_s: i as f64, north_m: dn, east_m: de, depth_m: 10.0, heading_rad: 0.0, vel_sigma_mps: 0.01 });
            // Soundings sampled at the true position, placed at the dead-reckoned one.
            pts.push((-40..=40).map(|k| Point { north_m: dn, east_m: de + k as f64, depth_m: depth(tn, te + k as f64) }).collect());
        }
        (pts, nav)
    }

    #[test]
    fn plane_extrapolation_is_exact_and_step_error_along_the_gradient_is_recovered() {
        let (pts, nav) = plane_swaths(V2::zeros());
        let a = associate(&pts, &nav, &AssocConfig::default());
        let s = a[5].expect("association formed");
        assert!(s.mean_ln_p.abs() < 1e-12 && s.delta.norm() < 1e-9);
        let delta = V2::new(0.3, -0.2);
        let (pts, nav) = plane_swaths(delta);
        let s = associate(&pts, &nav, &AssocConfig::default())[5].unwrap();
        // On a plane only the component along the gradient is observable.
        let g = V2::new(0.08, -0.15);
        assert!((s.delta.dot(&g) - delta.dot(&g)).abs() < 1e-6, "{:?}", s.delta);
        assert!(s.mean_ln_p < 0.0);
        assert!(a[0].is_none());
    }
}
