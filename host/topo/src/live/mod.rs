//! Online topological mapper fed by the firmware's own navigation solution (the closed loop with
//! the sensor head): places nodes from the firmware's estimate, recognises them from
//! polarization images in a learned (LMNN) metric behind a position gate, and turns each loop
//! closure into a position fix that the firmware can fuse as an *independent* measurement.
//!
//! Why not [`crate::slam`]: that filter keeps its own dead reckoning and a fixed 30-node UKF state
//! on a 64 MiB stack; here the firmware is the navigation filter, and the map must scale to
//! thousands of nodes with bounded memory and a per-frame cost far below the camera period.
//!
//! Design:
//! - **Nodes** are placed every `node_spacing_m` of travel of the nav solution (its path length,
//!   from the nav samples) without a recognition event, at a frame with features and aided nav,
//!   from the firmware's estimate at the frame time: position `x0`, covariance `P0` (2x2). Its
//!   samples are the features of `samples_per_node` frames centred on creation (a short buffer of
//!   the previous frames, then the next ones). Nodes are never moved afterwards.
//! - **Training**: after `train_after_nodes` nodes, LMNN on the node samples (labels = node ids)
//!   and the appearance threshold of [`TopoMap::train`] (`threshold_factor` x the 90th percentile
//!   of the nearest same-node distances). The map `y = L diag(1/scale) (f - mean)` is folded into
//!   one affine map; every node sample's mapped vector is stored in one contiguous array (at
//!   training and at each later node sample), so recognition is a flat scan. No retraining.
//! - **Recognition** of a frame at t1 (nav `x1`, `P1`): the position gate first: for each node
//!   older than `min_revisit_s`, `D = P1 - P0` projected onto PSD with eigenvalues floored at
//!   `min_drift_m2`, `m = x1 - x0`, gate statistic `m^T (D + V)^-1 m < gate_chi2` with
//!   `V = recognition_sigma_m^2 I`. Then appearance: the nearest gated node in the learned metric
//!   below the threshold is recognised. The first frame that matches is seen a metre or two
//!   before the place (the footprints overlap): the recognition is held while the next frames
//!   match the same node better (at most `best_match_hold_s`) and the best one is sent, its place
//!   `x0` being where the node's best-matching sample was taken (the firmware's estimate then;
//!   a node's samples span two metres of travel), not the node's centre frame. The fix is
//!   stamped with that frame's time and fused late by the firmware. A node whose gate is wider than `max_gate_sigma_m`
//!   (1 sigma, largest axis of `D + V`) fails it: the scene has look-alike places a cell or two
//!   apart, and a gate that wide would let them through. The nearest node overall (of those old enough) below the
//!   threshold is counted as an appearance-only match, and as a gate refusal when its node failed
//!   the gate.
//! - **The fix** does not count the firmware's information twice: the node's error `e0` (cov
//!   `P0`) is still part of the firmware's error at t1, `e1 = e0 + d`, drift `d ~ N(0, D)`. The
//!   recognition `x(t1) = x(t0) + v`, `v ~ N(0, V)` makes `m` an observation of `d` with noise
//!   `v`: posterior `mu = x1 - D (D+V)^-1 m`, `Sigma = P1 - D (D+V)^-1 D`. The firmware fuses a fix
//!   as an independent measurement with its prior `(x1, P1)`, so we send the equivalent one:
//!   `R = (Sigma^-1 - P1^-1)^-1`, `z = x1 + R Sigma^-1 (mu - x1)` (computed in a form without
//!   cancellation, see [`fix`]). `P0 -> 0` gives `R -> V`; `D -> 0` gives `R -> infinity`: no fix is
//!   sent when every eigenvalue of `R` exceeds `max_fix_var_m2` or the fix would shrink the
//!   variance by less than `min_info_gain` in every direction. A direction of `R` above
//!   `max_fix_eig_m2` is capped there (with `z` moved so that the information vector is kept), so
//!   the firmware's f32 Cholesky sees a bounded condition number. At most one fix per node per
//!   `refractory_s`, and one of any node per `min_fix_interval_s`.
//! - **Bad input** is counted and survived: frames out of order (counter or time going back) and
//!   duplicated counters are ignored (a counter that goes back for `restart_frames` frames in a row
//!   with time going forward is a camera restart), gaps in the counter counted, frames without features
//!   (blackout) counted (node placement by travel resumes when images return), non-finite nav or
//!   features refused; nodes capped at `max_nodes` (`map_full_events`), nav window bounded in time
//!   and count, closures kept up to `max_closures` (oldest dropped), no large stacks.
//!
//! Limits of the model: `e1 = e0 + d` with `d` independent of `e0` holds while the firmware only
//! dead-reckons or fuses our fixes of nodes placed before; an absolute fix (or one of our fixes
//! from an older node) fused between a node's placement and its recognition decorrelates the
//! errors, and `P1 - P0` then underestimates (or is not) the drift covariance (the floor keeps it
//! PD). The fix uses the firmware's prior at t1 as telemetered: a fix still in flight when the
//! next one is computed is not in that prior (`min_fix_interval_s` must exceed that round trip).
//! Nav time going back for `nav_reset_samples` samples in a row restarts the nav window and the
//! frame order (a corrupted future stamp, or a sensor-head reboot); after a reboot the map still
//! lives in the old solution's frame and time base (old nodes are not candidates until the new
//! time passes theirs), so start a new mapper then.

pub mod fix;

use std::collections::VecDeque;

use nalgebra::{Matrix2, Vector2};
use serde::Serialize;
use subnav_wire::Command;

use crate::lmnn::{LmnnConfig, LmnnModel};
use crate::map::{Node, TopoMap};
use crate::polar_image::N_FEATURES;
use fix::{FixMathError, eig_sym, equivalent_fix, floor_eig, inv_pd, sym, symmetrise, tri};

/// One navigation solution of the firmware, from its telemetry (in time order).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavSample {
    pub t_us: u64,
    pub pos_ned_m: [f64; 3],
    /// Horizontal covariance NN, NE, EE (m^2).
    pub cov_ne_m2: [f64; 3],
    /// The firmware reports aided navigation (only aided samples place or recognise nodes).
    pub aided: bool,
    /// The firmware's horizontal velocity 1-sigma (largest of north and east, m/s; 0 if unknown).
    pub vel_sigma_mps: f64,
}

/// One camera frame: its frame counter (from the camera), its sensor-head trigger time, features.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraFrame {
    pub frame: u32,
    pub t_us: u64,
    pub features: Option<[f64; N_FEATURES]>,
}

/// What the mapper did with a frame, for scoring outside it ([`crate::live_eval`]: a
/// simulation pairs each event with the truth of the frame it came from).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub enum MapEvent {
    /// Node `node` was placed at the frame of `t_us`.
    NodePlaced { node: usize, t_us: u64 },
    /// The frame of `t_us` was scanned against the map (a recognition attempt).
    Attempt { t_us: u64 },
    /// The nearest node overall (of those old enough) matched in appearance; `gate_refused`: its
    /// position gate refused it.
    AppearanceMatch { t_us: u64, node: usize, gate_refused: bool },
    /// The frame of `t_us` recognised node `node` (the nearest gated node below the threshold).
    Recognised { t_us: u64, node: usize },
}

/// Tuning.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LiveConfig {
    /// Travel (m) without a recognition event after which a node is placed.
    pub node_spacing_m: f64,
    /// Feature samples per node (centred on creation; more than the LMNN k = 3 to be trained on).
    pub samples_per_node: usize,
    /// Nodes before the metric is learned.
    pub train_after_nodes: usize,
    /// Appearance threshold = this x the 90th percentile of nearest same-node distances.
    pub threshold_factor: f64,
    /// How far from a node (1 sigma per axis, m) a recognised image can be taken.
    pub recognition_sigma_m: f64,
    /// Position gate (chi-square, 2 dof).
    pub gate_chi2: f64,
    /// No recognition of a node whose gate is wider than this (1 sigma of the largest axis of
    /// `D + V`, m): the scene repeats itself (look-alike cells a few metres apart), so a gate
    /// wider than a cell or two lets a look-alike through. When the firmware's own uncertainty has
    /// grown that large (e.g. the DVL lost for minutes) the map waits instead of guessing.
    pub max_gate_sigma_m: f64,
    /// At most one fix per node per this (s).
    pub refractory_s: f64,
    /// A recognition is held while the next frames match the same node better (the vehicle
    /// still approaching its place) and sent for the best of them, at most this long after the
    /// first (s; 0 sends the first at once).
    pub best_match_hold_s: f64,
    /// At most one fix (of any node) per this (s): longer than the round trip of a fix to the
    /// firmware and back into its telemetered covariance, so a fix still in flight is not
    /// counted again by the next one.
    pub min_fix_interval_s: f64,
    /// A frame counter that went back is a camera restart once this many frames in a row (times
    /// and counters increasing among them) agree; the first ones are ignored as out of order.
    pub restart_frames: usize,
    /// Nav time going back is a new time base once this many samples in a row (increasing among
    /// them) agree; the first ones are ignored as out of order.
    pub nav_reset_samples: usize,
    /// Hard bound on the number of nodes.
    pub max_nodes: usize,
    /// Floor on the eigenvalues of the drift covariance `D = P1 - P0` (m^2).
    pub min_drift_m2: f64,
    /// Nodes younger than this (s) are not candidates (a revisit, not the place just left).
    pub min_revisit_s: f64,
    /// Nav window: time span (s) and a hard bound on the number of samples.
    pub nav_window_s: f64,
    pub max_nav_samples: usize,
    /// Travel is the nav path length through points at least this far apart (m).
    pub odo_step_m: f64,
    /// Nav samples bracketing a frame farther apart than this (s): no position for the frame.
    pub max_nav_gap_s: f64,
    /// Buffered / collected frame features older than this (s) relative to the frame are not node
    /// samples (frames were missing).
    pub max_sample_age_s: f64,
    /// No fix when every eigenvalue of `R` exceeds this (m^2).
    pub max_fix_var_m2: f64,
    /// No fix when it would shrink the variance by less than this fraction in every direction.
    pub min_info_gain: f64,
    /// Eigenvalues of `R` are capped here (m^2), keeping the information vector.
    pub max_fix_eig_m2: f64,
    /// No fix while the firmware's horizontal velocity 1-sigma exceeds this (m/s): its velocity
    /// is then held by nothing but position fixes (the DVL lost), so a fix from a false
    /// recognition (a look-alike cell a few metres off, with the small `R` of a true one) also
    /// turns the velocity, which no later fix corrects in time: measured in the one-hour
    /// every-fault dive, 8 map fixes in the first minute of a DVL lock loss sent the estimate
    /// kilometres away while the USBL alone kept it within 3 sigma (docs/RELIABILITY.md).
    /// Recognition goes on (counted); only the fix waits for an aided velocity.
    pub max_fix_vel_sigma_mps: f64,
    /// Accepted closures kept for [`LiveMapper::closures`] (the oldest half is dropped when full).
    pub max_closures: usize,
    /// LMNN tuning.
    #[serde(skip)]
    pub lmnn: LmnnConfig,
}

impl Default for LiveConfig {
    fn default() -> Self {
        LiveConfig {
            node_spacing_m: 6.0,
            samples_per_node: 5,
            train_after_nodes: 40,
            threshold_factor: 1.5,
            recognition_sigma_m: 1.5,
            gate_chi2: subnav_base::chi2::chi2_2_99(),
            max_gate_sigma_m: 3.0,
            refractory_s: 8.0,
            best_match_hold_s: 4.0,
            min_fix_interval_s: 2.0,
            restart_frames: 3,
            nav_reset_samples: 10,
            max_nodes: 8192,
            min_drift_m2: 0.01,
            min_revisit_s: 30.0,
            nav_window_s: 30.0,
            max_nav_samples: 4096,
            odo_step_m: 0.5,
            max_nav_gap_s: 2.0,
            max_sample_age_s: 5.0,
            max_fix_var_m2: 100.0,
            max_fix_vel_sigma_mps: 0.05,
            min_info_gain: 0.01,
            max_fix_eig_m2: 1e6,
            max_closures: 4096,
            lmnn: LmnnConfig::default(),
        }
    }
}

/// A fix for the firmware: the equivalent independent measurement of its position at `t_us`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MapFix {
    pub t_us: u64,
    pub node: usize,
    /// Measurement (N, E) and its covariance (NN, NE, EE), to be fused with the firmware's prior
    /// at `t_us` as an independent measurement.
    pub pos_ne_m: [f64; 2],
    pub cov_ne_m2: [f64; 3],
    /// The frame it came from, the prior it was computed against (the firmware's solution at
    /// `t_us`), the posterior that fusing it gives, the gate statistic and appearance distance.
    pub frame: u32,
    pub prior_ne_m: [f64; 2],
    pub prior_cov_ne_m2: [f64; 3],
    /// The firmware's depth at `t_us` (for [`MapFix::to_command`]).
    pub prior_depth_m: f64,
    pub posterior_ne_m: [f64; 2],
    pub posterior_cov_ne_m2: [f64; 3],
    pub gate_d2: f64,
    pub appearance_dist: f64,
    /// The place recognised: where the node's best-matching sample was taken (the firmware's
    /// estimate then), the `x0` of the fix.
    pub place_ne_m: [f64; 2],
}

impl MapFix {
    /// The downlink command: horizontal fix, with the depth `depth_m` and its variance (give the
    /// firmware's own depth at `t_us`, [`MapFix::prior_depth_m`], with a large variance, e.g.
    /// 1e4 m^2, so the fix does not inform depth).
    pub fn to_command(&self, depth_m: f64, depth_var_m2: f64) -> Command {
        let c = self.cov_ne_m2;
        Command::PositionFix {
            t_us: self.t_us,
            pos_ned_m: [self.pos_ne_m[0] as f32, self.pos_ne_m[1] as f32, depth_m as f32],
            cov_ned_m2: [c[0] as f32, c[1] as f32, 0.0, c[2] as f32, 0.0, depth_var_m2 as f32],
        }
    }
}

/// Why a frame was not used (benign: counted, nothing to fix).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum IgnoreReason {
    /// Frame counter or time went back.
    OutOfOrder,
    /// Same frame counter as the previous frame.
    Duplicate,
    /// No image (camera blackout).
    NoFeatures,
    /// The frame is older than the nav window (or than the first nav sample).
    NavExpired,
    /// The nav solution at the frame is not aided.
    NotAided,
    /// Recognition needs the learned metric; no node due.
    NotTrained,
    /// A node was due but the map holds `max_nodes`.
    MapFull,
}

/// Why a frame or a fix was refused (input or numerics).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub enum Refusal {
    NonFiniteFeatures,
    /// The nav samples bracketing the frame are `gap_s` apart.
    NavGap {
        gap_s: f64,
    },
    /// Appearance matched `node` (nearest overall) but its gate statistic `d2` failed.
    GateRefused {
        node: usize,
        d2: f64,
    },
    /// Recognised, but a fix of this node was sent less than `refractory_s` ago.
    Refractory {
        node: usize,
    },
    /// Recognised, but a fix (of any node) was sent less than `min_fix_interval_s` ago.
    FixInterval {
        node: usize,
    },
    /// Recognised, but the fix carries no useful information (R too large, or gain negligible).
    NoInformation {
        node: usize,
        min_var_m2: f64,
        max_gain: f64,
    },
    /// Recognised, but the covariances are not PD / the result degenerate.
    Numeric {
        node: usize,
    },
    /// Recognised, but the firmware's velocity is unaided (`max_fix_vel_sigma_mps`).
    VelocityUnaided {
        node: usize,
        vel_sigma_mps: f64,
    },
}

/// What a frame did.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub enum FrameOutcome {
    /// The nav window does not reach the frame time yet: call again with the same frame after more
    /// nav samples (nothing was changed or counted).
    NeedNav,
    /// A loop closure: send this fix.
    Fix(MapFix),
    /// A node was placed at this frame.
    Placed {
        node: usize,
    },
    /// The frame's features became a sample of a node being built.
    Sampled {
        node: usize,
    },
    /// Recognised; held while the next frames may match the node better (see
    /// `LiveConfig::best_match_hold_s`).
    Held {
        node: usize,
    },
    /// Trained, no recognition, no node due.
    NoMatch,
    Refused {
        reason: Refusal,
    },
    Ignored {
        reason: IgnoreReason,
    },
}

/// Result of a nav sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum NavOutcome {
    Accepted,
    /// Time not after the previous sample's: ignored.
    OutOfOrder,
    /// Non-finite, or a covariance that is not PSD: refused.
    Refused,
    /// Accepted as the start of a new time base (see `LiveConfig::nav_reset_samples`).
    TimeBaseReset,
}

/// A place.
#[derive(Debug, Clone, Serialize)]
pub struct LiveNode {
    pub id: usize,
    /// The firmware's estimate at creation (N, E) and its covariance (NN, NE, EE).
    pub pos_ned_m: [f64; 2],
    pub cov_ne_m2: [f64; 3],
    pub created_t_us: u64,
    /// Recognitions of this node, and fixes sent from it.
    pub observations: u32,
    pub fixes: u32,
    pub last_fix_t_us: Option<u64>,
    #[serde(skip)]
    pub samples: Vec<[f64; N_FEATURES]>,
    /// Where each sample's frame was taken: the firmware's estimate at its time (N, E), m. A
    /// recognition is of the best-matching sample's place, not the node's centre frame.
    #[serde(skip)]
    pub sample_places_ne_m: Vec<[f64; 2]>,
}

/// An accepted loop closure.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Closure {
    pub t_us: u64,
    pub node: usize,
    /// The firmware's position at `t_us` (the prior) and the fix sent.
    pub vehicle_ne_m: [f64; 2],
    pub fix_ne_m: [f64; 2],
    pub fix_cov_ne_m2: [f64; 3],
}

/// Counters.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct LiveStats {
    /// Frames processed (every `on_frame` call except `NeedNav`).
    pub frames: u64,
    pub frames_out_of_order: u64,
    pub frames_duplicated: u64,
    /// Gaps in the frame counter (frames never seen).
    pub frames_missing: u64,
    /// The frame counter restarted (see `LiveConfig::restart_frames`).
    pub camera_restarts: u64,
    pub frames_without_features: u64,
    pub frames_nonfinite_features: u64,
    pub frames_nav_expired: u64,
    pub frames_nav_gap: u64,
    pub frames_unaided: u64,
    pub nav_samples: u64,
    pub nav_out_of_order: u64,
    pub nav_refused: u64,
    pub nav_time_resets: u64,
    pub nodes: usize,
    pub map_full_events: u64,
    pub trained: bool,
    pub training_failures: u64,
    pub match_threshold: f64,
    /// Frames scanned against the map.
    pub recognition_attempts: u64,
    /// Nearest node overall below the threshold.
    pub appearance_matches: u64,
    /// Appearance matched (nearest overall) but the position gate refused that node.
    pub gate_refusals: u64,
    /// Of the gate refusals, those because the gate was wider than `max_gate_sigma_m`.
    pub gate_too_wide: u64,
    pub recognitions: u64,
    pub fixes: u64,
    pub fixes_refused_refractory: u64,
    pub fixes_refused_interval: u64,
    pub fixes_refused_no_information: u64,
    pub fixes_refused_numeric: u64,
    /// Recognitions sent no fix because the firmware's velocity was unaided.
    pub fixes_refused_velocity: u64,
}

#[derive(Debug, Clone, Copy)]
struct NavPoint {
    t_us: u64,
    pos: [f64; 2],
    depth_m: f64,
    cov: [f64; 3],
    aided: bool,
    vel_sigma_mps: f64,
    /// Path length of the nav solution since the first sample (m).
    odo_m: f64,
}

/// A recognition held for a better frame: the best so far.
#[derive(Debug, Clone, Copy)]
struct Held {
    node: usize,
    /// The place of the node's sample this frame matched best.
    place_ne_m: [f64; 2],
    /// Squared appearance distance, the frame, its nav and its gate statistic.
    app_d2: f64,
    frame: CameraFrame,
    nav: NavAt,
    gate_d2: f64,
    first_t_us: u64,
}

/// The nav solution at a frame.
#[derive(Debug, Clone, Copy)]
struct NavAt {
    pos: [f64; 2],
    depth_m: f64,
    cov: [f64; 3],
    aided: bool,
    vel_sigma_mps: f64,
    odo_m: f64,
}

enum NavLookup {
    At(NavAt),
    NeedNav,
    Expired,
    Gap(f64),
}

/// The learned metric folded into one affine map `y = A f + b` (A row-major, `dim x N_FEATURES`).
#[derive(Debug, Clone)]
struct Metric {
    dim: usize,
    a: Vec<f64>,
    b: Vec<f64>,
    threshold2: f64,
}

impl Metric {
    fn from_model(model: &LmnnModel, threshold: f64) -> Option<Self> {
        let dim = model.l.len();
        if dim == 0 || model.scaler.mean.len() != N_FEATURES || model.scaler.scale.len() != N_FEATURES {
            return None;
        }
        let mut a = vec![0.0; dim * N_FEATURES];
        let mut b = vec![0.0; dim];
        for r in 0..dim {
            let row = model.l.get(r)?;
            if row.len() != N_FEATURES {
                return None;
            }
            for c in 0..N_FEATURES {
                let v = row[c] / model.scaler.scale[c];
                a[r * N_FEATURES + c] = v;
                b[r] -= v * model.scaler.mean[c];
            }
        }
        let ok = a.iter().chain(b.iter()).all(|v| v.is_finite()) && threshold.is_finite() && threshold > 0.0;
        ok.then_some(Metric { dim, a, b, threshold2: threshold * threshold })
    }

    fn map_into(&self, f: &[f64; N_FEATURES], out: &mut [f64]) {
        for (r, o) in out.iter_mut().enumerate().take(self.dim) {
            let row = &self.a[r * N_FEATURES..(r + 1) * N_FEATURES];
            *o = self.b[r] + row.iter().zip(f).map(|(a, x)| a * x).sum::<f64>();
        }
    }
}

/// The mapper. See the module doc.
pub struct LiveMapper {
    cfg: LiveConfig,
    nav: VecDeque<NavPoint>,
    last_frame: Option<(u32, u64)>,
    /// Frames in a row with the counter below the last accepted one and time forward: (counter,
    /// time, how many).
    restart_run: Option<(u32, u64, usize)>,
    /// Nav samples in a row with time before the newest one: (time, how many).
    nav_back_run: Option<(u64, usize)>,
    last_fix_t_us: Option<u64>,
    /// The recognition being held for a better frame of the same node.
    held: Option<Held>,
    recent: VecDeque<(u64, [f64; N_FEATURES])>,
    /// Node being built: (id, creation time).
    collecting: Option<(usize, u64)>,
    last_event_odo_m: Option<f64>,
    nodes: Vec<LiveNode>,
    closures: Vec<Closure>,
    metric: Option<Metric>,
    /// Mapped node samples (`dim` each, contiguous) and the node index of each.
    mapped: Vec<f64>,
    owner: Vec<u32>,
    /// The place of each mapped sample (`LiveNode::sample_places_ne_m`).
    place_of: Vec<[f64; 2]>,
    next_train_at: usize,
    /// Travel odometer (m) and its last anchor position.
    odo_m: f64,
    odo_anchor: Option<[f64; 2]>,
    /// Per-node gate statistic of the current frame (reused; infinity = not a candidate).
    gate_scratch: Vec<f64>,
    stats: LiveStats,
}

fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

/// `P1 - P0` with eigenvalues floored, without trigonometry when no eigenvalue is below the floor.
fn drift_cov(p1: &Matrix2<f64>, p0: &Matrix2<f64>, floor: f64) -> Matrix2<f64> {
    let d = symmetrise(&(p1 - p0));
    let (a, b, c) = (d[(0, 0)], d[(0, 1)], d[(1, 1)]);
    let lo = 0.5 * (a + c) - (0.25 * (a - c) * (a - c) + b * b).sqrt();
    if lo >= floor { d } else { floor_eig(&d, floor) }
}

impl LiveMapper {
    pub fn new(cfg: LiveConfig) -> Self {
        LiveMapper {
            next_train_at: cfg.train_after_nodes.max(2),
            cfg,
            nav: VecDeque::new(),
            last_frame: None,
            restart_run: None,
            nav_back_run: None,
            last_fix_t_us: None,
            held: None,
            recent: VecDeque::new(),
            collecting: None,
            last_event_odo_m: None,
            nodes: Vec::new(),
            closures: Vec::new(),
            metric: None,
            mapped: Vec::new(),
            owner: Vec::new(),
            place_of: Vec::new(),
            odo_m: 0.0,
            odo_anchor: None,
            gate_scratch: Vec::new(),
            stats: LiveStats::default(),
        }
    }

    pub fn config(&self) -> &LiveConfig {
        &self.cfg
    }

    /// Add a nav sample to the window (last `nav_window_s`, at most `max_nav_samples`).
    pub fn on_nav(&mut self, nav: NavSample) -> NavOutcome {
        let [nn, ne, ee] = nav.cov_ne_m2;
        // A correlation a rounding step past +-1 (the telemetry is f32) is clamped; beyond that
        // the covariance is not PSD and refused. (Before the firmware's estimator runs its sigmas
        // are infinite: refused too.)
        let rounding = nn * ee - ne * ne >= -1e-5 * nn * ee;
        if !finite(&nav.pos_ned_m) || !finite(&nav.cov_ne_m2) || nn < 0.0 || ee < 0.0 || !rounding {
            self.stats.nav_refused += 1;
            return NavOutcome::Refused;
        }
        let cov = [nn, ne.clamp(-(nn * ee).sqrt(), (nn * ee).sqrt()), ee];
        let pos = [nav.pos_ned_m[0], nav.pos_ned_m[1]];
        let mut outcome = NavOutcome::Accepted;
        if self.nav.back().is_some_and(|last| nav.t_us <= last.t_us) {
            // Time back: out of order, unless `nav_reset_samples` such samples in a row agree (a
            // new time base, or one corrupted sample stamped in the future): then the window, the
            // frame order and the sample run start again from here.
            let run = match self.nav_back_run {
                Some((t, k)) if nav.t_us > t => k + 1,
                _ => 1,
            };
            if run < self.cfg.nav_reset_samples.max(1) {
                self.nav_back_run = Some((nav.t_us, run));
                self.stats.nav_out_of_order += 1;
                return NavOutcome::OutOfOrder;
            }
            self.nav.clear();
            self.odo_anchor = None;
            self.last_frame = None;
            self.restart_run = None;
            self.recent.clear();
            self.collecting = None;
            self.stats.nav_time_resets += 1;
            outcome = NavOutcome::TimeBaseReset;
        }
        self.nav_back_run = None;
        // Travel: the path length through anchors at least `odo_step_m` apart, so the jitter of
        // the solution between samples is not counted as travel.
        match self.odo_anchor {
            Some(a) if dist(a, pos) < self.cfg.odo_step_m => {}
            Some(a) => {
                self.odo_m += dist(a, pos);
                self.odo_anchor = Some(pos);
            }
            None => self.odo_anchor = Some(pos),
        }
        let odo_m = self.odo_m;
        self.stats.nav_samples += 1;
        // Unknown (non-finite) velocity sigma: unaided.
        let vel_sigma_mps = if nav.vel_sigma_mps.is_nan() { f64::INFINITY } else { nav.vel_sigma_mps.abs() };
        self.nav.push_back(NavPoint { t_us: nav.t_us, pos, depth_m: nav.pos_ned_m[2], cov, aided: nav.aided, vel_sigma_mps, odo_m });
        let window_us = (self.cfg.nav_window_s.max(0.0) * 1e6) as u64;
        while self.nav.len() > self.cfg.max_nav_samples.max(2)
            || self.nav.front().is_some_and(|f| f.t_us.saturating_add(window_us) < nav.t_us)
        {
            self.nav.pop_front();
        }
        outcome
    }

    fn nav_at(&self, t_us: u64) -> NavLookup {
        let Some(newest) = self.nav.back() else { return NavLookup::NeedNav };
        if newest.t_us < t_us {
            return NavLookup::NeedNav;
        }
        let b = self.nav.partition_point(|p| p.t_us < t_us);
        let Some(pb) = self.nav.get(b) else { return NavLookup::NeedNav };
        if pb.t_us == t_us {
            return NavLookup::At(NavAt {
                pos: pb.pos,
                depth_m: pb.depth_m,
                cov: pb.cov,
                aided: pb.aided,
                vel_sigma_mps: pb.vel_sigma_mps,
                odo_m: pb.odo_m,
            });
        }
        let Some(pa) = b.checked_sub(1).and_then(|a| self.nav.get(a)) else { return NavLookup::Expired };
        let gap_s = (pb.t_us - pa.t_us) as f64 * 1e-6;
        if gap_s > self.cfg.max_nav_gap_s {
            return NavLookup::Gap(gap_s);
        }
        let w = (t_us - pa.t_us) as f64 / (pb.t_us - pa.t_us) as f64;
        let lerp = |a: f64, b: f64| a + w * (b - a);
        NavLookup::At(NavAt {
            pos: [lerp(pa.pos[0], pb.pos[0]), lerp(pa.pos[1], pb.pos[1])],
            depth_m: lerp(pa.depth_m, pb.depth_m),
            // The later sample's covariance (conservative while drifting).
            cov: pb.cov,
            aided: pa.aided && pb.aided,
            vel_sigma_mps: pa.vel_sigma_mps.max(pb.vel_sigma_mps),
            odo_m: lerp(pa.odo_m, pb.odo_m),
        })
    }

    /// Process a frame (see [`FrameOutcome`]). Frames must come in counter order; on
    /// [`FrameOutcome::NeedNav`] hold the frame (and the later ones) and call again after more nav.
    pub fn on_frame(&mut self, frame: &CameraFrame) -> FrameOutcome {
        self.on_frame_observed(frame, &mut |_| {})
    }

    /// [`Self::on_frame`], telling `events` what it did ([`MapEvent`], in order).
    pub fn on_frame_observed(&mut self, frame: &CameraFrame, events: &mut dyn FnMut(MapEvent)) -> FrameOutcome {
        let mut restart = false;
        if let Some((last_n, last_t)) = self.last_frame {
            if frame.frame == last_n {
                self.stats.frames += 1;
                self.stats.frames_duplicated += 1;
                return FrameOutcome::Ignored { reason: IgnoreReason::Duplicate };
            }
            if frame.t_us <= last_t {
                self.stats.frames += 1;
                self.stats.frames_out_of_order += 1;
                return FrameOutcome::Ignored { reason: IgnoreReason::OutOfOrder };
            }
            if frame.frame < last_n {
                // Counter back, time forward: out of order, unless `restart_frames` such frames in a
                // row agree with each other (a camera restart).
                let run = match self.restart_run {
                    Some((n, t, k)) if frame.frame > n && frame.t_us > t => k + 1,
                    _ => 1,
                };
                if run < self.cfg.restart_frames.max(1) {
                    self.restart_run = Some((frame.frame, frame.t_us, run));
                    self.stats.frames += 1;
                    self.stats.frames_out_of_order += 1;
                    return FrameOutcome::Ignored { reason: IgnoreReason::OutOfOrder };
                }
                restart = true;
            }
        }
        let nav = self.nav_at(frame.t_us);
        if let NavLookup::NeedNav = nav {
            return FrameOutcome::NeedNav;
        }
        self.stats.frames += 1;
        match self.last_frame {
            Some(_) if restart => self.stats.camera_restarts += 1,
            Some((last_n, _)) => self.stats.frames_missing += u64::from(frame.frame - last_n - 1),
            None => {}
        }
        self.restart_run = None;
        self.last_frame = Some((frame.frame, frame.t_us));
        let t = frame.t_us;
        let max_age_us = (self.cfg.max_sample_age_s.max(0.0) * 1e6) as u64;

        // Features: a blackout or bad image ends the current sample run.
        let f = match frame.features {
            Some(f) if finite(&f) => f,
            other => {
                self.recent.clear();
                self.collecting = None;
                return if other.is_none() {
                    self.stats.frames_without_features += 1;
                    FrameOutcome::Ignored { reason: IgnoreReason::NoFeatures }
                } else {
                    self.stats.frames_nonfinite_features += 1;
                    FrameOutcome::Refused { reason: Refusal::NonFiniteFeatures }
                };
            }
        };
        let back = self.cfg.samples_per_node.saturating_sub(1) / 2;
        self.recent.push_back((t, f));
        while self.recent.len() > back + 1 || self.recent.front().is_some_and(|(ft, _)| ft.saturating_add(max_age_us) < t) {
            self.recent.pop_front();
        }
        if let Some((id, t0)) = self.collecting {
            if t.saturating_sub(t0) <= max_age_us && id < self.nodes.len() {
                let place = match &nav {
                    NavLookup::At(n) => n.pos,
                    _ => self.nodes[id].pos_ned_m,
                };
                self.add_sample(id, f, place);
                if self.nodes[id].samples.len() >= self.cfg.samples_per_node {
                    self.collecting = None;
                    self.maybe_train();
                }
                return FrameOutcome::Sampled { node: id };
            }
            self.collecting = None;
            self.maybe_train();
        }

        let nav = match nav {
            NavLookup::At(n) => n,
            NavLookup::NeedNav | NavLookup::Expired => {
                self.stats.frames_nav_expired += 1;
                return FrameOutcome::Ignored { reason: IgnoreReason::NavExpired };
            }
            NavLookup::Gap(gap_s) => {
                self.stats.frames_nav_gap += 1;
                return FrameOutcome::Refused { reason: Refusal::NavGap { gap_s } };
            }
        };
        if !nav.aided {
            self.stats.frames_unaided += 1;
            return FrameOutcome::Ignored { reason: IgnoreReason::NotAided };
        }

        let mut gate_refused = None;
        let mut result = None;
        if self.metric.is_some() {
            match self.recognise(frame, &f, &nav, events) {
                Recognition::None => {}
                Recognition::GateRefused(node, d2) => gate_refused = Some((node, d2)),
                Recognition::Event(outcome) => {
                    self.last_event_odo_m = Some(nav.odo_m);
                    result = Some(outcome);
                }
            }
        }
        if let Some(r) = result {
            return r;
        }
        let due = self.last_event_odo_m.is_none_or(|o| nav.odo_m - o >= self.cfg.node_spacing_m);
        if due {
            self.last_event_odo_m = Some(nav.odo_m);
            if self.nodes.len() >= self.cfg.max_nodes {
                self.stats.map_full_events += 1;
                return FrameOutcome::Ignored { reason: IgnoreReason::MapFull };
            }
            let id = self.place(t, &nav);
            events(MapEvent::NodePlaced { node: id, t_us: t });
            return FrameOutcome::Placed { node: id };
        }
        match (gate_refused, self.metric.is_some()) {
            (Some((node, d2)), _) => FrameOutcome::Refused { reason: Refusal::GateRefused { node, d2 } },
            (None, true) => FrameOutcome::NoMatch,
            (None, false) => FrameOutcome::Ignored { reason: IgnoreReason::NotTrained },
        }
    }

    fn place(&mut self, t: u64, nav: &NavAt) -> usize {
        let id = self.nodes.len();
        let samples: Vec<[f64; N_FEATURES]> = Vec::with_capacity(self.cfg.samples_per_node);
        self.nodes.push(LiveNode {
            id,
            pos_ned_m: nav.pos,
            cov_ne_m2: nav.cov,
            created_t_us: t,
            observations: 0,
            fixes: 0,
            last_fix_t_us: None,
            samples,
            sample_places_ne_m: Vec::with_capacity(self.cfg.samples_per_node),
        });
        let recent: Vec<(u64, [f64; N_FEATURES])> = self.recent.iter().copied().collect();
        for (tr, f) in recent {
            let place = self.place_at(tr, nav.pos);
            self.add_sample(id, f, place);
        }
        self.stats.nodes = self.nodes.len();
        if self.nodes[id].samples.len() < self.cfg.samples_per_node {
            self.collecting = Some((id, t));
        } else {
            self.maybe_train();
        }
        id
    }

    fn add_sample(&mut self, id: usize, f: [f64; N_FEATURES], place_ne_m: [f64; 2]) {
        let Some(node) = self.nodes.get_mut(id) else { return };
        node.samples.push(f);
        node.sample_places_ne_m.push(place_ne_m);
        if let Some(m) = &self.metric {
            let start = self.mapped.len();
            self.mapped.resize(start + m.dim, 0.0);
            m.map_into(&f, &mut self.mapped[start..]);
            self.owner.push(id as u32);
            self.place_of.push(place_ne_m);
        }
    }

    /// The firmware's position estimate at `t_us` (`fallback` outside the nav window).
    fn place_at(&self, t_us: u64, fallback: [f64; 2]) -> [f64; 2] {
        match self.nav_at(t_us) {
            NavLookup::At(n) => n.pos,
            _ => fallback,
        }
    }

    /// Train once enough nodes are complete (retried after a quarter of `train_after_nodes` more
    /// nodes when the fit fails).
    fn maybe_train(&mut self) {
        if self.metric.is_some() || self.collecting.is_some() {
            return;
        }
        let k = self.cfg.lmnn.k;
        let complete = self.nodes.iter().filter(|n| n.samples.len() > k).count();
        if complete < self.next_train_at {
            return;
        }
        let mut map = TopoMap::default();
        map.nodes = self
            .nodes
            .iter()
            .map(|n| Node::placed(n.id, n.created_t_us as f64 * 1e-6, n.samples.clone(), n.pos_ned_m, n.cov_ne_m2))
            .collect();
        let metric = map
            .train(&self.cfg.lmnn, self.cfg.threshold_factor)
            .ok()
            .and_then(|()| map.model.as_ref().and_then(|m| Metric::from_model(m, map.match_threshold)));
        let Some(metric) = metric else {
            self.stats.training_failures += 1;
            self.next_train_at = complete + (self.cfg.train_after_nodes / 4).max(1);
            return;
        };
        let total: usize = self.nodes.iter().map(|n| n.samples.len()).sum();
        self.mapped = Vec::with_capacity(total * metric.dim);
        self.owner = Vec::with_capacity(total);
        self.place_of = Vec::with_capacity(total);
        let mut buf = vec![0.0; metric.dim];
        for n in &self.nodes {
            for (k, s) in n.samples.iter().enumerate() {
                metric.map_into(s, &mut buf);
                self.mapped.extend_from_slice(&buf);
                self.owner.push(n.id as u32);
                self.place_of.push(n.sample_places_ne_m.get(k).copied().unwrap_or(n.pos_ned_m));
            }
        }
        self.stats.trained = true;
        self.stats.match_threshold = metric.threshold2.sqrt();
        self.metric = Some(metric);
    }

    fn recognise(&mut self, frame: &CameraFrame, f: &[f64; N_FEATURES], nav: &NavAt, events: &mut dyn FnMut(MapEvent)) -> Recognition {
        let Some(metric) = &self.metric else { return Recognition::None };
        let cfg = self.cfg;
        let t = frame.t_us;
        self.stats.recognition_attempts += 1;
        events(MapEvent::Attempt { t_us: t });
        let p1 = sym(nav.cov);
        let x1 = Vector2::new(nav.pos[0], nav.pos[1]);
        let v = Matrix2::identity() * cfg.recognition_sigma_m.powi(2);
        let min_age_us = (cfg.min_revisit_s.max(0.0) * 1e6) as u64;

        // Position gate of every node old enough to be revisited.
        self.gate_scratch.clear();
        for n in &self.nodes {
            let eligible = n.created_t_us.saturating_add(min_age_us) <= t;
            let d2 = if eligible {
                let d = drift_cov(&p1, &sym(n.cov_ne_m2), cfg.min_drift_m2);
                let m = x1 - Vector2::new(n.pos_ned_m[0], n.pos_ned_m[1]);
                let s = d + v;
                let ([_, lam_max], _) = eig_sym(&s);
                if lam_max > cfg.max_gate_sigma_m.powi(2) {
                    f64::MAX // too wide: fails the gate, still an appearance-only candidate
                } else {
                    inv_pd(&s).map_or(f64::INFINITY, |si| (m.transpose() * si * m)[(0, 0)])
                }
            } else {
                f64::INFINITY
            };
            self.gate_scratch.push(if d2.is_finite() { d2 } else { f64::INFINITY });
        }
        // An infinite gate statistic (node too young, or no PD innovation covariance) skips the
        // node below; a finite one failing the gate still counts for the appearance-only match.
        let mut q = [0.0; N_FEATURES];
        let dim = metric.dim.min(N_FEATURES);
        metric.map_into(f, &mut q[..dim]);
        let q = &q[..dim];
        let (mut best_all, mut best_gated) = ((f64::INFINITY, usize::MAX), (f64::INFINITY, usize::MAX));
        let mut best_sample = usize::MAX;
        for (s, &owner) in self.owner.iter().enumerate() {
            let node = owner as usize;
            let g = self.gate_scratch.get(node).copied().unwrap_or(f64::INFINITY);
            if g == f64::INFINITY {
                continue;
            }
            let row = &self.mapped[s * metric.dim..s * metric.dim + dim];
            let d2: f64 = row.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
            if d2 < best_all.0 {
                best_all = (d2, node);
            }
            if g < cfg.gate_chi2 && d2 < best_gated.0 {
                best_gated = (d2, node);
                best_sample = s;
            }
        }
        let thr2 = metric.threshold2;
        let mut refused = None;
        if best_all.0 < thr2 {
            self.stats.appearance_matches += 1;
            let g = self.gate_scratch[best_all.1];
            events(MapEvent::AppearanceMatch { t_us: t, node: best_all.1, gate_refused: g >= cfg.gate_chi2 });
            if g >= cfg.gate_chi2 {
                self.stats.gate_refusals += 1;
                self.stats.gate_too_wide += u64::from(g == f64::MAX);
                refused = Some((best_all.1, g));
            }
        }
        if best_gated.0.is_nan() || best_gated.0 >= thr2 {
            // The held recognition's run of matches has ended: send it.
            if let Some(h) = self.held.take() {
                return Recognition::Event(self.send(h));
            }
            return refused.map_or(Recognition::None, |(n, d2)| Recognition::GateRefused(n, d2));
        }
        let (app_d2, node) = best_gated;
        self.stats.recognitions += 1;
        events(MapEvent::Recognised { t_us: t, node });
        let gate_d2 = self.gate_scratch[node];
        let n = &mut self.nodes[node];
        n.observations += 1;
        let refractory_us = (cfg.refractory_s.max(0.0) * 1e6) as u64;
        if n.last_fix_t_us.is_some_and(|lt| t < lt.saturating_add(refractory_us)) {
            self.stats.fixes_refused_refractory += 1;
            return Recognition::Event(FrameOutcome::Refused { reason: Refusal::Refractory { node } });
        }
        if !(nav.vel_sigma_mps <= cfg.max_fix_vel_sigma_mps) {
            self.stats.fixes_refused_velocity += 1;
            return Recognition::Event(FrameOutcome::Refused {
                reason: Refusal::VelocityUnaided { node, vel_sigma_mps: nav.vel_sigma_mps },
            });
        }
        // The first frame that matches is seen while the vehicle still approaches the node's
        // place (its footprint overlaps the node's images from a metre or two away): hold it
        // while the next frames match the same node better, and send the best.
        let place_ne_m = self.place_of.get(best_sample).copied().unwrap_or(n.pos_ned_m);
        let this = Held { node, place_ne_m, app_d2, frame: *frame, nav: *nav, gate_d2, first_t_us: t };
        let hold_us = (cfg.best_match_hold_s.max(0.0) * 1e6) as u64;
        match self.held.take() {
            Some(h) if h.node == node && app_d2 < h.app_d2 && t.saturating_sub(h.first_t_us) < hold_us => {
                self.held = Some(Held { first_t_us: h.first_t_us, ..this });
                Recognition::Event(FrameOutcome::Held { node })
            }
            // Worse than the best (the place is passed), another node, or held long enough.
            Some(h) => Recognition::Event(self.send(h)),
            None if hold_us == 0 => Recognition::Event(self.send(this)),
            None => {
                self.held = Some(this);
                Recognition::Event(FrameOutcome::Held { node })
            }
        }
    }

    /// The fix of a (held) recognition, or why none is sent.
    fn send(&mut self, h: Held) -> FrameOutcome {
        let cfg = self.cfg;
        let Held { node, place_ne_m, app_d2, frame, nav, gate_d2, .. } = h;
        let t = frame.t_us;
        let p1 = sym(nav.cov);
        let x1 = Vector2::new(nav.pos[0], nav.pos[1]);
        let v = Matrix2::identity() * cfg.recognition_sigma_m.powi(2);
        let interval_us = (cfg.min_fix_interval_s.max(0.0) * 1e6) as u64;
        if self.last_fix_t_us.is_some_and(|lt| t < lt.saturating_add(interval_us)) {
            self.stats.fixes_refused_interval += 1;
            return FrameOutcome::Refused { reason: Refusal::FixInterval { node } };
        }
        let Some(n) = self.nodes.get_mut(node) else { return FrameOutcome::Refused { reason: Refusal::Numeric { node } } };
        let x0 = Vector2::new(place_ne_m[0], place_ne_m[1]);
        let math = match equivalent_fix(x0, &sym(n.cov_ne_m2), x1, &p1, &v, cfg.min_drift_m2) {
            Ok(m) => m,
            Err(FixMathError::NonFinite | FixMathError::NotPositiveDefinite | FixMathError::Degenerate) => {
                self.stats.fixes_refused_numeric += 1;
                return FrameOutcome::Refused { reason: Refusal::Numeric { node } };
            }
        };
        // Information: R's eigenvalues, and the generalised eigenvalues of P1 R^-1 (variance
        // shrinks by lambda / (1 + lambda) along each).
        let (r_eig, r_vec) = eig_sym(&math.r);
        let gain = inv_pd(&math.r).map(|ri| {
            let pr = p1 * ri;
            let (tr, det) = (pr.trace(), pr.determinant());
            let disc = (0.25 * tr * tr - det).max(0.0).sqrt();
            0.5 * tr + disc
        });
        let max_gain = gain.unwrap_or(0.0);
        if r_eig[0] > cfg.max_fix_var_m2 || max_gain.is_nan() || max_gain < cfg.min_info_gain {
            self.stats.fixes_refused_no_information += 1;
            return FrameOutcome::Refused { reason: Refusal::NoInformation { node, min_var_m2: r_eig[0], max_gain } };
        }
        // Cap the weak direction (largest eigenvalue), keeping R^-1 (z - x1) along it.
        let (mut r, mut z) = (math.r, math.z);
        if r_eig[1] > cfg.max_fix_eig_m2 {
            let u = Vector2::new(r_vec[0], r_vec[1]);
            let scale = cfg.max_fix_eig_m2 / r_eig[1];
            r = symmetrise(&(r - u * u.transpose() * (r_eig[1] - cfg.max_fix_eig_m2)));
            let dz = z - x1;
            let along = u.dot(&dz);
            z = x1 + dz - u * along * (1.0 - scale);
        }
        n.fixes += 1;
        n.last_fix_t_us = Some(t);
        self.last_fix_t_us = Some(t);
        self.stats.fixes += 1;
        let fix = MapFix {
            t_us: t,
            node,
            pos_ne_m: [z[0], z[1]],
            cov_ne_m2: tri(&r),
            frame: frame.frame,
            prior_ne_m: nav.pos,
            prior_cov_ne_m2: nav.cov,
            prior_depth_m: nav.depth_m,
            posterior_ne_m: [math.mu[0], math.mu[1]],
            posterior_cov_ne_m2: tri(&math.sigma),
            gate_d2,
            appearance_dist: app_d2.sqrt(),
            place_ne_m,
        };
        if self.closures.len() >= self.cfg.max_closures.max(2) {
            let half = self.closures.len() / 2;
            self.closures.drain(..half);
        }
        self.closures.push(Closure { t_us: t, node, vehicle_ne_m: nav.pos, fix_ne_m: fix.pos_ne_m, fix_cov_ne_m2: fix.cov_ne_m2 });
        FrameOutcome::Fix(fix)
    }

    pub fn stats(&self) -> LiveStats {
        self.stats.clone()
    }

    pub fn nodes(&self) -> &[LiveNode] {
        &self.nodes
    }

    /// Accepted loop closures (the most recent, up to `max_closures`).
    pub fn closures(&self) -> &[Closure] {
        &self.closures
    }

    /// Whether the metric has been learned, and its appearance threshold.
    pub fn match_threshold(&self) -> Option<f64> {
        self.metric.as_ref().map(|m| m.threshold2.sqrt())
    }

    /// Squared distance of a feature vector to each node's nearest sample in the learned metric
    /// (`None` before training); for diagnostics and tests, allocates.
    pub fn appearance_distances(&self, f: &[f64; N_FEATURES]) -> Option<Vec<f64>> {
        let m = self.metric.as_ref()?;
        let mut q = vec![0.0; m.dim];
        m.map_into(f, &mut q);
        let mut out = vec![f64::INFINITY; self.nodes.len()];
        for (s, &o) in self.owner.iter().enumerate() {
            let row = &self.mapped[s * m.dim..(s + 1) * m.dim];
            let d2: f64 = row.iter().zip(&q).map(|(a, b)| (a - b) * (a - b)).sum();
            if let Some(x) = out.get_mut(o as usize) {
                *x = x.min(d2);
            }
        }
        Some(out)
    }
}

enum Recognition {
    None,
    GateRefused(usize, f64),
    Event(FrameOutcome),
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    #[test]
    fn folded_metric_matches_the_model_map() {
        // Two classes of synthetic samples; the folded affine map equals LmnnModel::map.
        let mut rows = Vec::new();
        let mut y = Vec::new();
        for i in 0..12 {
            let c = (i % 2) as f64;
            rows.push(std::array::from_fn::<f64, N_FEATURES, _>(|k| c * 2.0 + (k as f64 * 0.37 + i as f64 * 1.3).sin()));
            y.push((i % 2) as i64);
        }
        let x = DMatrix::from_fn(rows.len(), N_FEATURES, |r, c| rows[r][c]);
        let model = LmnnModel::fit(&x, &y, &LmnnConfig { max_iter: 60, ..LmnnConfig::default() }).unwrap();
        let metric = Metric::from_model(&model, 1.0).unwrap();
        let want = model.map(&x);
        let mut got = vec![0.0; metric.dim];
        for (r, f) in rows.iter().enumerate() {
            metric.map_into(f, &mut got);
            for c in 0..metric.dim {
                assert!((got[c] - want[(r, c)]).abs() < 1e-9 * (1.0 + want[(r, c)].abs()), "row {r} col {c}");
            }
        }
    }
}
