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
    /// Budget of the impostor active set, relative to `||L_ref||_2`: the set is rebuilt once
    /// `||L - L_ref||_2` exceeds `active_set_eps ||L_ref||_2` (0 = full scan every evaluation).
    /// Any value gives the same triplets, only the speed changes.
    pub active_set_eps: f64,
}

impl Default for LmnnConfig {
    fn default() -> Self {
        Self { k: 3, min_iter: 50, max_iter: 1000, learn_rate: 1e-7, regularization: 0.5, convergence_tol: 1e-3, active_set_eps: 0.05 }
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
    labels: Vec<usize>,
    /// `targets[i * k + t]`.
    targets: Vec<usize>,
    k: usize,
    reg: f64,
    /// Pull term `sum_{i, j~>i} (x_i - x_j)(x_i - x_j)^T`.
    pull: DMatrix<f64>,
    /// Upper bounds of the input-space distances `||x_a - x_b||` (n x n, f32 rounded up).
    xdist: Vec<f32>,
    /// Per sample: the largest input distance to one of its targets.
    target_r: Vec<f64>,
}

/// Candidate impostors per anchor, valid while `delta_L = ||L - l_ref||_2 <= delta`: then for
/// every pair `||L v|| >= ||l_ref v|| - delta_L ||v||` (`v = x_a - x_b`, input space), so a triplet
/// `(a, j, b)` can only be active if `s_ref(a, b) - delta_L r(a, b) < sqrt(1 + far_L(a))`
/// (`s_ref = ||l_ref v||`, `r = ||v||`, `far_L(a)` the largest target distance of `a` at `L`).
///
/// For anchor `a` (CSR rows `start[a]..start[a + 1]`) the partners `b` of another class with
/// `s_ref - delta r < cover[a]`, sorted by `s_ref` ascending; `cover[a]` bounds
/// `sqrt(1 + far_L(a))` while the set is valid (checked at every evaluation). The scan of a row
/// stops at the first `s_ref >= radius + delta_L rmax[a]` (a prefix that is short right after a
/// rebuild and grows with `delta_L`), and a pair is measured only if its own bound lets it be
/// active. The bound is absolute, not relative
/// to `l_ref^-1`: LMNN on digits drives `L` close to singular, where a relative bound fails at
/// once.
struct ActiveSet {
    l_ref: DMatrix<f64>,
    delta: f64,
    start: Vec<usize>,
    partner: Vec<u32>,
    s_ref: Vec<f64>,
    r: Vec<f64>,
    cover: Vec<f64>,
    /// Per anchor: the largest `r` of its row.
    rmax: Vec<f64>,
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

/// An upper bound of the spectral norm of `a`: the smaller of `||a||_F` and
/// `||B^16||_F^(1/32)` with `B = a^T a` (`lambda_max(B)^16 <= ||B^16||_F <= d lambda_max(B)^16`, so
/// at most `d^(1/32)` above the true norm: 1.14 for d = 64; Frobenius alone can be `sqrt(d)` = 8
/// times too large). Computed by repeated squaring, normalised at each step; `4 d^3` flops.
fn spectral_norm_bound(a: &DMatrix<f64>) -> f64 {
    let fro = a.norm();
    if !(fro > 0.0) || !fro.is_finite() {
        return fro;
    }
    let mut b = a.transpose() * a;
    let s0 = b.norm();
    if !(s0 > 0.0) {
        return fro;
    }
    b /= s0;
    let mut log_lambda = s0.ln();
    let mut w = 1.0;
    for _ in 0..4 {
        b = &b * &b;
        let s = b.norm();
        if !(s > 0.0) || !s.is_finite() {
            break; // lambda of the normalised B is <= 1: the bound so far holds
        }
        w *= 0.5;
        log_lambda += w * s.ln();
        b /= s;
    }
    fro.min((0.5 * log_lambda).exp())
}

/// Weighted sum of outer products `sum w (x_a - x_b)(x_a - x_b)^T` as `X Lap X^T`, with the
/// Laplacian's nonzero columns only (`Y = X Lap` gathered into `d x m`, then one `Y X_m^T` GEMM
/// over the `m` samples that appear in an edge). `xt` is `d x n`.
fn sum_outer(xt: &DMatrix<f64>, edges: &[(usize, usize, f64)]) -> DMatrix<f64> {
    let d = xt.nrows();
    let n = xt.ncols();
    // Compact index of every sample in an edge, and its degree.
    let mut slot = vec![u32::MAX; n];
    let mut used: Vec<usize> = Vec::new();
    let mut deg: Vec<f64> = Vec::new();
    for &(a, b, w) in edges {
        for v in [a, b] {
            if slot[v] == u32::MAX {
                slot[v] = used.len() as u32;
                used.push(v);
                deg.push(0.0);
            }
            deg[slot[v] as usize] += w;
        }
    }
    let m = used.len();
    let x = xt.as_slice();
    let mut y = DMatrix::<f64>::zeros(d, m);
    let mut xm = DMatrix::<f64>::zeros(m, d);
    {
        let ys = y.as_mut_slice();
        for (s, (&v, &g)) in used.iter().zip(&deg).enumerate() {
            let xv = &x[v * d..(v + 1) * d];
            for r in 0..d {
                ys[s * d + r] = g * xv[r];
                xm[(s, r)] = xv[r];
            }
        }
        for &(a, b, w) in edges {
            let (sa, sb) = (slot[a] as usize, slot[b] as usize);
            for r in 0..d {
                ys[sa * d + r] -= w * x[b * d + r];
                ys[sb * d + r] -= w * x[a * d + r];
            }
        }
    }
    y * xm
}

/// Relative slack on every bound test (rounding of the Gram distances, the inverse, the norm).
const SLACK: f64 = 1e-9;

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
        let pull = sum_outer(&xt, &edges);
        let gram = x * &xt;
        let xdist: Vec<f32> = (0..n * n)
            .map(|ab| {
                let (a, b) = (ab / n, ab % n);
                let d2 = (gram[(a, a)] + gram[(b, b)] - 2.0 * gram[(a, b)]).max(0.0);
                // Rounded up: the Gram rounding plus the f32 cast.
                ((d2 + 1e-12 * (gram[(a, a)] + gram[(b, b)]) + 1e-300).sqrt() * (1.0 + 1e-6)) as f32
            })
            .collect();
        let target_r = (0..n).map(|a| (0..k).map(|t| xdist[a * n + targets[a * k + t]] as f64).fold(0.0, f64::max)).collect();
        Problem { xt, xdist, target_r, labels: labels.to_vec(), targets, k, reg, pull }
    }

    /// Target distances per (sample, target) under `lx`.
    fn target_dists(&self, lx: &DMatrix<f64>) -> Vec<f64> {
        (0..self.xt.ncols() * self.k).map(|it| sq_dist_cols(lx, it / self.k, self.targets[it])).collect()
    }

    /// Full scan at `l`: all cross-class squared distances from one Gram product `lx^T lx`.
    fn build_active_set(&self, l: &DMatrix<f64>, lx: &DMatrix<f64>, far: &[f64], eps: f64) -> ActiveSet {
        let n = self.xt.ncols();
        let delta = eps * spectral_norm_bound(l);
        let gram = lx.transpose() * lx;
        let norms: Vec<f64> = (0..n).map(|i| gram[(i, i)]).collect();
        // Rounding of `|a|^2 + |b|^2 - 2 a.b` is below ~4 d u (|a|^2 + |b|^2); 1e-12 max |.|^2 covers it.
        let round = 1e-12 * norms.iter().cloned().fold(0.0, f64::max) * (1.0 + lx.nrows() as f64 / 64.0);
        let g = gram.as_slice();
        let mut start = Vec::with_capacity(n + 1);
        let (mut partner, mut s_ref, mut r) = (Vec::new(), Vec::new(), Vec::new());
        let mut cover = Vec::with_capacity(n);
        let mut rmax = Vec::with_capacity(n);
        let mut row: Vec<(f64, f64, f64, u32)> = Vec::with_capacity(n);
        for a in 0..n {
            start.push(partner.len());
            let c = ((1.0 + far[a]).sqrt() + delta * self.target_r[a]) * (1.0 + SLACK);
            cover.push(c);
            row.clear();
            let col = &g[a * n..(a + 1) * n];
            for (b, &gab) in col.iter().enumerate() {
                if self.labels[b] != self.labels[a] {
                    let sr = (norms[a] + norms[b] - 2.0 * gab - round).max(0.0).sqrt();
                    let rab = self.xdist[a * n + b] as f64;
                    let kk = sr - delta * rab;
                    if kk < c {
                        row.push((kk, sr, rab, b as u32));
                    }
                }
            }
            // Sorted by the reference distance: at a later `L` the scan stops where
            // `s_ref - delta_L rmax >= radius`, a prefix that grows with `delta_L`.
            row.sort_unstable_by(|x, y| x.1.total_cmp(&y.1));
            rmax.push(row.iter().map(|e| e.2).fold(0.0, f64::max));
            for &(_, sr, rab, b) in &row {
                s_ref.push(sr);
                r.push(rab);
                partner.push(b);
            }
        }
        start.push(partner.len());
        ActiveSet { l_ref: l.clone(), delta, start, partner, s_ref, r, cover, rmax }
    }

    fn eval(&self, l: &DMatrix<f64>, set: &mut Option<ActiveSet>, eps_budget: f64, scans: &mut usize) -> Eval {
        let n = self.xt.ncols();
        let lx = l * &self.xt;
        let k = self.k;
        let tdist = self.target_dists(&lx);
        let far: Vec<f64> = (0..n).map(|i| tdist[i * k..(i + 1) * k].iter().cloned().fold(0.0, f64::max)).collect();
        // Radius per anchor at this `l` (sqrt of 1 + the largest target distance).
        let radius: Vec<f64> = far.iter().map(|f| (1.0 + f).sqrt() * (1.0 + SLACK)).collect();
        let bound = |s: &ActiveSet| -> Option<f64> {
            let dl = spectral_norm_bound(&(l - &s.l_ref)) * (1.0 + SLACK);
            (dl <= s.delta && radius.iter().zip(&s.cover).all(|(r, c)| r <= c)).then_some(dl)
        };
        let mut dl = if eps_budget > 0.0 { set.as_ref().and_then(bound) } else { None };
        if dl.is_none() {
            *set = (eps_budget > 0.0).then(|| self.build_active_set(l, &lx, &far, eps_budget));
            *scans += 1;
            dl = set.as_ref().map(|_| 0.0);
        }
        // Active triplets (a, j~>a, b): d(a, b) < 1 + d(a, j), b of another class.
        let mut edges: Vec<(usize, usize, f64)> = Vec::new();
        let mut tcount = vec![0usize; n * k];
        let mut active = 0usize;
        let mut visit = |a: usize, b: usize, edges: &mut Vec<(usize, usize, f64)>| {
            let dab = sq_dist_cols(&lx, a, b);
            let mut cnt = 0usize;
            for t in 0..k {
                if dab < 1.0 + tdist[a * k + t] {
                    tcount[a * k + t] += 1;
                    cnt += 1;
                }
            }
            if cnt > 0 {
                edges.push((a, b, -(cnt as f64)));
                active += cnt;
            }
        };
        match (set.as_ref(), dl) {
            (Some(s), Some(dl)) => {
                for a in 0..n {
                    let ra = radius[a];
                    let stop = ra + dl * s.rmax[a];
                    for idx in s.start[a]..s.start[a + 1] {
                        if s.s_ref[idx] >= stop {
                            break;
                        }
                        if s.s_ref[idx] - dl * s.r[idx] < ra {
                            visit(a, s.partner[idx] as usize, &mut edges);
                        }
                    }
                }
            }
            _ => {
                for a in 0..n {
                    for b in 0..n {
                        if self.labels[a] != self.labels[b] {
                            visit(a, b, &mut edges);
                        }
                    }
                }
            }
        }
        for (it, &c) in tcount.iter().enumerate() {
            if c > 0 {
                edges.push((it / k, self.targets[it], c as f64));
            }
        }
        let push = sum_outer(&self.xt, &edges);
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

    /// A whole fit with the active set follows the same path as full scans at every evaluation.
    #[test]
    fn fit_with_active_set_equals_full_scans() {
        let n = 90;
        let x =
            DMatrix::from_fn(n, 4, |i, j| (((i * 31 + j * 17) % 23) as f64 / 5.0).sin() * 2.0 + (i % 3) as f64 * 0.4 * (j as f64 - 1.5));
        let y: Vec<i64> = (0..n).map(|i| (i % 3) as i64).collect();
        let base = LmnnConfig { max_iter: 300, ..LmnnConfig::default() };
        let (la, ra) = fit(&x, &y, &LmnnConfig { active_set_eps: 0.5, ..base }).expect("fit");
        let (lb, rb) = fit(&x, &y, &LmnnConfig { active_set_eps: 0.0, ..base }).expect("fit");
        assert_eq!((ra.iterations, ra.evaluations, ra.active_triplets), (rb.iterations, rb.evaluations, rb.active_triplets));
        assert!(ra.full_scans < ra.evaluations / 4, "{ra:?}");
        assert_eq!(rb.full_scans, rb.evaluations);
        assert!((la - lb).norm() < 1e-9);
    }

    #[test]
    fn spectral_bound_is_an_upper_bound_and_tight() {
        let a = DMatrix::from_fn(6, 6, |i, j| ((i * 5 + j * 3) % 7) as f64 - 3.0 + if i == j { 0.5 } else { 0.0 });
        let sv = a.clone().singular_values().max();
        let b = spectral_norm_bound(&a);
        assert!(b >= sv * (1.0 - 1e-12) && b <= sv * 6f64.powf(1.0 / 32.0) * (1.0 + 1e-12), "{b} vs {sv}");
        assert!(b < a.norm());
        assert_eq!(spectral_norm_bound(&DMatrix::zeros(3, 3)), 0.0);
    }

    /// Local timing aid (not CI): `SUBNAV_LMNN_BENCH_CSV=standardised.csv cargo test --release -p subnav-topo bench_csv -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn bench_csv() {
        let path = std::env::var("SUBNAV_LMNN_BENCH_CSV").expect("SUBNAV_LMNN_BENCH_CSV");
        let (x, y) = crate::lmnn::model::read_csv(std::path::Path::new(&path)).expect("csv");
        let eps: f64 = std::env::var("SUBNAV_LMNN_EPS").ok().map_or(LmnnConfig::default().active_set_eps, |e| e.parse().expect("eps"));
        let t0 = std::time::Instant::now();
        let (_l, rep) = fit(&x, &y, &LmnnConfig { active_set_eps: eps, ..LmnnConfig::default() }).expect("fit");
        println!("eps {eps}: {:.3} s {rep:?}", t0.elapsed().as_secs_f64());
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
