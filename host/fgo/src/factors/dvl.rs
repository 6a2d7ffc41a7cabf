//! DVL factor: body-velocity observation in the DVL instrument frame, with the mounting rotation
//! `R_body_dvl` and the lever arm `l_body` (DVL head relative to the IMU, body frame).
//! Predicted `v_dvl = R_body_dvl^T (R^T v_enu + w_body x l_body)`, residual
//! `r = v_meas - v_dvl` (spec B3), covariance `R_DVL`. The angular rate `w_body` is the (gyro)
//! rate at the DVL time, taken as a known input: the gyro bias enters it only as
//! `b_g x l` (1e-3 rad/s x 1 m = 1 mm/s), well below the DVL noise.

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use super::{Evaluation, Noise};
use crate::state::NodeState;
use subnav_base::so3;

#[derive(Debug, Clone)]
pub struct DvlFactor {
    pub node: usize,
    pub vel_dvl_mps: Vector3<f64>,
    pub rot_body_dvl: Matrix3<f64>,
    pub lever_body_m: Vector3<f64>,
    pub omega_body_radps: Vector3<f64>,
    pub noise: Noise,
}

impl DvlFactor {
    pub fn predict(&self, x: &NodeState) -> Vector3<f64> {
        let rt = x.nav.rot_enu_flu.transpose();
        self.rot_body_dvl.transpose() * (rt * x.nav.vel_enu_mps + self.omega_body_radps.cross(&self.lever_body_m))
    }

    pub fn evaluate(&self, x: &NodeState) -> Evaluation {
        let rt = x.nav.rot_enu_flu.transpose();
        let v_body = rt * x.nav.vel_enu_mps;
        let r = self.vel_dvl_mps - self.predict(x);
        let mut j = DMatrix::zeros(3, 15);
        let rbd_t = self.rot_body_dvl.transpose();
        // d(R Exp(d))^T v / d d = [R^T v]x
        j.view_mut((0, 0), (3, 3)).copy_from(&(-rbd_t * so3::hat(&v_body)));
        j.view_mut((0, 6), (3, 3)).copy_from(&(-rbd_t * rt));
        Evaluation { residual: DVector::from_column_slice(r.as_slice()), jacobians: vec![j] }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::factors::Factor;
    use crate::factors::testutil::check_jacobians;
    use crate::state::{ImuBias, NavState};

    #[test]
    fn dvl_jacobians_and_lever_arm() {
        let f = DvlFactor {
            node: 0,
            vel_dvl_mps: Vector3::new(1.5, 0.0, 0.0),
            rot_body_dvl: so3::exp(&Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_4)),
            lever_body_m: Vector3::new(0.5, 0.0, -0.3),
            omega_body_radps: Vector3::new(0.0, 0.0, 0.2),
            noise: Noise::from_sigmas(&[0.01; 3]).unwrap(),
        };
        let x = NodeState::new(
            NavState::new(so3::exp(&Vector3::new(0.05, -0.02, 0.7)), Vector3::zeros(), Vector3::new(1.0, 1.2, -0.1)),
            ImuBias::default(),
        );
        check_jacobians(&Factor::Dvl(f.clone()), &[x], 1e-7);
        // yaw rate 0.2 rad/s with a 0.5 m forward lever arm adds 0.1 m/s to the left (body y).
        let still = NodeState::new(NavState::identity(), ImuBias::default());
        let v_body = f.rot_body_dvl * f.predict(&still);
        assert!((v_body - Vector3::new(0.0, 0.1, 0.0)).norm() < 1e-12, "{v_body}");
    }
}
