//! Priors: the initial-state prior (block-diagonal: attitude, position, velocity, biases, the
//! same split GTSAM's PoseRotationPrior / PoseTranslationPrior / PriorFactorVector /
//! PriorFactorConstantBias give) and the marginalisation prior the fixed-lag smoother leaves on
//! the oldest node it keeps: `r = S (x [-] x_lin) + s0`, already whitened.

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use super::{Evaluation, Noise};
use crate::FgoError;
use crate::state::NodeState;
use subnav_base::so3;

#[derive(Debug, Clone)]
pub struct PriorFactor {
    pub node: usize,
    pub mean: NodeState,
    pub noise: Noise,
}

/// Jacobian of `x0 [-] x` (i.e. `x0.local(x)`) with respect to the tangent of `x`.
fn local_jacobian(x0: &NodeState, x: &NodeState) -> (DVector<f64>, DMatrix<f64>) {
    let d = x0.local(x);
    let mut j = DMatrix::identity(15, 15);
    let th = Vector3::new(d[0], d[1], d[2]);
    let jr_inv = so3::dexp(&th).try_inverse().unwrap_or_else(Matrix3::identity);
    j.view_mut((0, 0), (3, 3)).copy_from(&jr_inv);
    (DVector::from_column_slice(d.as_slice()), j)
}

impl PriorFactor {
    /// Prior with sigmas for attitude (rad), position (m), velocity (m/s), acc bias, gyro bias.
    pub fn new(node: usize, mean: NodeState, sigmas: [f64; 5]) -> Result<Self, FgoError> {
        let mut s = Vec::with_capacity(15);
        for v in sigmas {
            s.extend_from_slice(&[v, v, v]);
        }
        Ok(Self { node, mean, noise: Noise::from_sigmas(&s)? })
    }

    pub fn evaluate(&self, x: &NodeState) -> Evaluation {
        let (r, j) = local_jacobian(&self.mean, x);
        Evaluation { residual: r, jacobians: vec![j] }
    }
}

#[derive(Debug, Clone)]
pub struct MarginalPrior {
    pub node: usize,
    pub lin: NodeState,
    /// `S` (15x15) with `S^T S` = marginal information.
    pub sqrt_info: DMatrix<f64>,
    /// `s0`, whitened residual at the linearisation point.
    pub r0: DVector<f64>,
    /// Identity (the residual is already whitened).
    pub noise: Noise,
}

impl MarginalPrior {
    pub fn new(node: usize, lin: NodeState, sqrt_info: DMatrix<f64>, r0: DVector<f64>) -> Self {
        let noise = Noise { cov: DMatrix::identity(15, 15), whitener: DMatrix::identity(15, 15) };
        Self { node, lin, sqrt_info, r0, noise }
    }

    pub fn evaluate(&self, x: &NodeState) -> Evaluation {
        let (d, j) = local_jacobian(&self.lin, x);
        Evaluation { residual: &self.sqrt_info * d + &self.r0, jacobians: vec![&self.sqrt_info * j] }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::factors::Factor;
    use crate::factors::testutil::check_jacobians;
    use crate::state::{ImuBias, NavState};

    #[test]
    fn prior_jacobians() {
        let m = NodeState::new(NavState::identity(), ImuBias::default());
        let x = NodeState::new(
            NavState::new(so3::exp(&Vector3::new(0.4, -0.3, 0.2)), Vector3::new(1.0, 2.0, 3.0), Vector3::zeros()),
            ImuBias::default(),
        );
        let f = Factor::Prior(PriorFactor::new(0, m, [0.1, 1.0, 0.1, 0.01, 0.001]).unwrap());
        check_jacobians(&f, &[x], 1e-7);
        assert!(PriorFactor::new(0, m, [0.1, -1.0, 0.1, 0.01, 0.001]).is_err());
    }
}
