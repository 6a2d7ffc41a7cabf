//! Range factor (LBL / single beacon, 3-D): the acoustic range from the vehicle's transducer
//! (lever arm `l` in the body) to a beacon at a known ENU position `b`, as a two-way travel time
//! turned into metres by the modem. Residual `r = |p + R l - b| - range` (m), variance
//! `sigma^2`. With the IMU and DVL factors this is the INS/DVL/LBL graph of a real AUV; the
//! smoother gates it like the USBL fixes ([`crate::smoother::Smoother::add_range`]). The 2-D
//! pose-graph form, with beacons known or estimated, is [`crate::range2d`].

use nalgebra::{DMatrix, DVector, Vector3};

use super::{Evaluation, Noise};
use crate::state::NodeState;
use subnav_base::so3;

#[derive(Debug, Clone)]
pub struct RangeFactor {
    pub node: usize,
    pub beacon_enu_m: Vector3<f64>,
    pub range_m: f64,
    pub lever_body_m: Vector3<f64>,
    pub noise: Noise,
}

impl RangeFactor {
    pub fn evaluate(&self, x: &NodeState) -> Evaluation {
        let r_mat = x.nav.rot_enu_flu;
        let d = x.nav.pos_enu_m + r_mat * self.lever_body_m - self.beacon_enu_m;
        let n = d.norm();
        // on the beacon the direction is undefined: zero Jacobian (the solver sees no gradient)
        let u = if n > 1e-9 { d / n } else { Vector3::zeros() };
        let mut j = DMatrix::zeros(1, 15);
        // d(R Exp(t) l)/dt = -R [l]x ; d p / d dp = I
        let jr = -(u.transpose() * r_mat * so3::hat(&self.lever_body_m));
        for k in 0..3 {
            j[(0, k)] = jr[k];
            j[(0, 3 + k)] = u[k];
        }
        Evaluation { residual: DVector::from_element(1, n - self.range_m), jacobians: vec![j] }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::factors::Factor;
    use crate::factors::testutil::check_jacobians;
    use crate::state::{ImuBias, NavState};

    #[test]
    fn range_jacobians() {
        let f = RangeFactor {
            node: 0,
            beacon_enu_m: Vector3::new(120.0, 40.0, -60.0),
            range_m: 30.0,
            lever_body_m: Vector3::new(0.5, -0.2, 0.3),
            noise: Noise::from_sigmas(&[0.75]).unwrap(),
        };
        let x = NodeState::new(
            NavState::new(so3::exp(&Vector3::new(0.1, 0.3, -1.0)), Vector3::new(99.0, 51.0, -29.0), Vector3::zeros()),
            ImuBias::default(),
        );
        check_jacobians(&Factor::Range(f.clone()), &[x], 1e-7);
        let e = f.evaluate(&x);
        let truth = (x.nav.pos_enu_m + x.nav.rot_enu_flu * f.lever_body_m - f.beacon_enu_m).norm() - 30.0;
        assert!((e.residual[0] - truth).abs() < 1e-12);
    }
}
