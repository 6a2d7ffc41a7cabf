//! AUKF-SLAM state (spec A5): the vehicle's horizontal position and the unknown water current,
//! augmented with the positions of the topological nodes, in the shared adaptive UKF
//! ([`subnav_core::ukf::Ukf`], f64 on the host).
//!
//! State `[p_N, p_E, c_N, c_E, n_1N, n_1E, ..., n_KN, n_KE]`, `K = MAX_NODES` fixed at compile time
//! (the shared UKF is const-generic and heap-free; 30 nodes = 64 states, 129 sigma points). A
//! free node slot holds 0 with a large, uncorrelated variance, so it does not influence the
//! others; adding a node writes its slot (the vehicle position, with the vehicle's covariance
//! row plus a small placement variance), a merge applies a "same place" update between two
//! nodes and frees one slot.
//!
//! - Predict: `p += dx_odometry + c dt` (dead-reckoned displacement from the compass heading and
//!   the water-relative speed, which misses the current), `c` a slow random walk, nodes static.
//! - Re-observation of node j (a recognised image): `z = p - n_j = 0` with the recognition
//!   covariance `R`, gated by its Mahalanobis distance (chi-square, 2 dof); the fading factor of
//!   the shared AUKF acts on the vehicle states only when the innovation is larger than predicted.
//! - Every accepted re-observation yields a [`PositionFix`](subnav_wire::Command::PositionFix)
//!   downlink for the firmware (position + covariance).

use nalgebra::{Matrix2, SMatrix, SVector, Vector2};
use subnav_core::ukf::{AdaptConfig, MeasNoise, Ukf, UkfConfig, UkfError, UpdateReport};
use subnav_wire::{Command, Downlink};

/// Node capacity of the filter state: 30 makes 64 states, the width of the shared UKF's
/// per-measurement fading mask (`u64`), so every state can be addressed by it.
pub const MAX_NODES: usize = 30;
/// State size: position (2), current (2), nodes (2 each).
pub const NX: usize = 4 + 2 * MAX_NODES;
/// Sigma points.
pub const NS: usize = 2 * NX + 1;
const _: () = assert!(NX <= 64, "the shared UKF's fading mask is a u64");
/// Variance of a free node slot (m^2).
const FREE_VAR: f64 = 1e4;
/// Chi-square 99 % for 2 degrees of freedom (9.2103, `subnav_base::chi2`).
pub use subnav_base::chi2::chi2_2_99;

/// Filter tuning.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlamTuning {
    /// Odometry noise density (m^2 per s of travel), per axis.
    pub q_pos_m2ps: f64,
    /// Current random walk (m^2/s^2 per s), per axis.
    pub q_current: f64,
    /// Initial position and current standard deviations.
    pub p0_pos_m: f64,
    pub p0_current_mps: f64,
    /// Placement standard deviation of a new node relative to the vehicle (m).
    pub node_sigma_m: f64,
    /// Whether the adaptive fading factor is on.
    pub fading: bool,
}

impl Default for SlamTuning {
    fn default() -> Self {
        SlamTuning { q_pos_m2ps: 0.02 * 0.02, q_current: 1e-6, p0_pos_m: 0.5, p0_current_mps: 0.05, node_sigma_m: 0.3, fading: true }
    }
}

pub struct SlamFilter {
    ukf: Box<Ukf<f64, NX, NS>>,
    used: [bool; MAX_NODES],
    tuning: SlamTuning,
    seq: u16,
}

fn node_idx(slot: usize) -> usize {
    4 + 2 * slot
}

impl SlamFilter {
    pub fn new(pos0: [f64; 2], tuning: SlamTuning) -> Result<Self, UkfError> {
        let mut adapt = AdaptConfig::plain();
        adapt.fading = tuning.fading;
        adapt.fading_s = 2.0;
        adapt.lambda_max = 20.0;
        let cfg = UkfConfig { alpha: 1.0, beta: 2.0, kappa: 0.0, adapt, p_floor: 1e-9, p_rel_floor: 0.0, q_floor: 0.0 };
        let mut x0 = SVector::<f64, NX>::zeros();
        x0[0] = pos0[0];
        x0[1] = pos0[1];
        let mut p0 = SMatrix::<f64, NX, NX>::identity() * FREE_VAR;
        for i in 0..2 {
            p0[(i, i)] = tuning.p0_pos_m.powi(2);
            p0[(2 + i, 2 + i)] = tuning.p0_current_mps.powi(2);
        }
        let mut q = SMatrix::<f64, NX, NX>::zeros();
        for i in 0..2 {
            q[(i, i)] = tuning.q_pos_m2ps;
            q[(2 + i, 2 + i)] = tuning.q_current;
        }
        let ukf = Box::new(Ukf::new(cfg, x0, p0, q)?);
        Ok(SlamFilter { ukf, used: [false; MAX_NODES], tuning, seq: 0 })
    }

    pub fn position(&self) -> [f64; 2] {
        let x = self.ukf.x();
        [x[0], x[1]]
    }

    pub fn current(&self) -> [f64; 2] {
        let x = self.ukf.x();
        [x[2], x[3]]
    }

    pub fn position_cov(&self) -> Matrix2<f64> {
        self.ukf.p().fixed_view::<2, 2>(0, 0).into_owned()
    }

    pub fn node_position(&self, slot: usize) -> Option<[f64; 2]> {
        (slot < MAX_NODES && self.used[slot]).then(|| {
            let x = self.ukf.x();
            [x[node_idx(slot)], x[node_idx(slot) + 1]]
        })
    }

    pub fn node_cov(&self, slot: usize) -> Matrix2<f64> {
        let k = node_idx(slot.min(MAX_NODES - 1));
        self.ukf.p().fixed_view::<2, 2>(k, k).into_owned()
    }

    pub fn free_slots(&self) -> usize {
        self.used.iter().filter(|u| !**u).count()
    }

    pub fn health(&self) -> subnav_core::ukf::UkfHealth<f64> {
        *self.ukf.health()
    }

    /// Time update over `dt_s` with the dead-reckoned displacement `dx_m` (N, E).
    pub fn predict(&mut self, dx_m: [f64; 2], dt_s: f64) -> Result<(), UkfError> {
        self.ukf.predict(dt_s, |x| {
            let mut y = *x;
            y[0] += dx_m[0] + x[2] * dt_s;
            y[1] += dx_m[1] + x[3] * dt_s;
            y
        })
    }

    /// Augment the state with a node at the vehicle's position; `None` when the map is full.
    pub fn add_node(&mut self) -> Option<usize> {
        let slot = self.used.iter().position(|u| !*u)?;
        let k = node_idx(slot);
        let mut x = *self.ukf.x();
        let mut p = *self.ukf.p();
        x[k] = x[0];
        x[k + 1] = x[1];
        // Node = vehicle position (+ placement noise): copy the vehicle's rows and columns.
        for i in 0..NX {
            for a in 0..2 {
                let v = if i == k || i == k + 1 { 0.0 } else { p[(a, i)] };
                p[(k + a, i)] = v;
                p[(i, k + a)] = v;
            }
        }
        for a in 0..2 {
            for b in 0..2 {
                p[(k + a, k + b)] = p[(a, b)] + if a == b { self.tuning.node_sigma_m.powi(2) } else { 0.0 };
            }
        }
        self.ukf.set_x(x).ok()?;
        self.ukf.set_p(p).ok()?;
        self.used[slot] = true;
        Some(slot)
    }

    /// Innovation covariance of `p - n_slot` plus `r` and the squared Mahalanobis distance of
    /// the zero measurement (the association gate).
    pub fn mahalanobis2(&self, slot: usize, r_m2: f64) -> Option<f64> {
        let pos = self.node_position(slot)?;
        let k = node_idx(slot);
        let p = self.ukf.p();
        let mut s = Matrix2::<f64>::identity() * r_m2;
        for a in 0..2 {
            for b in 0..2 {
                s[(a, b)] += p[(a, b)] + p[(k + a, k + b)] - p[(a, k + b)] - p[(k + a, b)];
            }
        }
        let x = self.ukf.x();
        let e = Vector2::new(x[0] - pos[0], x[1] - pos[1]);
        s.try_inverse().map(|si| (e.transpose() * si * e)[(0, 0)])
    }

    /// Re-observation of node `slot`: the vehicle is at the node, with covariance `r_m2` I.
    pub fn observe(&mut self, slot: usize, r_m2: f64) -> Result<UpdateReport<f64>, UkfError> {
        if slot >= MAX_NODES || !self.used[slot] {
            return Err(UkfError::BadConfig);
        }
        let k = node_idx(slot);
        let mut noise = MeasNoise::<f64, 2>::new(Matrix2::identity() * r_m2);
        noise.adapt = false;
        noise.fading_mask = 0b1111; // vehicle position and current
        self.ukf.update::<2, subnav_core::ukf::Euclidean, _>(&Vector2::zeros(), &mut noise, |x| Vector2::new(x[0] - x[k], x[1] - x[k + 1]))
    }

    /// Merge node `drop` into node `keep` (a "same place" update), then free `drop`'s slot.
    pub fn merge(&mut self, keep: usize, drop: usize, r_m2: f64) -> Result<(), UkfError> {
        if keep == drop || keep >= MAX_NODES || drop >= MAX_NODES || !self.used[keep] || !self.used[drop] {
            return Err(UkfError::BadConfig);
        }
        let (a, b) = (node_idx(keep), node_idx(drop));
        let mut noise = MeasNoise::<f64, 2>::new(Matrix2::identity() * r_m2);
        noise.adapt = false;
        // NX <= 64 (see MAX_NODES), so every node state has a bit in the mask.
        noise.fading_mask = 1u64 << a | 1u64 << (a + 1) | 1u64 << b | 1u64 << (b + 1);
        self.ukf.update::<2, subnav_core::ukf::Euclidean, _>(&Vector2::zeros(), &mut noise, |x| {
            Vector2::new(x[a] - x[b], x[a + 1] - x[b + 1])
        })?;
        self.free(drop)
    }

    fn free(&mut self, slot: usize) -> Result<(), UkfError> {
        let k = node_idx(slot);
        let mut x = *self.ukf.x();
        let mut p = *self.ukf.p();
        for a in 0..2 {
            x[k + a] = 0.0;
            for i in 0..NX {
                p[(k + a, i)] = 0.0;
                p[(i, k + a)] = 0.0;
            }
            p[(k + a, k + a)] = FREE_VAR;
        }
        self.ukf.set_x(x)?;
        self.ukf.set_p(p)?;
        self.used[slot] = false;
        Ok(())
    }

    /// The current position and covariance as a downlink `PositionFix` (depth from the depth
    /// sensor with its variance), with the next sequence number.
    pub fn position_fix(&mut self, t_us: u64, depth_m: f64, depth_var_m2: f64) -> Downlink {
        let pos = self.position();
        let p = self.position_cov();
        self.seq = self.seq.wrapping_add(1);
        Downlink {
            seq: self.seq,
            command: Command::PositionFix {
                t_us,
                pos_ned_m: [pos[0] as f32, pos[1] as f32, depth_m as f32],
                cov_ned_m2: [p[(0, 0)] as f32, p[(0, 1)] as f32, 0.0, p[(1, 1)] as f32, 0.0, depth_var_m2 as f32],
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_augmentation_reobservation_and_merge() {
        let std::thread::Result::Ok(()) = std::thread::Builder::new()
            .stack_size(32 << 20)
            .spawn(|| {
                let mut f = SlamFilter::new([0.0, 0.0], SlamTuning { fading: false, ..SlamTuning::default() }).unwrap();
                let a = f.add_node().unwrap();
                // Drive away and back with a biased odometry: the estimate drifts by 2 m north.
                for _ in 0..100 {
                    f.predict([0.02, 0.0], 1.0).unwrap();
                }
                let before = f.position();
                assert!((before[0] - 2.0).abs() < 1e-9);
                let var_before = f.position_cov()[(0, 0)];
                // Truly back at node a: the re-observation pulls the estimate toward it.
                let d2 = f.mahalanobis2(a, 0.25).unwrap();
                assert!(d2 < chi2_2_99(), "gate {d2}");
                let rep = f.observe(a, 0.25).unwrap();
                assert!(rep.accepted);
                assert!(f.position()[0] < 1.0, "{:?}", f.position());
                assert!(f.position_cov()[(0, 0)] < var_before);
                // A far node is gated out.
                let b = f.add_node().unwrap();
                for _ in 0..10 {
                    f.predict([3.0, 0.0], 1.0).unwrap();
                }
                assert!(f.mahalanobis2(b, 0.25).unwrap() > chi2_2_99());
                // Merge frees a slot; a fix carries the covariance.
                let free = f.free_slots();
                f.merge(a, b, 0.25).unwrap();
                assert_eq!(f.free_slots(), free + 1);
                assert!(f.node_position(b).is_none());
                let fix = f.position_fix(5, 10.0, 0.01);
                let Command::PositionFix { cov_ned_m2, .. } = fix.command else { panic!("not a fix") };
                assert!(cov_ned_m2[0] > 0.0 && cov_ned_m2[3] > 0.0);
                assert!(f.observe(b, 0.25).is_err(), "a freed slot cannot be observed");
            })
            .unwrap()
            .join()
        else {
            panic!("filter thread panicked")
        };
    }
}
