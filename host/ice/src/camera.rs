//! The up-looking stereo camera: extrinsics, projection to normalized image coordinates of the
//! left and right camera (right = left shifted by the baseline along the camera x axis), and
//! their Jacobians with respect to a clone's error state and the feature position.

use nalgebra::{Matrix3, SMatrix, Vector2, Vector3, Vector4};

use subnav_base::so3::hat;

/// One stereo observation in normalized image coordinates `[u_l, v_l, u_r, v_r]`.
pub type StereoObs = Vector4<f64>;

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StereoCamera {
    /// Camera (left) -> body rotation.
    pub rot_bc: Matrix3<f64>,
    /// Left camera centre in the body frame, m.
    pub pos_bc_m: Vector3<f64>,
    pub baseline_m: f64,
    /// Focal length in pixels (for the noise and the field of view).
    pub focal_px: f64,
    pub width_px: f64,
    pub height_px: f64,
    /// Pixel noise of a corner, 1 sigma.
    pub sigma_px: f64,
}

impl Default for StereoCamera {
    fn default() -> Self {
        // Optical axis = body up (-z of FRD); camera x = body right, camera y = body forward.
        let rot_bc = Matrix3::from_columns(&[Vector3::y(), Vector3::x(), -Vector3::z()]);
        Self {
            rot_bc,
            pos_bc_m: Vector3::new(0.2, -0.06, -0.15),
            baseline_m: 0.12,
            focal_px: 400.0,
            width_px: 640.0,
            height_px: 480.0,
            sigma_px: 1.0,
        }
    }
}

/// A camera pose hypothesis derived from a body pose.
pub struct CamPose {
    /// World -> left camera rotation.
    pub rot_cw: Matrix3<f64>,
    /// Left camera centre in the world.
    pub pos_wc: Vector3<f64>,
}

impl StereoCamera {
    pub fn sigma_norm(&self) -> f64 {
        self.sigma_px / self.focal_px
    }

    pub fn cam_pose(&self, rot_wb: &Matrix3<f64>, pos_wb: &Vector3<f64>) -> CamPose {
        CamPose { rot_cw: (rot_wb * self.rot_bc).transpose(), pos_wc: pos_wb + rot_wb * self.pos_bc_m }
    }

    /// Feature in left-camera coordinates.
    pub fn to_cam(&self, pose: &CamPose, p_w: &Vector3<f64>) -> Vector3<f64> {
        pose.rot_cw * (p_w - pose.pos_wc)
    }

    /// Projection of a left-camera point to both cameras; `None` if behind either camera.
    pub fn project(&self, p_c: &Vector3<f64>) -> Option<StereoObs> {
        if p_c.z < 0.1 {
            return None;
        }
        let r = p_c - Vector3::new(self.baseline_m, 0.0, 0.0);
        Some(Vector4::new(p_c.x / p_c.z, p_c.y / p_c.z, r.x / r.z, r.y / r.z))
    }

    /// Whether a normalized left/right observation falls on both sensors.
    pub fn in_view(&self, z: &StereoObs) -> bool {
        let (hw, hh) = (0.5 * self.width_px / self.focal_px, 0.5 * self.height_px / self.focal_px);
        z[0].abs() < hw && z[1].abs() < hh && z[2].abs() < hw && z[3].abs() < hh
    }

    /// d(obs)/d(p_c), 4x3.
    pub fn d_obs_d_pc(&self, p_c: &Vector3<f64>) -> SMatrix<f64, 4, 3> {
        let mut j = SMatrix::<f64, 4, 3>::zeros();
        for (row, q) in [(0, *p_c), (2, p_c - Vector3::new(self.baseline_m, 0.0, 0.0))] {
            let iz = 1.0 / q.z;
            j[(row, 0)] = iz;
            j[(row, 2)] = -q.x * iz * iz;
            j[(row + 1, 1)] = iz;
            j[(row + 1, 2)] = -q.y * iz * iz;
        }
        j
    }

    /// Jacobians of `p_c` w.r.t. the clone error `(dtheta_body, dp_w)` (3x6) and the feature (3x3).
    pub fn d_pc(&self, rot_wb: &Matrix3<f64>, pos_wb: &Vector3<f64>, p_w: &Vector3<f64>) -> (SMatrix<f64, 3, 6>, Matrix3<f64>) {
        // p_c = R_bc^T (R_wb^T (p_w - p_wb) - p_bc); R_wb = R_hat Exp(dtheta).
        let p_b = rot_wb.transpose() * (p_w - pos_wb);
        let rcb = self.rot_bc.transpose();
        let mut jx = SMatrix::<f64, 3, 6>::zeros();
        jx.fixed_view_mut::<3, 3>(0, 0).copy_from(&(rcb * hat(&p_b)));
        jx.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-rcb * rot_wb.transpose()));
        (jx, rcb * rot_wb.transpose())
    }
}

/// Helper: the 2-D left observation of a stereo observation.
pub fn left(z: &StereoObs) -> Vector2<f64> {
    Vector2::new(z[0], z[1])
}

#[cfg(test)]
mod tests {
    use super::*;
    use subnav_base::so3;

    #[test]
    fn jacobians_match_finite_differences() {
        let cam = StereoCamera::default();
        let rot = so3::exp(&Vector3::new(0.05, -0.03, 0.7));
        let pos = Vector3::new(3.0, -1.0, 5.0);
        let pf = Vector3::new(4.0, 0.5, 0.2);
        let f = |r: &Matrix3<f64>, p: &Vector3<f64>, pf: &Vector3<f64>| cam.project(&cam.to_cam(&cam.cam_pose(r, p), pf)).unwrap();
        let pc = cam.to_cam(&cam.cam_pose(&rot, &pos), &pf);
        let (jx, jf) = cam.d_pc(&rot, &pos, &pf);
        let jo = cam.d_obs_d_pc(&pc);
        let h = 1e-6;
        for k in 0..6 {
            let mut d = Vector3::zeros();
            d[k % 3] = h;
            let (r2, p2) = if k < 3 { (rot * so3::exp(&d), pos) } else { (rot, pos + d) };
            let num = (f(&r2, &p2, &pf) - f(&rot, &pos, &pf)) / h;
            let ana = jo * jx.column(k);
            assert!((num - ana).norm() < 1e-5, "clone column {k}: {num} vs {ana}");
        }
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = h;
            let num = (f(&rot, &pos, &(pf + d)) - f(&rot, &pos, &pf)) / h;
            let ana = jo * jf.column(k);
            assert!((num - ana).norm() < 1e-5, "feature column {k}");
        }
    }

    #[test]
    fn camera_looks_up() {
        let cam = StereoCamera::default();
        let pose = cam.cam_pose(&Matrix3::identity(), &Vector3::new(0.0, 0.0, 5.0));
        // A point 5 m above (NED: smaller z) is in front of the camera.
        let pc = cam.to_cam(&pose, &Vector3::new(0.2, -0.06, 0.0));
        assert!((pc.z - 4.85).abs() < 1e-12 && pc.x.abs() < 1e-12 && pc.y.abs() < 1e-12, "{pc}");
    }
}
