//! Filter health as the `FilterHealth` telemetry message.

use subnav_wire::messages::{AidStatus, AidStatuses, FilterHealth};

use super::filter::NavFilter;
use super::state::{ATT, BA, BG, POS, VEL};

impl<const N: usize, const S: usize> NavFilter<N, S> {
    /// Health for telemetry. Notes on the fields:
    /// - `q_diag`: mean of each group's diagonal of the (adapted) process noise, per second
    ///   (the per-interval Q divided by the nominal covariance interval).
    /// - `pd_repairs`: eigenvalue repairs of P plus Sage-Husa Q/R candidates that lost positive
    ///   definiteness and were replaced by the biased form (the message has one counter; see
    ///   [`crate::ukf::UkfHealth`] for them apart).
    /// - `cov_unrepairable`: steps the UKF refused because the new P could not be made PD
    ///   ([`crate::ukf::UkfError::CovarianceUnrepairable`]); the filter is unchanged by them.
    /// - `nonfinite_rejects`: inputs rejected before the UKF plus those the UKF rejected.
    /// - `late_fused` / `late_refused`: the delayed-fusion counters (`delayed_updates`,
    ///   `delay_rejects`).
    /// - `aid`: each source's latest NIS and noise variance; the estimator, which owns the aid
    ///   sources, fills the rest (test ratio, counts, times, resets).
    /// - `heading_resets` / `position_resets` are left 0: the estimator that decides them fills
    ///   them.
    /// - `cpu_load_permille` is left 0: the firmware fills it.
    pub fn health(&self) -> FilterHealth {
        let h = self.ukf.health();
        let q = self.ukf.q();
        let t = self.cfg.cov_dt_s();
        let g = |s: usize| (0..3).map(|k| q.get((s + k, s + k)).copied().unwrap_or(0.0)).sum::<f32>() / (3.0 * t);
        FilterHealth {
            t_us: self.t_us,
            aid: {
                let r = self.r_diag();
                let st = |k: usize| AidStatus { nis: self.nis[k], noise_var: r[k], ..AidStatus::default() };
                AidStatuses { heading: st(0), depth: st(1), dvl: st(2), position: st(3) }
            },
            imu_q_scale: self.q_scale_applied,
            lambda: self.lambda,
            q_diag: [g(ATT), g(VEL), g(POS), g(BG), g(BA)],
            pd_repairs: h.pd_repairs.saturating_add(h.adapt_fallbacks),
            cov_unrepairable: h.unrepairable_rejects,
            gate_rejects: h.gate_rejects,
            nonfinite_rejects: h.nonfinite_rejects.saturating_add(self.imu_rejects),
            late_fused: self.delayed_updates(),
            late_refused: self.delay_rejects(),
            heading_resets: 0,
            position_resets: 0,
            cpu_load_permille: 0,
        }
    }
}
