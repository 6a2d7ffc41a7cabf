//! Trajectory evaluation in the manner of OpenVINS's ov_eval: absolute trajectory error (ATE,
//! RMSE of position and orientation), relative pose error (RPE: position error of the relative
//! motion over segments of fixed travelled length, in the segment's start frame), normalized
//! estimation error squared (NEES, 3-dof orientation and position, averaged over time), and final
//! drift as a percentage of the distance travelled.
//!
//! No alignment is applied: the filter's world frame is the start pose (position and the yaw the
//! static initialization fixes), and the truth is expressed in the same frame, which is stricter
//! than ov_eval's position+yaw alignment.

use nalgebra::{Matrix3, Vector3};

use super::data::TruthSample;
use super::odometry::EstPose;
use subnav_base::so3;

#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct Metrics {
    pub distance_m: f64,
    pub final_error_m: f64,
    pub drift_pct: f64,
    pub ate_pos_m: f64,
    pub ate_ori_deg: f64,
    /// Mean RPE (position) over segments of `rpe_lengths_m`.
    pub rpe_m: Vec<(f64, f64)>,
    pub nees_ori: f64,
    pub nees_pos: f64,
    /// Position NEES split: horizontal (2-dof, consistent = 2) and vertical (1-dof, consistent = 1),
    /// each from its own marginal covariance block.
    pub nees_pos_h: f64,
    pub nees_pos_z: f64,
    /// 3-dof position NEES averaged over each quarter of the run (growth = overconfidence building up).
    pub nees_pos_quarters: [f64; 4],
    pub poses: usize,
}

/// The truth at time `t` (linear in position, nearest in rotation), expressed relative to the start.
fn truth_at(truth: &[TruthSample], t: f64) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let i = truth.partition_point(|s| s.t_s < t);
    let j = i.min(truth.len().checked_sub(1)?);
    let a = &truth[j.saturating_sub(1)];
    let b = &truth[j];
    let u = if b.t_s > a.t_s { ((t - a.t_s) / (b.t_s - a.t_s)).clamp(0.0, 1.0) } else { 0.0 };
    let rot = if u < 0.5 { a.rot } else { b.rot };
    Some((rot, a.pos_w_m * (1.0 - u) + b.pos_w_m * u))
}

pub fn evaluate(est: &[EstPose], truth: &[TruthSample], rpe_lengths_m: &[f64]) -> Metrics {
    let Some(origin) = truth.first().map(|s| s.pos_w_m) else { return Metrics::default() };
    let pairs: Vec<(&EstPose, Matrix3<f64>, Vector3<f64>)> =
        est.iter().filter_map(|e| truth_at(truth, e.t_s).map(|(r, p)| (e, r, p - origin))).collect();
    if pairs.is_empty() {
        return Metrics::default();
    }
    let n = pairs.len() as f64;
    let (mut se_p, mut se_r, mut nees_r, mut nees_p) = (0.0, 0.0, 0.0, 0.0);
    let (mut nees_h, mut nees_z) = (0.0, 0.0);
    let (mut q_sum, mut q_cnt) = ([0.0; 4], [0usize; 4]);
    let mut n_nees = 0usize;
    let mut dist = vec![0.0; pairs.len()];
    for (k, (e, r, p)) in pairs.iter().enumerate() {
        let dp = p - e.pos_w_m;
        let dth = so3::log(&(e.rot.transpose() * r));
        se_p += dp.norm_squared();
        se_r += dth.norm_squared();
        let pr = e.cov.fixed_view::<3, 3>(0, 0).into_owned();
        let pp = e.cov.fixed_view::<3, 3>(3, 3).into_owned();
        if let (Some(ir), Some(ip)) = (pr.try_inverse(), pp.try_inverse()) {
            nees_r += (dth.transpose() * ir * dth)[(0, 0)];
            let np = (dp.transpose() * ip * dp)[(0, 0)];
            nees_p += np;
            let q = (4 * k / pairs.len()).min(3);
            q_sum[q] += np;
            q_cnt[q] += 1;
            let ph = pp.fixed_view::<2, 2>(0, 0).into_owned();
            if let Some(ih) = ph.try_inverse() {
                let dh = dp.fixed_rows::<2>(0).into_owned();
                nees_h += (dh.transpose() * ih * dh)[(0, 0)];
            }
            if pp[(2, 2)] > 0.0 {
                nees_z += dp.z * dp.z / pp[(2, 2)];
            }
            n_nees += 1;
        }
        if k > 0 {
            dist[k] = dist[k - 1] + (p - pairs[k - 1].2).norm();
        }
    }
    let total = *dist.last().unwrap_or(&0.0);
    let (e_last, _, p_last) = pairs[pairs.len() - 1];
    let final_error_m = (p_last - e_last.pos_w_m).norm();
    let mut rpe = Vec::new();
    for &len in rpe_lengths_m {
        let (mut sum, mut cnt) = (0.0, 0usize);
        let mut j = 0;
        for i in 0..pairs.len() {
            while j < pairs.len() && dist[j] - dist[i] < len {
                j += 1;
            }
            if j >= pairs.len() {
                break;
            }
            let (ei, ri, pi) = &pairs[i];
            let (ej, _, pj) = &pairs[j];
            let rel_t = ri.transpose() * (pj - pi);
            let rel_e = ei.rot.transpose() * (ej.pos_w_m - ei.pos_w_m);
            sum += (rel_t - rel_e).norm();
            cnt += 1;
        }
        if cnt > 0 {
            rpe.push((len, sum / cnt as f64));
        }
    }
    Metrics {
        distance_m: total,
        final_error_m,
        drift_pct: if total > 0.0 { 100.0 * final_error_m / total } else { 0.0 },
        ate_pos_m: (se_p / n).sqrt(),
        ate_ori_deg: (se_r / n).sqrt().to_degrees(),
        rpe_m: rpe,
        nees_ori: nees_r / n_nees.max(1) as f64,
        nees_pos: nees_p / n_nees.max(1) as f64,
        nees_pos_h: nees_h / n_nees.max(1) as f64,
        nees_pos_z: nees_z / n_nees.max(1) as f64,
        nees_pos_quarters: std::array::from_fn(|q| if q_cnt[q] > 0 { q_sum[q] / q_cnt[q] as f64 } else { f64::NAN }),
        poses: pairs.len(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::SMatrix;

    #[test]
    fn hand_computed_metrics() {
        // Straight line 0..10 m along x; the estimate is 1 % long (x_est = 1.01 x) with P = I.
        let truth: Vec<TruthSample> = (0..=10)
            .map(|i| TruthSample {
                t_s: i as f64,
                rot: Matrix3::identity(),
                pos_w_m: Vector3::new(i as f64, 0.0, 5.0),
                vel_w_mps: Vector3::x(),
            })
            .collect();
        let est: Vec<EstPose> = (0..=10)
            .map(|i| EstPose {
                t_s: i as f64,
                rot: Matrix3::identity(),
                pos_w_m: Vector3::new(1.01 * i as f64, 0.0, 0.0),
                cov: SMatrix::identity(),
            })
            .collect();
        let m = evaluate(&est, &truth, &[5.0]);
        assert!((m.distance_m - 10.0).abs() < 1e-12);
        assert!((m.final_error_m - 0.1).abs() < 1e-12 && (m.drift_pct - 1.0).abs() < 1e-9);
        // ATE: sqrt(mean((0.01 i)^2)) over i = 0..10 = 0.01 sqrt(385 / 11).
        assert!((m.ate_pos_m - 0.01 * (385.0f64 / 11.0).sqrt()).abs() < 1e-12);
        // RPE over 5 m: every segment is 0.05 m too long.
        assert!((m.rpe_m[0].1 - 0.05).abs() < 1e-12);
        // NEES_pos: mean of (0.01 i)^2 = 1e-4 * 385 / 11.
        assert!((m.nees_pos - 1e-4 * 35.0).abs() < 1e-12);
        // All the error is horizontal (x): the split puts it there.
        assert!((m.nees_pos_h - 1e-4 * 35.0).abs() < 1e-12 && m.nees_pos_z == 0.0);
        // Quarters of 11 poses: k * 4 / 11 -> {0,1,2}, {3,4,5}, {6,7,8}, {9,10}.
        assert!((m.nees_pos_quarters[3] - 1e-4 * (81.0 + 100.0) / 2.0).abs() < 1e-12);
        assert_eq!(m.nees_ori, 0.0);
    }
}
