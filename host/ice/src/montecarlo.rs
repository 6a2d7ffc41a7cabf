//! Seeded simulated runs of the odometry and its ablations (no sonar, no depth, no adaptivity,
//! no first-estimate Jacobians, IMU-based clone augmentation only, IMU only), evaluated with [`super::eval`].

use anyhow::Result;

use super::eval::{Metrics, evaluate};
use super::frontend::FrontendStats;
use super::odometry::{OdometryConfig, RunStats, run};
use super::sim::{SimConfig, simulate};
use super::sonar;

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Variant {
    Full,
    NoSonar,
    NoDepth,
    NoAdaptivity,
    /// Plain EKF Jacobians (no first estimates).
    NoFej,
    /// Every clone augmented from the IMU pose (no previous-image-based augmentation).
    ImuAugmentation,
    ImuOnly,
}

impl Variant {
    pub const ALL: [Variant; 7] = [
        Variant::Full,
        Variant::NoSonar,
        Variant::NoDepth,
        Variant::NoAdaptivity,
        Variant::NoFej,
        Variant::ImuAugmentation,
        Variant::ImuOnly,
    ];
    pub fn name(self) -> &'static str {
        match self {
            Self::Full => "full",
            Self::NoSonar => "no-sonar",
            Self::NoDepth => "no-depth",
            Self::NoAdaptivity => "no-adaptivity",
            Self::NoFej => "no-fej",
            Self::ImuAugmentation => "imu-augmentation",
            Self::ImuOnly => "imu-only",
        }
    }
    pub fn config(self, base: &OdometryConfig) -> OdometryConfig {
        let mut c = *base;
        match self {
            Self::Full => {}
            Self::NoSonar => c.use_sonar = false,
            Self::NoDepth => c.use_depth = false,
            Self::NoAdaptivity => c.adaptive = false,
            Self::NoFej => c.fej = false,
            Self::ImuAugmentation => c.augment.previous_image = false,
            Self::ImuOnly => {
                c.use_camera = false;
                c.use_depth = false;
                c.use_sonar = false;
            }
        }
        c
    }
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct RunResult {
    pub seed: u64,
    pub variant: Variant,
    pub metrics: Metrics,
    pub stats: RunStats,
    /// Image front end counters (runs on rendered images only).
    pub frontend: Option<FrontendStats>,
}

pub const RPE_LENGTHS_M: [f64; 2] = [50.0, 100.0];

/// Simulate `seed` (with `sim.images`: render the stereo pairs and track them once for all
/// variants), derive the sonar velocities from the sonar images, and run each variant.
pub fn run_seed(sim: &SimConfig, base: &OdometryConfig, variants: &[Variant]) -> Result<Vec<RunResult>> {
    let mut data = simulate(sim);
    data.sonar_velocity = sonar::velocities(&data.sonar_frames, &base.sonar);
    let mut out = Vec::new();
    for &v in variants {
        let cfg = v.config(base);
        let (est, stats) = run(&data, &cfg, &data.cam)?;
        let metrics = evaluate(&est, &data.truth, &RPE_LENGTHS_M);
        out.push(RunResult { seed: sim.seed, variant: v, metrics, stats, frontend: data.frontend });
    }
    Ok(out)
}

/// Mean and max of a figure over runs; NaN (e.g. an RPE segment longer than the run) is skipped,
/// and an empty set gives NaN.
pub fn mean_max(xs: impl Iterator<Item = f64>) -> (f64, f64) {
    let v: Vec<f64> = xs.filter(|x| !x.is_nan()).collect();
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    (v.iter().sum::<f64>() / v.len() as f64, v.iter().copied().fold(f64::MIN, f64::max))
}

#[cfg(test)]
mod tests {
    use super::mean_max;

    #[test]
    fn mean_max_skips_nan() {
        assert_eq!(mean_max([1.0, f64::NAN, 3.0].into_iter()), (2.0, 3.0));
        let (m, x) = mean_max([f64::NAN].into_iter());
        assert!(m.is_nan() && x.is_nan());
    }
}
