//! Path correction (spec C4, C5) and the closure consistency vote.
//!
//! - Drift model: the dead-reckoning error of a step grows with variance
//!   `q_dist * step_length + (vel_sigma * dt)^2` (DVL/compass drift per metre plus the DR's own
//!   reported velocity uncertainty, large in water-track mode).
//! - [`vote`]: each closure gets one vote from every other closure whose keyframes are near its
//!   own and whose shift agrees with it within the drift accumulated between them (chi-square
//!   gate); closures without support are rejected.
//! - [`solve_global`]: weighted least squares on the keyframe offsets, D_S = H_S dX_key with
//!   continuity rows (dX_k - dX_{k-1} = 0, weight 1/drift variance), closure rows
//!   (dX_b - dX_a = shift, weight the closure information) and the anchor dX_0 = 0.
//! - [`distribute`]: between keyframes, the offset change is spread over the steps uniformly or
//!   by the spring model. Spring: stiffness theta_i is the curvature of -ln p(X_i | X_{i-1})
//!   (1/variance of the step, plus the weak-association information); the minimum of the spring
//!   energy sum theta_i (v_i - v_{i-1})^2 under the keyframe constraint is the equal-force
//!   solution theta_i (v_i - v_{i-1}) = const, i.e. step corrections proportional to the step
//!   variance. (The paper writes the equal-energy form theta_i (v_i - v_{i-1})^2 = const; that is
//!   not the stationary point of its own energy, so the minimum-energy form is used here.)

use super::{NavSample, V2};
use nalgebra::{DMatrix, DVector, Matrix2};
use subnav_base::chi2::chi2_2_99;

#[derive(Debug, Clone, serde::Serialize)]
pub struct DriftConfig {
    /// Position random-walk variance per metre travelled (m^2/m), for the graph's continuity
    /// rows and search windows (conservative: the compass bias makes drift systematic).
    pub q_dist_m2_per_m: f64,
    /// The same for the spring stiffness, where only the ratio between steps matters: the DR's
    /// per-metre drift in bottom lock against its reported velocity sigma.
    pub q_dist_spring_m2_per_m: f64,
    /// Weight of the weak-association information in the spring stiffness (0 = off).
    pub assoc_weight: f64,
}

impl Default for DriftConfig {
    fn default() -> Self {
        Self { q_dist_m2_per_m: 0.01, q_dist_spring_m2_per_m: 0.001, assoc_weight: 1.0 }
    }
}

/// Variance of each step's DR error (`out[0] = 0`).
pub fn step_variances(nav: &[NavSample], q_dist_m2_per_m: f64) -> Vec<f64> {
    let mut v = vec![0.0; nav.len()];
    for i in 1..nav.len() {
        let (a, b) = (&nav[i - 1], &nav[i]);
        let d = ((b.north_m - a.north_m).powi(2) + (b.east_m - a.east_m).powi(2)).sqrt();
        let dt = (b.t_s - a.t_s).abs();
        let s = if b.vel_sigma_mps.is_finite() { b.vel_sigma_mps.max(0.0) } else { 0.0 };
        v[i] = q_dist_m2_per_m * d + (s * dt).powi(2) + 1e-9;
    }
    v
}

/// A loop closure between the keyframes of two submaps: e_b - e_a = shift.
#[derive(Debug, Clone)]
pub struct Closure {
    pub a: usize,
    pub b: usize,
    pub key_a: usize,
    pub key_b: usize,
    pub shift: V2,
    pub cov: Matrix2<f64>,
}

/// Prefix sums of the step variances, for the drift variance between two pings.
pub struct DriftIndex {
    cum: Vec<f64>,
}

impl DriftIndex {
    pub fn new(step_var: &[f64]) -> Self {
        let mut cum = Vec::with_capacity(step_var.len());
        let mut s = 0.0;
        for v in step_var {
            s += v;
            cum.push(s);
        }
        Self { cum }
    }
    pub fn between(&self, i: usize, j: usize) -> f64 {
        let (i, j) = (i.min(j), i.max(j));
        match (self.cum.get(i), self.cum.get(j)) {
            (Some(a), Some(b)) => b - a,
            _ => 0.0,
        }
    }
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct VoteConfig {
    /// Chi-square gate for two closures to agree (2 dof, 99 %: 9.2103, `subnav_base::chi2`).
    pub chi2_gate: f64,
    /// Only closures within this drift standard deviation of each other vote (m).
    pub max_neighbour_sigma_m: f64,
    pub min_votes: usize,
}

impl Default for VoteConfig {
    fn default() -> Self {
        Self { chi2_gate: chi2_2_99(), max_neighbour_sigma_m: 6.0, min_votes: 1 }
    }
}

/// Votes per closure and the accept mask.
pub fn vote(closures: &[Closure], drift: &DriftIndex, cfg: &VoteConfig) -> (Vec<usize>, Vec<bool>) {
    let mut votes = vec![0usize; closures.len()];
    for (x, cx) in closures.iter().enumerate() {
        for (y, cy) in closures.iter().enumerate() {
            if x == y {
                continue;
            }
            // Pair the ends so that a-ends are close and b-ends are close (either orientation).
            let d1 = drift.between(cx.key_a, cy.key_a) + drift.between(cx.key_b, cy.key_b);
            let d2 = drift.between(cx.key_a, cy.key_b) + drift.between(cx.key_b, cy.key_a);
            let (dv, other) = if d1 <= d2 { (d1, cy.shift) } else { (d2, -cy.shift) };
            if dv.sqrt() > cfg.max_neighbour_sigma_m {
                continue;
            }
            let s = cx.cov + cy.cov + Matrix2::identity() * dv;
            let r = cx.shift - other;
            if let Some(inv) = s.try_inverse() {
                if (r.transpose() * inv * r)[(0, 0)] <= cfg.chi2_gate {
                    votes[x] += 1;
                }
            }
        }
    }
    let ok = votes.iter().map(|v| *v >= cfg.min_votes).collect();
    (votes, ok)
}

/// Weighted least squares for the keyframe offsets. `keys` are ping indices (ascending, keys[0]
/// is the anchor with offset 0), `closures` refer to key indices (`a`, `b`).
pub fn solve_global(keys: &[usize], closures: &[Closure], drift: &DriftIndex) -> Option<Vec<V2>> {
    let k = keys.len();
    if k == 0 {
        return Some(vec![]);
    }
    let n = 2 * k;
    let mut h = DMatrix::<f64>::zeros(n, n);
    let mut g = DVector::<f64>::zeros(n);
    // Anchor.
    for d in 0..2 {
        h[(d, d)] += 1e8;
    }
    // Continuity: e_m - e_{m-1} = 0 with variance = drift between the keys.
    for m in 1..k {
        let w = 1.0 / drift.between(keys[m - 1], keys[m]).max(1e-6);
        for d in 0..2 {
            let (i, j) = (2 * (m - 1) + d, 2 * m + d);
            h[(i, i)] += w;
            h[(j, j)] += w;
            h[(i, j)] -= w;
            h[(j, i)] -= w;
        }
    }
    // Closures: e_b - e_a = shift, weight cov^-1.
    for c in closures {
        let w = c.cov.try_inverse()?;
        let (ia, ib) = (2 * c.a, 2 * c.b);
        for r in 0..2 {
            for s in 0..2 {
                h[(ib + r, ib + s)] += w[(r, s)];
                h[(ia + r, ia + s)] += w[(r, s)];
                h[(ib + r, ia + s)] -= w[(r, s)];
                h[(ia + r, ib + s)] -= w[(r, s)];
            }
        }
        let ws = w * c.shift;
        for r in 0..2 {
            g[ib + r] += ws[r];
            g[ia + r] -= ws[r];
        }
    }
    let x = h.cholesky()?.solve(&g);
    Some((0..k).map(|m| V2::new(x[2 * m], x[2 * m + 1])).collect())
}

/// Closures whose normalized residual after the global solve exceeds `chi2` are removed one at a
/// time (worst first) and the solve repeated. Returns the offsets and the kept mask.
pub fn solve_robust(keys: &[usize], closures: &[Closure], drift: &DriftIndex, chi2: f64) -> Option<(Vec<V2>, Vec<bool>)> {
    let mut keep = vec![true; closures.len()];
    loop {
        let used: Vec<Closure> = closures.iter().zip(&keep).filter(|(_, k)| **k).map(|(c, _)| c.clone()).collect();
        let e = solve_global(keys, &used, drift)?;
        let mut worst = (0.0, None);
        for (idx, c) in closures.iter().enumerate() {
            if !keep[idx] {
                continue;
            }
            let r = e[c.b] - e[c.a] - c.shift;
            let m = c.cov.try_inverse().map_or(0.0, |w| (r.transpose() * w * r)[(0, 0)]);
            if m > worst.0 {
                worst = (m, Some(idx));
            }
        }
        match worst {
            (m, Some(idx)) if m > chi2 => keep[idx] = false,
            _ => return Some((e, keep)),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Distribution {
    Uniform,
    Spring,
}

/// Per-ping offsets from keyframe offsets. `step_var[i]` is the variance of step (i-1 -> i),
/// `extra_stiffness[i]` added information on that step (weak association), keys ascending.
/// Before the first key the offset ramps from 0 at ping 0; after the last key it stays constant.
pub fn distribute(
    n: usize,
    keys: &[usize],
    key_e: &[V2],
    step_var: &[f64],
    extra_stiffness: Option<&[f64]>,
    mode: Distribution,
) -> Vec<V2> {
    let mut out = vec![V2::zeros(); n];
    if n == 0 {
        return out;
    }
    let mut kk: Vec<(usize, V2)> = keys.iter().copied().zip(key_e.iter().copied()).filter(|(k, _)| *k < n).collect();
    if kk.first().is_none_or(|f| f.0 != 0) {
        kk.insert(0, (0, V2::zeros()));
    }
    let weight = |i: usize| -> f64 {
        match mode {
            Distribution::Uniform => 1.0,
            Distribution::Spring => {
                let v = step_var.get(i).copied().unwrap_or(1.0).max(1e-12);
                let theta = 1.0 / v + extra_stiffness.and_then(|s| s.get(i)).copied().unwrap_or(0.0).max(0.0);
                1.0 / theta
            }
        }
    };
    for w in kk.windows(2) {
        let ((p0, e0), (p1, e1)) = (w[0], w[1]);
        let total: f64 = (p0 + 1..=p1).map(weight).sum();
        let mut acc = 0.0;
        out[p0] = e0;
        for i in p0 + 1..=p1 {
            acc += weight(i);
            let f = if total > 0.0 { acc / total } else { 1.0 };
            out[i] = e0 + (e1 - e0) * f;
        }
    }
    if let Some(&(pl, el)) = kk.last() {
        for o in out.iter_mut().skip(pl) {
            *o = el;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn global_solution_matches_the_analytic_three_keyframe_case() {
        // Anchor e0 = 0; continuity weights w1 (e1 - e0), w2 (e2 - e1); closure e2 - e0 = D with
        // weight wc. Minimising w1 e1^2 + w2 (e2 - e1)^2 + wc (e2 - D)^2 gives
        // e2 = wc D / (wc + w12) with w12 = w1 w2 / (w1 + w2), e1 = e2 w2 / (w1 + w2).
        let step_var = vec![0.0, 2.0, 0.5, 1.5, 0.5]; // pings 0..4, keys at 0, 2, 4
        let drift = DriftIndex::new(&step_var);
        let keys = [0, 2, 4];
        let (v1, v2) = (drift.between(0, 2), drift.between(2, 4));
        assert!((v1 - 2.5).abs() < 1e-12 && (v2 - 2.0).abs() < 1e-12);
        let (w1, w2, wc) = (1.0 / v1, 1.0 / v2, 1.0 / 0.25);
        let d = V2::new(3.0, -1.5);
        let c = Closure { a: 0, b: 2, key_a: 0, key_b: 4, shift: d, cov: Matrix2::identity() * 0.25 };
        let e = solve_global(&keys, &[c], &drift).unwrap();
        let w12 = w1 * w2 / (w1 + w2);
        let e2 = d * (wc / (wc + w12));
        let e1 = e2 * (w2 / (w1 + w2));
        assert!(e[0].norm() < 1e-6);
        assert!((e[1] - e1).norm() < 1e-6, "{:?} vs {e1:?}", e[1]);
        assert!((e[2] - e2).norm() < 1e-6, "{:?} vs {e2:?}", e[2]);
    }

    #[test]
    fn spring_distributes_in_proportion_to_step_variance_uniform_evenly() {
        let keys = [0, 4];
        let ke = [V2::zeros(), V2::new(8.0, 0.0)];
        let var = [0.0, 1.0, 3.0, 0.0 + 1e-12, 4.0];
        let s = distribute(6, &keys, &ke, &var, None, Distribution::Spring);
        let want = [0.0, 1.0, 4.0, 4.0, 8.0, 8.0];
        for (a, b) in s.iter().zip(want) {
            assert!((a.x - b).abs() < 1e-6, "{s:?}");
        }
        let u = distribute(6, &keys, &ke, &var, None, Distribution::Uniform);
        for (i, a) in u.iter().enumerate() {
            assert!((a.x - [0.0, 2.0, 4.0, 6.0, 8.0, 8.0][i]).abs() < 1e-12);
        }
        // The spring solution has the lower energy sum (v_i - v_{i-1})^2 / var_i.
        let energy = |v: &[V2]| (1..5).map(|i| (v[i] - v[i - 1]).norm_squared() / var[i].max(1e-12)).sum::<f64>();
        let ones = [0.0, 1.0, 1.0, 1.0, 1.0];
        let uni = distribute(6, &keys, &ke, &ones, None, Distribution::Spring);
        assert!((energy(&s) - 64.0 / 8.0).abs() < 1e-6 && energy(&s) <= energy(&uni));
        // Extra stiffness on a step takes correction away from it.
        let stiff = [0.0, 0.0, 1e9, 0.0, 0.0];
        let s2 = distribute(6, &keys, &ke, &var, Some(&stiff), Distribution::Spring);
        assert!((s2[2].x - s2[1].x).abs() < 1e-6);
    }

    #[test]
    fn voting_keeps_consistent_closures_and_rejects_an_outlier() {
        let step_var = vec![0.1; 1000];
        let drift = DriftIndex::new(&step_var);
        let mk = |a, b, ka, kb, s: V2| Closure { a, b, key_a: ka, key_b: kb, shift: s, cov: Matrix2::identity() * 0.25 };
        let cs = vec![
            mk(1, 10, 100, 800, V2::new(5.0, 2.0)),
            mk(2, 11, 150, 760, V2::new(5.3, 1.8)),
            mk(3, 12, 200, 700, V2::new(4.8, 2.4)),
            mk(2, 10, 160, 790, V2::new(-12.0, 9.0)), // false closure among them
            mk(5, 20, 400, 990, V2::new(0.0, 0.0)),   // isolated: nobody nearby to support it
        ];
        let (votes, ok) = vote(&cs, &drift, &VoteConfig::default());
        assert_eq!(ok, vec![true, true, true, false, false], "votes {votes:?}");
    }
}
