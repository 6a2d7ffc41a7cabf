//! USBL factor: position fix of the vehicle's transponder in ENU, valid at the acoustic
//! transmission time (arrival time minus the acoustic delay). The graph places a node at that
//! valid time stamp (splitting the IMU interval if the fix arrives late), so no interpolation
//! between nodes is needed. Residual `r = p_meas - (p + R l_body)` (spec B3 with lever arm),
//! covariance `R_USBL`.

use nalgebra::{DMatrix, DVector, Vector3};

use super::{Evaluation, Noise};
use crate::state::NodeState;
use subnav_base::so3;

#[derive(Debug, Clone)]
pub struct UsblFactor {
    pub node: usize,
    pub pos_enu_m: Vector3<f64>,
    pub lever_body_m: Vector3<f64>,
    pub noise: Noise,
    /// Inflation the gate applied: `noise` = the nominal noise scaled by `kappa` (1 = none).
    pub kappa: f64,
}

impl UsblFactor {
    pub fn evaluate(&self, x: &NodeState) -> Evaluation {
        let r_mat = x.nav.rot_enu_flu;
        let r = self.pos_enu_m - (x.nav.pos_enu_m + r_mat * self.lever_body_m);
        let mut j = DMatrix::zeros(3, 15);
        // d(R Exp(d) l)/dd = -R [l]x
        j.view_mut((0, 0), (3, 3)).copy_from(&(r_mat * so3::hat(&self.lever_body_m)));
        for k in 0..3 {
            j[(k, 3 + k)] = -1.0;
        }
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
    fn usbl_jacobians() {
        let f = UsblFactor {
            node: 0,
            pos_enu_m: Vector3::new(100.0, 50.0, -30.0),
            lever_body_m: Vector3::new(0.3, 0.1, 0.4),
            noise: Noise::from_sigmas(&[1.0, 1.0, 0.5]).unwrap(),
            kappa: 1.0,
        };
        let x = NodeState::new(
            NavState::new(so3::exp(&Vector3::new(0.1, 0.3, -1.0)), Vector3::new(99.0, 51.0, -29.0), Vector3::zeros()),
            ImuBias::default(),
        );
        check_jacobians(&Factor::Usbl(f), &[x], 1e-7);
    }
}
