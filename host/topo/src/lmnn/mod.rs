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
//! - impostors come from an exact active set: after a full `O(n^2 d)` scan at a reference
//!   `L_ref`, only pairs that can still violate a margin are kept. With
//!   `eps = ||L - L_ref||_F ||L_ref^-1||_2`, every distance satisfies
//!   `(1 - eps) ||L_ref v|| <= ||L v|| <= (1 + eps) ||L_ref v||`, so a pair outside the kept set
//!   cannot be an impostor while `eps` stays under the budget used to build it; the set is
//!   rebuilt when it does not. The result is the same triplet set as a full scan every step.
//! - the gradient `sum_w w (x_a - x_b)(x_a - x_b)^T` is one `X Lap X^T` with a sparse graph
//!   Laplacian, i.e. one dense `d x n x d` product.
//!
//! Written here rather than taken from a crate: no maintained Rust crate implements LMNN (linfa
//! has no metric learning).

pub mod knn;
pub mod model;
pub mod solver;

pub use knn::{accuracy, predict};
pub use model::{LmnnModel, Scaler};
pub use solver::{FitReport, LmnnConfig, LmnnError, fit};
