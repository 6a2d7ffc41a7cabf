//! Factor-graph INS/DVL/USBL navigation with abnormal-observation handling (spec 002).
//!
//! Nouns, one file each: [`state`] (node state in ENU with an FLU body, and the conversion to the
//! project's NED/FRD convention), [`preintegration`] (Forster on-manifold IMU preintegration in
//! GTSAM 4.3's tangent form, bias Jacobians, covariance), [`factors`] (IMU + bias random walk,
//! DVL, USBL, LBL range, priors; one file per sensor), [`gating`] (Mahalanobis test with an
//! adaptive robust scale, covariance inflation, decision log, batch re-decision), [`solver`] (batch Levenberg-Marquardt on a sparse Cholesky), [`smoother`]
//! (fixed-lag smoother for real time; it also makes the gating decisions and hands the batch
//! problem over), [`sim`] (AUV mission simulator with truth), [`log`] (the JSON-lines sensor log
//! of `subnav fgo`), [`montecarlo`] and [`ukf_baseline`] (evaluation), [`kitti`] /
//! [`kitti_run`] (real car data), and the range-aided 2-D pose graph of a real AUV (GOATS):
//! [`pyfg`] (PyFactorGraph text reader) and [`range2d`] (SE2 odometry + ranges to known or
//! unknown beacons, gated, solved by LM).
//!
//! Checked against GTSAM 4.3 (PyPI) in `tests/tests/peer_gtsam.rs`: preintegration to 1e-9,
//! batch optimum to 1e-6 m; the GOATS pose graph in `tests/tests/peer_gtsam_pyfg.rs`. Figures in
//! docs/PERFORMANCE.md ("Factor-graph INS/DVL/USBL", "Real data: KITTI", "Real AUV data: GOATS").
//!
//! Solver choice. Evaluated first (crates.io metadata and docs): factrs 0.3 (faer 0.23 + faer-ext
//! + num-dual + statrs + a proc-macro crate), tiny-solver 0.18 (faer 0.23 + faer-ext + num-dual +
//! rayon), apex-solver 1.5 (faer 0.24, nalgebra 0.33 - a second nalgebra beside the project's
//! 0.34 - plus camera/io crates, rust-version 1.93). All three bring faer, by far the heaviest
//! build in their trees (on the 2-core CI machine that matters), and none has GTSAM's tangent
//! preintegration and component-wise IMU residual, which the issue requires to 1e-9 / 1e-6;
//! what we would take from them is the LM loop and the sparse solve. So the sparse Cholesky
//! comes from `nalgebra-sparse` (small, on the nalgebra 0.34 we already build) and the LM loop
//! (GTSAM's damping schedule) and the factors are written here. The graph is a chain
//! (block-tridiagonal information), so the natural ordering has no fill and no fill-reducing
//! ordering is needed.

/// Re-exported for the peer tests (they build nalgebra values for this API).
pub use nalgebra;

pub mod factors;
pub mod gating;
pub mod kitti;
pub mod kitti_run;
pub mod log;
pub mod montecarlo;
pub mod preintegration;
pub mod pyfg;
pub mod range2d;
pub mod sim;
pub mod smoother;
pub mod solver;
pub mod state;
pub mod ukf_baseline;

/// Errors of this module: bad input data or a numeric failure, never a panic.
#[derive(Debug, Clone, PartialEq)]
pub enum FgoError {
    Input(String),
    Numeric(String),
}

impl From<subnav_base::chi2::Chi2Error> for FgoError {
    fn from(e: subnav_base::chi2::Chi2Error) -> Self {
        FgoError::Input(e.to_string())
    }
}

impl std::fmt::Display for FgoError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FgoError::Input(s) => write!(f, "bad input: {s}"),
            FgoError::Numeric(s) => write!(f, "numeric failure: {s}"),
        }
    }
}

impl std::error::Error for FgoError {}
