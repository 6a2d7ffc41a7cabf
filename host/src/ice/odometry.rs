//! The under-ice odometry back end: static initialization, then an event loop over IMU samples,
//! stereo frames (clone augmentation, feature bookkeeping, MSCKF updates of lost tracks and of
//! tracks in pruned frames, window pruning two at a time), depth readings and sonar velocities.

use std::collections::HashMap;

use anyhow::{Result, bail};
use nalgebra::{DMatrix, Matrix3, SMatrix, Vector3};

use super::camera::StereoCamera;
use super::data::Dataset;
use super::depth::{DepthConfig, DepthUpdater};
use super::msckf::{self, Track};
use super::propagation::{ImuNoise, ImuSample, propagate, static_init};
use super::sonar::{SonarConfig, SonarUpdater};
use super::state::{BA, BG, FilterState, IMU_DIM, POS, SCALE, TH, VEL};
use super::window::{PoseRef, PruneConfig, select_two_to_prune};

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct OdometryConfig {
    pub use_camera: bool,
    pub use_depth: bool,
    pub use_sonar: bool,
    /// Adaptive depth and sonar noise (off: fixed R).
    pub adaptive: bool,
    /// Clones kept in the window (pruned two at a time when exceeded).
    pub window: usize,
    pub prune: PruneConfig,
    /// Chi-square gate probability of the feature update.
    pub gate: f64,
    /// Tracking is good when at least this fraction of the previous frame's features is tracked.
    pub good_tracking: f64,
    pub imu: ImuNoise,
    pub depth: DepthConfig,
    pub sonar: SonarConfig,
}

impl Default for OdometryConfig {
    fn default() -> Self {
        Self {
            use_camera: true,
            use_depth: true,
            use_sonar: true,
            adaptive: true,
            window: 10,
            prune: PruneConfig::default(),
            gate: 0.95,
            good_tracking: 0.5,
            imu: ImuNoise::default(),
            depth: DepthConfig::default(),
            sonar: SonarConfig::default(),
        }
    }
}

/// One estimated pose with its 6x6 covariance over `(dtheta_body, dp_w)`.
#[derive(Debug, Clone, PartialEq)]
pub struct EstPose {
    pub t_s: f64,
    pub rot: Matrix3<f64>,
    pub pos_w_m: Vector3<f64>,
    pub cov: SMatrix<f64, 6, 6>,
}

#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct RunStats {
    pub frames: usize,
    pub features_used: usize,
    pub features_gated: usize,
    pub triangulation_failed: usize,
    pub depth_used: usize,
    pub depth_gated: usize,
    pub sonar_used: usize,
    pub sonar_gated: usize,
    pub prune_kept_baseline: usize,
    pub final_depth_r_m2: f64,
    pub final_sonar_r_m2ps2: f64,
}

fn pose_of(st: &FilterState) -> EstPose {
    let mut cov = SMatrix::<f64, 6, 6>::zeros();
    for a in 0..3 {
        for b in 0..3 {
            cov[(a, b)] = st.cov[(TH + a, TH + b)];
            cov[(a, 3 + b)] = st.cov[(TH + a, POS + b)];
            cov[(3 + a, b)] = st.cov[(POS + a, TH + b)];
            cov[(3 + a, 3 + b)] = st.cov[(POS + a, POS + b)];
        }
    }
    EstPose { t_s: st.imu.t_s, rot: st.imu.rot, pos_w_m: st.imu.pos_w_m, cov }
}

fn interp(a: &ImuSample, b: &ImuSample, t: f64) -> ImuSample {
    let u = ((t - a.t_s) / (b.t_s - a.t_s).max(1e-12)).clamp(0.0, 1.0);
    ImuSample { t_s: t, gyro_radps: a.gyro_radps * (1.0 - u) + b.gyro_radps * u, acc_mps2: a.acc_mps2 * (1.0 - u) + b.acc_mps2 * u }
}

struct Frontier {
    features: HashMap<u64, Track>,
    prev_ids: Vec<u64>,
}

/// Run the odometry over a data set. Returns the pose after each stereo frame (or every 0.2 s
/// without camera).
pub fn run(data: &Dataset, cfg: &OdometryConfig, cam: &StereoCamera) -> Result<(Vec<EstPose>, RunStats)> {
    let still: Vec<ImuSample> = data.imu.iter().filter(|s| s.t_s <= data.still_s).copied().collect();
    let init = static_init(&still).map_err(|e| anyhow::anyhow!("{e}"))?;
    let Some(start) = data.imu.iter().position(|s| s.t_s >= init.t_s) else { bail!("no IMU data after initialization") };
    let mut p0 = DMatrix::zeros(IMU_DIM, IMU_DIM);
    for k in 0..3 {
        p0[(TH + k, TH + k)] = if k < 2 { 1e-6 } else { 1e-10 };
        p0[(VEL + k, VEL + k)] = 1e-6;
        p0[(POS + k, POS + k)] = 1e-10;
        p0[(BG + k, BG + k)] = 1e-8;
        p0[(BA + k, BA + k)] = 4e-4;
    }
    p0[(SCALE, SCALE)] = 0.03f64.powi(2);
    let mut st = FilterState { imu: init, clones: Vec::new(), cov: p0 };
    let mut dcfg = cfg.depth;
    dcfg.adaptive = cfg.adaptive;
    let mut depth = DepthUpdater::new(dcfg);
    let mut scfg = cfg.sonar;
    scfg.adaptive = cfg.adaptive;
    let mut sonar = SonarUpdater::new(scfg);
    let mut stats = RunStats::default();
    let mut out = Vec::new();
    let mut fr = Frontier { features: HashMap::new(), prev_ids: Vec::new() };

    // Depth reference: the mean of the readings taken while still (at least one, within 0.5 s of
    // the initialization otherwise). Its noise is a constant error of every relative depth, so it
    // goes into the initial vertical-position variance instead of being ignored.
    if cfg.use_depth {
        let still_readings: Vec<f64> = data.depth.iter().filter(|d| d.t_s <= st.imu.t_s).map(|d| d.depth_m).collect();
        let (reference, count) = if still_readings.is_empty() {
            let near = data.depth.iter().min_by(|a, b| (a.t_s - st.imu.t_s).abs().total_cmp(&(b.t_s - st.imu.t_s).abs()));
            match near {
                Some(d) if (d.t_s - st.imu.t_s).abs() < 0.5 => (Some(d.depth_m), 1usize),
                _ => (None, 0),
            }
        } else {
            (Some(still_readings.iter().sum::<f64>() / still_readings.len() as f64), still_readings.len())
        };
        if let Some(r) = reference {
            depth.set_reference(r, &st.imu);
            st.cov[(POS + 2, POS + 2)] += cfg.depth.sigma_m.powi(2) / count as f64;
        }
    }
    let (mut fi, mut di, mut si) = (0usize, 0usize, 0usize);
    let t0 = st.imu.t_s;
    while fi < data.frames.len() && data.frames[fi].t_s <= t0 {
        fi += 1;
    }
    while di < data.depth.len() && data.depth[di].t_s <= t0 {
        di += 1;
    }
    while si < data.sonar_velocity.len() && data.sonar_velocity[si].t_s <= t0 {
        si += 1;
    }
    let mut next_out = t0;
    for k in start + 1..data.imu.len() {
        let (a, b) = (&data.imu[k - 1], &data.imu[k]);
        let prev = st.imu.clone();
        // Stereo frames inside (a, b]: propagate exactly to the frame time first.
        let mut cur = *a;
        while cfg.use_camera && fi < data.frames.len() && data.frames[fi].t_s <= b.t_s {
            let f = &data.frames[fi];
            let mid = interp(a, b, f.t_s);
            propagate(&mut st, &cur, &mid, &cfg.imu);
            cur = mid;
            process_frame(&mut st, &mut fr, f, cfg, cam, &mut stats);
            out.push(pose_of(&st));
            fi += 1;
        }
        propagate(&mut st, &cur, b, &cfg.imu);
        while di < data.depth.len() && data.depth[di].t_s <= b.t_s {
            if cfg.use_depth {
                depth.update(&mut st, &prev, data.depth[di].t_s, data.depth[di].depth_m);
            }
            di += 1;
        }
        while si < data.sonar_velocity.len() && data.sonar_velocity[si].t_s <= b.t_s {
            if cfg.use_sonar {
                sonar.update(&mut st, &prev, &data.sonar_velocity[si]);
            }
            si += 1;
        }
        if !cfg.use_camera && b.t_s >= next_out {
            out.push(pose_of(&st));
            next_out += 0.2;
        }
        if st.cov.iter().any(|v| !v.is_finite()) || st.imu.pos_w_m.iter().any(|v| !v.is_finite()) {
            bail!("filter diverged (non-finite state) at t = {:.2} s", b.t_s);
        }
    }
    stats.depth_used = depth.used;
    stats.depth_gated = depth.gated;
    stats.sonar_used = sonar.used;
    stats.sonar_gated = sonar.gated;
    stats.final_depth_r_m2 = depth.noise.r[(0, 0)];
    stats.final_sonar_r_m2ps2 = sonar.noise.r[(0, 0)];
    Ok((out, stats))
}

fn process_frame(
    st: &mut FilterState,
    fr: &mut Frontier,
    f: &super::data::Frame,
    cfg: &OdometryConfig,
    cam: &StereoCamera,
    stats: &mut RunStats,
) {
    stats.frames += 1;
    st.augment(f.frame_id);
    let ids: Vec<u64> = f.obs.iter().map(|o| o.0).collect();
    let tracked = fr.prev_ids.iter().filter(|i| ids.contains(i)).count();
    let good = !fr.prev_ids.is_empty() && tracked as f64 >= cfg.good_tracking * fr.prev_ids.len() as f64;
    for (id, z) in &f.obs {
        fr.features.entry(*id).or_default().push((f.frame_id, *z));
    }
    // Tracks lost in this frame.
    let lost: Vec<u64> = fr.features.keys().filter(|k| !ids.contains(k)).copied().collect();
    let mut finished: Vec<Track> = Vec::new();
    for id in lost {
        if let Some(t) = fr.features.remove(&id)
            && t.len() >= 3
        {
            finished.push(t);
        }
    }
    // Window full: two clones go; their features (>= 3 observations) are used first.
    let mut prune: Option<[usize; 2]> = None;
    if st.clones.len() > cfg.window {
        let refs: Vec<PoseRef> = st.clones.iter().map(|c| PoseRef { rot: &c.rot, pos: &c.pos_w_m }).collect();
        prune = select_two_to_prune(&refs, good, &cfg.prune);
        if let Some(p) = prune {
            if p != [0, 1] {
                stats.prune_kept_baseline += 1;
            }
            let pruned_ids = [st.clones[p[0]].frame_id, st.clones[p[1]].frame_id];
            let keys: Vec<u64> = fr.features.keys().copied().collect();
            for key in keys {
                let Some(t) = fr.features.get_mut(&key) else { continue };
                if !t.iter().any(|(fid, _)| pruned_ids.contains(fid)) {
                    continue;
                }
                if t.len() >= 3 {
                    if let Some(t) = fr.features.remove(&key) {
                        finished.push(t);
                    }
                } else {
                    t.retain(|(fid, _)| !pruned_ids.contains(fid));
                }
            }
        }
    }
    if !finished.is_empty() {
        let s = msckf::update(st, cam, &finished, cfg.gate);
        stats.features_used += s.features_used;
        stats.features_gated += s.gated_out;
        stats.triangulation_failed += s.triangulation_failed;
    }
    if let Some(p) = prune {
        st.marginalize(&p);
    }
    fr.prev_ids = ids;
}
