//! The sliding window of camera clones and the spec's pruning rule (D3): when the window is
//! full, two clones are removed at a time.
//!
//! Our reading of the rule (the spec's sentence is terse): with the window ordered oldest
//! `f_0` .. newest `f_{n-1}`, let `k = n - 2` (the newest frame is always kept: tracking continues
//! from it).
//! - Pass 1: if tracking is good and `f_k` moved less than `max_translation_m` and rotated less
//!   than `max_rotation_rad` relative to `f_{k-3}`, remove `f_k`; otherwise remove the oldest frame.
//! - Pass 2: the same test for `f_{k-1}` relative to `f_{k-3}` (two frames back from it); if it
//!   fails, remove the oldest frame not removed yet.
//!
//! A frame close to its neighbours adds little parallax, so dropping it keeps the window's
//! baseline; otherwise the oldest goes (its features are used in an update first).

use nalgebra::{Matrix3, Vector3};

use subnav_base::so3;

/// Thresholds of the pruning rule.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct PruneConfig {
    pub max_translation_m: f64,
    pub max_rotation_rad: f64,
}

impl Default for PruneConfig {
    fn default() -> Self {
        Self { max_translation_m: 0.25, max_rotation_rad: 0.035 }
    }
}

/// A clone pose as the rule sees it (world <- body rotation and position).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseRef<'a> {
    pub rot: &'a Matrix3<f64>,
    pub pos: &'a Vector3<f64>,
}

fn close(a: PoseRef, b: PoseRef, cfg: &PruneConfig) -> bool {
    let dp = (a.pos - b.pos).norm();
    let dr = so3::log(&(a.rot.transpose() * b.rot)).norm();
    dp < cfg.max_translation_m && dr < cfg.max_rotation_rad
}

/// Indices (into `poses`, oldest first) of the two clones to remove, ascending. `None` when the
/// window has fewer than 5 frames (the rule needs `f_{k-3}` and keeps the newest).
pub fn select_two_to_prune(poses: &[PoseRef], tracking_good: bool, cfg: &PruneConfig) -> Option<[usize; 2]> {
    let n = poses.len();
    if n < 5 {
        return None;
    }
    let k = n - 2;
    let mut removed: Vec<usize> = Vec::with_capacity(2);
    let oldest_left = |removed: &[usize]| (0..n).find(|i| !removed.contains(i)).unwrap_or(0);
    for cand in [k, k - 1] {
        if tracking_good && close(poses[cand], poses[k - 3], cfg) && !removed.contains(&cand) {
            removed.push(cand);
        } else {
            let o = oldest_left(&removed);
            removed.push(o);
        }
    }
    removed.sort_unstable();
    Some([removed[0], removed[1]])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn poses(xs: &[f64]) -> (Vec<Matrix3<f64>>, Vec<Vector3<f64>>) {
        (xs.iter().map(|_| Matrix3::identity()).collect(), xs.iter().map(|&x| Vector3::new(x, 0.0, 0.0)).collect())
    }

    fn refs<'a>(r: &'a [Matrix3<f64>], p: &'a [Vector3<f64>]) -> Vec<PoseRef<'a>> {
        r.iter().zip(p).map(|(rot, pos)| PoseRef { rot, pos }).collect()
    }

    #[test]
    fn hand_cases_of_the_two_at_a_time_rule() {
        let cfg = PruneConfig { max_translation_m: 0.25, max_rotation_rad: 0.035 };
        // 7 frames, k = 5, f_{k-3} = f_2 at x = 2.0.
        // f_5 at 2.1 (0.1 m from f_2: close), f_4 at 2.2 (0.2 m: close) -> remove 4 and 5.
        let (r, p) = poses(&[0.0, 1.0, 2.0, 2.05, 2.2, 2.1, 2.15]);
        assert_eq!(select_two_to_prune(&refs(&r, &p), true, &cfg), Some([4, 5]));
        // Same poses but tracking is poor -> the two oldest.
        assert_eq!(select_two_to_prune(&refs(&r, &p), false, &cfg), Some([0, 1]));
        // f_5 at 2.3 (0.3 m: moved), f_4 at 2.2 (close) -> oldest (0) and 4.
        let (r, p) = poses(&[0.0, 1.0, 2.0, 2.05, 2.2, 2.3, 2.4]);
        assert_eq!(select_two_to_prune(&refs(&r, &p), true, &cfg), Some([0, 4]));
        // f_5 close, f_4 moved (2.5) -> 5 and oldest.
        let (r, p) = poses(&[0.0, 1.0, 2.0, 2.05, 2.5, 2.1, 2.4]);
        assert_eq!(select_two_to_prune(&refs(&r, &p), true, &cfg), Some([0, 5]));
        // Steady motion of 0.5 m per frame -> the two oldest.
        let (r, p) = poses(&[0.0, 0.5, 1.0, 1.5, 2.0, 2.5]);
        assert_eq!(select_two_to_prune(&refs(&r, &p), true, &cfg), Some([0, 1]));
        // Too few frames.
        let (r, p) = poses(&[0.0, 0.5, 1.0, 1.5]);
        assert_eq!(select_two_to_prune(&refs(&r, &p), true, &cfg), None);
    }

    #[test]
    fn rotation_threshold_applies() {
        let cfg = PruneConfig { max_translation_m: 0.25, max_rotation_rad: 0.035 };
        let (mut r, p) = poses(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        // k = 4, f_{k-3} = f_1. f_4 yawed 0.05 rad (> 0.035) -> not close; f_3 yawed 0.02 -> close.
        r[4] = so3::exp(&Vector3::new(0.0, 0.0, 0.05));
        r[3] = so3::exp(&Vector3::new(0.0, 0.0, 0.02));
        assert_eq!(select_two_to_prune(&refs(&r, &p), true, &cfg), Some([0, 3]));
    }
}
