//! The one scoring of the head's navigation solutions against a simulated dive's truth. `subnav
//! run` (its text summary and `--format json`, through `subnav_sil::run::RunOutput::score`), the
//! report (`subnav_report`, from a recording and its truth) and the live truth-error topic
//! (`/subnav/truth/error`, [`crate::export::topics`]) all call it, so they agree by construction.
//!
//! Definitions (what a page that shows the figures says it scores):
//! - an **epoch** is one `Nav` solution; the error is estimate minus truth at its time of
//!   validity, heading from the body->NED quaternion's ZYX yaw, wrapped to [-180, 180) deg;
//! - **scored**: the aided epochs (`NavMode::Aided`), the alignment before them left out;
//!   position (horizontal RMS, final, max; depth RMSE) over all of them, and the fraction within
//!   3 sigma (north and east each within 3 of their sigmas);
//! - **heading** over the **converged** aided epochs (yaw 1-sigma at most
//!   [`HEADING_CONVERGED_SIGMA_DEG`]): RMSE, max, fraction within 3 sigma; the RMSE over all
//!   aided epochs is given beside it.
//!
//! Sums are taken in epoch order, so a score is the same to the bit whoever computes it from the
//! same epochs and truth.

use nalgebra::{Quaternion, UnitQuaternion};
use serde::Serialize;
use subnav_core::ukf::wrap_deg;
use subnav_wire::{NavMode, NavSolution};

/// Yaw 1-sigma (deg) at or below which the heading counts as converged.
pub const HEADING_CONVERGED_SIGMA_DEG: f64 = 5.0;

/// The truth at an epoch's time: NED position (m) and yaw (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Truth {
    pub pos_ned_m: [f64; 3],
    pub yaw_rad: f64,
}

/// One epoch's errors against the truth and its reported sigmas.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Epoch {
    pub t_s: f64,
    /// Estimate minus truth, NED, m.
    pub err_ned_m: [f64; 3],
    pub horizontal_err_m: f64,
    /// Estimate minus truth, deg in [-180, 180).
    pub heading_err_deg: f64,
    pub sigma_pos_m: [f64; 3],
    pub sigma_horizontal_m: f64,
    pub sigma_heading_deg: f64,
    /// Yaw sigma at most [`HEADING_CONVERGED_SIGMA_DEG`].
    pub heading_converged: bool,
    /// North and east each within 3 of their sigmas.
    pub horizontal_within_3_sigma: bool,
    pub heading_within_3_sigma: bool,
}

/// Yaw (deg) of a body->NED quaternion `[w, x, y, z]` (ZYX Euler; nalgebra normalises it).
pub fn yaw_deg(att_nb_wxyz: [f32; 4]) -> f64 {
    let [w, x, y, z] = att_nb_wxyz.map(f64::from);
    UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)).euler_angles().2.to_degrees()
}

/// The errors of the solution `n` against `truth` (any mode; [`Scorer`] keeps the aided ones).
pub fn epoch(n: &NavSolution, truth: &Truth) -> Epoch {
    let f = f64::from;
    let (en, ee) = (f(n.pos_ned_m[0]) - truth.pos_ned_m[0], f(n.pos_ned_m[1]) - truth.pos_ned_m[1]);
    let ed = f(n.pos_ned_m[2]) - truth.pos_ned_m[2];
    let eh = wrap_deg(yaw_deg(n.att_nb_wxyz) - truth.yaw_rad.to_degrees());
    let sigma_pos_m = n.sigma_pos_m.map(f);
    let sigma_heading_deg = f(n.sigma_att_rad[2]).to_degrees();
    Epoch {
        t_s: n.t_us as f64 * 1e-6,
        err_ned_m: [en, ee, ed],
        horizontal_err_m: (en * en + ee * ee).sqrt(),
        heading_err_deg: eh,
        sigma_pos_m,
        sigma_horizontal_m: (sigma_pos_m[0] * sigma_pos_m[0] + sigma_pos_m[1] * sigma_pos_m[1]).sqrt(),
        sigma_heading_deg,
        heading_converged: sigma_heading_deg <= HEADING_CONVERGED_SIGMA_DEG,
        horizontal_within_3_sigma: en.abs() <= 3.0 * sigma_pos_m[0] && ee.abs() <= 3.0 * sigma_pos_m[1],
        heading_within_3_sigma: eh.abs() <= 3.0 * sigma_heading_deg,
    }
}

/// The figures of a run (see the module doc for what each scores). NaN: nothing to score.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Score {
    /// Aided epochs scored.
    pub scored: usize,
    /// Of which with a converged heading.
    pub heading_converged_epochs: usize,
    pub first_aided_s: Option<f64>,
    pub last_aided_s: Option<f64>,
    pub heading_converged_s: Option<f64>,
    /// Heading over the converged epochs.
    pub heading_rmse_deg: f64,
    pub heading_max_abs_err_deg: f64,
    pub heading_within_3_sigma: f64,
    /// Heading over every aided epoch.
    pub heading_rmse_all_aided_deg: f64,
    pub horizontal_rms_err_m: f64,
    pub horizontal_final_err_m: f64,
    pub horizontal_max_err_m: f64,
    pub depth_rmse_m: f64,
    /// Fraction of aided epochs with north and east within 3 sigma.
    pub within_3_sigma: f64,
}

/// Accumulates epochs into a [`Score`].
#[derive(Debug, Clone, Default)]
pub struct Scorer {
    n: usize,
    n_conv: usize,
    first_s: Option<f64>,
    last_s: Option<f64>,
    conv_s: Option<f64>,
    sum_h2: f64,
    sum_h2_conv: f64,
    sum_p2: f64,
    sum_d2: f64,
    inside: usize,
    h_inside: usize,
    h_max: f64,
    p_final: f64,
    p_max: f64,
}

impl Scorer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Scores `n` against `truth` if it is aided; returns its epoch then.
    pub fn add(&mut self, n: &NavSolution, truth: &Truth) -> Option<Epoch> {
        if n.mode != NavMode::Aided {
            return None;
        }
        let e = epoch(n, truth);
        let [en, ee, ed] = e.err_ned_m;
        let eh = e.heading_err_deg;
        self.first_s.get_or_insert(e.t_s);
        self.last_s = Some(e.t_s);
        self.n += 1;
        self.sum_h2 += eh * eh;
        self.sum_p2 += en * en + ee * ee;
        self.sum_d2 += ed * ed;
        if e.heading_converged {
            self.conv_s.get_or_insert(e.t_s);
            self.sum_h2_conv += eh * eh;
            self.n_conv += 1;
            self.h_max = self.h_max.max(eh.abs());
            if e.heading_within_3_sigma {
                self.h_inside += 1;
            }
        }
        self.p_final = e.horizontal_err_m;
        self.p_max = self.p_max.max(e.horizontal_err_m);
        if e.horizontal_within_3_sigma {
            self.inside += 1;
        }
        Some(e)
    }

    pub fn score(&self) -> Score {
        let mut s = Score {
            scored: self.n,
            heading_converged_epochs: self.n_conv,
            first_aided_s: self.first_s,
            last_aided_s: self.last_s,
            heading_converged_s: self.conv_s,
            heading_rmse_deg: f64::NAN,
            heading_max_abs_err_deg: self.h_max,
            heading_within_3_sigma: f64::NAN,
            heading_rmse_all_aided_deg: f64::NAN,
            horizontal_rms_err_m: f64::NAN,
            horizontal_final_err_m: f64::NAN,
            horizontal_max_err_m: self.p_max,
            depth_rmse_m: f64::NAN,
            within_3_sigma: f64::NAN,
        };
        if self.n > 0 {
            let n = self.n as f64;
            s.heading_rmse_all_aided_deg = (self.sum_h2 / n).sqrt();
            s.horizontal_rms_err_m = (self.sum_p2 / n).sqrt();
            s.horizontal_final_err_m = self.p_final;
            s.depth_rmse_m = (self.sum_d2 / n).sqrt();
            s.within_3_sigma = self.inside as f64 / n;
        }
        if self.n_conv > 0 {
            s.heading_rmse_deg = (self.sum_h2_conv / self.n_conv as f64).sqrt();
            s.heading_within_3_sigma = self.h_inside as f64 / self.n_conv as f64;
        }
        s
    }
}
