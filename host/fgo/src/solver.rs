//! Batch Levenberg-Marquardt over all nodes of a graph, on a sparse Cholesky factorisation
//! (`nalgebra-sparse`, left-looking with symbolic analysis) of the damped normal equations
//! `(J^T J + lambda I) dx = -J^T r` built from whitened factor Jacobians. The damping schedule is
//! GTSAM's default (lambda 1e-5, x10 on a rejected step, /10 on an accepted one), so both stop at
//! the same optimum when run to tight tolerances. Also gives marginal covariances of single nodes
//! (block of the inverse information) for the gating test.

use nalgebra::{DMatrix, DVector, SMatrix};
use nalgebra_sparse::CscMatrix;
use nalgebra_sparse::factorization::CscCholesky;

use super::FgoError;
use super::factors::Factor;
use super::state::{NodeState, Tangent};

pub type Matrix15 = SMatrix<f64, 15, 15>;

#[derive(Debug, Clone, Copy)]
pub struct LmOptions {
    pub max_iterations: usize,
    /// Stop when the relative cost decrease of an accepted step is below this.
    pub relative_tol: f64,
    /// Stop when the absolute cost decrease is below this.
    pub absolute_tol: f64,
    pub lambda_initial: f64,
    pub lambda_max: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        Self { max_iterations: 100, relative_tol: 1e-10, absolute_tol: 1e-10, lambda_initial: 1e-5, lambda_max: 1e10 }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmReport {
    pub iterations: usize,
    pub initial_cost: f64,
    pub final_cost: f64,
    pub converged: bool,
}

fn states_of<'a>(nodes: &'a [NodeState], f: &Factor) -> Result<Vec<&'a NodeState>, FgoError> {
    f.nodes().into_iter().map(|i| nodes.get(i).ok_or_else(|| FgoError::Input(format!("factor refers to missing node {i}")))).collect()
}

/// `sum 0.5 |W r|^2`
pub fn total_cost(nodes: &[NodeState], factors: &[Factor]) -> Result<f64, FgoError> {
    let mut c = 0.0;
    for f in factors {
        c += f.cost(&states_of(nodes, f)?);
    }
    Ok(c)
}

/// Block sparsity of the information matrix of a factor set (15x15 blocks), with the CSC
/// pattern built once so that every LM iteration only refills values and refactors numerically.
struct System {
    n: usize,
    /// (row block, col block) -> index into `blocks`
    index: std::collections::HashMap<(usize, usize), usize>,
    /// value offset in the CSC value array of each block's (0, 0) entry, and its column stride
    block_offset: Vec<usize>,
    col_ptr: Vec<usize>,
    pattern: CscMatrix<f64>,
    diag_value_pos: Vec<usize>,
}

impl System {
    fn new(n: usize, factors: &[Factor]) -> Result<Self, FgoError> {
        let mut cols: Vec<Vec<usize>> = (0..n).map(|i| vec![i]).collect();
        for f in factors {
            let keys = f.nodes();
            for a in &keys {
                if *a >= n {
                    return Err(FgoError::Input(format!("factor refers to missing node {a}")));
                }
                for b in &keys {
                    cols[*b].push(*a);
                }
            }
        }
        for c in &mut cols {
            c.sort_unstable();
            c.dedup();
        }
        let mut col_ptr = Vec::with_capacity(15 * n + 1);
        let mut row_idx = Vec::new();
        let mut index = std::collections::HashMap::new();
        let mut block_offset = Vec::new();
        let mut diag_value_pos = Vec::with_capacity(15 * n);
        col_ptr.push(0);
        for (b, rows) in cols.iter().enumerate() {
            let col_len = rows.len() * 15;
            for c in 0..15 {
                let base = row_idx.len();
                for (k, a) in rows.iter().enumerate() {
                    if c == 0 {
                        index.insert((*a, b), block_offset.len());
                        block_offset.push(base + 15 * k);
                    }
                    if *a == b {
                        diag_value_pos.push(base + 15 * k + c);
                    }
                    for r in 0..15 {
                        row_idx.push(15 * a + r);
                    }
                }
                debug_assert_eq!(row_idx.len() - base, col_len);
                col_ptr.push(row_idx.len());
            }
        }
        let nnz = row_idx.len();
        let pattern = CscMatrix::try_from_csc_data(15 * n, 15 * n, col_ptr.clone(), row_idx, vec![0.0; nnz])
            .map_err(|e| FgoError::Numeric(format!("sparsity pattern: {e}")))?;
        Ok(Self { n, index, block_offset, col_ptr, pattern, diag_value_pos })
    }

    /// Fill `J^T J` (values, CSC order) and `J^T r`.
    fn fill(&self, nodes: &[NodeState], factors: &[Factor], values: &mut [f64], g: &mut DVector<f64>) -> Result<(), FgoError> {
        values.iter_mut().for_each(|v| *v = 0.0);
        g.fill(0.0);
        for f in factors {
            let keys = f.nodes();
            let lin = f.linearize(&states_of(nodes, f)?);
            if !lin.residual.iter().all(|x| x.is_finite()) || !lin.jacobians.iter().all(|j| j.iter().all(|x| x.is_finite())) {
                return Err(FgoError::Numeric(format!("factor on nodes {keys:?} evaluated to NaN/inf")));
            }
            for (a, ja) in keys.iter().zip(lin.jacobians.iter()) {
                let mut seg = g.rows_mut(15 * a, 15);
                seg += ja.transpose() * &lin.residual;
                for (b, jb) in keys.iter().zip(lin.jacobians.iter()) {
                    let hab = ja.transpose() * jb;
                    let id = self.index[&(*a, *b)];
                    let off = self.block_offset[id];
                    let stride = self.col_ptr[15 * b + 1] - self.col_ptr[15 * b];
                    for c in 0..15 {
                        let col = &mut values[off + c * stride..off + c * stride + 15];
                        for (r, v) in col.iter_mut().enumerate() {
                            *v += hab[(r, c)];
                        }
                    }
                }
            }
        }
        Ok(())
    }

    fn matrix(&self, values: &[f64], damping: f64) -> CscMatrix<f64> {
        let mut m = self.pattern.clone();
        m.values_mut().copy_from_slice(values);
        if damping != 0.0 {
            let v = m.values_mut();
            for p in &self.diag_value_pos {
                v[*p] += damping;
            }
        }
        m
    }
}

/// Gauss-Newton normal equations: information `H = J^T J + damping I` (sparse, full symmetric)
/// and `g = J^T r`.
pub fn normal_equations(nodes: &[NodeState], factors: &[Factor], damping: f64) -> Result<(CscMatrix<f64>, DVector<f64>), FgoError> {
    let sys = System::new(nodes.len(), factors)?;
    let mut values = vec![0.0; sys.pattern.nnz()];
    let mut g = DVector::zeros(15 * sys.n);
    sys.fill(nodes, factors, &mut values, &mut g)?;
    Ok((sys.matrix(&values, damping), g))
}

fn factor(h: &CscMatrix<f64>) -> Result<CscCholesky<f64>, FgoError> {
    CscCholesky::factor(h).map_err(|e| FgoError::Numeric(format!("information matrix not positive definite ({e:?})")))
}

type Vector15 = nalgebra::SVector<f64, 15>;

/// Information of a chain graph (every factor on one node or two consecutive nodes: the
/// INS graphs here), block tridiagonal: diagonal blocks `H_ii`, sub-diagonal `H_{i+1,i}`, and
/// `g = J^T r`. Solved by a block Cholesky on 15x15 fixed-size blocks (no fill on a chain), which
/// is several times faster than the general sparse Cholesky on these problems.
struct Chain {
    diag: Vec<Matrix15>,
    sub: Vec<Matrix15>,
    g: Vec<Vector15>,
}

fn is_chain(n: usize, factors: &[Factor]) -> bool {
    n >= 1
        && factors.iter().all(|f| {
            let k = f.nodes();
            k.iter().all(|a| *a < n) && k.iter().all(|a| k.iter().all(|b| a.abs_diff(*b) <= 1))
        })
}

impl Chain {
    fn new(n: usize) -> Self {
        Self { diag: vec![Matrix15::zeros(); n], sub: vec![Matrix15::zeros(); n.saturating_sub(1)], g: vec![Vector15::zeros(); n] }
    }

    fn fill(&mut self, nodes: &[NodeState], factors: &[Factor]) -> Result<(), FgoError> {
        self.diag.iter_mut().for_each(|m| m.fill(0.0));
        self.sub.iter_mut().for_each(|m| m.fill(0.0));
        self.g.iter_mut().for_each(|v| v.fill(0.0));
        for f in factors {
            let keys = f.nodes();
            let lin = f.linearize(&states_of(nodes, f)?);
            if !lin.residual.iter().all(|x| x.is_finite()) || !lin.jacobians.iter().all(|j| j.iter().all(|x| x.is_finite())) {
                return Err(FgoError::Numeric(format!("factor on nodes {keys:?} evaluated to NaN/inf")));
            }
            for (a, ja) in keys.iter().zip(lin.jacobians.iter()) {
                self.g[*a] += ja.tr_mul(&lin.residual).fixed_rows::<15>(0);
                for (b, jb) in keys.iter().zip(lin.jacobians.iter()) {
                    if a == b {
                        self.diag[*a] += ja.tr_mul(jb).fixed_view::<15, 15>(0, 0);
                    } else if *a == *b + 1 {
                        self.sub[*b] += ja.tr_mul(jb).fixed_view::<15, 15>(0, 0);
                    }
                }
            }
        }
        Ok(())
    }

    /// Block Cholesky of `H + damping I`: the lower factors `L_i` and `C_i = H_{i,i-1} L_{i-1}^-T`.
    fn factor(&self, damping: f64) -> Option<(Vec<Matrix15>, Vec<Matrix15>)> {
        let n = self.diag.len();
        let mut l = Vec::with_capacity(n);
        let mut c = Vec::with_capacity(n.saturating_sub(1));
        for i in 0..n {
            let mut d = self.diag[i] + Matrix15::identity() * damping;
            if i > 0 {
                let prev: &Matrix15 = &l[i - 1];
                let ci = prev.solve_lower_triangular(&self.sub[i - 1].transpose())?.transpose();
                d -= ci * ci.transpose();
                c.push(ci);
            }
            let d = (d + d.transpose()) * 0.5;
            l.push(nalgebra::Cholesky::new(d)?.l());
        }
        Some((l, c))
    }

    fn solve(l: &[Matrix15], c: &[Matrix15], b: &[Vector15]) -> Option<Vec<Vector15>> {
        let n = l.len();
        let mut y = Vec::with_capacity(n);
        for i in 0..n {
            let mut r = b[i];
            if i > 0 {
                r -= c[i - 1] * y[i - 1];
            }
            y.push(l[i].solve_lower_triangular(&r)?);
        }
        let mut x = vec![Vector15::zeros(); n];
        for i in (0..n).rev() {
            let mut r = y[i];
            if i + 1 < n {
                r -= c[i].transpose() * x[i + 1];
            }
            x[i] = l[i].tr_solve_lower_triangular(&r)?;
        }
        Some(x)
    }
}

/// The Levenberg-Marquardt loop both linear solvers share: relinearise, try damped steps with
/// GTSAM's schedule until one lowers the cost, stop on a small decrease or step, or when no
/// damping lowers the cost (a minimum to machine precision). `linearize` rebuilds the normal
/// equations at the nodes; `step` solves them damped by lambda and returns the increment per
/// node, or `None` when the damped system is not positive definite (more damping follows).
fn levenberg_marquardt(
    nodes: &mut [NodeState],
    factors: &[Factor],
    opts: &LmOptions,
    mut linearize: impl FnMut(&[NodeState]) -> Result<(), FgoError>,
    mut step: impl FnMut(f64) -> Option<Vec<Tangent>>,
) -> Result<LmReport, FgoError> {
    let initial_cost = total_cost(nodes, factors)?;
    let mut cost = initial_cost;
    let mut lambda = opts.lambda_initial;
    let mut converged = false;
    let mut iterations = 0;
    while iterations < opts.max_iterations {
        iterations += 1;
        linearize(nodes)?;
        let mut accepted = false;
        let mut step_small = false;
        while lambda <= opts.lambda_max {
            let Some(dx) = step(lambda) else {
                lambda *= 10.0;
                continue;
            };
            let candidate: Vec<NodeState> = nodes.iter().zip(&dx).map(|(x, d)| x.retract(d)).collect();
            let new_cost = total_cost(&candidate, factors)?;
            if new_cost.is_finite() && new_cost <= cost {
                let decrease = cost - new_cost;
                nodes.copy_from_slice(&candidate);
                step_small = dx.iter().map(|d| d.amax()).fold(0.0, f64::max) < 1e-12;
                converged = decrease <= opts.absolute_tol || decrease <= opts.relative_tol * cost || step_small;
                cost = new_cost;
                lambda = (lambda / 10.0).max(1e-16);
                accepted = true;
                break;
            }
            lambda *= 10.0;
        }
        if !accepted {
            // no step lowers the cost: at a minimum to machine precision
            converged = true;
        }
        if converged || step_small {
            break;
        }
    }
    Ok(LmReport { iterations, initial_cost, final_cost: cost, converged })
}

/// Optimise `nodes` in place.
pub fn solve_lm(nodes: &mut [NodeState], factors: &[Factor], opts: &LmOptions) -> Result<LmReport, FgoError> {
    if nodes.iter().any(|x| !x.is_finite()) {
        return Err(FgoError::Input("initial node state contains NaN/inf".into()));
    }
    if is_chain(nodes.len(), factors) {
        // Block-tridiagonal normal equations: a block Cholesky along the chain.
        let ch = std::cell::RefCell::new(Chain::new(nodes.len()));
        return levenberg_marquardt(
            nodes,
            factors,
            opts,
            |nodes| ch.borrow_mut().fill(nodes, factors),
            |lambda| {
                let ch = ch.borrow();
                let (l, c) = ch.factor(lambda)?;
                Some(Chain::solve(&l, &c, &ch.g)?.iter().map(|d| -d).collect())
            },
        );
    }
    // General sparse normal equations: one symbolic Cholesky, refactored numerically per step.
    let sys = System::new(nodes.len(), factors)?;
    let n = nodes.len();
    let state = std::cell::RefCell::new((vec![0.0; sys.pattern.nnz()], DVector::zeros(15 * sys.n)));
    let mut chol: Option<CscCholesky<f64>> = None;
    levenberg_marquardt(
        nodes,
        factors,
        opts,
        |nodes| {
            let (values, g) = &mut *state.borrow_mut();
            sys.fill(nodes, factors, values, g)
        },
        |lambda| {
            let (values, g) = &*state.borrow();
            let hd = sys.matrix(values, lambda);
            let ok = match chol.as_mut() {
                Some(c) => c.refactor(hd.values()).is_ok(),
                None => match CscCholesky::factor(&hd) {
                    Ok(c) => {
                        chol = Some(c);
                        true
                    }
                    Err(_) => false,
                },
            };
            let c = chol.as_ref().filter(|_| ok)?;
            let dx = -c.solve(g);
            let dx = dx.column(0);
            Some((0..n).map(|i| Tangent::from_iterator(dx.rows(15 * i, 15).iter().copied())).collect())
        },
    )
}

/// Marginal covariance (15x15) of node `k` given all factors, at the current estimate.
pub fn marginal_covariance(nodes: &[NodeState], factors: &[Factor], k: usize) -> Result<Matrix15, FgoError> {
    if k >= nodes.len() {
        return Err(FgoError::Input(format!("no node {k}")));
    }
    if is_chain(nodes.len(), factors) {
        let mut ch = Chain::new(nodes.len());
        ch.fill(nodes, factors)?;
        let (l, c) = ch.factor(0.0).ok_or_else(|| FgoError::Numeric("information matrix not positive definite".into()))?;
        let mut m = Matrix15::zeros();
        let mut e = vec![Vector15::zeros(); nodes.len()];
        for i in 0..15 {
            e[k][i] = 1.0;
            let x = Chain::solve(&l, &c, &e).ok_or_else(|| FgoError::Numeric("singular information".into()))?;
            m.set_column(i, &x[k]);
            e[k][i] = 0.0;
        }
        return Ok((m + m.transpose()) * 0.5);
    }
    let (h, _) = normal_equations(nodes, factors, 0.0)?;
    let chol = factor(&h)?;
    let mut e = DMatrix::zeros(15 * nodes.len(), 15);
    for i in 0..15 {
        e[(15 * k + i, i)] = 1.0;
    }
    let x = chol.solve(&e);
    let blk = x.rows(15 * k, 15);
    let m = Matrix15::from_iterator(blk.iter().copied());
    Ok((m + m.transpose()) * 0.5)
}

/// Marginal covariances (15x15) of the nodes `ks`, at the current estimate, from one
/// factorisation. On a chain the diagonal blocks of the inverse come from a forward and a
/// backward Schur-complement sweep (`A_i = H_ii - H_i,i-1 A_i-1^-1 H_i-1,i`, `C_i` the same from
/// the other end; the marginal information of node i is `A_i + C_i - H_ii`), O(n) in all.
pub fn marginal_covariances(nodes: &[NodeState], factors: &[Factor], ks: &[usize]) -> Result<Vec<Matrix15>, FgoError> {
    if let Some(k) = ks.iter().find(|k| **k >= nodes.len()) {
        return Err(FgoError::Input(format!("no node {k}")));
    }
    if !is_chain(nodes.len(), factors) {
        return ks.iter().map(|k| marginal_covariance(nodes, factors, *k)).collect();
    }
    let n = nodes.len();
    let mut ch = Chain::new(n);
    ch.fill(nodes, factors)?;
    let not_pd = || FgoError::Numeric("information matrix not positive definite".into());
    let sym = |m: Matrix15| (m + m.transpose()) * 0.5;
    // forward: fwd[i] = information of node i with the nodes before it marginalised
    let mut fwd = Vec::with_capacity(n);
    for i in 0..n {
        let mut a = ch.diag[i];
        if i > 0 {
            let prev: &Matrix15 = &fwd[i - 1];
            let b = ch.sub[i - 1];
            let c = nalgebra::Cholesky::new(sym(*prev)).ok_or_else(not_pd)?;
            a -= b * c.solve(&b.transpose());
        }
        fwd.push(sym(a));
    }
    let mut bwd = vec![Matrix15::zeros(); n];
    for i in (0..n).rev() {
        let mut a = ch.diag[i];
        if i + 1 < n {
            let b = ch.sub[i];
            let c = nalgebra::Cholesky::new(bwd[i + 1]).ok_or_else(not_pd)?;
            a -= b.transpose() * c.solve(&b);
        }
        bwd[i] = sym(a);
    }
    ks.iter()
        .map(|k| {
            let info = sym(fwd[*k] + bwd[*k] - ch.diag[*k]);
            let c = nalgebra::Cholesky::new(info).ok_or_else(not_pd)?;
            Ok(sym(c.inverse()))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{SimConfig, simulate};
    use crate::smoother::{self, SmootherConfig};

    #[test]
    fn block_tridiagonal_path_equals_the_dense_inverse() {
        let sim = simulate(&SimConfig { duration_s: 12.0, seed: 2, ..Default::default() });
        let res = smoother::run(&sim.log, SmootherConfig::default(), false, |_, _| {}).unwrap();
        let nodes: Vec<NodeState> = res.batch.iter().map(|e| e.state).collect();
        assert!(is_chain(nodes.len(), &res.batch_factors) && nodes.len() > 5);
        // marginal covariance: chain path vs the dense inverse of the (general, CSC) information
        let (h, g) = normal_equations(&nodes, &res.batch_factors, 0.0).unwrap();
        let dense: DMatrix<f64> = DMatrix::from(&h);
        let inv = dense.clone().try_inverse().unwrap();
        for k in [0, nodes.len() / 2, nodes.len() - 1] {
            let m = marginal_covariance(&nodes, &res.batch_factors, k).unwrap();
            let d = inv.view((15 * k, 15 * k), (15, 15));
            let err = (0..15).flat_map(|r| (0..15).map(move |c| (r, c))).map(|(r, c)| (m[(r, c)] - d[(r, c)]).abs()).fold(0.0, f64::max);
            assert!(err <= 1e-6 * d.amax(), "node {k}: {err} of {}", d.amax());
        }
        // all of them at once (the two-sided sweep) against the same dense inverse
        let ks: Vec<usize> = (0..nodes.len()).collect();
        let all = marginal_covariances(&nodes, &res.batch_factors, &ks).unwrap();
        for (k, m) in all.iter().enumerate() {
            let d = inv.view((15 * k, 15 * k), (15, 15));
            let err = (0..15).flat_map(|r| (0..15).map(move |c| (r, c))).map(|(r, c)| (m[(r, c)] - d[(r, c)]).abs()).fold(0.0, f64::max);
            assert!(err <= 1e-6 * d.amax(), "sweep, node {k}: {err} of {}", d.amax());
        }
        // a damped step: chain solve vs dense solve
        let mut ch = Chain::new(nodes.len());
        ch.fill(&nodes, &res.batch_factors).unwrap();
        let (l, c) = ch.factor(1e-3).unwrap();
        let x = Chain::solve(&l, &c, &ch.g).unwrap();
        let xd = (dense + DMatrix::identity(15 * nodes.len(), 15 * nodes.len()) * 1e-3).lu().solve(&g).unwrap();
        let err = x.iter().enumerate().map(|(i, v)| (v - xd.rows(15 * i, 15)).amax()).fold(0.0, f64::max);
        assert!(err <= 1e-8 * xd.amax().max(1.0), "step differs by {err}");
        // not a chain: a factor across three nodes is refused by the chain path
        let mut f = res.batch_factors.clone();
        if let Some(Factor::BiasRw(b)) = f.iter_mut().find(|f| matches!(f, Factor::BiasRw(_))) {
            b.node_j = b.node_i + 2;
        }
        assert!(!is_chain(nodes.len(), &f));
    }
}
