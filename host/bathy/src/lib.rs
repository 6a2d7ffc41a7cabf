//! Bathymetric graph SLAM from multibeam soundings (spec 003, Ma et al. 2020).
//!
//! Pipeline, one module per noun:
//! - [`sim`]: seafloor height field ([`terrain`]), multibeam echosounder, survey with crossing
//!   lines and a drifting dead reckoning (DVL + gyro compass); the truth is kept for evaluation.
//! - [`points`]: soundings (range, beam angle) + pose -> world-frame 2.5D points (spec C1).
//! - [`grid`]: mean-per-cell gridding, bilinear sampling, ESRI ASCII grid output.
//! - [`submap`]: submaps cut by path length and terrain information (difference of normals).
//! - [`matching`]: loop closure by grid correlation + Gauss-Newton refinement between overlapping
//!   submaps, with gates that reject flat or ambiguous terrain (spec C2).
//! - [`association`]: weak data association between consecutive swaths by terrain
//!   extrapolation (spec C3).
//! - [`correction`]: voting over closures, global weighted least squares on keyframe offsets
//!   (spec C4), local correction by the spring model or uniformly (spec C5).
//! - [`pipeline`]: the whole chain plus the evaluation metrics; [`io`] CSV input/output;
//!   [`plot`] PNG figures.
//!
//! Frames and units: NED world frame (north_m, east_m, depth_m positive down), heading_rad from
//! north towards east; beam angles positive to starboard. Everything here is f64 (host code).
//!
//! Sign convention used throughout: the navigation offset of pose k is
//! `e_k = dead_reckoning_k - truth_k` (horizontal, metres); a corrected pose is `dr_k - e_k`.

pub mod association;
pub mod correction;
pub mod grid;
pub mod io;
pub mod matching;
pub mod pipeline;
pub mod plot;
pub mod points;
pub mod sim;
pub mod submap;
pub mod terrain;

/// One navigation sample per ping: the pose the soundings are referenced to.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NavSample {
    pub t_s: f64,
    pub north_m: f64,
    pub east_m: f64,
    /// Vehicle depth (pressure sensor), positive down.
    pub depth_m: f64,
    pub heading_rad: f64,
    /// 1-sigma velocity error of the dead reckoning over this step (DVL bottom lock ~0.01,
    /// water track ~0.2). Drives the drift model of the graph and the springs.
    pub vel_sigma_mps: f64,
}

/// One multibeam return: beam angle in the across-track plane (positive to starboard, 0 =
/// nadir) and slant range computed by the sonar with its assumed sound speed.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Beam {
    pub angle_rad: f64,
    pub range_m: f64,
}

/// One ping (swath) of the echosounder.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Ping {
    pub t_s: f64,
    pub beams: Vec<Beam>,
}

/// A survey as the processing chain sees it: the dead-reckoned navigation at each ping time
/// (`nav[i]` belongs to `pings[i]`) and the pings.
#[derive(Debug, Clone, Default)]
pub struct Survey {
    pub nav: Vec<NavSample>,
    pub pings: Vec<Ping>,
}

/// A world-frame sounding.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    pub north_m: f64,
    pub east_m: f64,
    pub depth_m: f64,
}

/// Horizontal 2-vector in the NED frame (north, east).
pub type V2 = nalgebra::Vector2<f64>;
