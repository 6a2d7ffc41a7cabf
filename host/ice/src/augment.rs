//! Clone augmentation (spec D3, patent s313-s315): every image appends a clone of the IMU pose
//! (the IMU-based method, [`FilterState::augment`]); when feature tracking is good, the new clone
//! is in addition tied to the previous image's clone by a stereo relative pose (the
//! previous-image-based method).
//!
//! Previous-image-based method (stochastic cloning, Roumeliotis & Burdick 2002): the features seen
//! by both images are triangulated in each left camera from their stereo disparity (point and
//! covariance from the pixel noise), aligned 3-D to 3-D (robust step: the hypothesis with the
//! most inliers by a Mahalanobis test, among the increment predicted by the filter and Kabsch
//! fits of 3-point samples; then the two-frame maximum-likelihood refinement on the inliers: Gauss-
//! Newton over the increment and the points on the stereo reprojection errors of both images,
//! the increment's covariance being its block of the inverse normal matrix), and the
//! increment `T_{c_k-1 -> c_k}` is an EKF measurement of the two clones' relative pose. In the
//! linear-Gaussian case this equals augmenting the new clone as `previous clone (+) increment`
//! (covariance `J P J^T + G Sigma G^T`, cross-covariance `J P`) and then constraining it to the
//! IMU pose; we use the update form so that the new clone's first estimate is the IMU's (the
//! first-estimate Jacobians of [`super::state`] need the two to coincide) and so the IMU state is
//! corrected as well. The unit tests check the composition analytically.
//!
//! Two ways to put the increment into the filter (`AugmentConfig::explicit_increment`): the
//! explicit relative pose with the two-frame estimate's covariance ([`relative_pose_update`]), or
//! (the default) the inliers' stereo observations of both images as a null-space-projected feature
//! update (`msckf::update_min_obs` with two-image tracks), linearized at the clones' first
//! estimates. To first order they carry the same information (the explicit covariance is the
//! Schur complement of the same normal equations), but the standalone two-frame problem is poorly
//! conditioned (0.12 m baseline, scene at 5 m: rotation about the camera x/y axes trades against
//! lateral translation) and its linearized covariance under-reports the spread of the estimate
//! (`increment_covariance_matches_monte_carlo`), which made the filter overconfident (120 m run,
//! seed 7: position NEES 5.3 explicit, 1.4 in the update form), whereas the update form is
//! linearized at the IMU-predicted poses.
//!
//! No double counting: an observation is used once. The increment uses a subset of the common
//! features (at most `max_features`, those whose observation in the previous image was not used by
//! the previous increment); the inliers' observations in both images are then removed from their
//! MSCKF tracks (the caller does it with [`RelPose::inliers`]), so the later feature update never
//! sees them again, and two consecutive increments never share an observation (their errors are
//! independent, as the update assumes). The other features stay with the MSCKF.
//!
//! Own code because no maintained crate gives a covariance-weighted 3-D/3-D alignment with its
//! covariance (the Kabsch core is nalgebra's SVD).

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, Vector3};

use crate::camera::{StereoCamera, StereoObs};
use crate::state::{CLONE_DIM, FilterState};
use subnav_base::so3::{self, hat};

type Matrix6 = SMatrix<f64, 6, 6>;

/// When and how the previous-image-based method is used.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct AugmentConfig {
    /// Use the previous-image-based method when tracking is good (off: IMU-based only).
    pub previous_image: bool,
    /// Features used for one increment (the rest stay with the MSCKF).
    pub max_features: usize,
    /// Fewer inliers than this: tracking is poor, IMU-based only.
    pub min_inliers: usize,
    /// Minimum disparity (normalized units) of a stereo point.
    pub min_disparity: f64,
    /// Chi-square probability of the inlier test (3 dof) and of the update gate (6 dof).
    pub gate: f64,
    /// How the increment enters the filter: `true` = the explicit relative pose and its covariance
    /// ([`relative_pose_update`]); `false` = its inliers' two-image stereo observations in a
    /// null-space-projected update linearized at the clones (the same information to first
    /// order; see the module doc for why this is the default).
    pub explicit_increment: bool,
}

impl Default for AugmentConfig {
    fn default() -> Self {
        Self { previous_image: true, max_features: 8, min_inliers: 6, min_disparity: 5e-3, gate: 0.99, explicit_increment: false }
    }
}

/// A point in the left camera from one stereo observation, with its covariance.
pub fn stereo_point(cam: &StereoCamera, z: &StereoObs, min_disparity: f64) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    let d = z[0] - z[2];
    if !(d >= min_disparity) || !z.iter().all(|v| v.is_finite()) {
        return None;
    }
    let b = cam.baseline_m;
    let depth = b / d;
    let p = Vector3::new(z[0] * depth, z[1] * depth, depth);
    // d p / d (u_l, v_l, u_r, v_r).
    let dz_dul = -depth * depth / b;
    let mut j = SMatrix::<f64, 3, 4>::zeros();
    j[(2, 0)] = dz_dul;
    j[(2, 2)] = -dz_dul;
    j[(0, 0)] = depth + z[0] * dz_dul;
    j[(0, 2)] = -z[0] * dz_dul;
    j[(1, 1)] = depth;
    j[(1, 0)] = z[1] * dz_dul;
    j[(1, 2)] = -z[1] * dz_dul;
    let cov = j * j.transpose() * cam.sigma_norm().powi(2);
    Some((p, cov))
}

/// A stereo relative pose `q = rot p + trans` (a point `p` in the previous left camera, `q` in
/// the new one), its covariance over `(dphi, dtrans)` with `rot = rot_hat Exp(dphi)`, and the
/// feature ids of its inliers.
#[derive(Debug, Clone, PartialEq)]
pub struct RelPose {
    pub rot: Matrix3<f64>,
    pub trans: Vector3<f64>,
    pub cov: Matrix6,
    pub inliers: Vec<u64>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RelPoseError {
    TooFewPoints(usize),
    TooFewInliers(usize),
    Degenerate,
}

impl std::fmt::Display for RelPoseError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RelPoseError::TooFewPoints(n) => {
                write!(f, "relative pose: only {n} common features with usable stereo depth (need min_inliers, at least 3)")
            }
            RelPoseError::TooFewInliers(n) => {
                write!(f, "relative pose: only {n} inliers in the best hypothesis (need min_inliers, at least 3)")
            }
            RelPoseError::Degenerate => f.write_str("relative pose: degenerate geometry (no hypothesis, or the refinement failed)"),
        }
    }
}

impl std::error::Error for RelPoseError {}

/// Kabsch: the rotation and translation minimizing `sum |q - (R p + t)|^2`.
pub fn kabsch(p: &[Vector3<f64>], q: &[Vector3<f64>]) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let n = p.len();
    if n < 3 || q.len() != n {
        return None;
    }
    let cp: Vector3<f64> = p.iter().sum::<Vector3<f64>>() / n as f64;
    let cq: Vector3<f64> = q.iter().sum::<Vector3<f64>>() / n as f64;
    let mut h = Matrix3::zeros();
    for (a, b) in p.iter().zip(q) {
        h += (a - cp) * (b - cq).transpose();
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (vt.transpose() * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = vt.transpose() * d * u.transpose();
    if !r.iter().all(|v| v.is_finite()) {
        return None;
    }
    Some((r, cq - r * cp))
}

/// Mahalanobis distance squared of the alignment residual of one pair.
fn mahal(r: &Matrix3<f64>, t: &Vector3<f64>, p: &(Vector3<f64>, Matrix3<f64>), q: &(Vector3<f64>, Matrix3<f64>)) -> f64 {
    let e = q.0 - r * p.0 - t;
    let c = q.1 + r * p.1 * r.transpose();
    c.cholesky().map_or(f64::INFINITY, |ch| e.dot(&ch.solve(&e)))
}

/// Relative pose from the common features of two stereo frames (`(feature id, observation)`).
/// Uses at most `cfg.max_features` of them (the first ones in the given order). `prior` (e.g. the
/// increment the filter predicts from the IMU) is one more hypothesis of the robust step: with
/// a 0.12 m baseline at 5 m the stereo depth is 15 times less certain than the lateral position,
/// so a 3-point Kabsch fit (unweighted) is often far off and finds few inliers.
pub fn estimate_relative_pose(
    cam: &StereoCamera,
    prev: &[(u64, StereoObs)],
    cur: &[(u64, StereoObs)],
    cfg: &AugmentConfig,
    prior: Option<(Matrix3<f64>, Vector3<f64>)>,
) -> Result<RelPose, RelPoseError> {
    let mut pairs = Vec::new();
    for (id, zc) in cur {
        if pairs.len() >= cfg.max_features {
            break;
        }
        let Some((_, zp)) = prev.iter().find(|(i, _)| i == id) else { continue };
        if let (Some(a), Some(b)) = (stereo_point(cam, zp, cfg.min_disparity), stereo_point(cam, zc, cfg.min_disparity)) {
            pairs.push((*id, a, b));
        }
    }
    let n = pairs.len();
    if n < cfg.min_inliers.max(3) {
        return Err(RelPoseError::TooFewPoints(n));
    }
    let limit = subnav_base::chi2::chi2_quantile(3, cfg.gate).unwrap_or(11.34);
    // Robust step: every 3-point sample of the first pairs (deterministic), keep the largest
    // consensus (at most 220 samples: n <= 12 gives C(12, 3) = 220).
    let m = n.min(12);
    let mut best: Vec<usize> = Vec::new();
    let mut best_hyp: Option<(Matrix3<f64>, Vector3<f64>)> = None;
    if let Some((r, t)) = prior {
        best = (0..n).filter(|&i| mahal(&r, &t, &pairs[i].1, &pairs[i].2) <= limit).collect();
        best_hyp = Some((r, t));
    }
    for a in 0..m {
        for b in a + 1..m {
            for c in b + 1..m {
                let ps = [pairs[a].1.0, pairs[b].1.0, pairs[c].1.0];
                let qs = [pairs[a].2.0, pairs[b].2.0, pairs[c].2.0];
                let Some((r, t)) = kabsch(&ps, &qs) else { continue };
                let inl: Vec<usize> = (0..n).filter(|&i| mahal(&r, &t, &pairs[i].1, &pairs[i].2) <= limit).collect();
                if inl.len() > best.len() {
                    best = inl;
                    best_hyp = Some((r, t));
                }
            }
        }
    }
    if best.len() < cfg.min_inliers.max(3) {
        return Err(RelPoseError::TooFewInliers(best.len()));
    }
    // Start the refinement from the winning hypothesis.
    let (r, t) = best_hyp.ok_or(RelPoseError::Degenerate)?;
    let obs: Vec<(StereoObs, StereoObs, Vector3<f64>)> = best
        .iter()
        .filter_map(|&i| {
            let id = pairs[i].0;
            let zp = prev.iter().find(|(j, _)| *j == id)?.1;
            let zc = cur.iter().find(|(j, _)| *j == id)?.1;
            Some((zp, zc, pairs[i].1.0))
        })
        .collect();
    let (r, t, cov) = refine_two_frame(cam, &obs, r, t).ok_or(RelPoseError::Degenerate)?;
    Ok(RelPose { rot: r, trans: t, cov, inliers: best.iter().map(|&i| pairs[i].0).collect() })
}

/// Two-frame maximum-likelihood refinement: Gauss-Newton over the increment `(R, t)` and the
/// points `p_i` (previous left camera) on the normalized stereo reprojection errors of both
/// images, `z_prev_i - pi(p_i)` and `z_cur_i - pi(R p_i + t)`, all with the pixel noise. The
/// increment's covariance is the `(dphi, dt)` block of the inverse normal matrix (the points
/// marginalized). A weighted 3-D/3-D fit instead is biased and overconfident here: the stereo
/// depth error (15 % at 5 m) is far from Gaussian and its covariance, evaluated at the noisy
/// point, is correlated with the error.
fn refine_two_frame(
    cam: &StereoCamera,
    obs: &[(StereoObs, StereoObs, Vector3<f64>)],
    mut r: Matrix3<f64>,
    mut t: Vector3<f64>,
) -> Option<(Matrix3<f64>, Vector3<f64>, Matrix6)> {
    let n = obs.len();
    let dim = 6 + 3 * n;
    let mut pts: Vec<Vector3<f64>> = obs.iter().map(|o| o.2).collect();
    let w = 1.0 / cam.sigma_norm().powi(2);
    let mut info = DMatrix::zeros(dim, dim);
    for it in 0..8 {
        info = DMatrix::zeros(dim, dim);
        let mut g = DVector::zeros(dim);
        for (i, (zp, zc, _)) in obs.iter().enumerate() {
            let p = pts[i];
            let o = 6 + 3 * i;
            // Previous image: depends on p only.
            let jp = cam.d_obs_d_pc(&p);
            let ep = zp - cam.project(&p)?;
            let a = jp.transpose() * jp * w;
            let mut blk = info.view_mut((o, o), (3, 3));
            blk += a;
            let mut gb = g.rows_mut(o, 3);
            gb += jp.transpose() * ep * w;
            // Current image: q = R p + t (R = R_hat Exp(dphi): dq/dphi = -R [p]x).
            let q = r * p + t;
            let jq = cam.d_obs_d_pc(&q);
            let ec = zc - cam.project(&q)?;
            let mut j = SMatrix::<f64, 4, 9>::zeros();
            j.fixed_view_mut::<4, 3>(0, 0).copy_from(&(jq * (-r * hat(&p))));
            j.fixed_view_mut::<4, 3>(0, 3).copy_from(&jq);
            j.fixed_view_mut::<4, 3>(0, 6).copy_from(&(jq * r));
            let jtj = j.transpose() * j * w;
            let jte = j.transpose() * ec * w;
            let idx = [0, 1, 2, 3, 4, 5, o, o + 1, o + 2];
            for (a1, &r1) in idx.iter().enumerate() {
                g[r1] += jte[a1];
                for (b1, &c1) in idx.iter().enumerate() {
                    info[(r1, c1)] += jtj[(a1, b1)];
                }
            }
        }
        let step = info.clone().cholesky()?.solve(&g);
        if !step.iter().all(|v| v.is_finite()) {
            return None;
        }
        r = so3::orthonormalize(&(r * so3::exp(&Vector3::new(step[0], step[1], step[2]))));
        t += Vector3::new(step[3], step[4], step[5]);
        for (i, p) in pts.iter_mut().enumerate() {
            *p += Vector3::new(step[6 + 3 * i], step[7 + 3 * i], step[8 + 3 * i]);
        }
        if step.norm() < 1e-9 || it == 7 {
            break;
        }
    }
    let full = info.cholesky()?.inverse();
    let cov = Matrix6::from_fn(|a, b| 0.5 * (full[(a, b)] + full[(b, a)]));
    cov.iter().all(|v| v.is_finite()).then_some((r, t, cov))
}

/// The relative camera pose of two body poses: `(R_wc_b^T R_wc_a, R_wc_b^T (p_wc_a - p_wc_b))`.
pub fn predicted_relative_pose(
    cam: &StereoCamera,
    (ra, pa): (&Matrix3<f64>, &Vector3<f64>),
    (rb, pb): (&Matrix3<f64>, &Vector3<f64>),
) -> (Matrix3<f64>, Vector3<f64>) {
    let (ca, cb) = (cam.cam_pose(ra, pa), cam.cam_pose(rb, pb));
    (cb.rot_cw * ca.rot_cw.transpose(), cb.rot_cw * (ca.pos_wc - cb.pos_wc))
}

/// Jacobian (6 x 12) of the relative pose `(dphi, dtrans)` with respect to the clone errors
/// `(dtheta_a, dp_a, dtheta_b, dp_b)` (body-frame attitude errors, world positions).
pub fn relative_pose_jacobian(
    cam: &StereoCamera,
    (ra, pa): (&Matrix3<f64>, &Vector3<f64>),
    (rb, pb): (&Matrix3<f64>, &Vector3<f64>),
) -> SMatrix<f64, 6, 12> {
    let (rd, td) = predicted_relative_pose(cam, (ra, pa), (rb, pb));
    let rcb = cam.rot_bc.transpose();
    let a_t = (rb * cam.rot_bc).transpose();
    let l = cam.pos_bc_m;
    let mut h = SMatrix::<f64, 6, 12>::zeros();
    h.fixed_view_mut::<3, 3>(0, 0).copy_from(&rcb);
    h.fixed_view_mut::<3, 3>(0, 6).copy_from(&(-rd.transpose() * rcb));
    h.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-a_t * ra * hat(&l)));
    h.fixed_view_mut::<3, 3>(3, 3).copy_from(&a_t);
    h.fixed_view_mut::<3, 3>(3, 6).copy_from(&(hat(&td) * rcb + a_t * rb * hat(&l)));
    h.fixed_view_mut::<3, 3>(3, 9).copy_from(&(-a_t));
    h
}

/// EKF update of clones `a` (previous image) and `b` (new image) with a measured relative pose.
/// Jacobians at the clones' first estimates (FEJ), residual at the current estimates; gated by a
/// 6-dof chi-square test at `gate`. Returns whether the update was applied.
pub fn relative_pose_update(st: &mut FilterState, cam: &StereoCamera, a: usize, b: usize, m: &RelPose, gate: f64) -> bool {
    let (Some(ca), Some(cb)) = (st.clones.get(a), st.clones.get(b)) else { return false };
    let fej = st.fej_enabled;
    let (rd, td) = predicted_relative_pose(cam, (&ca.rot, &ca.pos_w_m), (&cb.rot, &cb.pos_w_m));
    let (la, lb) = (ca.lin(fej), cb.lin(fej));
    let hj = relative_pose_jacobian(cam, (&la.0, &la.1), (&lb.0, &lb.1));
    let rphi = so3::log(&(rd.transpose() * m.rot));
    let rt = m.trans - td;
    let r = DVector::from_iterator(6, rphi.iter().chain(rt.iter()).copied());
    let n = st.dim();
    let mut h = DMatrix::zeros(6, n);
    let (oa, ob) = (FilterState::clone_offset(a), FilterState::clone_offset(b));
    h.view_mut((0, oa), (6, CLONE_DIM)).copy_from(&hj.fixed_view::<6, 6>(0, 0));
    h.view_mut((0, ob), (6, CLONE_DIM)).copy_from(&hj.fixed_view::<6, 6>(0, 6));
    let rcov = DMatrix::from_iterator(6, 6, m.cov.iter().copied());
    let s = &h * &st.cov * h.transpose() + &rcov;
    let Some(chol) = s.cholesky() else { return false };
    let gamma = r.dot(&chol.solve(&r));
    let limit = subnav_base::chi2::chi2_quantile(6, gate).unwrap_or(16.81);
    if !gamma.is_finite() || gamma > limit {
        return false;
    }
    st.ekf_update(&r, &h, &rcov).is_some()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::state::{CloneState, ImuState};
    use nalgebra::Vector6;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    fn scene(cam: &StereoCamera, ra: &Matrix3<f64>, pa: &Vector3<f64>) -> Vec<Vector3<f64>> {
        // Points on a rough plane 5 m above the vehicle (NED: z smaller), spread over the field of
        // view (+-4 m x +-3 m at 5 m), as the simulator's ice features are.
        let mut pts = Vec::new();
        for i in 0..4 {
            for j in 0..3 {
                let p = Vector3::new(pa.x - 3.0 + 2.0 * i as f64, pa.y - 2.2 + 2.2 * j as f64, pa.z - 5.0 + 0.3 * ((i * j) as f64).sin());
                let z = cam.project(&cam.to_cam(&cam.cam_pose(ra, pa), &p));
                if z.is_some() {
                    pts.push(p);
                }
            }
        }
        pts
    }

    fn observe(cam: &StereoCamera, r: &Matrix3<f64>, p: &Vector3<f64>, pts: &[Vector3<f64>]) -> Vec<(u64, StereoObs)> {
        pts.iter().enumerate().filter_map(|(i, x)| cam.project(&cam.to_cam(&cam.cam_pose(r, p), x)).map(|z| (i as u64, z))).collect()
    }

    fn poses() -> ((Matrix3<f64>, Vector3<f64>), (Matrix3<f64>, Vector3<f64>)) {
        let ra = so3::exp(&Vector3::new(0.02, -0.01, 0.4));
        let pa = Vector3::new(3.0, -2.0, 5.0);
        let rb = ra * so3::exp(&Vector3::new(0.005, 0.003, 0.03));
        let pb = pa + Vector3::new(0.18, 0.07, -0.02);
        ((ra, pa), (rb, pb))
    }

    #[test]
    fn noise_free_increment_is_the_truth() {
        let cam = StereoCamera::default();
        let ((ra, pa), (rb, pb)) = poses();
        let pts = scene(&cam, &ra, &pa);
        let (za, zb) = (observe(&cam, &ra, &pa, &pts), observe(&cam, &rb, &pb, &pts));
        let cfg = AugmentConfig { max_features: 12, ..AugmentConfig::default() };
        let m = estimate_relative_pose(&cam, &za, &zb, &cfg, None).unwrap();
        let (rt, tt) = predicted_relative_pose(&cam, (&ra, &pa), (&rb, &pb));
        assert!(so3::log(&(rt.transpose() * m.rot)).norm() < 1e-9, "{}", m.rot);
        assert!((m.trans - tt).norm() < 1e-9, "{} vs {tt}", m.trans);
        // Composition: the new body pose from the previous one and the increment.
        let rwc_b = ra * cam.rot_bc * m.rot.transpose();
        let pwc_b = pa + ra * cam.pos_bc_m - rwc_b * m.trans;
        let rb2 = rwc_b * cam.rot_bc.transpose();
        let pb2 = pwc_b - rb2 * cam.pos_bc_m;
        assert!(so3::log(&(rb.transpose() * rb2)).norm() < 1e-9 && (pb2 - pb).norm() < 1e-9);
        // A gross mismatch is rejected by the robust step.
        let mut zb2 = zb.clone();
        zb2[2].1[0] += 0.05;
        zb2[2].1[2] += 0.05;
        let m2 = estimate_relative_pose(&cam, &za, &zb2, &cfg, None).unwrap();
        assert!(!m2.inliers.contains(&zb2[2].0) && m2.inliers.len() == zb.len().min(12) - 1);
        // Too few common features: an error, not a panic.
        assert!(estimate_relative_pose(&cam, &za[..3], &zb, &cfg, None).is_err());
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let cam = StereoCamera::default();
        let ((ra, pa), (rb, pb)) = poses();
        let h = relative_pose_jacobian(&cam, (&ra, &pa), (&rb, &pb));
        let (r0, t0) = predicted_relative_pose(&cam, (&ra, &pa), (&rb, &pb));
        let eps = 1e-7;
        for k in 0..12 {
            let mut d = Vector3::zeros();
            d[k % 3] = eps;
            let (mut ra2, mut pa2, mut rb2, mut pb2) = (ra, pa, rb, pb);
            match k / 3 {
                0 => ra2 = ra * so3::exp(&d),
                1 => pa2 = pa + d,
                2 => rb2 = rb * so3::exp(&d),
                _ => pb2 = pb + d,
            }
            let (r1, t1) = predicted_relative_pose(&cam, (&ra2, &pa2), (&rb2, &pb2));
            let num_phi = so3::log(&(r0.transpose() * r1)) / eps;
            let num_t = (t1 - t0) / eps;
            let col = h.column(k);
            assert!((num_phi - col.fixed_rows::<3>(0)).norm() < 1e-5, "phi column {k}");
            assert!((num_t - col.fixed_rows::<3>(3)).norm() < 1e-5, "t column {k}");
        }
    }

    #[test]
    fn increment_covariance_matches_monte_carlo() {
        let cam = StereoCamera::default();
        let ((ra, pa), (rb, pb)) = poses();
        let pts = scene(&cam, &ra, &pa);
        let (za, zb) = (observe(&cam, &ra, &pa, &pts), observe(&cam, &rb, &pb, &pts));
        let (rt, tt) = predicted_relative_pose(&cam, (&ra, &pa), (&rb, &pb));
        let cfg = AugmentConfig { gate: 0.999_999, max_features: 12, ..AugmentConfig::default() };
        let noise = Normal::new(0.0, cam.sigma_norm()).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let n = 2000;
        let mut emp = Matrix6::zeros();
        let mut pred = Matrix6::zeros();
        let mut nees = 0.0;
        for _ in 0..n {
            let mut perturb = |z: &[(u64, StereoObs)]| -> Vec<(u64, StereoObs)> {
                z.iter().map(|(i, o)| (*i, o + StereoObs::from_fn(|_, _| noise.sample(&mut rng)))).collect()
            };
            let (a, b) = (perturb(&za), perturb(&zb));
            let m = estimate_relative_pose(&cam, &a, &b, &cfg, Some((rt, tt))).unwrap();
            let e = Vector6::from_iterator(so3::log(&(rt.transpose() * m.rot)).iter().chain((m.trans - tt).iter()).copied());
            emp += e * e.transpose();
            pred += m.cov;
            nees += e.dot(&(m.cov.try_inverse().unwrap() * e));
        }
        emp /= n as f64;
        pred /= n as f64;
        nees /= n as f64;
        // 6-dof NEES of a consistent estimate averages 6 (+-0.2 at 2000 samples; the stereo depth
        // is nonlinear, so allow 10 %). Per axis, the empirical variance over the predicted one:
        // the rotation about the camera y axis (traded against translation along x) is the worst,
        // about 1.26 measured (the linearized covariance under-reports it in this weak direction;
        // in a narrower scene of +-1.5 x +-1.2 m the NEES was 12). Bound 1.35.
        let ratios: Vec<f64> = (0..6).map(|k| emp[(k, k)] / pred[(k, k)]).collect();
        eprintln!("increment NEES {nees:.2}, empirical / predicted variance per axis {ratios:.2?}");
        assert!((nees - 6.0).abs() < 0.6, "NEES {nees}\nemp {emp}\npred {pred}");
        for (k, ratio) in ratios.iter().enumerate() {
            assert!((ratio - 1.0).abs() < 0.35, "axis {k}: empirical / predicted variance {ratio}");
        }
    }

    #[test]
    fn update_composes_the_previous_clone_with_the_increment() {
        // With an uninformative new clone (IMU), the update leaves the new clone at
        // `previous (+) increment` with covariance J P_a J^T + G Sigma G^T and cross-covariance J P_a.
        let cam = StereoCamera::default();
        let ((ra, pa), (rb, pb)) = poses();
        let imu = ImuState {
            t_s: 0.0,
            rot: rb,
            vel_w_mps: Vector3::zeros(),
            pos_w_m: pb,
            bias_gyro_radps: Vector3::zeros(),
            bias_acc_mps2: Vector3::zeros(),
            sonar_scale: 1.0,
            depth_ref_err_m: 0.0,
            sonar_bias_mps: 0.0,
        };
        const I: usize = crate::state::IMU_DIM;
        let (ca, cb) = (I, I + 6);
        let mut cov = DMatrix::identity(I, I) * 1e-6;
        let mut st = FilterState::new(imu, cov.clone());
        st.clones.push(CloneState::new(0.0, 0, ra, pa));
        cov = DMatrix::zeros(I + 12, I + 12);
        // Previous clone: a generic SPD covariance; new clone (index 1) almost unknown.
        let pa_cov = DMatrix::from_fn(6, 6, |i, j| if i == j { 1e-4 * (1.0 + i as f64) } else { 2e-5 / (1.0 + (i + j) as f64) });
        cov.view_mut((ca, ca), (6, 6)).copy_from(&pa_cov);
        for k in 0..I {
            cov[(k, k)] = 1e-6;
        }
        for k in cb..cb + 6 {
            cov[(k, k)] = 1e4;
        }
        st.cov = cov;
        // The new clone's estimate is off by 0.3 m and 0.02 rad; the measured increment is exact.
        let (rt, tt) = predicted_relative_pose(&cam, (&ra, &pa), (&rb, &pb));
        let sigma = Matrix6::from_diagonal(&Vector6::new(1e-6, 2e-6, 1e-6, 4e-4, 4e-4, 1e-3));
        st.clones.push(CloneState::new(0.0, 1, rb * so3::exp(&Vector3::new(0.0, 0.0, 0.02)), pb + Vector3::new(0.3, 0.0, 0.0)));
        let m = RelPose { rot: rt, trans: tt, cov: sigma, inliers: vec![] };
        st.fej_enabled = false;
        // Iterate (the update is linearized at the wrong estimate first).
        for _ in 0..3 {
            let save = st.cov.clone();
            assert!(relative_pose_update(&mut st, &cam, 0, 1, &m, 1.0 - 1e-12));
            st.cov = save;
        }
        let c = &st.clones[1];
        assert!(so3::log(&(rb.transpose() * c.rot)).norm() < 1e-6 && (c.pos_w_m - pb).norm() < 1e-5, "{} {}", c.pos_w_m, pb);
        // One more update from the converged estimate gives the covariance to compare.
        assert!(relative_pose_update(&mut st, &cam, 0, 1, &m, 1.0 - 1e-12));
        // Analytic: the new clone error = J_a dx_a + G n, with J_a = -H_b^-1 H_a, G = H_b^-1.
        let h = relative_pose_jacobian(&cam, (&ra, &pa), (&rb, &pb));
        let hb_inv = h.fixed_view::<6, 6>(0, 6).into_owned().try_inverse().unwrap();
        let ja = -hb_inv * h.fixed_view::<6, 6>(0, 0);
        let pa6 = Matrix6::from_iterator(pa_cov.iter().copied());
        let expect_bb = ja * pa6 * ja.transpose() + hb_inv * sigma * hb_inv.transpose();
        let expect_ba = ja * pa6;
        let got_bb = Matrix6::from_iterator(st.cov.view((cb, cb), (6, 6)).iter().copied());
        let got_ba = Matrix6::from_iterator(st.cov.view((cb, ca), (6, 6)).iter().copied());
        let rel = |a: &Matrix6, b: &Matrix6| (a - b).norm() / b.norm();
        assert!(rel(&got_bb, &expect_bb) < 1e-3, "{got_bb}\n{expect_bb}");
        assert!(rel(&got_ba, &expect_ba) < 1e-3, "{got_ba}\n{expect_ba}");
        // The previous clone's own covariance is unchanged (the new clone carried no information).
        let got_aa = Matrix6::from_iterator(st.cov.view((ca, ca), (6, 6)).iter().copied());
        assert!(rel(&got_aa, &pa6) < 1e-3);
    }
}
