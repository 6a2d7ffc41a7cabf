//! Batch Levenberg-Marquardt over all nodes of a graph, on a sparse Cholesky factorisation
//! (`nalgebra-sparse`, left-looking with symbolic analysis) of the damped normal equations
//! `(J^T J + lambda I) dx = -J^T r` built from whitened factor Jacobians. The damping schedule is
//! GTSAM's default (lambda 1e-5, x10 on a rejected step, /10 on an accepted one), so both stop at
//! the same optimum when run to tight tolerances. Also gives marginal covariances of single nodes
//! (block of the inverse information) for the gating test.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector, SMatrix};
use nalgebra_sparse::factorization::CscCholesky;
use nalgebra_sparse::{CooMatrix, CscMatrix};

use super::factors::Factor;
use super::state::{NodeState, Tangent};
use super::FgoError;

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
    f.nodes()
        .into_iter()
        .map(|i| nodes.get(i).ok_or_else(|| FgoError::Input(format!("factor refers to missing node {i}"))))
        .collect()
}

/// `sum 0.5 |W r|^2`
pub fn total_cost(nodes: &[NodeState], factors: &[Factor]) -> Result<f64, FgoError> {
    let mut c = 0.0;
    for f in factors {
        c += f.cost(&states_of(nodes, f)?);
    }
    Ok(c)
}

/// Gauss-Newton normal equations: information `H = J^T J` (sparse, full symmetric) and `g = J^T r`.
pub fn normal_equations(nodes: &[NodeState], factors: &[Factor], damping: f64) -> Result<(CscMatrix<f64>, DVector<f64>), FgoError> {
    let n = nodes.len();
    let mut blocks: BTreeMap<(usize, usize), Matrix15> = BTreeMap::new();
    let mut g = DVector::zeros(15 * n);
    for i in 0..n {
        blocks.insert((i, i), Matrix15::identity() * damping);
    }
    for f in factors {
        let keys = f.nodes();
        let lin = f.linearize(&states_of(nodes, f)?);
        if !lin.residual.iter().all(|x| x.is_finite()) || !lin.jacobians.iter().all(|j| j.iter().all(|x| x.is_finite())) {
            return Err(FgoError::Numeric(format!("factor on nodes {keys:?} evaluated to NaN/inf")));
        }
        for (a, ja) in keys.iter().zip(lin.jacobians.iter()) {
            let ga = ja.transpose() * &lin.residual;
            let mut seg = g.rows_mut(15 * a, 15);
            seg += ga;
            for (b, jb) in keys.iter().zip(lin.jacobians.iter()) {
                let hab: DMatrix<f64> = ja.transpose() * jb;
                let blk = blocks.entry((*a, *b)).or_insert_with(Matrix15::zeros);
                *blk += Matrix15::from_iterator(hab.iter().copied());
            }
        }
    }
    let mut coo = CooMatrix::new(15 * n, 15 * n);
    for ((a, b), blk) in &blocks {
        for c in 0..15 {
            for r in 0..15 {
                coo.push(15 * a + r, 15 * b + c, blk[(r, c)]);
            }
        }
    }
    Ok((CscMatrix::from(&coo), g))
}

fn factor(h: &CscMatrix<f64>) -> Result<CscCholesky<f64>, FgoError> {
    CscCholesky::factor(h).map_err(|e| FgoError::Numeric(format!("information matrix not positive definite ({e:?})")))
}

/// Optimise `nodes` in place.
pub fn solve_lm(nodes: &mut [NodeState], factors: &[Factor], opts: &LmOptions) -> Result<LmReport, FgoError> {
    if nodes.iter().any(|x| !x.is_finite()) {
        return Err(FgoError::Input("initial node state contains NaN/inf".into()));
    }
    let initial_cost = total_cost(nodes, factors)?;
    let mut cost = initial_cost;
    let mut lambda = opts.lambda_initial;
    let mut converged = false;
    let mut iterations = 0;
    while iterations < opts.max_iterations {
        iterations += 1;
        let (h, g) = normal_equations(nodes, factors, 0.0)?;
        let mut accepted = false;
        let mut step_small = false;
        while lambda <= opts.lambda_max {
            let hd = add_diagonal(&h, lambda);
            let chol = match CscCholesky::factor(&hd) {
                Ok(c) => c,
                Err(_) => {
                    lambda *= 10.0;
                    continue;
                }
            };
            let dx = -chol.solve(&g);
            let dx = dx.column(0);
            let candidate: Vec<NodeState> = nodes
                .iter()
                .enumerate()
                .map(|(i, x)| x.retract(&Tangent::from_iterator(dx.rows(15 * i, 15).iter().copied())))
                .collect();
            let new_cost = total_cost(&candidate, factors)?;
            if new_cost.is_finite() && new_cost <= cost {
                let decrease = cost - new_cost;
                nodes.copy_from_slice(&candidate);
                step_small = dx.amax() < 1e-12;
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

fn add_diagonal(h: &CscMatrix<f64>, lambda: f64) -> CscMatrix<f64> {
    let mut out = h.clone();
    for c in 0..out.ncols() {
        let mut col = out.col_mut(c);
        let (rows, vals) = col.rows_and_values_mut();
        if let Ok(k) = rows.binary_search(&c) {
            vals[k] += lambda;
        }
    }
    out
}

/// Marginal covariance (15x15) of node `k` given all factors, at the current estimate.
pub fn marginal_covariance(nodes: &[NodeState], factors: &[Factor], k: usize) -> Result<Matrix15, FgoError> {
    if k >= nodes.len() {
        return Err(FgoError::Input(format!("no node {k}")));
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
