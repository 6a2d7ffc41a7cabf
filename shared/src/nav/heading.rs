//! Heading update from the polarization compass (`CompassReport::heading_rad`).
//!
//! `z = yaw(Exp(phi) R_nominal)`, a 1-D angle: wrapped residual and circular mean
//! ([`AngleSpace`]), so a heading near +-pi is handled, and the attitude error enters through the
//! rotation, not through a linearization.

use nalgebra::{SVector, UnitQuaternion, Vector1};

use crate::ukf::{AngleSpace, UpdateReport};

use super::filter::{KIND_HEADING, NavError, NavFilter};
use super::state::{ATT, NominalState, seg, yaw_of};

/// Predicted heading of an error sigma point.
pub fn h_heading<const N: usize>(nom: &NominalState, dx: &SVector<f32, N>) -> Vector1<f32> {
    let q = UnitQuaternion::from_scaled_axis(seg(dx, ATT)) * nom.att_nb;
    Vector1::new(yaw_of(&q))
}

impl<const N: usize, const S: usize> NavFilter<N, S> {
    /// Heading (rad from north, clockwise) with its 1-sigma (`None` or non-positive: the
    /// configured/adapted noise). When R adaptation is on for the heading, the adapted R is used
    /// and `sigma_rad` is ignored.
    pub fn update_heading(&mut self, t_us: u64, heading_rad: f32, sigma_rad: Option<f32>) -> Result<UpdateReport<f32>, NavError> {
        self.begin_update(&[heading_rad, sigma_rad.unwrap_or(1.0)])?;
        if let Some(s) = sigma_rad.filter(|s| *s > 0.0) {
            if !(self.cfg.ukf.adapt.r_cov && self.noise_heading.adapt) {
                self.noise_heading.r[(0, 0)] = s * s;
            }
        }
        let nom = self.nom;
        let z = Vector1::new(crate::ukf::wrap_pi(heading_rad));
        let r = self.ukf.update::<1, AngleSpace, _>(&z, &mut self.noise_heading, |dx| h_heading(&nom, dx));
        self.end_update(KIND_HEADING, t_us, r)
    }
}
