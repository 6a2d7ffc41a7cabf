//! The topological map: nodes with their image samples (feature vectors) and a filter slot
//! holding their position, edges between nodes visited one after the other, and association of
//! a new image in the learned metric.

use nalgebra::DMatrix;
use serde::Serialize;

use crate::lmnn::{LmnnConfig, LmnnModel};
use crate::polar_image::N_FEATURES;

/// A place.
#[derive(Debug, Clone, Serialize)]
pub struct Node {
    pub id: usize,
    /// Slot in the SLAM filter state.
    pub slot: usize,
    pub created_t_s: f64,
    pub samples: Vec<[f64; N_FEATURES]>,
    /// Estimated position (N, E) and its covariance (NN, NE, EE), refreshed from the filter.
    pub pos_ned_m: [f64; 2],
    pub cov_m2: [f64; 3],
    /// Truth at creation (simulations only; for the evaluation, never used by the estimator).
    pub truth_ned_m: Option<[f64; 2]>,
    pub observations: u32,
    /// Ids of nodes merged into this one.
    pub merged: Vec<usize>,
}

impl Node {
    /// A node placed at `pos_ned_m` (N, E) with covariance `cov_m2` (NN, NE, EE) from its
    /// `samples`: no truth (the online mapper's nodes; a simulation adds it for its evaluation),
    /// no filter slot, not yet observed or merged.
    pub fn placed(id: usize, created_t_s: f64, samples: Vec<[f64; N_FEATURES]>, pos_ned_m: [f64; 2], cov_m2: [f64; 3]) -> Self {
        Node { id, slot: 0, created_t_s, samples, pos_ned_m, cov_m2, truth_ned_m: None, observations: 0, merged: Vec::new() }
    }
}

/// An edge: consecutive visits, or a merge.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
pub struct Edge {
    pub a: usize,
    pub b: usize,
}

/// Result of matching an image against the map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    pub node: usize,
    /// Nearest-sample distance in the learned metric (Euclidean in the mapped space).
    pub dist: f64,
}

#[derive(Debug, Default, Clone, Serialize)]
pub struct TopoMap {
    pub nodes: Vec<Node>,
    pub edges: Vec<Edge>,
    #[serde(skip)]
    pub model: Option<LmnnModel>,
    /// Appearance threshold in the learned metric (set at training).
    pub match_threshold: f64,
}

impl TopoMap {
    pub fn node(&self, id: usize) -> Option<&Node> {
        self.nodes.iter().find(|n| n.id == id)
    }

    pub fn node_mut(&mut self, id: usize) -> Option<&mut Node> {
        self.nodes.iter_mut().find(|n| n.id == id)
    }

    pub fn add_edge(&mut self, a: usize, b: usize) {
        if a == b {
            return;
        }
        let e = Edge { a: a.min(b), b: a.max(b) };
        if !self.edges.contains(&e) {
            self.edges.push(e);
        }
    }

    /// Fit LMNN on the node samples (label = node id) and set the appearance threshold to
    /// `threshold_factor` times the 90th percentile of each sample's distance to its nearest
    /// same-node sample. Nodes with fewer than `k + 1` samples are left out of the fit.
    pub fn train(&mut self, cfg: &LmnnConfig, threshold_factor: f64) -> anyhow::Result<()> {
        let rows: Vec<(&[f64; N_FEATURES], i64)> =
            self.nodes.iter().filter(|n| n.samples.len() > cfg.k).flat_map(|n| n.samples.iter().map(move |s| (s, n.id as i64))).collect();
        anyhow::ensure!(rows.len() >= 2 * (cfg.k + 1), "not enough node samples to learn a metric ({} samples)", rows.len());
        let x = DMatrix::from_fn(rows.len(), N_FEATURES, |r, c| rows[r].0[c]);
        let y: Vec<i64> = rows.iter().map(|r| r.1).collect();
        let model = LmnnModel::fit(&x, &y, cfg)?;
        let mapped = model.map(&x);
        let mut nn: Vec<f64> = (0..rows.len())
            .filter_map(|i| {
                (0..rows.len()).filter(|&j| j != i && y[j] == y[i]).map(|j| (mapped.row(i) - mapped.row(j)).norm()).min_by(f64::total_cmp)
            })
            .collect();
        nn.sort_by(f64::total_cmp);
        let p90 = nn.get((nn.len().saturating_sub(1)) * 9 / 10).copied().unwrap_or(1.0);
        self.match_threshold = p90 * threshold_factor;
        self.model = Some(model);
        Ok(())
    }

    /// Nodes ordered by their nearest-sample distance to `f` in the learned metric (all nodes,
    /// nearest first); empty before training.
    pub fn candidates(&self, f: &[f64; N_FEATURES]) -> Vec<Candidate> {
        let Some(model) = &self.model else { return Vec::new() };
        let q = model.map(&DMatrix::from_row_slice(1, N_FEATURES, f));
        let mut out: Vec<Candidate> = self
            .nodes
            .iter()
            .filter(|n| !n.samples.is_empty())
            .map(|n| {
                let xs = DMatrix::from_fn(n.samples.len(), N_FEATURES, |r, c| n.samples[r][c]);
                let m = model.map(&xs);
                let dist = m.row_iter().map(|r| (r - q.row(0)).norm()).fold(f64::INFINITY, f64::min);
                Candidate { node: n.id, dist }
            })
            .collect();
        out.sort_by(|a, b| a.dist.total_cmp(&b.dist));
        out
    }

    /// Mean over the samples of `a` of the nearest-sample distance to `b` (learned metric).
    pub fn node_distance(&self, a: usize, b: usize) -> Option<f64> {
        let model = self.model.as_ref()?;
        let (na, nb) = (self.node(a)?, self.node(b)?);
        if na.samples.is_empty() || nb.samples.is_empty() {
            return None;
        }
        let map = |n: &Node| model.map(&DMatrix::from_fn(n.samples.len(), N_FEATURES, |r, c| n.samples[r][c]));
        let (ma, mb) = (map(na), map(nb));
        let s: f64 = ma.row_iter().map(|ra| mb.row_iter().map(|rb| (ra - rb).norm()).fold(f64::INFINITY, f64::min)).sum();
        Some(s / ma.nrows() as f64)
    }
}
