//! Scoring of the online mapper ([`crate::live`]) against a simulation's truth, outside the
//! mapper (as OpenVINS's `ov_eval` scores its estimator): the mapper runs on images and the
//! head's solution alone and reports what it did as [`MapEvent`]s; this module takes those
//! events with the truth of the frame each came from and counts the recognitions that were of
//! the right place.
//!
//! Definitions: a node's truth is the truth of the frame that placed it; a recognition (or an
//! appearance-only match) is **correct** when the frame's truth is within `correct_radius_m` of
//! the node's; a recognition attempt is an **opportunity** when some node old enough to be a
//! candidate (`LiveConfig::min_revisit_s`) has its truth within `opportunity_radius_m` of the
//! frame's. Precision: correct / recognitions; recall: correct recognitions at opportunities /
//! opportunities.

use serde::Serialize;

use crate::live::{CameraFrame, FrameOutcome, LiveConfig, LiveMapper, MapEvent};

/// The scoring's radii.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MapScoreConfig {
    /// A recognition is correct within this of the node's truth (m).
    pub correct_radius_m: f64,
    /// An opportunity is a recognition attempt within this of some candidate node's truth (m).
    pub opportunity_radius_m: f64,
}

impl Default for MapScoreConfig {
    fn default() -> Self {
        MapScoreConfig { correct_radius_m: 3.0, opportunity_radius_m: 2.0 }
    }
}

/// The map's figures against the truth.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct MapScore {
    /// Appearance-only matches (the nearest node overall below the threshold) that were correct.
    pub appearance_correct: u64,
    /// Gate refusals of a correct appearance match (what the gate costs in recall).
    pub gate_refusals_correct: u64,
    /// Recognitions, and the correct ones.
    pub recognitions: u64,
    pub correct: u64,
    pub precision: Option<f64>,
    pub opportunities: u64,
    pub recalled: u64,
    pub recall: Option<f64>,
}

/// Scores a mapper's events; feed it every event with the truth of the frame it came from.
#[derive(Debug, Clone)]
pub struct MapScorer {
    cfg: MapScoreConfig,
    min_age_us: u64,
    /// Per node: creation time and truth then (finite, or none).
    nodes: Vec<(u64, Option<[f64; 2]>)>,
    /// The current recognition attempt: its time and whether it is an opportunity.
    attempt: Option<(u64, bool)>,
    score: MapScore,
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

impl MapScorer {
    /// A scorer for a mapper configured with `live` (its candidate age).
    pub fn new(live: &LiveConfig, cfg: MapScoreConfig) -> Self {
        MapScorer {
            cfg,
            min_age_us: (live.min_revisit_s.max(0.0) * 1e6) as u64,
            nodes: Vec::new(),
            attempt: None,
            score: MapScore::default(),
        }
    }

    /// The truth at node `id`'s placement (None: unknown or never placed).
    pub fn node_truth(&self, id: usize) -> Option<[f64; 2]> {
        self.nodes.get(id).and_then(|n| n.1)
    }

    fn correct(&self, node: usize, truth: Option<[f64; 2]>) -> Option<bool> {
        let nt = self.node_truth(node)?;
        Some(dist(truth?, nt) < self.cfg.correct_radius_m)
    }

    /// One event of the frame whose truth (N, E, m) is `frame_truth_ne_m`.
    pub fn on_event(&mut self, e: &MapEvent, frame_truth_ne_m: Option<[f64; 2]>) {
        let truth = frame_truth_ne_m.filter(|p| p.iter().all(|x| x.is_finite()));
        match *e {
            MapEvent::NodePlaced { node, t_us } => {
                if self.nodes.len() <= node {
                    self.nodes.resize(node + 1, (u64::MAX, None));
                }
                self.nodes[node] = (t_us, truth);
            }
            MapEvent::Attempt { t_us } => {
                let opportunity = truth.is_some_and(|tr| {
                    self.nodes.iter().any(|&(created, nt)| {
                        created.saturating_add(self.min_age_us) <= t_us && nt.is_some_and(|nt| dist(tr, nt) < self.cfg.opportunity_radius_m)
                    })
                });
                self.attempt = Some((t_us, opportunity));
                self.score.opportunities += u64::from(opportunity);
            }
            MapEvent::AppearanceMatch { node, gate_refused, .. } => {
                let ok = self.correct(node, truth) == Some(true);
                self.score.appearance_correct += u64::from(ok);
                self.score.gate_refusals_correct += u64::from(ok && gate_refused);
            }
            MapEvent::Recognised { node, t_us } => {
                let ok = self.correct(node, truth) == Some(true);
                let opportunity = self.attempt.is_some_and(|(t, o)| t == t_us && o);
                let s = &mut self.score;
                s.recognitions += 1;
                s.correct += u64::from(ok);
                s.recalled += u64::from(ok && opportunity);
            }
        }
        let s = &mut self.score;
        s.precision = (s.recognitions > 0).then(|| s.correct as f64 / s.recognitions as f64);
        s.recall = (s.opportunities > 0).then(|| s.recalled as f64 / s.opportunities as f64);
    }

    pub fn score(&self) -> MapScore {
        self.score.clone()
    }
}

/// A mapper with its scorer: frames go in with their truth (simulations and tests).
pub struct ScoredMapper {
    pub mapper: LiveMapper,
    pub scorer: MapScorer,
}

impl ScoredMapper {
    pub fn new(live: LiveConfig) -> Self {
        ScoredMapper { scorer: MapScorer::new(&live, MapScoreConfig::default()), mapper: LiveMapper::new(live) }
    }

    /// [`LiveMapper::on_frame`], its events scored against `truth_ne_m` (the frame's truth).
    pub fn on_frame(&mut self, frame: &CameraFrame, truth_ne_m: Option<[f64; 2]>) -> FrameOutcome {
        let scorer = &mut self.scorer;
        self.mapper.on_frame_observed(frame, &mut |e| scorer.on_event(&e, truth_ne_m))
    }
}

impl ScoredMapper {
    /// The map's figures against the truth so far.
    pub fn score(&self) -> MapScore {
        self.scorer.score()
    }
}

impl std::ops::Deref for ScoredMapper {
    type Target = LiveMapper;
    fn deref(&self) -> &LiveMapper {
        &self.mapper
    }
}

impl std::ops::DerefMut for ScoredMapper {
    fn deref_mut(&mut self) -> &mut LiveMapper {
        &mut self.mapper
    }
}
