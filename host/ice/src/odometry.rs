//! The under-ice odometry back end: static initialization, then an event loop over IMU samples,
//! stereo frames (clone augmentation, feature bookkeeping, MSCKF updates of lost tracks and of
//! tracks in pruned frames, window pruning two at a time), depth readings and sonar velocities.

use std::collections::HashMap;

use anyhow::{Result, bail};
use nalgebra::{DMatrix, Matrix3, SMatrix, Vector3};

use super::augment::{self, AugmentConfig, estimate_relative_pose, relative_pose_update};
use super::camera::StereoCamera;
use super::data::Dataset;
use super::depth::{DepthConfig, DepthUpdater, robust_reference};
use super::msckf::{self, Track};
use super::propagation::{ImuNoise, ImuSample, propagate, static_init};
use super::sonar::{SonarConfig, SonarUpdater};
use super::state::{BA, BG, DEPTH_REF, FilterState, IMU_DIM, POS, SCALE, SONAR_BIAS, TH, VEL};
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
    /// First-estimate Jacobians (off: plain EKF, re-linearized at every estimate).
    pub fej: bool,
    /// Clone augmentation: IMU-based, and previous-image-based when tracking is good.
    pub augment: AugmentConfig,
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
            fej: true,
            augment: AugmentConfig::default(),
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
    /// Frames whose clone was also tied to the previous image's (stereo relative pose).
    pub augment_previous_image: usize,
    /// Frames augmented from the IMU only (first frame, poor tracking, too few inliers, gated).
    pub augment_imu: usize,
    /// Of those: tracking good but the stereo increment failed (too few points or inliers) ...
    pub augment_no_increment: usize,
    /// ... or was rejected by the update's chi-square gate.
    pub augment_gated: usize,
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
    prev_frame: Option<u64>,
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
    p0[(SONAR_BIAS, SONAR_BIAS)] = cfg.sonar.bias_sigma_mps.powi(2);
    let sb = (cfg.sonar.bias_sigma_mps, cfg.sonar.bias_tau_s);
    let mut st = FilterState::new(init, p0);
    st.fej_enabled = cfg.fej;
    let mut dcfg = cfg.depth;
    dcfg.adaptive = cfg.adaptive;
    let mut depth = DepthUpdater::new(dcfg);
    let mut scfg = cfg.sonar;
    scfg.adaptive = cfg.adaptive;
    let mut sonar = SonarUpdater::new(scfg);
    let mut stats = RunStats::default();
    let mut out = Vec::new();
    let mut fr = Frontier { features: HashMap::new(), prev_ids: Vec::new(), prev_frame: None };

    // Depth reference: robust mean of the readings taken while still (or the one reading within
    // 0.5 s of the initialization). Its error is the same in every relative depth: the state
    // `DEPTH_REF` with the reference's variance as prior (see `depth`).
    if cfg.use_depth {
        let mut still_readings: Vec<f64> = data.depth.iter().filter(|d| d.t_s <= st.imu.t_s).map(|d| d.depth_m).collect();
        if still_readings.is_empty() {
            let near = data.depth.iter().min_by(|a, b| (a.t_s - st.imu.t_s).abs().total_cmp(&(b.t_s - st.imu.t_s).abs()));
            if let Some(d) = near.filter(|d| (d.t_s - st.imu.t_s).abs() < 0.5) {
                still_readings.push(d.depth_m);
            }
        }
        if let Some((r, var)) = robust_reference(&still_readings, 0.002, cfg.depth.sigma_m) {
            depth.set_reference(r, &st.imu);
            st.cov[(DEPTH_REF, DEPTH_REF)] = var;
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
            propagate(&mut st, &cur, &mid, &cfg.imu, sb);
            cur = mid;
            process_frame(&mut st, &mut fr, f, cfg, cam, &mut stats);
            out.push(pose_of(&st));
            fi += 1;
        }
        propagate(&mut st, &cur, b, &cfg.imu, sb);
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
    // Previous-image-based augmentation when tracking is good (see `augment`): the stereo
    // increment from the previous image ties the new clone to the previous one; the observations
    // it used leave their MSCKF tracks so that no observation is used twice.
    let mut used_previous = false;
    if cfg.augment.previous_image
        && good
        && let Some(prev_fid) = fr.prev_frame
        && let Some(a) = st.clones.iter().position(|c| c.frame_id == prev_fid)
    {
        let (mut prev_obs, mut cur_obs) = (Vec::new(), Vec::new());
        for (id, z) in &f.obs {
            if let Some((_, zp)) = fr.features.get(id).and_then(|t| t.iter().find(|(fid, _)| *fid == prev_fid)) {
                prev_obs.push((*id, *zp));
                cur_obs.push((*id, *z));
            }
        }
        let (ca, cb) = (&st.clones[a], &st.clones[st.clones.len() - 1]);
        let prior = augment::predicted_relative_pose(cam, (&ca.rot, &ca.pos_w_m), (&cb.rot, &cb.pos_w_m));
        match estimate_relative_pose(cam, &prev_obs, &cur_obs, &cfg.augment, Some(prior)) {
            Ok(m) => {
                let b = st.clones.len() - 1;
                let applied = if cfg.augment.explicit_increment {
                    relative_pose_update(st, cam, a, b, &m, cfg.augment.gate)
                } else {
                    // The inliers' observations in both images, features marginalized by the
                    // null-space projection, linearized at the clones' (first) estimates.
                    let tracks: Vec<Track> = m
                        .inliers
                        .iter()
                        .filter_map(|id| {
                            let zp = prev_obs.iter().find(|(i, _)| i == id)?.1;
                            let zc = cur_obs.iter().find(|(i, _)| i == id)?.1;
                            Some(vec![(prev_fid, zp), (f.frame_id, zc)])
                        })
                        .collect();
                    // Applied when any feature passed its gate; all inliers' observations are then
                    // taken out of the MSCKF tracks (the gated ones are lost, never used twice).
                    msckf::update_min_obs(st, cam, &tracks, cfg.gate, 2).features_used > 0
                };
                if applied {
                    used_previous = true;
                    for id in &m.inliers {
                        if let Some(t) = fr.features.get_mut(id) {
                            t.retain(|(fid, _)| *fid != prev_fid && *fid != f.frame_id);
                        }
                    }
                } else {
                    stats.augment_gated += 1;
                }
            }
            Err(_) => stats.augment_no_increment += 1,
        }
    }
    if used_previous {
        stats.augment_previous_image += 1;
    } else {
        stats.augment_imu += 1;
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
    fr.prev_frame = Some(f.frame_id);
}
