//! The LMNN optimiser: target neighbours, exact active-set impostors, loss and gradient, and the
//! step-size-adapting gradient descent (see the module doc of [`super`]).

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

/// Tuning; the defaults are metric-learn 0.7.0's.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LmnnConfig {
    /// Target neighbours per sample.
    pub k: usize,
    pub min_iter: usize,
    pub max_iter: usize,
    /// Initial learning rate.
    pub learn_rate: f64,
    /// Weight of the pull term (the push term gets `1 - regularization`).
    pub regularization: f64,
    /// Stop when the objective changes by less than this (after `min_iter`).
    pub convergence_tol: f64,
    /// Relative distance budget of the impostor active set (0 = full scan every evaluation).
    pub active_set_eps: f64,
}

impl Default for LmnnConfig {
    fn default() -> Self {
        Self { k: 3, min_iter: 50, max_iter: 1000, learn_rate: 1e-7, regularization: 0.5, convergence_tol: 1e-3, active_set_eps: 0.2 }
    }
}

/// Why a fit was refused.
#[derive(Debug, Clone, PartialEq)]
pub enum LmnnError {
    /// Fewer than two samples, or rows and labels of different lengths, or no features.
    Shape(String),
    /// A feature is NaN or infinite.
    NonFinite {
        row: usize,
        col: usize,
    },
    /// A class has fewer than `k + 1` samples (it needs `k` target neighbours besides itself).
    SmallClass {
        label: i64,
        count: usize,
        k: usize,
    },
    /// Only one class: there is nothing to separate.
    OneClass,
    BadConfig(String),
}

impl std::fmt::Display for LmnnError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LmnnError::Shape(s) => write!(f, "bad training data shape: {s}"),
            LmnnError::NonFinite { row, col } => write!(f, "feature {col} of sample {row} is not finite"),
            LmnnError::SmallClass { label, count, k } => {
                write!(f, "class {label} has {count} samples; k = {k} target neighbours need at least {}", k + 1)
            }
            LmnnError::OneClass => write!(f, "all samples have the same label; LMNN needs at least two classes"),
            LmnnError::BadConfig(s) => write!(f, "bad LMNN configuration: {s}"),
        }
    }
}

impl std::error::Error for LmnnError {}

/// Outcome of a fit.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FitReport {
    pub iterations: usize,
    pub converged: bool,
    pub objective: f64,
    pub active_triplets: usize,
    /// Loss/gradient evaluations (accepted and retried steps).
    pub evaluations: usize,
    /// Full impostor scans (active-set rebuilds).
    pub full_scans: usize,
}

/// Data laid out for the solver: `xt` is `d x n` (one sample per column, contiguous).
struct Problem {
    xt: DMatrix<f64>,
    x: DMatrix<f64>,
    labels: Vec<usize>,
    /// `targets[i * k + t]`.
    targets: Vec<usize>,
    k: usize,
    reg: f64,
    /// Pull term `sum_{i, j~>i} (x_i - x_j)(x_i - x_j)^T`.
    pull: DMatrix<f64>,
}

/// Candidate impostor pairs `(a, b)`, `a < b`, different labels, valid while
/// `||(L - l_ref) l_ref^-1||_F <= eps` (an upper bound of the spectral norm: then
/// `| ||L v|| - ||l_ref v|| | <= eps ||l_ref v||` for every `v`).
struct ActiveSet {
    pairs: Vec<(u32, u32)>,
    l_ref: DMatrix<f64>,
    l_ref_inv: Option<DMatrix<f64>>,
    eps: f64,
}

struct Eval {
    grad: DMatrix<f64>,
    objective: f64,
    active: usize,
}

/// Squared distance between columns `a` and `b` (column-major storage: contiguous slices).
fn sq_dist_cols(m: &DMatrix<f64>, a: usize, b: usize) -> f64 {
    let d = m.nrows();
    let s = m.as_slice();
    let (ca, cb) = (&s[a * d..(a + 1) * d], &s[b * d..(b + 1) * d]);
    let mut acc = 0.0;
    for (x, y) in ca.iter().zip(cb) {
        acc += (x - y) * (x - y);
    }
    acc
}

/// Squared distances between all columns of `m` (n x n), via the Gram matrix.
fn pairwise_sq(m: &DMatrix<f64>) -> DMatrix<f64> {
    let gram = m.transpose() * m;
    let n = m.ncols();
    let norms: Vec<f64> = (0..n).map(|i| gram[(i, i)]).collect();
    DMatrix::from_fn(n, n, |i, j| (norms[i] + norms[j] - 2.0 * gram[(i, j)]).max(0.0))
}

/// Weighted sum of outer products `sum w (x_a - x_b)(x_a - x_b)^T` as `X Lap X^T`.
/// `xt` is `d x n`, `x` the same data `n x d`.
fn sum_outer(xt: &DMatrix<f64>, x_nd: &DMatrix<f64>, edges: &[(usize, usize, f64)]) -> DMatrix<f64> {
    let d = xt.nrows();
    let n = xt.ncols();
    // Laplacian: degree (diagonal) and off-diagonal weights, then Y = X Lap column by column.
    let mut deg = vec![0.0; n];
    for &(a, b, w) in edges {
        deg[a] += w;
        deg[b] += w;
    }
    let x = xt.as_slice();
    let mut y = DMatrix::<f64>::zeros(d, n);
    {
        let ys = y.as_mut_slice();
        for (i, &g) in deg.iter().enumerate() {
            if g != 0.0 {
                for r in 0..d {
                    ys[i * d + r] = g * x[i * d + r];
                }
            }
        }
        for &(a, b, w) in edges {
            for r in 0..d {
                ys[a * d + r] -= w * x[b * d + r];
                ys[b * d + r] -= w * x[a * d + r];
            }
        }
    }
    y * x_nd
}

impl Problem {
    fn new(x: &DMatrix<f64>, labels: &[usize], k: usize, reg: f64) -> Self {
        let xt = x.transpose();
        let n = xt.ncols();
        let mut targets = vec![0usize; n * k];
        let nclass = labels.iter().max().map_or(0, |m| m + 1);
        for c in 0..nclass {
            let idx: Vec<usize> = (0..n).filter(|&i| labels[i] == c).collect();
            for &i in &idx {
                let mut cand: Vec<(f64, usize)> = idx.iter().filter(|&&j| j != i).map(|&j| (sq_dist_cols(&xt, i, j), j)).collect();
                cand.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                for t in 0..k {
                    targets[i * k + t] = cand[t].1;
                }
            }
        }
        let edges: Vec<(usize, usize, f64)> =
            (0..n).flat_map(|i| (0..k).map(move |t| (i, t))).map(|(i, t)| (i, targets[i * k + t], 1.0)).collect();
        let pull = sum_outer(&xt, x, &edges);
        Problem { xt, x: x.clone(), labels: labels.to_vec(), targets, k, reg, pull }
    }

    /// Max target distance per sample under `lx`.
    fn target_dists(&self, lx: &DMatrix<f64>) -> Vec<f64> {
        (0..self.xt.ncols() * self.k).map(|it| sq_dist_cols(lx, it / self.k, self.targets[it])).collect()
    }

    fn build_active_set(&self, l: &DMatrix<f64>, lx: &DMatrix<f64>, tdist: &[f64], eps: f64) -> ActiveSet {
        let n = self.xt.ncols();
        let k = self.k;
        let far: Vec<f64> = (0..n).map(|i| tdist[i * k..(i + 1) * k].iter().cloned().fold(0.0, f64::max)).collect();
        let l_ref_inv = l.clone().try_inverse().filter(|m| m.iter().all(|v| v.is_finite()));
        let eps = if l_ref_inv.is_some() { eps } else { 0.0 };
        let (lo, hi) = ((1.0 - eps).powi(2), (1.0 + eps).powi(2));
        let d2 = pairwise_sq(lx);
        let mut pairs = Vec::new();
        for b in 0..n {
            for a in 0..b {
                if self.labels[a] != self.labels[b] && lo * d2[(a, b)] < 1.0 + hi * far[a].max(far[b]) {
                    pairs.push((a as u32, b as u32));
                }
            }
        }
        ActiveSet { pairs, l_ref: l.clone(), l_ref_inv, eps }
    }

    fn eval(&self, l: &DMatrix<f64>, set: &mut Option<ActiveSet>, eps_budget: f64, scans: &mut usize) -> Eval {
        let lx = l * &self.xt;
        let k = self.k;
        let tdist = self.target_dists(&lx);
        let valid = set.as_ref().is_some_and(|s| s.l_ref_inv.as_ref().is_some_and(|inv| ((l - &s.l_ref) * inv).norm() <= s.eps));
        if !valid {
            *set = Some(self.build_active_set(l, &lx, &tdist, eps_budget));
            *scans += 1;
        }
        let Some(s) = set.as_ref() else { unreachable!("active set built above") };
        // Active triplets: (i, j~>i, l) with d(i, l) < 1 + d(i, j).
        let mut edges: Vec<(usize, usize, f64)> = Vec::new();
        let mut active = 0usize;
        for &(a, b) in &s.pairs {
            let (a, b) = (a as usize, b as usize);
            let dab = sq_dist_cols(&lx, a, b);
            for (i, other) in [(a, b), (b, a)] {
                let mut cnt = 0usize;
                for t in 0..k {
                    if dab < 1.0 + tdist[i * k + t] {
                        edges.push((i, self.targets[i * k + t], 1.0));
                        cnt += 1;
                    }
                }
                if cnt > 0 {
                    edges.push((i, other, -(cnt as f64)));
                    active += cnt;
                }
            }
        }
        let push = sum_outer(&self.xt, &self.x, &edges);
        let g = &self.pull * self.reg + push * (1.0 - self.reg);
        let lg = l * g;
        let objective = active as f64 * (1.0 - self.reg) + lg.dot(l);
        Eval { grad: lg * 2.0, objective, active }
    }
}

/// Map labels to 0..C (sorted unique); returns (indices, unique labels).
pub(crate) fn encode_labels(y: &[i64]) -> (Vec<usize>, Vec<i64>) {
    let mut uniq: Vec<i64> = y.to_vec();
    uniq.sort_unstable();
    uniq.dedup();
    let idx = y.iter().map(|v| uniq.binary_search(v).unwrap_or(0)).collect();
    (idx, uniq)
}

/// Learn `L` (d x d) on samples `x` (n x d, one row per sample) with labels `y`.
pub fn fit(x: &DMatrix<f64>, y: &[i64], cfg: &LmnnConfig) -> Result<(DMatrix<f64>, FitReport), LmnnError> {
    let (n, d) = x.shape();
    if n < 2 || d == 0 || y.len() != n {
        return Err(LmnnError::Shape(format!("{n} samples x {d} features, {} labels", y.len())));
    }
    if let Some((idx, _)) = x.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(LmnnError::NonFinite { row: idx % n, col: idx / n });
    }
    // Each setting checked on its own, so the message names it (not a dump of the whole config).
    let checks = [
        (cfg.k >= 1, format!("k must be at least 1, got {}", cfg.k)),
        (cfg.learn_rate > 0.0 && cfg.learn_rate.is_finite(), format!("learn_rate must be > 0, got {}", cfg.learn_rate)),
        ((0.0..=1.0).contains(&cfg.regularization), format!("regularization must be in 0..=1, got {}", cfg.regularization)),
        (cfg.max_iter >= 2, format!("max_iter must be at least 2, got {}", cfg.max_iter)),
        ((0.0..1.0).contains(&cfg.active_set_eps), format!("active_set_eps must be in [0, 1), got {}", cfg.active_set_eps)),
    ];
    if let Some((_, msg)) = checks.into_iter().find(|(ok, _)| !ok) {
        return Err(LmnnError::BadConfig(msg));
    }
    let (labels, uniq) = encode_labels(y);
    if uniq.len() < 2 {
        return Err(LmnnError::OneClass);
    }
    for (c, &lab) in uniq.iter().enumerate() {
        let count = labels.iter().filter(|&&l| l == c).count();
        if count < cfg.k + 1 {
            return Err(LmnnError::SmallClass { label: lab, count, k: cfg.k });
        }
    }
    let prob = Problem::new(x, &labels, cfg.k, cfg.regularization);
    let mut set = None;
    let mut scans = 0;
    let mut evals = 1;
    let mut l = DMatrix::<f64>::identity(d, d);
    let mut cur = prob.eval(&l, &mut set, cfg.active_set_eps, &mut scans);
    let mut lr = cfg.learn_rate;
    let mut it = 1;
    let mut converged = false;
    for i in 2..cfg.max_iter {
        it = i;
        let (l_next, next, delta) = loop {
            let l_next = &l - &cur.grad * lr;
            let next = prob.eval(&l_next, &mut set, cfg.active_set_eps, &mut scans);
            evals += 1;
            let delta = next.objective - cur.objective;
            // `!(delta <= 0)` also rejects a NaN objective; the rate cannot underflow forever.
            if (delta.is_nan() || delta > 0.0) && lr > f64::MIN_POSITIVE {
                lr /= 2.0;
            } else {
                break (l_next, next, delta);
            }
        };
        l = l_next;
        cur = next;
        lr *= 1.01;
        if i > cfg.min_iter && delta.abs() < cfg.convergence_tol {
            converged = true;
            break;
        }
    }
    Ok((
        l,
        FitReport {
            iterations: it,
            converged,
            objective: cur.objective,
            active_triplets: cur.active,
            evaluations: evals,
            full_scans: scans,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The active set gives the same objective and gradient as a full scan.
    #[test]
    fn active_set_matches_full_scan() {
        let n = 60;
        let x = DMatrix::from_fn(n, 3, |i, j| ((i * 7 + j * 13) % 17) as f64 / 4.0 + (i % 3) as f64 * 0.3 * j as f64);
        let labels: Vec<usize> = (0..n).map(|i| i % 3).collect();
        let p = Problem::new(&x, &labels, 3, 0.5);
        let l0 = DMatrix::<f64>::identity(3, 3);
        let mut set = None;
        let mut scans = 0;
        let _ = p.eval(&l0, &mut set, 0.2, &mut scans);
        let l1 = DMatrix::from_row_slice(3, 3, &[1.05, 0.02, 0.0, -0.03, 0.97, 0.04, 0.0, 0.01, 1.02]);
        let a = p.eval(&l1, &mut set, 0.2, &mut scans);
        assert_eq!(scans, 1, "l1 is within the budget: no rebuild");
        let mut full = None;
        let b = p.eval(&l1, &mut full, 0.0, &mut scans);
        assert_eq!(a.active, b.active);
        assert!((a.objective - b.objective).abs() < 1e-9);
        assert!((a.grad - b.grad).norm() < 1e-9);
    }

    #[test]
    fn refuses_bad_input() {
        let x = DMatrix::from_row_slice(4, 1, &[0.0, 1.0, 2.0, f64::NAN]);
        assert!(matches!(fit(&x, &[0, 0, 1, 1], &LmnnConfig::default()), Err(LmnnError::NonFinite { row: 3, col: 0 })));
        let x = DMatrix::from_row_slice(4, 1, &[0.0, 1.0, 2.0, 3.0]);
        assert!(matches!(fit(&x, &[0, 0, 1, 1], &LmnnConfig::default()), Err(LmnnError::SmallClass { .. })));
        assert!(matches!(fit(&x, &[0, 0, 0, 0], &LmnnConfig { k: 1, ..LmnnConfig::default() }), Err(LmnnError::OneClass)));
        assert!(matches!(fit(&x, &[0, 0, 1], &LmnnConfig::default()), Err(LmnnError::Shape(_))));
    }
}
