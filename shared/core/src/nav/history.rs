//! Fusion of a measurement at its own time of validity (DVL ensembles ~0.1-0.5 s late, USBL-like
//! and map fixes 0.5-3 s late) in fixed memory.
//!
//! **What.** [`History`] is a ring of the nominal state's past (time, attitude, NED velocity, NED
//! position; not the biases, which are constants of the model and current), one entry per
//! [`HISTORY_SPACING_US`] grid point, [`HISTORY_LEN`] entries: a horizon of
//! `(HISTORY_LEN - 1) * HISTORY_SPACING_US` = 4.05 s behind the newest entry, plus the time since.
//! A measurement valid at `t_m < t_now` is fused by the *current* UKF:
//!
//! 1. the nominal at `t_m` is interpolated between the two neighbouring entries (the current
//!    nominal is the last node): linear in position and velocity, normalized lerp of the attitude;
//! 2. each error sigma point of the current filter is mapped back to `t_m` by
//!    [`super::strapdown::retrodict_error`], the inverse of the error transition the UKF predict
//!    uses, over the interval `[t_m, t_now]` whose increments come from the history itself:
//!    `dv_f = v_now - v_m - g T`, `dp_f = p_now - p_m - v_m T - g T^2 / 2` (exact for the
//!    strapdown's trapezoidal integration), `c = T (R_m + R_now) / 2`, `cc = T^2 (R_m / 3 + R_now / 6)`
//!    (rotation linear in time between the two ends);
//! 3. the measurement model is evaluated on that past nominal + mapped error, the UKF update runs
//!    with the current covariance, and the resulting error mean is injected at `t_now` as usual.
//!
//! This is the delayed-measurement fusion of Larsen, Andersen, Ravn & Poulsen (1998) in
//! sigma-point form: the measurement is re-expressed as one of the current error state.
//!
//! **Neglected, with their size.** (a) The process noise over the delay: the current `P` mapped
//! back is the covariance at `t_m` *plus* the mapped process noise of `[t_m, t_now]`, so the
//! update is conservative by the growth of `P` over the delay (3 s at the head's tuning: velocity
//! random walk `0.003^2 * 3` = 2.7e-5 (m/s)^2, position `0.005^2 * 3` = 7.5e-5 m^2, against a fix's
//! R of ~1 m^2; over 0.3 s of DVL delay 2.7e-6 against a DVL's R of ~1e-4 to 2.5e-3); the
//! cross-covariance is off by the same term. (b) The mapping is first order in the bias errors
//! and takes the rotation linear in time between the interval's ends and the specific force
//! constant for the gyro-drift terms; against the forward transition over 300 short intervals
//! (3 s, 0.3 rad turn, sigma-point-sized errors; `strapdown` tests) it is off by 1.2e-5 rad,
//! 0.4 mm/s, 0.6 mm. (c) Interpolation between grid points: position is off by `a h^2 / 8` for
//! acceleration `a` and spacing `h` = 0.1 s (0.6 mm at 0.5 m/s^2). (d) The on-time filter meets
//! the attitude nonlinearity (`Exp(phi)` acting on gravity's specific force) in each short
//! predict, re-linearized about an updated state; the late one in one mapping: second order in
//! the attitude sigma. Measured (`delay_tests`, a fix 3 s late vs on time, moving and turning):
//! 0.7 mm after an alignment (3 mrad tilt sigma), 3.5 cm with the unaligned default 20 mrad.
//! What is *not* neglected: the tilt error x specific force over the delay (4 cm of position for
//! 1 mrad over 3 s) and the attitude drift from the gyro-bias error (3 cm/s for 0.5 mrad/s over
//! 3 s), both in [`super::strapdown::retrodict_error`].
//!
//! **Keeping the past consistent.** Every injection of an error mean `dx` at `t_now` (after a
//! measurement update, and after a UKF predict or coast step too) is applied to every entry,
//! mapped back to the entry's time by the same map (`NavFilter::correct_history`: that of
//! `retrodict_error`, with the bias part of the attitude to first order). Two reasons: a later
//! delayed measurement is compared with a past the filter has already corrected (the same
//! information fused twice moves the state by the second fusion's share only, not twice), and
//! the increments above are *differences* of nominal states, so a change of the current nominal
//! that did not reach the past would be counted as specific force (measured: leaving the
//! predicts' means out of the history made the 3 s late fix of `delay_tests` end 7.5 mm instead
//! of 0.7 mm from the on-time one). The corrections are deferred and summed (issue 38:
//! `NavFilter::inject`): those of one instant add up, a pending one is carried to the next
//! predict's time through the same error transition, and it is applied to the entries before a
//! new one is recorded; a delayed fusion reads its two bracketing entries through it
//! ([`History::epoch_with`]). One pass over the entries per grid point instead of one per
//! injection.
//!
//! **Why this and not the alternatives** (RAM on the MCU: firmware <= 32 KiB including stack,
//! 29.4 KiB used before this module):
//! - a delayed-horizon filter with an output predictor needs the IMU samples of the whole delay:
//!   3 s x 200 Hz x 28 B = 17 KB;
//! - state (and covariance) history with re-propagation re-runs the UKF predicts of the delay,
//!   30 (at 10 Hz) to 60 predicts per fix at ~158k instructions each (docs/PERFORMANCE.md,
//!   `nav.propagate_with_ukf_predict`) = 4.7-9.5 M instructions in one call, tens of ms on the
//!   M4F, and the 15 x 15 covariance per stored step (900 B each) on top.
//! - this one: 41 x 48 B = 1.97 KB (`NavFilter15` 5920 -> 7944 B), no stored covariance.
//!   Cost, x86-64 instruction counts of the release build under callgrind
//!   (`delay_tests::delayed_update_cost`, 200 updates each): a delayed update costs 14.4k more
//!   than a current one (position fix 53.3k -> 67.7k, DVL 60.5k -> 74.9k: the mapping of the 31
//!   sigma points, 430 each, and the interpolation, 1.1k); every injection (accepted update or
//!   UKF predict) corrects the full history for 20.8k (~510 per entry), which the current
//!   updates above include. At the head's rates (~10 predicts + ~15 accepted updates per
//!   second) that is ~0.5M instructions/s; the target's own counts (`cargo xtask bench-target`)
//!   were not measured for this change.
//!
//! **Time rules** (`NavFilter::update_position`, `update_dvl`, `update_body_velocity`):
//! stamped more than `NavConfig::max_future_us` after the filter time: `NavError::FromFuture`;
//! within [`CURRENT_WITHIN_US`] before the filter time, or in the future within the bound: fused
//! as current; older than the oldest entry: `NavError::TooOld`; else delayed as above. Refused
//! measurements leave the state untouched and are counted (`NavFilter::delay_rejects`).
//!
//! **Discontinuities.** The history only spans time the nominal was propagated through: it is
//! cleared (and restarted with the current state) by `new` and `reinit` (an entry at the initial
//! time), a first IMU sample more than `max_imu_dt_s` after the initial time, an IMU gap refused
//! as `BadTime` (the nominal did not move across it) and a heading reset (the nominal frame
//! turned). Coasting without the IMU records entries too; an interval that reaches back
//! across a coast maps the error with the coast's own model (constant velocity: no
//! specific-force or bias coupling), exactly as the coast's UKF predict did.

use nalgebra::{Matrix3, SVector, UnitQuaternion, Vector3};

use super::state::NominalState;
use super::strapdown::{Increments, retrodict_error};

/// Grid spacing of the history, µs. Linear interpolation over 150 ms is off by `a dt^2 / 8`
/// in position (0.1 mm at 0.05 m/s^2) and the attitude's normalized lerp by far less than the
/// gyro noise at an AUV's turn rates; a finer grid costs RAM (the M4F's boot stack holds two
/// copies of the filter: 48 B per entry twice).
pub const HISTORY_SPACING_US: u64 = 150_000;
/// Entries in the history: 4.05 s of horizon at 150 ms.
pub const HISTORY_LEN: usize = 28;
/// A measurement stamped at most this much before the filter time is fused as current, µs.
pub const CURRENT_WITHIN_US: u64 = 1_000;

/// One past nominal state (48 bytes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Snapshot {
    pub t_us: u64,
    pub att_nb: UnitQuaternion<f32>,
    pub vel_ned_mps: Vector3<f32>,
    pub pos_ned_m: Vector3<f32>,
}

impl Snapshot {
    pub fn of(t_us: u64, nom: &NominalState) -> Self {
        Self { t_us, att_nb: nom.att_nb, vel_ned_mps: nom.vel_ned_mps, pos_ned_m: nom.pos_ned_m }
    }

    /// All components finite (by their sum: NaN and infinities propagate; a sum that overflows
    /// from finite parts of ~1e38 counts as not finite, which only empties the history).
    fn is_finite(&self) -> bool {
        let q = &self.att_nb.coords;
        let (v, p) = (&self.vel_ned_mps, &self.pos_ned_m);
        (q.x + q.y + q.z + q.w + v.x + v.y + v.z + p.x + p.y + p.z).is_finite()
    }

    /// Linear interpolation at `t_us` between `self` (earlier) and `b` (later); attitude by
    /// normalized lerp on the same hemisphere.
    fn lerp(&self, b: &Snapshot, t_us: u64) -> Snapshot {
        let span = b.t_us.saturating_sub(self.t_us);
        let s = if span == 0 { 1.0 } else { (t_us.saturating_sub(self.t_us)) as f32 / span as f32 };
        let qa = self.att_nb.into_inner();
        let mut qb = b.att_nb.into_inner();
        if qa.dot(&qb) < 0.0 {
            qb = -qb;
        }
        let q = UnitQuaternion::new_normalize(qa * (1.0 - s) + qb * s);
        Snapshot {
            t_us,
            att_nb: q,
            vel_ned_mps: self.vel_ned_mps + (b.vel_ned_mps - self.vel_ned_mps) * s,
            pos_ned_m: self.pos_ned_m + (b.pos_ned_m - self.pos_ned_m) * s,
        }
    }
}

/// The nominal at a past time and the interval back to it, for [`super::strapdown::retrodict_error`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PastEpoch {
    /// Nominal at the measurement time (biases: the current ones).
    pub nom: NominalState,
    /// Increments of `[t_m, t_now]`.
    pub inc: Increments,
    /// `exp(T / tau)`: the Markov drift error back in time.
    pub markov_growth: f32,
}

/// The fixed-size ring of past nominal states (see the module doc).
#[derive(Debug, Clone)]
pub struct History {
    buf: [Snapshot; HISTORY_LEN],
    /// Index of the oldest entry.
    start: usize,
    len: usize,
    /// Next grid time to record at.
    next_grid_us: u64,
    /// End of the latest coast (an interval from before it uses the coast's error model).
    coast_end_us: Option<u64>,
}

impl History {
    pub fn new() -> Self {
        let z = Snapshot { t_us: 0, att_nb: UnitQuaternion::identity(), vel_ned_mps: Vector3::zeros(), pos_ned_m: Vector3::zeros() };
        Self { buf: [z; HISTORY_LEN], start: 0, len: 0, next_grid_us: 0, coast_end_us: None }
    }

    /// Forget everything and start again from `nom` at `t_us`.
    pub fn restart(&mut self, t_us: u64, nom: &NominalState) {
        self.start = 0;
        self.len = 0;
        self.coast_end_us = None;
        self.next_grid_us = 0;
        self.record(t_us, nom);
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The `i`-th entry, oldest first.
    pub fn get(&self, i: usize) -> Option<&Snapshot> {
        if i >= self.len {
            return None;
        }
        self.buf.get((self.start + i) % HISTORY_LEN)
    }

    pub fn oldest_t_us(&self) -> Option<u64> {
        self.get(0).map(|s| s.t_us)
    }

    /// Record `nom` at `t_us` if it reached the next grid point (the oldest entry is dropped when
    /// full). Times must not decrease; a non-finite state is not recorded.
    pub fn record(&mut self, t_us: u64, nom: &NominalState) {
        if t_us < self.next_grid_us || !nom.is_finite() {
            return;
        }
        let s = Snapshot::of(t_us, nom);
        if self.len < HISTORY_LEN {
            if let Some(e) = self.buf.get_mut((self.start + self.len) % HISTORY_LEN) {
                *e = s;
            }
            self.len += 1;
        } else {
            if let Some(e) = self.buf.get_mut(self.start) {
                *e = s;
            }
            self.start = (self.start + 1) % HISTORY_LEN;
        }
        self.next_grid_us = (t_us / HISTORY_SPACING_US).saturating_add(1).saturating_mul(HISTORY_SPACING_US);
    }

    /// Whether [`Self::record`] at `t_us` would add an entry.
    pub fn due(&self, t_us: u64) -> bool {
        t_us >= self.next_grid_us
    }

    /// The filter coasted up to `t_us`.
    pub fn mark_coast(&mut self, t_us: u64) {
        self.coast_end_us = Some(t_us);
    }

    /// Nominal at `t_m` (between the oldest entry and `now`, the current nominal at `t_now`),
    /// and the interval `[t_m, t_now]`; `None` if `t_m` is older than the history or after `t_now`.
    pub fn epoch(&self, t_m_us: u64, t_now_us: u64, now: &NominalState, gravity_mps2: f32, markov_tau_s: f32) -> Option<PastEpoch> {
        self.epoch_with(t_m_us, t_now_us, now, gravity_mps2, markov_tau_s, |e| *e)
    }

    /// [`Self::epoch`] with the stored entries read through `fix` (a correction not yet applied
    /// to the history: only the two entries around `t_m` need it; the current nominal `now`
    /// has it already).
    pub fn epoch_with(
        &self,
        t_m_us: u64,
        t_now_us: u64,
        now: &NominalState,
        gravity_mps2: f32,
        markov_tau_s: f32,
        fix: impl Fn(&Snapshot) -> Snapshot,
    ) -> Option<PastEpoch> {
        if t_m_us > t_now_us {
            return None;
        }
        let cur = Snapshot::of(t_now_us, now);
        // Bracket: the last entry at or before t_m, and its successor (or the current nominal).
        let mut before: Option<Snapshot> = None;
        let mut after = cur;
        let mut after_stored = false;
        for i in (0..self.len).rev() {
            let e = *self.get(i)?;
            if e.t_us <= t_m_us {
                before = Some(fix(&e));
                break;
            }
            after = e;
            after_stored = true;
        }
        if after_stored {
            after = fix(&after);
        }
        let past = before?.lerp(&after, t_m_us);
        if !past.is_finite() {
            return None;
        }
        let coasted = self.coast_end_us.is_some_and(|c| t_m_us < c);
        let (inc, markov_growth) = interval(&past, t_now_us, now, coasted, gravity_mps2, markov_tau_s);
        let nom = NominalState { att_nb: past.att_nb, vel_ned_mps: past.vel_ned_mps, pos_ned_m: past.pos_ned_m, ..*now };
        Some(PastEpoch { nom, inc, markov_growth })
    }

    /// End of the latest coast, if the history holds one.
    pub fn coast_end_us(&self) -> Option<u64> {
        self.coast_end_us
    }

    /// Replace every entry `e` by `f(e)`. If any result is not finite the history is emptied
    /// (a partly corrected past would be inconsistent) and `false` returned.
    pub fn correct(&mut self, mut f: impl FnMut(&Snapshot) -> Snapshot) -> bool {
        for i in 0..self.len {
            if let Some(e) = self.buf.get_mut((self.start + i) % HISTORY_LEN) {
                let n = f(e);
                if !n.is_finite() {
                    self.start = 0;
                    self.len = 0;
                    return false;
                }
                *e = n;
            }
        }
        true
    }
}

/// Increments of the interval from `past` to the current nominal `now` at `t_now_us` (see the
/// module doc), and `exp(T / tau)`. `coasted`: the interval reaches across a coast, whose error
/// model has no specific-force or bias coupling (only `T`).
pub fn interval(
    past: &Snapshot,
    t_now_us: u64,
    now: &NominalState,
    coasted: bool,
    gravity_mps2: f32,
    markov_tau_s: f32,
) -> (Increments, f32) {
    let t_s = t_now_us.saturating_sub(past.t_us) as f32 * 1e-6;
    let mut inc = Increments::zero();
    inc.dt_s = t_s;
    if !coasted {
        let g = Vector3::new(0.0, 0.0, gravity_mps2);
        inc.dv_f = now.vel_ned_mps - past.vel_ned_mps - g * t_s;
        inc.dp_f = now.pos_ned_m - past.pos_ned_m - past.vel_ned_mps * t_s - g * (0.5 * t_s * t_s);
        let r_m: Matrix3<f32> = past.att_nb.to_rotation_matrix().into_inner();
        let r_now: Matrix3<f32> = now.att_nb.to_rotation_matrix().into_inner();
        inc.c = (r_m + r_now) * (0.5 * t_s);
        inc.cc = (r_m * (1.0 / 3.0) + r_now * (1.0 / 6.0)) * (t_s * t_s);
    }
    (inc, libm::expf(t_s / markov_tau_s))
}

impl PastEpoch {
    /// A current error sigma point mapped back to the measurement time.
    pub fn map<const N: usize>(&self, dx: &SVector<f32, N>) -> SVector<f32, N> {
        retrodict_error(dx, &self.inc, self.markov_growth)
    }
}

impl Default for History {
    fn default() -> Self {
        Self::new()
    }
}
