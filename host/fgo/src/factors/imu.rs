//! IMU factor between consecutive nodes and the bias random-walk factor.
//!
//! The IMU residual is GTSAM's component-wise ImuFactor error (`ImuFactorErrorMode::ComponentWise`):
//! with `X_hat_j = predict(X_i, b_i)` from the preintegrated increments,
//! `r = [Log(R_j^T R_hat_j), R_j^T (p_hat_j - p_j), R_j^T (v_hat_j - v_j)]`, covariance = the
//! preintegrated covariance moved into the residual's coordinates
//! ([`Preintegrated::residual_cov`], as GTSAM 4.3's ImuFactor does). To first order this is spec 002's Forster residual
//! (`Log(Delta R^T R_i^T R_j)`, `R_i^T (v_j - v_i - g dt) - Delta v`, ...) expressed at node j,
//! and it is the form GTSAM solves, which the peer test compares against.
//! Bias random walk: `r = b_j - b_i`, covariance `diag(s_acc^2, s_gyro^2) * dt`.

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use super::{Evaluation, Noise};
use crate::FgoError;
use crate::preintegration::Preintegrated;
use crate::state::NodeState;
use subnav_base::so3;

#[derive(Debug, Clone)]
pub struct ImuFactor {
    pub node_i: usize,
    pub node_j: usize,
    pub pim: Preintegrated,
    pub noise: Noise,
    /// Variance scale of `noise` over the preintegrated covariance of `pim` (1 = the IMU
    /// parameters as given; see [`crate::gating`], the IMU noise scale).
    pub noise_scale: f64,
}

fn put(j: &mut DMatrix<f64>, r: usize, c: usize, m: &Matrix3<f64>) {
    j.view_mut((r, c), (3, 3)).copy_from(m);
}

impl ImuFactor {
    pub fn new(node_i: usize, node_j: usize, pim: Preintegrated) -> Result<Self, FgoError> {
        if pim.delta_t_s <= 0.0 {
            return Err(FgoError::Input(format!("IMU factor {node_i}->{node_j} has no IMU samples")));
        }
        let noise = Noise::from_fixed(&pim.residual_cov())?;
        Ok(Self { node_i, node_j, pim, noise, noise_scale: 1.0 })
    }

    /// Set the variance scale of the noise (relative to the parameters'), `s > 0`.
    pub fn set_noise_scale(&mut self, s: f64) {
        self.noise = self.noise.scaled(s / self.noise_scale);
        self.noise_scale = s;
    }

    /// The residual alone (no Jacobians): what the LM's cost evaluations need.
    pub fn residual(&self, xi: &NodeState, xj: &NodeState) -> DVector<f64> {
        let pim = &self.pim;
        let z = pim.bias_corrected(&xi.bias);
        let dt = pim.delta_t_s;
        let g = pim.params.gravity();
        let ri = xi.nav.rot_enu_flu;
        let rjt = xj.nav.rot_enu_flu.transpose();
        let r_hat = ri * so3::exp(&Vector3::new(z[0], z[1], z[2]));
        let p_hat = xi.nav.pos_enu_m + xi.nav.vel_enu_mps * dt + g * (0.5 * dt * dt) + ri * Vector3::new(z[3], z[4], z[5]);
        let v_hat = xi.nav.vel_enu_mps + g * dt + ri * Vector3::new(z[6], z[7], z[8]);
        let mut residual = DVector::zeros(9);
        residual.fixed_rows_mut::<3>(0).copy_from(&so3::log(&(rjt * r_hat)));
        residual.fixed_rows_mut::<3>(3).copy_from(&(rjt * (p_hat - xj.nav.pos_enu_m)));
        residual.fixed_rows_mut::<3>(6).copy_from(&(rjt * (v_hat - xj.nav.vel_enu_mps)));
        residual
    }

    pub fn evaluate(&self, xi: &NodeState, xj: &NodeState) -> Evaluation {
        let pim = &self.pim;
        let z = pim.bias_corrected(&xi.bias);
        let theta_c = Vector3::new(z[0], z[1], z[2]);
        let zp = Vector3::new(z[3], z[4], z[5]);
        let zv = Vector3::new(z[6], z[7], z[8]);
        let dt = pim.delta_t_s;
        let g = pim.params.gravity();
        let ri = xi.nav.rot_enu_flu;
        let rj = xj.nav.rot_enu_flu;
        let rjt = rj.transpose();
        let exp_c = so3::exp(&theta_c);
        let r_hat = ri * exp_c;
        let p_hat = xi.nav.pos_enu_m + xi.nav.vel_enu_mps * dt + g * (0.5 * dt * dt) + ri * zp;
        let v_hat = xi.nav.vel_enu_mps + g * dt + ri * zv;
        let e = rjt * r_hat;
        let r_theta = so3::log(&e);
        let r_p = rjt * (p_hat - xj.nav.pos_enu_m);
        let r_v = rjt * (v_hat - xj.nav.vel_enu_mps);
        let mut residual = DVector::zeros(9);
        residual.fixed_rows_mut::<3>(0).copy_from(&r_theta);
        residual.fixed_rows_mut::<3>(3).copy_from(&r_p);
        residual.fixed_rows_mut::<3>(6).copy_from(&r_v);

        let jr_inv = so3::dexp(&r_theta).try_inverse().unwrap_or_else(Matrix3::identity);
        let jr_c = so3::dexp(&theta_c);
        let rjt_ri = rjt * ri;
        let mut ji = DMatrix::zeros(9, 15);
        let mut jj = DMatrix::zeros(9, 15);
        // rotation residual
        put(&mut ji, 0, 0, &(jr_inv * exp_c.transpose()));
        put(&mut jj, 0, 0, &(-jr_inv * e.transpose()));
        let d_theta_d_bg = pim.d_zeta_d_bias_gyro.fixed_view::<3, 3>(0, 0).into_owned();
        let d_theta_d_ba = pim.d_zeta_d_bias_acc.fixed_view::<3, 3>(0, 0).into_owned();
        put(&mut ji, 0, 9, &(jr_inv * jr_c * d_theta_d_ba));
        put(&mut ji, 0, 12, &(jr_inv * jr_c * d_theta_d_bg));
        // position residual
        put(&mut ji, 3, 0, &(rjt_ri * (-so3::hat(&zp))));
        put(&mut ji, 3, 3, &rjt);
        put(&mut ji, 3, 6, &(rjt * dt));
        put(&mut ji, 3, 9, &(rjt_ri * pim.d_zeta_d_bias_acc.fixed_view::<3, 3>(3, 0)));
        put(&mut ji, 3, 12, &(rjt_ri * pim.d_zeta_d_bias_gyro.fixed_view::<3, 3>(3, 0)));
        put(&mut jj, 3, 0, &so3::hat(&r_p));
        put(&mut jj, 3, 3, &(-rjt));
        // velocity residual
        put(&mut ji, 6, 0, &(rjt_ri * (-so3::hat(&zv))));
        put(&mut ji, 6, 6, &rjt);
        put(&mut ji, 6, 9, &(rjt_ri * pim.d_zeta_d_bias_acc.fixed_view::<3, 3>(6, 0)));
        put(&mut ji, 6, 12, &(rjt_ri * pim.d_zeta_d_bias_gyro.fixed_view::<3, 3>(6, 0)));
        put(&mut jj, 6, 0, &so3::hat(&r_v));
        put(&mut jj, 6, 6, &(-rjt));
        Evaluation { residual, jacobians: vec![ji, jj] }
    }
}

#[derive(Debug, Clone)]
pub struct BiasRandomWalkFactor {
    pub node_i: usize,
    pub node_j: usize,
    pub noise: Noise,
    /// Variance scale of `noise` over the given random walk (see [`ImuFactor::noise_scale`]).
    pub noise_scale: f64,
}

impl BiasRandomWalkFactor {
    /// Random walk over `dt_s` with sigmas per sqrt(s).
    pub fn new(node_i: usize, node_j: usize, acc_rw: f64, gyro_rw: f64, dt_s: f64) -> Result<Self, FgoError> {
        let sa = acc_rw * dt_s.sqrt();
        let sg = gyro_rw * dt_s.sqrt();
        Ok(Self { node_i, node_j, noise: Noise::from_sigmas(&[sa, sa, sa, sg, sg, sg])?, noise_scale: 1.0 })
    }

    /// Set the variance scale of the noise (relative to the given random walk), `s > 0`.
    pub fn set_noise_scale(&mut self, s: f64) {
        self.noise = self.noise.scaled(s / self.noise_scale);
        self.noise_scale = s;
    }

    pub fn evaluate(&self, xi: &NodeState, xj: &NodeState) -> Evaluation {
        let mut residual = DVector::zeros(6);
        residual.fixed_rows_mut::<3>(0).copy_from(&(xj.bias.acc_mps2 - xi.bias.acc_mps2));
        residual.fixed_rows_mut::<3>(3).copy_from(&(xj.bias.gyro_radps - xi.bias.gyro_radps));
        let mut ji = DMatrix::zeros(6, 15);
        let mut jj = DMatrix::zeros(6, 15);
        for k in 0..6 {
            ji[(k, 9 + k)] = -1.0;
            jj[(k, 9 + k)] = 1.0;
        }
        Evaluation { residual, jacobians: vec![ji, jj] }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::factors::Factor;
    use crate::factors::testutil::check_jacobians;
    use crate::preintegration::ImuParams;
    use crate::state::{ImuBias, NavState};

    #[test]
    fn imu_jacobians_match_numeric() {
        let mut pim = Preintegrated::new(ImuParams::default(), ImuBias::default());
        for k in 0..150 {
            let t = k as f64 * 0.01;
            pim.integrate(&Vector3::new(0.2 * t.sin(), 0.1, 9.7), &Vector3::new(0.1, -0.2 * t, 0.3), 0.01).unwrap();
        }
        let f = Factor::Imu(ImuFactor::new(0, 1, pim).unwrap());
        let xi = NodeState::new(
            NavState::new(so3::exp(&Vector3::new(0.1, 0.2, 1.0)), Vector3::new(10.0, -5.0, -20.0), Vector3::new(1.0, 0.5, 0.0)),
            ImuBias::new(Vector3::new(0.01, -0.02, 0.005), Vector3::new(1e-3, -2e-3, 5e-4)),
        );
        let xj = NodeState::new(
            NavState::new(so3::exp(&Vector3::new(0.15, 0.1, 1.4)), Vector3::new(11.2, -4.0, -20.1), Vector3::new(0.9, 0.7, 0.1)),
            ImuBias::default(),
        );
        check_jacobians(&f, &[xi, xj], 1e-6);
        if let Factor::Imu(imu) = &f {
            assert!((imu.residual(&xi, &xj) - imu.evaluate(&xi, &xj).residual).amax() < 1e-15);
        }
        let b = Factor::BiasRw(BiasRandomWalkFactor::new(0, 1, 1e-3, 1e-4, 1.5).unwrap());
        check_jacobians(&b, &[xi, xj], 1e-8);
    }
}
