//! Heading update from the polarization compass (`CompassReport::heading_rad`).
//!
//! `z = yaw(Exp(phi) R_nominal)`, a 1-D angle: wrapped residual and circular mean
//! ([`AngleSpace`]), so a heading near +-pi is handled, and the attitude error enters through the
//! rotation, not through a linearization.

use super::rotation::quat_from_rotation_vector;
use nalgebra::{SMatrix, SVector, UnitQuaternion, Vector1};

use crate::ukf::{AngleSpace, UpdateReport};

use super::filter::{KIND_HEADING, NavError, NavFilter, settle};
use super::state::{ATT, NominalState, VEL, seg, yaw_of};

/// Predicted heading of an error sigma point.
pub fn h_heading<const N: usize>(nom: &NominalState, dx: &SVector<f32, N>) -> Vector1<f32> {
    let q = quat_from_rotation_vector(&seg(dx, ATT)) * nom.att_nb;
    Vector1::new(yaw_of(&q))
}

impl<const N: usize, const S: usize> NavFilter<N, S> {
    /// Heading (rad from north, clockwise) with its 1-sigma (`None` or non-positive: the
    /// configured/adapted noise). When R adaptation is on for the heading, the adapted R is used
    /// and `sigma_rad` is ignored.
    pub fn update_heading(&mut self, t_us: u64, heading_rad: f32, sigma_rad: Option<f32>) -> Result<UpdateReport<f32>, NavError> {
        self.begin_update(&[heading_rad, sigma_rad.unwrap_or(1.0)])?;
        let mut noise = self.noise_heading;
        if let Some(s) = sigma_rad.filter(|s| *s > 0.0) {
            if !(self.cfg.ukf.adapt.r_cov && noise.adapt) {
                noise.r[(0, 0)] = s * s;
            }
        }
        let nom = self.nom;
        let z = Vector1::new(crate::ukf::wrap_pi(heading_rad));
        // The heading reads only the attitude error (`update_dep`: 7 evaluations, not 2N + 1).
        let r = self.ukf.update_dep::<1, AngleSpace, _>(&z, &mut noise, ATT + 3, |dx| h_heading(&nom, dx));
        settle(&mut self.noise_heading, noise, &r);
        self.end_update(KIND_HEADING, t_us, r, false)
    }
}

impl<const N: usize, const S: usize> NavFilter<N, S> {
    /// Heading reset (re-acquisition): turn the nominal attitude and velocity about the NED down
    /// axis so the yaw becomes `heading_rad`, rotate their error covariance with them, and make
    /// the yaw error independent of every other state with 1-sigma `sigma_rad`. The heading
    /// noise statistics restart from the configuration (an R adapted while every fix was being
    /// rejected describes the wrong state, not the sensor).
    ///
    /// For the estimator's use when the heading gate has rejected a long run of mutually
    /// consistent compass fixes (a wrong initial heading), like EKF2's yaw reset. The position is
    /// left alone: it cannot be recovered from a heading.
    pub fn reset_heading(&mut self, heading_rad: f32, sigma_rad: f32) -> Result<(), NavError> {
        if !heading_rad.is_finite() || !(sigma_rad.is_finite() && sigma_rad > 0.0) {
            return Err(self.reject_nonfinite());
        }
        self.begin_update(&[])?;
        let delta = crate::ukf::wrap_pi(heading_rad - yaw_of(&self.nom.att_nb));
        let rz = UnitQuaternion::from_axis_angle(&nalgebra::Vector3::z_axis(), delta);
        let mut nom = self.nom;
        nom.att_nb = rz * nom.att_nb;
        nom.vel_ned_mps = rz * nom.vel_ned_mps;
        if !nom.is_finite() {
            return Err(NavError::NonFinite);
        }
        // P <- T P T^T with T = blockdiag(Rz on the attitude and velocity errors, I), then the
        // yaw error decorrelated and set.
        let r = rz.to_rotation_matrix().into_inner();
        let mut t = SMatrix::<f32, N, N>::identity();
        for blk in [ATT, VEL] {
            if blk + 3 <= N {
                t.fixed_view_mut::<3, 3>(blk, blk).copy_from(&r);
            }
        }
        let mut p = t * self.ukf.p() * t.transpose();
        super::filter::set_yaw_uncorrelated(&mut p, sigma_rad * sigma_rad);
        self.ukf.set_p(p)?;
        self.nom = nom;
        // The nominal frame turned: the recorded past is no longer the same trajectory.
        self.hist.restart(self.t_us, &self.nom);
        let k0 = self.cfg.ukf.adapt.k0;
        self.noise_heading = self.cfg.heading.noise();
        self.noise_heading.k = k0;
        Ok(())
    }
}
