//! Body-frame velocity update (DVL bottom lock, or any velocity measured in FRD).
//!
//! `z = (Exp(phi) R)^T (v + dv)`: couples attitude (heading) and velocity errors, which is what
//! bounds the horizontal drift between heading and position fixes. No lever arm or mounting
//! rotation: a DVL away from the IMU or turned against the body axes uses [`super::dvl`].

use super::rotation::quat_from_rotation_vector;
use nalgebra::{SVector, Vector3};

use crate::ukf::{Euclidean, UpdateReport};

use super::filter::{KIND_VELOCITY, NavError, NavFilter, settle};
use super::state::{ATT, NominalState, VEL, seg};

/// Predicted body velocity of an error sigma point.
pub fn h_body_velocity<const N: usize>(nom: &NominalState, dx: &SVector<f32, N>) -> Vector3<f32> {
    let q = quat_from_rotation_vector(&seg(dx, ATT)) * nom.att_nb;
    q.inverse_transform_vector(&(nom.vel_ned_mps + seg(dx, VEL)))
}

impl<const N: usize, const S: usize> NavFilter<N, S> {
    /// Velocity in the body frame (FRD, m/s) with a per-axis 1-sigma (`None`: configured/adapted),
    /// valid at `t_us` (time rules of [`super::history`], as `update_position`).
    pub fn update_body_velocity(
        &mut self,
        t_us: u64,
        vel_frd_mps: [f32; 3],
        sigma_mps: Option<f32>,
    ) -> Result<UpdateReport<f32>, NavError> {
        let vals = [vel_frd_mps[0], vel_frd_mps[1], vel_frd_mps[2], sigma_mps.unwrap_or(1.0)];
        if !vals.iter().all(|v| v.is_finite()) {
            return Err(self.reject_nonfinite());
        }
        let delayed = self.check_time(t_us)?;
        self.begin_update(&vals)?;
        let mut noise = self.noise_vel;
        if let Some(s) = sigma_mps.filter(|s| *s > 0.0) {
            if !(self.cfg.ukf.adapt.r_cov && noise.adapt) {
                noise.r = nalgebra::Matrix3::identity() * (s * s);
            }
        }
        let z = Vector3::from(vel_frd_mps);
        // One closure for both cases (one instantiation of the UKF update: flash on the M4F).
        let past = if delayed { Some(self.past_epoch(t_us)?) } else { None };
        let nom = self.nom;
        // Current: the model reads attitude and velocity only (`update_dep`); the retrodiction
        // reads every state.
        let dep = if past.is_some() { N } else { VEL + 3 };
        let r = self.ukf.update_dep::<3, Euclidean, _>(&z, &mut noise, dep, |dx| match &past {
            Some(ep) => h_body_velocity(&ep.nom, &ep.map(dx)),
            None => h_body_velocity(&nom, dx),
        });
        settle(&mut self.noise_vel, noise, &r);
        self.end_update(KIND_VELOCITY, t_us, r, delayed)
    }
}

impl<const N: usize, const S: usize> NavFilter<N, S> {
    /// Reset the velocity to `vel_ned_mps` with per-axis variances `var_ned_m2ps2` (NED): the
    /// velocity's correlations with every other error state are dropped (the estimate is new),
    /// the nominal's recorded past restarts (it is no longer one trajectory), the velocity noise
    /// statistics restart from the configuration. Attitude and position are left alone.
    ///
    /// For the estimator's velocity aid when the gate has refused a velocity sensor that works
    /// for longer than a velocity error can honestly explain (a filter gone free-inertial), as
    /// [`NavFilter::reset_position`] is for position fixes. Refused input changes nothing.
    pub fn reset_velocity(&mut self, vel_ned_mps: [f32; 3], var_ned_m2ps2: [f32; 3]) -> Result<(), NavError> {
        self.reset_block(VEL, &vel_ned_mps, &var_ned_m2ps2)?;
        self.nom.vel_ned_mps = Vector3::from(vel_ned_mps);
        self.hist.restart(self.t_us, &self.nom);
        self.noise_vel = self.cfg.velocity.noise();
        self.noise_vel.k = self.cfg.ukf.adapt.k0;
        Ok(())
    }
}
