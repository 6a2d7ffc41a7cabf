//! Simulated survey with revisits: a racetrack loop flown several times over the rendered
//! seafloor, dead reckoning that misses the water current (plus compass-heading and speed
//! noise), the topological map built online, and the evaluation (node recognition precision /
//! recall, position drift with loop-closure fixes vs dead reckoning alone).
//!
//! The run, per camera frame (every `frame_dt_s`):
//! 1. truth pose on the loop; dead-reckoned displacement; filter predict;
//! 2. render the mosaic at the true pose, demosaic, Stokes, features;
//! 3. a new node's samples are the features of `samples_per_node` frames centred on its creation
//!    point (the previous frames are kept in a short buffer);
//! 4. after `train_after_s` (about one lap): LMNN on the node samples (labels = node ids), then
//!    merge adjacent too-similar nodes (position gate + mean sample distance under the learned
//!    metric below the threshold: the duplicates made when the first lap closes);
//! 5. at key frames after training: candidates in the learned metric below the threshold, the
//!    nearest one that passes the Mahalanobis position gate is recognised; a recognition is a
//!    re-observation update (at most one per node every `refractory_s`) and a position fix;
//! 6. a new node is created after `node_spacing_m` of travel without a node event.
//!
//! Ground truth is used only for the figures: a recognition is correct when the vehicle is
//! within `correct_radius_m` of the node's true position; an opportunity is a key frame within
//! `opportunity_radius_m` of some node's true position.

use std::f64::consts::PI;

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;
use subnav_wire::Downlink;

use super::map::{Node, TopoMap};
use super::scene::{Scene, SceneConfig, coastal_water};
use super::slam::{SlamFilter, SlamTuning, chi2_2_99};
use crate::lmnn::LmnnConfig;
use crate::polar_image::{N_FEATURES, demosaic, features, stokes};

/// A racetrack loop: two straight legs (north, then back south) joined by half circles.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Racetrack {
    pub leg_m: f64,
    pub radius_m: f64,
    pub speed_mps: f64,
    pub depth_m: f64,
}

impl Racetrack {
    pub fn perimeter_m(&self) -> f64 {
        2.0 * self.leg_m + 2.0 * PI * self.radius_m
    }

    /// True (north, east) position and heading at time `t_s`.
    pub fn at(&self, t_s: f64) -> ([f64; 2], f64) {
        let (l, r) = (self.leg_m, self.radius_m);
        let s = (self.speed_mps * t_s).rem_euclid(self.perimeter_m());
        if s < l {
            ([s, 0.0], 0.0)
        } else if s < l + PI * r {
            let a = (s - l) / r;
            ([l + r * a.sin(), r - r * a.cos()], a)
        } else if s < 2.0 * l + PI * r {
            ([l - (s - l - PI * r), 2.0 * r], PI)
        } else {
            let a = (s - 2.0 * l - PI * r) / r;
            ([-r * a.sin(), r + r * a.cos()], PI + a)
        }
    }
}

/// Everything a survey run needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurveyConfig {
    pub track: Racetrack,
    pub laps: f64,
    pub frame_dt_s: f64,
    /// Recognition is tried every `keyframe_every` frames.
    pub keyframe_every: usize,
    pub node_spacing_m: f64,
    pub samples_per_node: usize,
    /// Water current the odometry misses (N, E), m/s.
    pub current_mps: [f64; 2],
    pub speed_noise_mps: f64,
    pub heading_bias_rad: f64,
    pub heading_noise_rad: f64,
    /// Standard deviation of a recognition fix (m).
    pub fix_sigma_m: f64,
    pub refractory_s: f64,
    /// LMNN training time (s) and appearance threshold factor.
    pub train_after_s: f64,
    pub threshold_factor: f64,
    /// Use the Mahalanobis position gate (off = appearance only, for comparison).
    pub position_gate: bool,
    pub correct_radius_m: f64,
    pub opportunity_radius_m: f64,
    pub seed: u64,
    pub scene: SceneConfig,
    pub tuning: SlamTuning,
}

impl Default for SurveyConfig {
    fn default() -> Self {
        let track = Racetrack { leg_m: 40.0, radius_m: 10.0, speed_mps: 1.0, depth_m: 10.0 };
        SurveyConfig {
            track,
            laps: 3.0,
            frame_dt_s: 0.5,
            keyframe_every: 2,
            node_spacing_m: 6.0,
            samples_per_node: 5,
            current_mps: [0.015, -0.012],
            speed_noise_mps: 0.02,
            heading_bias_rad: 1f64.to_radians(),
            heading_noise_rad: 0.5f64.to_radians(),
            fix_sigma_m: 1.5,
            refractory_s: 8.0,
            train_after_s: track.perimeter_m() / track.speed_mps + 4.0,
            threshold_factor: 1.5,
            position_gate: true,
            correct_radius_m: 3.0,
            opportunity_radius_m: 2.0,
            seed: 1,
            scene: SceneConfig::default(),
            tuning: SlamTuning { q_pos_m2ps: 0.03 * 0.03, ..SlamTuning::default() },
        }
    }
}

/// One row of the trajectory log.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct TrackPoint {
    pub t_s: f64,
    pub truth_ned_m: [f64; 2],
    /// With loop-closure fixes (the SLAM filter) and dead reckoning alone.
    pub slam_ned_m: [f64; 2],
    pub dr_ned_m: [f64; 2],
}

/// The figures of a run.
#[derive(Debug, Clone, Serialize)]
pub struct SurveyReport {
    pub duration_s: f64,
    pub nodes: usize,
    pub nodes_created: usize,
    pub merges: usize,
    pub keyframes_after_training: usize,
    pub recognitions: usize,
    pub correct_recognitions: usize,
    pub opportunities: usize,
    pub recalled_opportunities: usize,
    pub precision: f64,
    pub recall: f64,
    /// Appearance-only matches (best candidate under the threshold, no position gate) and how
    /// many were correct: what the gate saves us from.
    pub appearance_matches: usize,
    pub appearance_correct: usize,
    pub fixes: usize,
    pub final_drift_slam_m: f64,
    pub final_drift_dr_m: f64,
    pub max_drift_last_lap_slam_m: f64,
    pub max_drift_last_lap_dr_m: f64,
    pub estimated_current_mps: [f64; 2],
    pub match_threshold: f64,
    pub map_full_events: usize,
    pub pd_repairs: u32,
    pub fading_events: u32,
}

pub struct SurveyResult {
    pub report: SurveyReport,
    pub map: TopoMap,
    pub track: Vec<TrackPoint>,
    pub fixes: Vec<Downlink>,
    /// Wire frames of the fixes (postcard + COBS), ready for a downlink.
    pub fix_frames: Vec<Vec<u8>>,
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

/// Run a simulated survey. Runs on its own thread with a large stack (the filter state is
/// 64 x 64 and the UKF keeps its sigma points on the stack). `progress` gets the fraction done.
pub fn run(cfg: &SurveyConfig, progress: &mut (dyn FnMut(f64) + Send)) -> anyhow::Result<SurveyResult> {
    big_stack(|| run_inner(cfg, progress, &mut |_, _, _| Ok(())))
}

/// Receives each simulated frame: time (s), mosaic, dead-reckoned position (N, E).
pub type FrameSink<'a> = dyn FnMut(f64, &crate::polar_image::Mosaic, [f64; 2]) -> anyhow::Result<()> + Send + 'a;

/// [`run`], also handing every frame's mosaic and dead-reckoned position (N, E) to `sink`
/// (e.g. to write an images directory and a navigation log).
pub fn run_with_frames(cfg: &SurveyConfig, progress: &mut (dyn FnMut(f64) + Send), sink: &mut FrameSink) -> anyhow::Result<SurveyResult> {
    big_stack(|| run_inner(cfg, progress, sink))
}

fn big_stack<T: Send>(f: impl FnOnce() -> anyhow::Result<T> + Send) -> anyhow::Result<T> {
    std::thread::scope(|s| {
        let h = std::thread::Builder::new().stack_size(64 << 20).spawn_scoped(s, f)?;
        h.join().map_err(|_| anyhow::anyhow!("mapping thread panicked"))?
    })
}

/// One camera frame for the mapper.
#[derive(Debug, Clone, Copy)]
pub struct Frame {
    pub t_s: f64,
    /// Dead-reckoned displacement since the previous frame (N, E), m.
    pub dx_m: [f64; 2],
    /// Image features (`None` or non-finite: no usable image at this frame).
    pub features: Option<[f64; N_FEATURES]>,
    /// Truth (simulations), for the evaluation only.
    pub truth_ned_m: Option<[f64; 2]>,
    /// Depth (m) for the position fixes; `None`: the survey depth of the configuration.
    pub depth_m: Option<f64>,
}

/// Build a map from recorded frames (e.g. a recording's navigation solutions and an images
/// directory); the figures that need truth stay zero.
pub fn build(
    cfg: &SurveyConfig,
    start_ned_m: [f64; 2],
    frames: &[Frame],
    progress: &mut (dyn FnMut(f64) + Send),
) -> anyhow::Result<SurveyResult> {
    big_stack(|| {
        anyhow::ensure!(cfg.samples_per_node > 3, "samples_per_node must exceed the LMNN k = 3");
        let duration = frames.last().map_or(0.0, |f| f.t_s) - frames.first().map_or(0.0, |f| f.t_s);
        let t0 = frames.first().map_or(0.0, |f| f.t_s);
        let mut m = Mapper::new(cfg, start_ned_m, duration, f64::INFINITY)?;
        // Times inside the mapper are relative to the first frame; fixes carry sensor-head time.
        m.t_offset_s = t0;
        for (i, fr) in frames.iter().enumerate() {
            m.step(&Frame { t_s: fr.t_s - t0, ..*fr })?;
            if i % 20 == 0 {
                progress(i as f64 / frames.len().max(1) as f64);
            }
        }
        progress(1.0);
        Ok(m.finish())
    })
}

fn run_inner(cfg: &SurveyConfig, progress: &mut (dyn FnMut(f64) + Send), sink: &mut FrameSink) -> anyhow::Result<SurveyResult> {
    anyhow::ensure!(cfg.frame_dt_s > 0.0 && cfg.laps > 0.0 && cfg.keyframe_every > 0, "bad survey timing");
    anyhow::ensure!(cfg.samples_per_node > 3, "samples_per_node must exceed the LMNN k = 3");
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let (el, az) = (50f64.to_radians(), 150f64.to_radians());
    let sun = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), -el.sin());
    let scene = Scene::new(cfg.scene, coastal_water(), sun, cfg.track.depth_m, &mut rng);
    let duration = cfg.laps * cfg.track.perimeter_m() / cfg.track.speed_mps;
    let frames = (duration / cfg.frame_dt_s).floor() as usize;
    let lap_s = cfg.track.perimeter_m() / cfg.track.speed_mps;
    let speed_n = Normal::new(0.0, cfg.speed_noise_mps.max(0.0))?;
    let head_n = Normal::new(0.0, cfg.heading_noise_rad.max(0.0))?;
    let (p0, _) = cfg.track.at(0.0);
    let mut m = Mapper::new(cfg, p0, duration, duration - lap_s)?;
    for k in 1..=frames {
        let t = k as f64 * cfg.frame_dt_s;
        let (truth, yaw) = cfg.track.at(t);
        // Odometry: water-relative velocity (misses the current), compass heading with bias.
        let (truth_prev, _) = cfg.track.at(t - cfg.frame_dt_s);
        let ground = [truth[0] - truth_prev[0], truth[1] - truth_prev[1]];
        let water_rel = [ground[0] - cfg.current_mps[0] * cfg.frame_dt_s, ground[1] - cfg.current_mps[1] * cfg.frame_dt_s];
        let v = (water_rel[0].powi(2) + water_rel[1].powi(2)).sqrt() / cfg.frame_dt_s + speed_n.sample(&mut rng);
        let course = water_rel[1].atan2(water_rel[0]) + cfg.heading_bias_rad + head_n.sample(&mut rng);
        let dx = [v * cfg.frame_dt_s * course.cos(), v * cfg.frame_dt_s * course.sin()];
        // Image and features at the true pose.
        let mosaic = scene.render(truth[0], truth[1], yaw, &mut rng);
        let f: [f64; N_FEATURES] = features(&stokes(&demosaic(&mosaic)));
        m.step(&Frame { t_s: t, dx_m: dx, features: Some(f), truth_ned_m: Some(truth), depth_m: Some(cfg.track.depth_m) })?;
        sink(t, &mosaic, m.dr)?;
        if k % 20 == 0 {
            progress(k as f64 / frames as f64);
        }
    }
    progress(1.0);
    Ok(m.finish())
}

/// The online mapper: filter, map and the bookkeeping of node creation and recognition.
struct Mapper<'a> {
    cfg: &'a SurveyConfig,
    filt: SlamFilter,
    dr: [f64; 2],
    map: TopoMap,
    fix_r: f64,
    track: Vec<TrackPoint>,
    fixes: Vec<Downlink>,
    fix_frames: Vec<Vec<u8>>,
    collecting: Option<usize>,
    since_event_m: f64,
    last_node: Option<usize>,
    trained: bool,
    next_id: usize,
    last_fix_t: Vec<f64>,
    recent: std::collections::VecDeque<[f64; N_FEATURES]>,
    rep: SurveyReport,
    k: usize,
    last_lap_after_s: f64,
    t_offset_s: f64,
    depth_m: f64,
}

impl<'a> Mapper<'a> {
    fn new(cfg: &'a SurveyConfig, p0: [f64; 2], duration: f64, last_lap_after_s: f64) -> anyhow::Result<Self> {
        let filt = SlamFilter::new(p0, cfg.tuning).map_err(|e| anyhow::anyhow!("filter init: {e}"))?;
        Ok(Mapper {
            cfg,
            filt,
            dr: p0,
            map: TopoMap::default(),
            fix_r: cfg.fix_sigma_m.powi(2),
            track: Vec::new(),
            fixes: Vec::new(),
            fix_frames: Vec::new(),
            collecting: None,
            since_event_m: f64::INFINITY,
            last_node: None,
            trained: false,
            next_id: 0,
            last_fix_t: Vec::new(),
            recent: std::collections::VecDeque::new(),
            rep: SurveyReport {
                duration_s: duration,
                nodes: 0,
                nodes_created: 0,
                merges: 0,
                keyframes_after_training: 0,
                recognitions: 0,
                correct_recognitions: 0,
                opportunities: 0,
                recalled_opportunities: 0,
                precision: 0.0,
                recall: 0.0,
                appearance_matches: 0,
                appearance_correct: 0,
                fixes: 0,
                final_drift_slam_m: 0.0,
                final_drift_dr_m: 0.0,
                max_drift_last_lap_slam_m: 0.0,
                max_drift_last_lap_dr_m: 0.0,
                estimated_current_mps: [0.0; 2],
                match_threshold: 0.0,
                map_full_events: 0,
                pd_repairs: 0,
                fading_events: 0,
            },
            k: 0,
            last_lap_after_s,
            t_offset_s: 0.0,
            depth_m: cfg.track.depth_m,
        })
    }

    fn step(&mut self, fr: &Frame) -> anyhow::Result<()> {
        let cfg = self.cfg;
        self.k += 1;
        let k = self.k;
        let t = fr.t_s;
        let dx = fr.dx_m;
        anyhow::ensure!(dx.iter().all(|v| v.is_finite()) && t.is_finite(), "frame at t = {t} s: non-finite time or displacement");
        self.dr = [self.dr[0] + dx[0], self.dr[1] + dx[1]];
        let dt = self.track.last().map_or(cfg.frame_dt_s, |p| (t - p.t_s).max(1e-3));
        self.filt.predict(dx, dt).map_err(|e| anyhow::anyhow!("predict: {e}"))?;
        self.since_event_m += (dx[0] * dx[0] + dx[1] * dx[1]).sqrt();
        let truth_opt = fr.truth_ned_m;
        if let Some(d) = fr.depth_m.filter(|d| d.is_finite()) {
            self.depth_m = d;
        }
        if let Some(f) = fr.features.filter(|f| f.iter().all(|x| x.is_finite())) {
            self.image_step(t, k, f, truth_opt)?;
        }
        let slam = self.filt.position();
        let truth = truth_opt.unwrap_or([f64::NAN; 2]);
        self.track.push(TrackPoint { t_s: t, truth_ned_m: truth, slam_ned_m: slam, dr_ned_m: self.dr });
        if truth_opt.is_some() && t > self.last_lap_after_s {
            self.rep.max_drift_last_lap_slam_m = self.rep.max_drift_last_lap_slam_m.max(dist(slam, truth));
            self.rep.max_drift_last_lap_dr_m = self.rep.max_drift_last_lap_dr_m.max(dist(self.dr, truth));
        }
        Ok(())
    }

    fn image_step(&mut self, t: f64, k: usize, f: [f64; N_FEATURES], truth_opt: Option<[f64; 2]>) -> anyhow::Result<()> {
        let cfg = self.cfg;
        let fix_r = self.fix_r;
        let truth = truth_opt.unwrap_or([f64::NAN; 2]);
        let t_fix_us = ((t + self.t_offset_s).max(0.0) * 1e6).round() as u64;
        let depth_m = self.depth_m;
        let Mapper {
            filt, map, rep, collecting, since_event_m, last_node, trained, next_id, last_fix_t, recent, fixes, fix_frames, ..
        } = self;

        let back = cfg.samples_per_node.saturating_sub(1) / 2;
        recent.push_back(f);
        while recent.len() > back + 1 {
            recent.pop_front();
        }
        if let Some(id) = *collecting {
            if let Some(n) = map.node_mut(id) {
                n.samples.push(f);
                if n.samples.len() >= cfg.samples_per_node {
                    *collecting = None;
                }
            } else {
                *collecting = None;
            }
        }

        if !*trained && t >= cfg.train_after_s && collecting.is_none() {
            map.train(&LmnnConfig::default(), cfg.threshold_factor)?;
            rep.match_threshold = map.match_threshold;
            *trained = true;
            // Merge adjacent too-similar nodes (first-lap closure duplicates).
            let ids: Vec<usize> = map.nodes.iter().map(|n| n.id).collect();
            for &b in ids.iter().rev() {
                for &a in &ids {
                    if a >= b || map.node(a).is_none() || map.node(b).is_none() {
                        continue;
                    }
                    let (sa, sb) = (map.node(a).map(|n| n.slot).unwrap_or(0), map.node(b).map(|n| n.slot).unwrap_or(0));
                    let gate = match (filt.node_position(sa), filt.node_position(sb)) {
                        (Some(pa), Some(pb)) => {
                            let c = filt.node_cov(sa) + filt.node_cov(sb);
                            let e = nalgebra::Vector2::new(pa[0] - pb[0], pa[1] - pb[1]);
                            c.try_inverse().map(|ci| (e.transpose() * ci * e)[(0, 0)]).unwrap_or(f64::INFINITY)
                        }
                        _ => f64::INFINITY,
                    };
                    let close = (b - a) > 2 && gate < chi2_2_99();
                    if close
                        && map.node_distance(a, b).is_some_and(|d| d < map.match_threshold)
                        && filt.merge(sa, sb, cfg.tuning.node_sigma_m.powi(2) * 2.0 + fix_r).is_ok()
                    {
                        let dropped = map.nodes.iter().position(|n| n.id == b).map(|i| map.nodes.remove(i));
                        if let (Some(d), Some(keep)) = (dropped, map.node_mut(a)) {
                            keep.samples.extend(d.samples);
                            keep.merged.push(d.id);
                        }
                        map.edges.iter_mut().for_each(|e| {
                            if e.a == b {
                                e.a = a;
                            }
                            if e.b == b {
                                e.b = a;
                            }
                        });
                        map.edges.retain(|e| e.a != e.b);
                        rep.merges += 1;
                        break;
                    }
                }
            }
        }

        let mut event = false;
        if *trained && k % cfg.keyframe_every == 0 && collecting.is_none() {
            rep.keyframes_after_training += 1;
            let cands = map.candidates(&f);
            let is_correct =
                |id: usize, map: &TopoMap| map.node(id).and_then(|n| n.truth_ned_m).is_some_and(|p| dist(p, truth) < cfg.correct_radius_m);
            if let Some(c) = cands.first().filter(|c| c.dist < map.match_threshold) {
                rep.appearance_matches += 1;
                rep.appearance_correct += is_correct(c.node, map) as usize;
            }
            let chosen = cands.iter().take_while(|c| c.dist < map.match_threshold).find(|c| {
                !cfg.position_gate || map.node(c.node).and_then(|n| filt.mahalanobis2(n.slot, fix_r)).is_some_and(|d2| d2 < chi2_2_99())
            });
            let opportunity =
                truth_opt.is_some() && map.nodes.iter().any(|n| n.truth_ned_m.is_some_and(|p| dist(p, truth) < cfg.opportunity_radius_m));
            rep.opportunities += opportunity as usize;
            if let Some(c) = chosen {
                rep.recognitions += 1;
                let ok = is_correct(c.node, map);
                rep.correct_recognitions += ok as usize;
                rep.recalled_opportunities += (ok && opportunity) as usize;
                event = true;
                if let Some(prev) = *last_node {
                    map.add_edge(prev, c.node);
                }
                *last_node = Some(c.node);
                let slot = map.node(c.node).map(|n| n.slot);
                let due = last_fix_t.get(c.node).is_none_or(|&lt| t - lt >= cfg.refractory_s);
                if let (Some(slot), true) = (slot, due) {
                    if filt.observe(slot, fix_r).is_ok_and(|r| r.accepted) {
                        if let Some(lt) = last_fix_t.get_mut(c.node) {
                            *lt = t;
                        }
                        if let Some(n) = map.node_mut(c.node) {
                            n.observations += 1;
                        }
                        let fix = filt.position_fix(t_fix_us, depth_m, 0.01);
                        let mut buf = [0u8; subnav_wire::MAX_DOWNLINK_FRAME];
                        if let Ok(frame) = subnav_wire::encode(&fix, &mut buf) {
                            fix_frames.push(frame.to_vec());
                        }
                        fixes.push(fix);
                    }
                }
            }
        }
        if event {
            *since_event_m = 0.0;
        }
        if *since_event_m >= cfg.node_spacing_m && collecting.is_none() {
            match filt.add_node() {
                Some(slot) => {
                    let id = *next_id;
                    *next_id += 1;
                    last_fix_t.push(f64::NEG_INFINITY);
                    map.nodes.push(Node {
                        id,
                        slot,
                        created_t_s: t,
                        samples: recent.iter().copied().collect(),
                        pos_ned_m: filt.position(),
                        cov_m2: [0.0; 3],
                        truth_ned_m: truth_opt,
                        observations: 0,
                        merged: Vec::new(),
                    });
                    if let Some(prev) = *last_node {
                        map.add_edge(prev, id);
                    }
                    *last_node = Some(id);
                    *collecting = Some(id);
                    rep.nodes_created += 1;
                }
                None => rep.map_full_events += 1,
            }
            *since_event_m = 0.0;
        }

        Ok(())
    }

    fn finish(self) -> SurveyResult {
        let Mapper { filt, mut map, mut rep, track, fixes, fix_frames, .. } = self;
        for n in map.nodes.iter_mut() {
            if let Some(p) = filt.node_position(n.slot) {
                n.pos_ned_m = p;
                let c = filt.node_cov(n.slot);
                n.cov_m2 = [c[(0, 0)], c[(0, 1)], c[(1, 1)]];
            }
        }
        let last = track.last().copied();
        rep.nodes = map.nodes.len();
        rep.fixes = fixes.len();
        rep.precision = if rep.recognitions > 0 { rep.correct_recognitions as f64 / rep.recognitions as f64 } else { 0.0 };
        rep.recall = if rep.opportunities > 0 { rep.recalled_opportunities as f64 / rep.opportunities as f64 } else { 0.0 };
        if let Some(l) = last.filter(|l| l.truth_ned_m[0].is_finite()) {
            rep.final_drift_slam_m = dist(l.slam_ned_m, l.truth_ned_m);
            rep.final_drift_dr_m = dist(l.dr_ned_m, l.truth_ned_m);
        }
        rep.estimated_current_mps = filt.current();
        let h = filt.health();
        rep.pd_repairs = h.pd_repairs;
        rep.fading_events = h.fading_events;
        SurveyResult { report: rep, map, track, fixes, fix_frames }
    }
}
