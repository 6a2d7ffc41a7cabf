//! Under-ice odometry (spec 004): an MSCKF-style error-state EKF fusing an IMU, an up-looking
//! stereo camera, a depth gauge and a forward-looking imaging sonar (velocity by phase correlation).
//!
//! Nouns: [`state`] (IMU state, clones, covariance hygiene), [`augment`] (IMU- or previous-image-
//! based clone augmentation), [`propagation`] (static init, RK4,
//! discrete noise), [`camera`] (stereo model), [`triangulation`], [`msckf`] (null-space
//! projected, gated feature update), [`window`] (pruning rule), [`depth`] and [`sonar`] (one file
//! per sensor update), [`phasecorr`], [`odometry`] (the event loop), [`sim`], [`data`] (files),
//! [`eval`] (ATE / RPE / NEES), [`montecarlo`] (seeded runs and ablations), [`frontend`] (dehazing,
//! flat-port refraction, FAST + KLT stereo tracker), [`render`] (stereo images of the ice for it).
//!
//! The back end takes stereo observations from the image front end (rendered or `stereo.csv`
//! images) or as feature tracks (the simulator's synthetic tracks, or `tracks.csv`).

pub mod augment;
pub mod camera;
pub mod data;
pub mod depth;
pub mod eval;
pub mod frontend;
pub mod montecarlo;
pub mod msckf;
pub mod odometry;
pub mod phasecorr;
pub mod propagation;
pub mod render;
pub mod sim;
pub mod sonar;
pub mod state;
pub mod triangulation;
pub mod window;
