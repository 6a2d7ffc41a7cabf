//! Large Margin Nearest Neighbour metric learning (Weinberger & Saul, spec A3) and kNN in the
//! learned metric.
//!
//! LMNN learns a linear map `L` (`M = L^T L`, PSD by construction) minimising
//! `reg * sum_{j~>i} d_M(i, j) + (1 - reg) * sum_{j~>i, l: y_l != y_i} [1 + d_M(i, j) - d_M(i, l)]_+`
//! over the target neighbours `j~>i` (the `k` nearest same-class samples in the Euclidean metric
//! at the start) and the impostors `l`. The optimiser follows the reference implementation
//! (metric-learn 0.7.0, which we cross-check against in `tests/tests/peer_metric_learn.rs`):
//! identity start, plain gradient steps on `L` (gradient `2 L G`, `G` the weighted sum of outer
//! products of active pull/push pairs), a step is retried with half the learning rate while the
//! objective goes up and the rate grows by 1 % after each accepted step, stop after `min_iter`
//! once the objective changes by less than `convergence_tol`, or at `max_iter`.
//!
//! What makes it fast (module [`solver`]):
//! - all distances come from one `L X` product per evaluation (columns contiguous);
//! - impostors come from an exact active set: a full scan at a reference `L_ref` (all
//!   cross-class distances from one Gram product `(L_ref X)^T (L_ref X)`, a GEMM) keeps, per
//!   anchor, the other-class samples that could still violate one of its margins while
//!   `e = ||(L - L_ref) L_ref^-1||_2 <= eps`, sorted by their reference distance. Then every
//!   distance satisfies `(1 - e) ||L_ref v|| <= ||L v|| <= (1 + e) ||L_ref v||`, so at an `L` with
//!   bound `e` only the prefix of each anchor's row within `(1 + far) / (1 - e)^2` can hold an
//!   impostor: the evaluation computes the exact distances of that prefix only, and the set is
//!   rebuilt when `e` exceeds the budget. `e` is bounded by repeated squaring of
//!   `A^T A` (at most `d^(1/32)` above the true spectral norm, where the Frobenius norm can be
//!   `sqrt(d)` above), so a larger budget costs memory, not scan time, and rebuilds are rare.
//!   The result is the same triplet set as a full scan every step (unit-tested on whole fits).
//! - the gradient `sum_w w (x_a - x_b)(x_a - x_b)^T` is one `X Lap X^T` with a sparse graph
//!   Laplacian, restricted to the samples with a nonzero degree: one dense `d x m x d` product.
//!
//! Dense products are nalgebra's (`matrixmultiply` underneath).
//!
//! Written here rather than taken from a crate: no maintained Rust crate implements LMNN (linfa
//! has no metric learning).

pub mod knn;
pub mod model;
pub mod solver;

pub use knn::{accuracy, predict};
pub use model::{LmnnModel, Scaler};
pub use solver::{FitReport, LmnnConfig, LmnnError, fit};
