//! Depth update from the pressure sensor (`DepthSample::depth_m`, NED z, positive down).
//!
//! `z = p_z + dp_z`: linear, so the update is the exact Kalman update
//! ([`crate::ukf::Ukf::update_linear`]: what the sigma points gave, at a fraction of the cost).

use nalgebra::{SMatrix, SVector, Vector1};

use crate::ukf::UpdateReport;

use super::filter::{KIND_DEPTH, NavError, NavFilter, settle};
use super::state::{NominalState, POS};

/// Predicted depth of an error sigma point.
pub fn h_depth<const N: usize>(nom: &NominalState, dx: &SVector<f32, N>) -> Vector1<f32> {
    Vector1::new(nom.pos_ned_m.z + dx.get(POS + 2).copied().unwrap_or(0.0))
}

impl<const N: usize, const S: usize> NavFilter<N, S> {
    /// Depth (m, positive down) with its 1-sigma (`None`: configured/adapted noise).
    pub fn update_depth(&mut self, t_us: u64, depth_m: f32, sigma_m: Option<f32>) -> Result<UpdateReport<f32>, NavError> {
        self.begin_update(&[depth_m, sigma_m.unwrap_or(1.0)])?;
        let mut noise = self.noise_depth;
        if let Some(s) = sigma_m.filter(|s| *s > 0.0) {
            if !(self.cfg.ukf.adapt.r_cov && noise.adapt) {
                noise.r[(0, 0)] = s * s;
            }
        }
        let nom = self.nom;
        // Linear in the error state: the exact Kalman update (`Ukf::update_linear`).
        let mut hm = SMatrix::<f32, 1, N>::zeros();
        if let Some(v) = hm.get_mut((0, POS + 2)) {
            *v = 1.0;
        }
        let r = self.ukf.update_linear::<1, _>(&Vector1::new(depth_m), &mut noise, &hm, |dx| h_depth(&nom, dx));
        settle(&mut self.noise_depth, noise, &r);
        self.end_update(KIND_DEPTH, t_us, r, false)
    }
}
