//! Factors of the INS/DVL/USBL graph: one file per sensor (IMU + bias random walk, DVL, USBL,
//! LBL range) and
//! the priors. Each factor gives its residual, its Jacobians with respect to the 15-dimensional
//! tangent of each node it touches (analytic; checked numerically in the tests) and its
//! covariance. The solver whitens with the Cholesky factor of the covariance.

pub mod dvl;
pub mod imu;
pub mod prior;
pub mod range;
pub mod usbl;

use nalgebra::{DMatrix, DVector, SMatrix};

use super::FgoError;
use super::state::NodeState;

pub use dvl::DvlFactor;
pub use imu::{BiasRandomWalkFactor, ImuFactor};
pub use prior::{MarginalPrior, PriorFactor};
pub use range::RangeFactor;
pub use usbl::UsblFactor;

/// Jacobian block of a residual with respect to one node (rows x 15).
pub type JacBlock = DMatrix<f64>;

/// Residual and Jacobians (not whitened).
pub struct Evaluation {
    pub residual: DVector<f64>,
    pub jacobians: Vec<JacBlock>,
}

/// A factor of the graph.
#[derive(Debug, Clone)]
pub enum Factor {
    Prior(PriorFactor),
    Marginal(MarginalPrior),
    Imu(ImuFactor),
    BiasRw(BiasRandomWalkFactor),
    Dvl(DvlFactor),
    Usbl(UsblFactor),
    Range(RangeFactor),
}

impl Factor {
    /// Node indices this factor connects.
    pub fn nodes(&self) -> Vec<usize> {
        match self {
            Factor::Prior(f) => vec![f.node],
            Factor::Marginal(f) => vec![f.node],
            Factor::Imu(f) => vec![f.node_i, f.node_j],
            Factor::BiasRw(f) => vec![f.node_i, f.node_j],
            Factor::Dvl(f) => vec![f.node],
            Factor::Usbl(f) => vec![f.node],
            Factor::Range(f) => vec![f.node],
        }
    }

    pub fn set_nodes(&mut self, map: &dyn Fn(usize) -> usize) {
        match self {
            Factor::Prior(f) => f.node = map(f.node),
            Factor::Marginal(f) => f.node = map(f.node),
            Factor::Imu(f) => {
                f.node_i = map(f.node_i);
                f.node_j = map(f.node_j)
            }
            Factor::BiasRw(f) => {
                f.node_i = map(f.node_i);
                f.node_j = map(f.node_j)
            }
            Factor::Dvl(f) => f.node = map(f.node),
            Factor::Usbl(f) => f.node = map(f.node),
            Factor::Range(f) => f.node = map(f.node),
        }
    }

    /// Scale the noise of the IMU and bias random-walk factors to `s` times their nominal
    /// variance (other factors are left alone).
    pub fn set_imu_noise_scale(&mut self, s: f64) {
        match self {
            Factor::Imu(f) => f.set_noise_scale(s),
            Factor::BiasRw(f) => f.set_noise_scale(s),
            _ => {}
        }
    }

    /// Residual and Jacobians at `states` (one per entry of [`Factor::nodes`]).
    pub fn evaluate(&self, states: &[&NodeState]) -> Evaluation {
        match self {
            Factor::Prior(f) => f.evaluate(states[0]),
            Factor::Marginal(f) => f.evaluate(states[0]),
            Factor::Imu(f) => f.evaluate(states[0], states[1]),
            Factor::BiasRw(f) => f.evaluate(states[0], states[1]),
            Factor::Dvl(f) => f.evaluate(states[0]),
            Factor::Usbl(f) => f.evaluate(states[0]),
            Factor::Range(f) => f.evaluate(states[0]),
        }
    }

    /// Whitening matrix `W` (`W^T W = cov^-1`).
    pub fn whitener(&self) -> &DMatrix<f64> {
        match self {
            Factor::Prior(f) => &f.noise.whitener,
            Factor::Marginal(f) => &f.noise.whitener,
            Factor::Imu(f) => &f.noise.whitener,
            Factor::BiasRw(f) => &f.noise.whitener,
            Factor::Dvl(f) => &f.noise.whitener,
            Factor::Usbl(f) => &f.noise.whitener,
            Factor::Range(f) => &f.noise.whitener,
        }
    }

    /// Whitened residual and Jacobians.
    pub fn linearize(&self, states: &[&NodeState]) -> Evaluation {
        let e = self.evaluate(states);
        let w = self.whitener();
        Evaluation { residual: w * e.residual, jacobians: e.jacobians.iter().map(|j| w * j).collect() }
    }

    /// `0.5 |W r|^2`
    pub fn cost(&self, states: &[&NodeState]) -> f64 {
        let r = match self {
            Factor::Imu(f) => f.residual(states[0], states[1]),
            _ => self.evaluate(states).residual,
        };
        0.5 * (self.whitener() * r).norm_squared()
    }
}

/// Gaussian noise: covariance and its whitening matrix.
#[derive(Debug, Clone, PartialEq)]
pub struct Noise {
    pub cov: DMatrix<f64>,
    pub whitener: DMatrix<f64>,
}

impl Noise {
    /// From a covariance; symmetrised, rejected with an error if not finite positive definite.
    pub fn from_cov(cov: DMatrix<f64>) -> Result<Self, FgoError> {
        if !cov.iter().all(|x| x.is_finite()) || !cov.is_square() {
            return Err(FgoError::Numeric("covariance is not a finite square matrix".into()));
        }
        let sym = (&cov + cov.transpose()) * 0.5;
        let chol = sym.clone().cholesky().ok_or_else(|| FgoError::Numeric(format!("covariance is not positive definite: {sym}")))?;
        let l_inv = chol.l().try_inverse().ok_or_else(|| FgoError::Numeric("covariance Cholesky factor is singular".into()))?;
        Ok(Self { cov: sym, whitener: l_inv })
    }

    pub fn from_fixed<const N: usize>(cov: &SMatrix<f64, N, N>) -> Result<Self, FgoError> {
        Self::from_cov(DMatrix::from_iterator(N, N, cov.iter().copied()))
    }

    /// Diagonal from sigmas.
    pub fn from_sigmas(sigmas: &[f64]) -> Result<Self, FgoError> {
        if !sigmas.iter().all(|s| s.is_finite() && *s > 0.0) {
            return Err(FgoError::Input(format!("noise sigmas must be finite and > 0: {sigmas:?}")));
        }
        Self::from_cov(DMatrix::from_diagonal(&DVector::from_iterator(sigmas.len(), sigmas.iter().map(|s| s * s))))
    }

    /// Same noise with the covariance scaled by `kappa` (> 0).
    pub fn scaled(&self, kappa: f64) -> Self {
        Self { cov: &self.cov * kappa, whitener: &self.whitener / kappa.sqrt() }
    }
}

#[cfg(test)]
pub(crate) mod testutil {
    use super::*;
    use crate::state::Tangent;

    /// Central-difference Jacobians of `f.evaluate` for comparison with the analytic ones.
    pub fn numeric_jacobians(f: &Factor, states: &[NodeState]) -> Vec<DMatrix<f64>> {
        let h = 1e-6;
        let mut out = Vec::new();
        for k in 0..states.len() {
            let dim = f.evaluate(&states.iter().collect::<Vec<_>>()).residual.len();
            let mut j = DMatrix::zeros(dim, 15);
            for c in 0..15 {
                let mut d = Tangent::zeros();
                d[c] = h;
                let mut sp = states.to_vec();
                sp[k] = states[k].retract(&d);
                let mut sm = states.to_vec();
                sm[k] = states[k].retract(&(-d));
                let rp = f.evaluate(&sp.iter().collect::<Vec<_>>()).residual;
                let rm = f.evaluate(&sm.iter().collect::<Vec<_>>()).residual;
                j.set_column(c, &((rp - rm) / (2.0 * h)));
            }
            out.push(j);
        }
        out
    }

    pub fn check_jacobians(f: &Factor, states: &[NodeState], tol: f64) {
        let an = f.evaluate(&states.iter().collect::<Vec<_>>()).jacobians;
        let nu = numeric_jacobians(f, states);
        for (a, n) in an.iter().zip(nu.iter()) {
            let err = (a - n).amax();
            assert!(err < tol, "analytic vs numeric Jacobian differ by {err}\n{a}\n{n}");
        }
    }
}
