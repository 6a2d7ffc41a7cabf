//! The MSCKF stereo update (D4): for each feature seen by >= 3 clones, triangulate, stack its
//! reprojection residuals `r = H_x dx + H_f dp_f + n`, remove the feature error by projecting on
//! the left null space of `H_f` (Givens rotations, applied in place to `H_x` and `r`), gate the
//! projected residual with a chi-square test, then make one EKF update with all accepted features
//! (stacked Jacobian compressed by QR when it has more rows than the state).

use nalgebra::{DMatrix, DVector};

use super::camera::{StereoCamera, StereoObs};
use super::state::{CLONE_DIM, FilterState};
use super::triangulation::triangulate;
use subnav_base::chi2::chi2_quantile;

/// A feature's observations: (frame id, stereo observation).
pub type Track = Vec<(u64, StereoObs)>;

#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct UpdateStats {
    pub features_used: usize,
    pub gated_out: usize,
    pub triangulation_failed: usize,
    pub rows: usize,
}

/// Rotate rows `i-1` and `i` so that `hf[(i, col)]` becomes zero, applying the same rotation to `hx` and `r`.
fn givens(hf: &mut DMatrix<f64>, hx: &mut DMatrix<f64>, r: &mut DVector<f64>, i: usize, col: usize) {
    let (a, b) = (hf[(i - 1, col)], hf[(i, col)]);
    if b == 0.0 {
        return;
    }
    let rr = a.hypot(b);
    let (c, s) = (a / rr, b / rr);
    let rot_rows = |m: &mut DMatrix<f64>| {
        for k in 0..m.ncols() {
            let (x, y) = (m[(i - 1, k)], m[(i, k)]);
            m[(i - 1, k)] = c * x + s * y;
            m[(i, k)] = -s * x + c * y;
        }
    };
    rot_rows(hf);
    rot_rows(hx);
    let (x, y) = (r[i - 1], r[i]);
    r[i - 1] = c * x + s * y;
    r[i] = -s * x + c * y;
}

/// Left-null-space projection: returns `(N^T H_x, N^T r)` with `N^T H_f = 0`, `rows - 3` rows.
pub fn nullspace_project(mut hf: DMatrix<f64>, mut hx: DMatrix<f64>, mut r: DVector<f64>) -> (DMatrix<f64>, DVector<f64>) {
    let m = hf.nrows();
    for col in 0..hf.ncols() {
        for i in (col + 1..m).rev() {
            givens(&mut hf, &mut hx, &mut r, i, col);
        }
    }
    let k = hf.ncols();
    (hx.rows(k, m - k).into_owned(), r.rows(k, m - k).into_owned())
}

/// Build the projected residual of one feature seen by at least `min_obs` clones. `None` if it
/// cannot be triangulated.
fn feature_rows(st: &FilterState, cam: &StereoCamera, track: &Track, min_obs: usize) -> Option<(DMatrix<f64>, DVector<f64>)> {
    let idx: Vec<(usize, StereoObs)> =
        track.iter().filter_map(|(fid, z)| st.clones.iter().position(|c| c.frame_id == *fid).map(|i| (i, *z))).collect();
    if idx.len() < min_obs.max(2) {
        return None;
    }
    let obs: Vec<_> = idx.iter().map(|(i, z)| (&st.clones[*i], *z)).collect();
    let pf = triangulate(cam, &obs).ok()?;
    let m = 4 * idx.len();
    let n = st.dim();
    let mut hx = DMatrix::zeros(m, n);
    let mut hf = DMatrix::zeros(m, 3);
    let mut r = DVector::zeros(m);
    for (j, (i, z)) in idx.iter().enumerate() {
        let c = &st.clones[*i];
        let pc = cam.to_cam(&cam.cam_pose(&c.rot, &c.pos_w_m), &pf);
        let h = cam.project(&pc)?;
        // Jacobians at the clone's first estimate (FEJ, see `state`), residual at the current one.
        let (rot_lin, pos_lin) = c.lin(st.fej_enabled);
        let pc_lin = cam.to_cam(&cam.cam_pose(&rot_lin, &pos_lin), &pf);
        let jo = cam.d_obs_d_pc(&pc_lin);
        let (jx, jf) = cam.d_pc(&rot_lin, &pos_lin, &pf);
        hx.view_mut((4 * j, FilterState::clone_offset(*i)), (4, CLONE_DIM)).copy_from(&(jo * jx));
        hf.view_mut((4 * j, 0), (4, 3)).copy_from(&(jo * jf));
        r.rows_mut(4 * j, 4).copy_from(&(z - h));
    }
    Some(nullspace_project(hf, hx, r))
}

/// One MSCKF update with the given finished tracks. `confidence` is the chi-square gate's
/// probability (e.g. 0.95).
pub fn update(st: &mut FilterState, cam: &StereoCamera, tracks: &[Track], confidence: f64) -> UpdateStats {
    update_min_obs(st, cam, tracks, confidence, 3)
}

/// [`update`] for tracks of at least `min_obs` (>= 2) clones: the two-image stereo tracks of the
/// previous-image-based augmentation (`augment`) use 2.
pub fn update_min_obs(st: &mut FilterState, cam: &StereoCamera, tracks: &[Track], confidence: f64, min_obs: usize) -> UpdateStats {
    let mut stats = UpdateStats::default();
    let var = cam.sigma_norm().powi(2);
    let mut blocks: Vec<(DMatrix<f64>, DVector<f64>)> = Vec::new();
    for t in tracks {
        let Some((h0, r0)) = feature_rows(st, cam, t, min_obs) else {
            stats.triangulation_failed += 1;
            continue;
        };
        let dof = r0.len();
        let mut s = &h0 * &st.cov * h0.transpose();
        for d in 0..dof {
            s[(d, d)] += var;
        }
        let Some(chol) = s.cholesky() else {
            stats.gated_out += 1;
            continue;
        };
        let gamma = r0.dot(&chol.solve(&r0));
        let limit = chi2_quantile(dof, confidence).unwrap_or(f64::INFINITY);
        if gamma.is_finite() && gamma <= limit {
            blocks.push((h0, r0));
        } else {
            stats.gated_out += 1;
        }
    }
    if blocks.is_empty() {
        return stats;
    }
    let rows: usize = blocks.iter().map(|b| b.1.len()).sum();
    let n = st.dim();
    let mut h = DMatrix::zeros(rows, n);
    let mut r = DVector::zeros(rows);
    let mut o = 0;
    for (hb, rb) in &blocks {
        h.view_mut((o, 0), (rb.len(), n)).copy_from(hb);
        r.rows_mut(o, rb.len()).copy_from(rb);
        o += rb.len();
    }
    // Measurement compression: H = Q1 R1 -> (R1, Q1^T r), isotropic noise unchanged.
    let (h, r) = if rows > n {
        let qr = h.qr();
        let q = qr.q();
        let r1 = qr.r();
        (r1, q.transpose() * r)
    } else {
        (h, r)
    };
    let rn = DMatrix::identity(r.len(), r.len()) * var;
    if st.ekf_update(&r, &h, &rn).is_some() {
        stats.features_used = blocks.len();
        stats.rows = rows;
    }
    stats
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nullspace_projection_removes_the_feature() {
        // Random-ish H_f (8x3), H_x (8x5), r = H_f a + H_x b: the projected residual equals N^T H_x b.
        let hf = DMatrix::from_fn(8, 3, |i, j| ((i * 7 + j * 3) % 5) as f64 - 2.0 + 0.1 * i as f64);
        let hx = DMatrix::from_fn(8, 5, |i, j| ((i * 3 + j * 5) % 7) as f64 * 0.3 - 1.0);
        let a = DVector::from_vec(vec![0.5, -1.0, 2.0]);
        let b = DVector::from_vec(vec![0.1, 0.2, -0.3, 0.4, 0.0]);
        let r = &hf * &a + &hx * &b;
        let (h0, r0) = nullspace_project(hf.clone(), hx.clone(), r);
        assert_eq!((h0.nrows(), r0.len()), (5, 5));
        assert!((&h0 * &b - &r0).norm() < 1e-12, "feature term not removed");
        // The rotation is orthonormal: the same projection of pure noise keeps its norm bound.
        let (_, rf) = nullspace_project(hf.clone(), hx.clone(), &hf * &a);
        assert!(rf.norm() < 1e-12);
    }
}
