//! Generic fixed-size (adaptive) unscented Kalman filter.
//!
//! - [`Ukf`]: `N` states, `S = 2N + 1` sigma points (scaled unscented transform, van der Merwe
//!   weights), user state space ([`Space`]: add / residual / mean, e.g. wrapped angles),
//!   measurement updates of any size `M` at any rate, `P` kept symmetric PD ([`pd`]).
//! - [`adapt`]: Sage-Husa noise statistics and the fading factor (spec A5), each switchable; with
//!   all switches off the same code is a plain UKF, checked against FilterPy
//!   (`tests/tests/peer_filterpy.rs`).
//! - [`gate`]: chi-square innovation gate with a floor.
//!
//! Written here rather than taken from a crate: the Rust UKF crates we know allocate (Vec /
//! DMatrix) or have no adaptive layer and no hooks for error-state attitude; this core needs to
//! run on the Cortex-M4F without a heap. Generic over the scalar: f32 on the target, f64 for the
//! peer check.

pub mod adapt;
mod filter;
pub mod gate;
pub mod pd;
pub mod space;
pub mod weights;

pub use adapt::{AdaptConfig, MeasNoise, NisQScale, QScaleConfig};
pub use filter::{Ukf, UkfConfig, UkfError, UkfHealth, UpdateReport};
pub use space::{AngleSpace, Euclidean, Space, wrap_deg, wrap_pi};
pub use weights::SigmaWeights;

/// The nalgebra this module is built on (for crates that do not depend on it directly).
pub use nalgebra;
