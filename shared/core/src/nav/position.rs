//! Position fix with covariance (what the host sends after recognizing a topological node:
//! `Command::PositionFix`).
//!
//! `z = p + dp`, NED metres; the fix brings its own covariance (upper triangle xx, xy, xz, yy,
//! yz, zz), so R adaptation is off for it by default. The covariance is checked (finite, PD) and
//! refused otherwise. A position reset (re-acquisition of a lost position) is here too.

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

use crate::ukf::pd;
use crate::ukf::{Euclidean, UpdateReport};

use super::filter::{KIND_POSITION, NavError, NavFilter, settle};
use super::history::CURRENT_WITHIN_US;
use super::state::{NominalState, POS, seg};

/// Predicted position of an error sigma point.
pub fn h_position<const N: usize>(nom: &NominalState, dx: &SVector<f32, N>) -> Vector3<f32> {
    nom.pos_ned_m + seg(dx, POS)
}

impl<const N: usize, const S: usize> NavFilter<N, S> {
    /// Position fix (NED, m) with its covariance (upper triangle xx, xy, xz, yy, yz, zz; m^2),
    /// valid at `t_us`: fused at that time if it is in the past (see [`super::history`]; older
    /// than the history: `NavError::TooOld`, stamped beyond `NavConfig::max_future_us`:
    /// `NavError::FromFuture`, both counted in `delay_rejects`, state untouched).
    pub fn update_position(&mut self, t_us: u64, pos_ned_m: [f32; 3], cov_ned_m2: [f32; 6]) -> Result<UpdateReport<f32>, NavError> {
        let mut vals = [0.0f32; 9];
        vals[..3].copy_from_slice(&pos_ned_m);
        vals[3..].copy_from_slice(&cov_ned_m2);
        if !vals.iter().all(|v| v.is_finite()) {
            return Err(self.reject_nonfinite());
        }
        let delayed = self.check_time(t_us)?;
        self.begin_update(&vals)?;
        let [xx, xy, xz, yy, yz, zz] = cov_ned_m2;
        let r = Matrix3::new(xx, xy, xz, xy, yy, yz, xz, yz, zz);
        if nalgebra::linalg::Cholesky::new(r).is_none() || !pd::all_finite(&r) {
            return Err(self.reject_nonfinite());
        }
        let mut noise = self.noise_pos;
        if !(self.cfg.ukf.adapt.r_cov && noise.adapt) {
            noise.r = r;
        }
        let z = Vector3::from(pos_ned_m);
        let past = if delayed { Some(self.past_epoch(t_us)?) } else { None };
        let nom = self.nom;
        let res = match &past {
            // Mapped back through the (nonlinear) retrodiction: sigma points.
            Some(ep) => self.ukf.update::<3, Euclidean, _>(&z, &mut noise, |dx| h_position(&ep.nom, &ep.map(dx))),
            // Current: linear in the error state, the exact Kalman update.
            None => {
                let mut hm = SMatrix::<f32, 3, N>::zeros();
                for k in 0..3 {
                    if let Some(v) = hm.get_mut((k, POS + k)) {
                        *v = 1.0;
                    }
                }
                self.ukf.update_linear::<3, _>(&z, &mut noise, &hm, |dx| h_position(&nom, dx))
            }
        };
        settle(&mut self.noise_pos, noise, &res);
        self.end_update(KIND_POSITION, t_us, res, delayed)
    }

    /// The nominal position at `t_us`, now or in the history (NED, m); `None` outside them.
    /// Changes nothing (a time outside the history is not counted as a refused measurement).
    pub fn position_at(&self, t_us: u64) -> Option<Vector3<f32>> {
        if t_us > self.t_us.saturating_add(self.cfg.max_future_us) {
            return None;
        }
        if t_us.saturating_add(CURRENT_WITHIN_US) >= self.t_us {
            return Some(self.nom.pos_ned_m);
        }
        self.epoch_at(t_us).map(|e| e.nom.pos_ned_m)
    }

    /// Position reset (re-acquisition): move the nominal position to `pos_ned_m` and make its
    /// error independent of every other state with variances `var_ned_m2` (N, E, D); the
    /// position noise statistics restart from the configuration.
    ///
    /// For the estimator's use when the gate has refused a run of mutually consistent position
    /// fixes (a lost position, e.g. after a long DVL outage with false map fixes), as for the
    /// heading ([`NavFilter::reset_heading`]). Attitude and velocity are left alone.
    pub fn reset_position(&mut self, pos_ned_m: [f32; 3], var_ned_m2: [f32; 3]) -> Result<(), NavError> {
        self.reset_block(POS, &pos_ned_m, &var_ned_m2)?;
        self.nom.pos_ned_m = Vector3::from(pos_ned_m);
        // The nominal position jumped: the recorded past is no longer the same trajectory.
        self.hist.restart(self.t_us, &self.nom);
        self.noise_pos = self.cfg.position.noise();
        self.noise_pos.k = self.cfg.ukf.adapt.k0;
        Ok(())
    }
}

impl<const N: usize, const S: usize> NavFilter<N, S> {
    /// The covariance part of a reset of the 3-state block at `start` to new values: checked
    /// (finite values, finite positive variances: else refused, counted, nothing changes), the
    /// partial covariance interval flushed, the block's rows and columns zeroed and its
    /// diagonal set to `var` (symmetric, PD if P was). The caller sets the nominal.
    pub(crate) fn reset_block(&mut self, start: usize, values: &[f32; 3], var: &[f32; 3]) -> Result<(), NavError> {
        if !values.iter().all(|v| v.is_finite()) || !var.iter().all(|v| v.is_finite() && *v > 0.0) {
            return Err(self.reject_nonfinite());
        }
        self.begin_update(&[])?;
        let mut p = *self.ukf.p();
        for (k, var) in var.iter().enumerate() {
            for i in 0..N {
                for idx in [(start + k, i), (i, start + k)] {
                    if let Some(v) = p.get_mut(idx) {
                        *v = 0.0;
                    }
                }
            }
            if let Some(v) = p.get_mut((start + k, start + k)) {
                *v = *var;
            }
        }
        self.ukf.set_p(p)?;
        Ok(())
    }
}
