//! Feature triangulation for the MSCKF update (D4): a world point from its stereo observations in
//! several clones, initialized from the first stereo pair's disparity and refined by Gauss-Newton
//! on the normalized reprojection error of all left and right observations.

use nalgebra::{Matrix3, Vector3};

use super::camera::{StereoCamera, StereoObs};
use super::state::CloneState;

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TriangulationError {
    /// Disparity too small or negative for the initial guess.
    NoDisparity,
    /// Normal equations singular or the point went behind a camera.
    Degenerate,
    /// Final RMS reprojection error above the limit (normalized units).
    Residual(f64),
}

impl std::fmt::Display for TriangulationError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TriangulationError::NoDisparity => f.write_str("triangulation: stereo disparity too small or negative for an initial depth"),
            TriangulationError::Degenerate => f.write_str("triangulation: normal equations singular or the point went behind a camera"),
            TriangulationError::Residual(rms) => {
                write!(f, "triangulation: RMS reprojection error {rms:.3e} (normalized units) above the limit")
            }
        }
    }
}

impl std::error::Error for TriangulationError {}

/// Gauss-Newton triangulation. `obs` pairs a clone with its observation.
pub fn triangulate(cam: &StereoCamera, obs: &[(&CloneState, StereoObs)]) -> Result<Vector3<f64>, TriangulationError> {
    let (c0, z0) = obs.first().ok_or(TriangulationError::Degenerate)?;
    let disparity = z0[0] - z0[2];
    if disparity < 1e-4 {
        return Err(TriangulationError::NoDisparity);
    }
    let depth = cam.baseline_m / disparity;
    let pose0 = cam.cam_pose(&c0.rot, &c0.pos_w_m);
    let mut p = pose0.rot_cw.transpose() * Vector3::new(z0[0] * depth, z0[1] * depth, depth) + pose0.pos_wc;
    let poses: Vec<_> = obs.iter().map(|(c, z)| (cam.cam_pose(&c.rot, &c.pos_w_m), *z)).collect();
    let mut rms = f64::INFINITY;
    for _ in 0..8 {
        let mut a = Matrix3::zeros();
        let mut b = Vector3::zeros();
        let mut sq = 0.0;
        for (pose, z) in &poses {
            let pc = cam.to_cam(pose, &p);
            let h = cam.project(&pc).ok_or(TriangulationError::Degenerate)?;
            let r = z - h;
            let j = cam.d_obs_d_pc(&pc) * pose.rot_cw;
            a += j.transpose() * j;
            b += j.transpose() * r;
            sq += r.norm_squared();
        }
        rms = (sq / (4 * poses.len()) as f64).sqrt();
        let dp = a.cholesky().ok_or(TriangulationError::Degenerate)?.solve(&b);
        p += dp;
        if dp.norm() < 1e-6 {
            break;
        }
    }
    if !p.iter().all(|v| v.is_finite()) {
        return Err(TriangulationError::Degenerate);
    }
    let limit = 6.0 * cam.sigma_norm();
    if rms > limit {
        return Err(TriangulationError::Residual(rms));
    }
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;
    use subnav_base::so3;

    #[test]
    fn exact_observations_give_the_point() {
        let cam = StereoCamera::default();
        let pf = Vector3::new(2.0, 1.0, 0.3);
        let clones: Vec<CloneState> = (0..4)
            .map(|i| {
                CloneState::new(
                    i as f64,
                    i,
                    so3::exp(&Vector3::new(0.01 * i as f64, 0.0, 0.1 * i as f64)),
                    Vector3::new(0.3 * i as f64, 0.1, 5.0),
                )
            })
            .collect();
        let obs: Vec<_> = clones.iter().map(|c| (c, cam.project(&cam.to_cam(&cam.cam_pose(&c.rot, &c.pos_w_m), &pf)).unwrap())).collect();
        // Perturb the first observation's disparity so the initial guess is off by ~10 %.
        let mut obs2 = obs.clone();
        obs2[0].1[2] += 0.002;
        let p = triangulate(&cam, &obs2).unwrap();
        assert!((p - pf).norm() < 0.05, "{p}");
        let p = triangulate(&cam, &obs).unwrap();
        assert!((p - pf).norm() < 1e-6, "{p}");
        // Inconsistent observations are refused by the residual check.
        let mut bad = obs.clone();
        bad[3].1[0] += 0.1;
        assert!(matches!(triangulate(&cam, &bad), Err(TriangulationError::Residual(_))));
    }
}
