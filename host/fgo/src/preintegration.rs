//! On-manifold IMU preintegration (Forster et al.) in GTSAM's tangent-space form, the form GTSAM
//! 4.3's default `PreintegratedImuMeasurements` uses: the increment is kept as
//! `zeta = [theta, delta_p, delta_v]` with `Delta R = Exp(theta)`, updated per sample with
//! `theta += dexp(theta)^-1 w dt`, `delta_p += delta_v dt + R a dt^2/2`, `delta_v += R a dt`.
//! It is independent of the start state, so relinearising never re-integrates; bias changes are
//! applied to first order through the bias Jacobians `d zeta / d b_acc`, `d zeta / d b_gyro`.
//! The covariance of `zeta` is propagated with the transition `A` and input Jacobians `B`, `C`:
//! `P <- A P A^T + B (Q_acc/dt) B^T + C (Q_gyro/dt) C^T`, plus `Q_int dt` on the position block
//! (GTSAM's integration covariance). Noise densities are continuous-time (per sqrt(Hz)).

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

use super::FgoError;
use super::state::{ImuBias, NavState};
use subnav_base::so3;

pub type Vector9 = SVector<f64, 9>;
pub type Matrix9 = SMatrix<f64, 9, 9>;
pub type Matrix93 = SMatrix<f64, 9, 3>;

/// IMU noise model and gravity, the fields of GTSAM's `PreintegrationParams` used here.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ImuParams {
    /// Gravity in ENU, normally `[0, 0, -9.81]`.
    pub gravity_enu_mps2: [f64; 3],
    /// Accelerometer white-noise density sigma, (m/s^2)/sqrt(Hz).
    pub acc_noise_density: f64,
    /// Gyro white-noise density sigma, (rad/s)/sqrt(Hz).
    pub gyro_noise_density: f64,
    /// Integration noise sigma (GTSAM `integrationCovariance`), m/sqrt(s)-ish; small.
    pub integration_sigma: f64,
    /// Accelerometer bias random-walk sigma, (m/s^2)*sqrt(Hz)... per sqrt(s).
    pub acc_bias_rw: f64,
    /// Gyro bias random-walk sigma, (rad/s) per sqrt(s).
    pub gyro_bias_rw: f64,
}

impl Default for ImuParams {
    fn default() -> Self {
        Self {
            gravity_enu_mps2: [0.0, 0.0, -9.81],
            acc_noise_density: 2e-3,
            gyro_noise_density: 1e-4,
            integration_sigma: 1e-4,
            acc_bias_rw: 1e-4,
            gyro_bias_rw: 1e-5,
        }
    }
}

impl ImuParams {
    pub fn gravity(&self) -> Vector3<f64> {
        Vector3::from(self.gravity_enu_mps2)
    }
    pub fn acc_cov(&self) -> Matrix3<f64> {
        Matrix3::identity() * self.acc_noise_density.powi(2)
    }
    pub fn gyro_cov(&self) -> Matrix3<f64> {
        Matrix3::identity() * self.gyro_noise_density.powi(2)
    }
    pub fn integration_cov(&self) -> Matrix3<f64> {
        Matrix3::identity() * self.integration_sigma.powi(2)
    }
    pub fn validate(&self) -> Result<(), FgoError> {
        // The integration sigma may be 0 (GTSAM's KITTI metadata): the accelerometer noise
        // keeps the position block of the preintegrated covariance positive definite.
        let all = [self.acc_noise_density, self.gyro_noise_density, self.acc_bias_rw, self.gyro_bias_rw];
        if !self.gravity_enu_mps2.iter().all(|g| g.is_finite())
            || !all.iter().all(|x| x.is_finite() && *x > 0.0)
            || !(self.integration_sigma.is_finite() && self.integration_sigma >= 0.0)
        {
            return Err(FgoError::Input(format!("IMU parameters must be finite, noise sigmas > 0 (integration >= 0): {self:?}")));
        }
        Ok(())
    }
}

/// Preintegrated IMU measurements between two nodes.
#[derive(Debug, Clone, PartialEq)]
pub struct Preintegrated {
    pub params: ImuParams,
    /// Bias used while integrating (linearisation point of the bias correction).
    pub bias_hat: ImuBias,
    pub delta_t_s: f64,
    /// `[theta, delta_p, delta_v]`
    pub zeta: Vector9,
    pub d_zeta_d_bias_acc: Matrix93,
    pub d_zeta_d_bias_gyro: Matrix93,
    /// Covariance of `zeta` (order theta, p, v).
    pub cov: Matrix9,
}

impl Preintegrated {
    pub fn new(params: ImuParams, bias_hat: ImuBias) -> Self {
        Self {
            params,
            bias_hat,
            delta_t_s: 0.0,
            zeta: Vector9::zeros(),
            d_zeta_d_bias_acc: Matrix93::zeros(),
            d_zeta_d_bias_gyro: Matrix93::zeros(),
            cov: Matrix9::zeros(),
        }
    }

    /// Integrate one sample (specific force and angular rate in the body frame) held for `dt_s`.
    pub fn integrate(&mut self, acc_mps2: &Vector3<f64>, gyro_radps: &Vector3<f64>, dt_s: f64) -> Result<(), FgoError> {
        if !(dt_s > 0.0 && dt_s.is_finite()) {
            return Err(FgoError::Input(format!("IMU sample interval must be > 0 and finite, got {dt_s}")));
        }
        if !acc_mps2.iter().chain(gyro_radps.iter()).all(|x| x.is_finite()) {
            return Err(FgoError::Input("IMU sample contains NaN or infinity".into()));
        }
        let a = acc_mps2 - self.bias_hat.acc_mps2;
        let w = gyro_radps - self.bias_hat.gyro_radps;
        let theta = Vector3::new(self.zeta[0], self.zeta[1], self.zeta[2]);
        let pos = Vector3::new(self.zeta[3], self.zeta[4], self.zeta[5]);
        let vel = Vector3::new(self.zeta[6], self.zeta[7], self.zeta[8]);

        let inv = so3::apply_inv_dexp(&theta, &w);
        let r = inv.rot;
        let a_nav = r * a;
        let dt22 = 0.5 * dt_s * dt_s;

        let mut next = Vector9::zeros();
        next.fixed_rows_mut::<3>(0).copy_from(&(theta + inv.value * dt_s));
        next.fixed_rows_mut::<3>(3).copy_from(&(pos + vel * dt_s + a_nav * dt22));
        next.fixed_rows_mut::<3>(6).copy_from(&(vel + a_nav * dt_s));

        // A = d next / d zeta
        let a_nav_h_theta = r * so3::hat(&(-a)) * inv.dexp;
        let mut big_a = Matrix9::identity();
        {
            let mut blk = big_a.fixed_view_mut::<3, 3>(0, 0);
            blk += inv.d_omega * dt_s;
        }
        big_a.fixed_view_mut::<3, 3>(3, 0).copy_from(&(a_nav_h_theta * dt22));
        big_a.fixed_view_mut::<3, 3>(3, 6).copy_from(&(Matrix3::identity() * dt_s));
        big_a.fixed_view_mut::<3, 3>(6, 0).copy_from(&(a_nav_h_theta * dt_s));
        // B = d next / d acc, C = d next / d gyro
        let mut big_b = Matrix93::zeros();
        big_b.fixed_view_mut::<3, 3>(3, 0).copy_from(&(r * dt22));
        big_b.fixed_view_mut::<3, 3>(6, 0).copy_from(&(r * dt_s));
        let mut big_c = Matrix93::zeros();
        big_c.fixed_view_mut::<3, 3>(0, 0).copy_from(&(inv.d_v * dt_s));

        self.delta_t_s += dt_s;
        self.zeta = next;
        self.d_zeta_d_bias_acc = big_a * self.d_zeta_d_bias_acc - big_b;
        self.d_zeta_d_bias_gyro = big_a * self.d_zeta_d_bias_gyro - big_c;

        let p = &self.params;
        let mut cov = big_a * self.cov * big_a.transpose();
        cov += big_b * (p.acc_cov() / dt_s) * big_b.transpose();
        cov += big_c * (p.gyro_cov() / dt_s) * big_c.transpose();
        {
            let mut blk = cov.fixed_view_mut::<3, 3>(3, 3);
            blk += p.integration_cov() * dt_s;
        }
        // keep it symmetric by construction
        self.cov = (cov + cov.transpose()) * 0.5;
        Ok(())
    }

    /// Covariance of the component-wise IMU residual (GTSAM 4.3 `residualCovariance()`, the
    /// ImuFactor's noise): `T P T^T` with `T = diag(dexp(theta), Delta R^T, Delta R^T)`, which
    /// moves the rotation part to the right-perturbation chart of `Exp(theta)` and the position and
    /// velocity parts into the frame at the end of the interval, where the residual lives.
    pub fn residual_cov(&self) -> Matrix9 {
        let theta = Vector3::new(self.zeta[0], self.zeta[1], self.zeta[2]);
        let dr_t = so3::exp(&theta).transpose();
        let mut t = Matrix9::zeros();
        t.fixed_view_mut::<3, 3>(0, 0).copy_from(&so3::dexp(&theta));
        t.fixed_view_mut::<3, 3>(3, 3).copy_from(&dr_t);
        t.fixed_view_mut::<3, 3>(6, 6).copy_from(&dr_t);
        let c = t * self.cov * t.transpose();
        (c + c.transpose()) * 0.5
    }

    pub fn delta_rot(&self) -> Matrix3<f64> {
        so3::exp(&Vector3::new(self.zeta[0], self.zeta[1], self.zeta[2]))
    }
    pub fn delta_pos(&self) -> Vector3<f64> {
        Vector3::new(self.zeta[3], self.zeta[4], self.zeta[5])
    }
    pub fn delta_vel(&self) -> Vector3<f64> {
        Vector3::new(self.zeta[6], self.zeta[7], self.zeta[8])
    }

    /// `zeta` corrected to first order for `bias` (instead of re-integrating).
    pub fn bias_corrected(&self, bias: &ImuBias) -> Vector9 {
        self.zeta
            + self.d_zeta_d_bias_acc * (bias.acc_mps2 - self.bias_hat.acc_mps2)
            + self.d_zeta_d_bias_gyro * (bias.gyro_radps - self.bias_hat.gyro_radps)
    }

    /// Predicted state at the end of the interval from `state_i` and `bias_i` (GTSAM `predict`).
    pub fn predict(&self, state_i: &NavState, bias_i: &ImuBias) -> NavState {
        let z = self.bias_corrected(bias_i);
        let dt = self.delta_t_s;
        let g = self.params.gravity();
        let ri = state_i.rot_enu_flu;
        let rit = ri.transpose();
        let d_theta = Vector3::new(z[0], z[1], z[2]);
        let d_p = Vector3::new(z[3], z[4], z[5]) + rit * state_i.vel_enu_mps * dt + rit * g * (0.5 * dt * dt);
        let d_v = Vector3::new(z[6], z[7], z[8]) + rit * g * dt;
        NavState {
            rot_enu_flu: ri * so3::exp(&d_theta),
            pos_enu_m: state_i.pos_enu_m + ri * d_p,
            vel_enu_mps: state_i.vel_enu_mps + ri * d_v,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_rates_analytic_case() {
        // Pure rotation about z at constant rate and constant body specific force cancelling gravity:
        // Delta R = Exp(w T), Delta v = 0 from the start state at rest (predict keeps v = 0).
        let p = ImuParams::default();
        let mut pim = Preintegrated::new(p, ImuBias::default());
        let w = Vector3::new(0.0, 0.0, 0.3);
        let f = Vector3::new(0.0, 0.0, 9.81);
        for _ in 0..100 {
            pim.integrate(&f, &w, 0.01).unwrap();
        }
        let expected = so3::exp(&(w * 1.0));
        assert!((pim.delta_rot() - expected).norm() < 1e-12);
        let s = pim.predict(&NavState::identity(), &ImuBias::default());
        assert!(s.vel_enu_mps.norm() < 1e-12 && s.pos_enu_m.norm() < 1e-12, "{s:?}");
        // covariance symmetric positive definite
        let eig = pim.cov.symmetric_eigenvalues();
        assert!(eig.iter().all(|e| *e > 0.0));
    }

    #[test]
    fn bias_jacobians_match_reintegration() {
        let p = ImuParams::default();
        let samples: Vec<(Vector3<f64>, Vector3<f64>)> = (0..200)
            .map(|k| {
                let t = k as f64 * 0.01;
                (Vector3::new(0.3 * t.sin(), 0.1, 9.81 + 0.2 * t.cos()), Vector3::new(0.05, -0.1 * t.cos(), 0.2))
            })
            .collect();
        let run = |b: ImuBias| {
            let mut pim = Preintegrated::new(p, b);
            for (a, w) in &samples {
                pim.integrate(a, w, 0.01).unwrap();
            }
            pim
        };
        let base = run(ImuBias::default());
        let db = ImuBias::new(Vector3::new(1e-3, -2e-3, 1e-3), Vector3::new(2e-4, 1e-4, -3e-4));
        let exact = run(db).zeta;
        let approx = base.bias_corrected(&db);
        assert!((exact - approx).norm() < 1e-5, "{}", (exact - approx).norm());
        // and the correction is much better than none
        assert!((exact - base.zeta).norm() > 100.0 * (exact - approx).norm());
    }

    #[test]
    fn bad_samples_are_errors() {
        let mut pim = Preintegrated::new(ImuParams::default(), ImuBias::default());
        assert!(pim.integrate(&Vector3::zeros(), &Vector3::zeros(), 0.0).is_err());
        assert!(pim.integrate(&Vector3::new(f64::NAN, 0.0, 0.0), &Vector3::zeros(), 0.01).is_err());
        assert_eq!(pim.delta_t_s, 0.0);
    }
}
