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
//!   anchor `a`, the other-class samples `b` that could still violate one of its margins while
//!   `delta_L = ||L - L_ref||_2 <= active_set_eps ||L_ref||_2`, sorted by their reference
//!   distance. Every pair obeys `||L v|| >= ||L_ref v|| - delta_L ||v||` (`v = x_a - x_b`), so at
//!   a later `L` only a prefix of each row can hold an impostor and each entry is measured only if
//!   its own bound allows; the set is rebuilt when the budget or a row's cover is exceeded.
//!   `delta_L` is bounded by repeated squaring of `A^T A` (at most `d^(1/32)` above the true
//!   spectral norm; Frobenius can be `sqrt(d)` above). The bound is absolute: a bound relative to
//!   `L_ref^-1` (an earlier version) failed on digits, where `L` becomes nearly singular and the
//!   set was rebuilt on every second evaluation. The result is the same triplet set as a full
//!   scan every step (unit-tested on whole fits).
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
