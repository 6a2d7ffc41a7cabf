//! Under-ice scene simulator with truth: a vehicle ~5 m under a rough ice underside runs a
//! lawnmower at 1 m/s after floating still for `still_s`; it carries an IMU (white noise and
//! random-walk biases), an up-looking stereo camera (corner features on the ice with pixel noise,
//! a fraction of gross mismatches, random track losses), a forward-looking imaging sonar tilted
//! 30 deg up (polar images rendered from point scatterers on the ice with speckle-like noise) and a
//! depth gauge (offset, white noise that doubles in the middle third of the run, rare spikes,
//! timestamps between IMU samples).
//!
//! With `images` set, the stereo observations come from the image front end instead: stereo
//! pairs of the textured ice rendered through the flat port in hazy water (`render`), tracked
//! with FAST + KLT (`frontend::StereoTracker`). The other sensors are the same draws either way.
//!
//! Truth kinematics are sampled at the IMU rate with `R_k+1 = R_k Exp(w_k dt)` exactly, and the
//! IMU reports `w_k` and `f_k = R_k^T (a_k - g)` (`subnav_base::imu`: turns from a
//! [`TurnSchedule`], errors of [`SimConfig::imu_grade`] by [`ImuErrors`]).

use std::collections::HashMap;

use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use super::camera::StereoCamera;
use super::data::{Dataset, DepthReading, Frame, TruthSample};
use super::depth::DepthConfig;
use super::frontend::{FrontendStats, StereoTracker, TrackerConfig};
use super::phasecorr::Gray;
use super::propagation::{ImuNoise, ImuSample, gravity_w};
use super::render::{StereoRenderer, WaterConfig};
use super::sonar::SonarConfig;
use subnav_base::imu::{self, DrawOrder, ImuErrors, ImuGrade, TurnProfile, TurnSchedule};

/// Turn-on bias of the simulated IMU: uniform in +-this (gyro rad/s, accelerometer m/s^2).
pub const TURN_ON_BIAS_HALF_WIDTH: (f64, f64) = (2e-4, 0.02);

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SimConfig {
    pub seed: u64,
    /// Path length after the still period, m.
    pub distance_m: f64,
    pub speed_mps: f64,
    pub leg_m: f64,
    pub depth_below_ice_m: f64,
    pub still_s: f64,
    pub imu_hz: f64,
    pub cam_hz: f64,
    pub depth_hz: f64,
    pub max_features: usize,
    pub outlier_fraction: f64,
    pub track_loss_per_frame: f64,
    pub depth_sigma_m: f64,
    pub imu: ImuNoise,
    pub cam: StereoCamera,
    pub sonar: SonarConfig,
    pub depth: DepthConfig,
    /// Render sonar images (off: no sonar data at all).
    pub sonar_images: bool,
    /// Stereo observations from rendered images through the FAST + KLT front end (off: synthetic
    /// feature tracks with `cam.sigma_px` noise, mismatches and track losses).
    pub images: bool,
    pub water: WaterConfig,
    pub tracker: TrackerConfig,
    /// Vision outage `(start_s, duration_s)`: the camera sees only turbid water (no features),
    /// so the sonar and the depth gauge carry the odometry through it.
    pub vision_outage: Option<(f64, f64)>,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            seed: 1,
            distance_m: 500.0,
            speed_mps: 1.0,
            leg_m: 100.0,
            depth_below_ice_m: 5.0,
            still_s: 2.0,
            imu_hz: 200.0,
            cam_hz: 5.0,
            depth_hz: 10.0,
            max_features: 40,
            outlier_fraction: 0.01,
            track_loss_per_frame: 0.02,
            depth_sigma_m: 0.02,
            imu: ImuNoise::default(),
            cam: StereoCamera::default(),
            sonar: SonarConfig::default(),
            depth: DepthConfig::default(),
            sonar_images: true,
            images: false,
            water: WaterConfig::default(),
            tracker: TrackerConfig::default(),
            vision_outage: None,
        }
    }
}

/// Ice underside depth (NED z, m) at a horizontal position: ~0 with 0.3-0.5 m relief.
pub fn ice_z(x: f64, y: f64) -> f64 {
    0.3 * (0.21 * x + 0.5).sin() * (0.17 * y).sin() + 0.2 * (0.05 * x + 0.11 * y).sin() + 0.1 * (0.9 * x - 0.7 * y).sin()
}

fn hash3(a: i64, b: i64, c: u64) -> u64 {
    let mut z = (a as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (b as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ c.wrapping_mul(0x1656_67B1_9E37_79F9);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

fn unit(h: u64) -> f64 {
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Points on the ice in the 1 m cell `(cx, cy)`: `(id, position, strength)`.
fn cell_points(cx: i64, cy: i64, seed: u64, per_cell: usize, salt: u64) -> impl Iterator<Item = (u64, Vector3<f64>, f64)> {
    (0..per_cell).map(move |j| {
        let h = hash3(cx, cy, seed ^ salt ^ (j as u64).wrapping_mul(0x2545_F491_4F6C_DD1D));
        let x = cx as f64 + unit(h);
        let y = cy as f64 + unit(hash3(cx, cy, h));
        let strength = 0.3 + unit(hash3(cy, cx, h));
        (h, Vector3::new(x, y, ice_z(x, y)), strength)
    })
}

impl SimConfig {
    /// The simulated IMU's grade: the odometry's noise model ([`ImuNoise`]) and the turn-on
    /// bias (uniform in +-[`TURN_ON_BIAS_HALF_WIDTH`], as 1-sigma).
    pub fn imu_grade(&self) -> ImuGrade {
        ImuGrade {
            gyro_noise_density: self.imu.gyro_radps_rthz,
            accel_noise_density: self.imu.acc_mps2_rthz,
            gyro_bias_rw: self.imu.gyro_bias_walk,
            accel_bias_rw: self.imu.acc_bias_walk,
            gyro_bias_sigma: TURN_ON_BIAS_HALF_WIDTH.0 / 3f64.sqrt(),
            accel_bias_sigma: TURN_ON_BIAS_HALF_WIDTH.1 / 3f64.sqrt(),
        }
    }
}

pub fn simulate(cfg: &SimConfig) -> Dataset {
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let dt = 1.0 / cfg.imu_hz;
    let ramp_s = 5.0;
    // Lawnmower turns of 20 s with a smooth (raised-cosine) yaw rate, after the still period and ramp.
    let path = TurnSchedule::of_duration(cfg.leg_m / cfg.speed_mps, 20.0, TurnProfile::RaisedCosine);
    let speed_at = |t: f64| {
        let u = ((t - cfg.still_s) / ramp_s).clamp(0.0, 1.0);
        cfg.speed_mps * u * u * (3.0 - 2.0 * u)
    };
    let z0 = cfg.depth_below_ice_m;
    let depth_at = |t: f64| {
        let u = ((t - cfg.still_s) / 10.0).clamp(0.0, 1.0);
        z0 + u * u * (3.0 - 2.0 * u) * 0.5 * (2.0 * std::f64::consts::PI * (t - cfg.still_s) / 90.0).sin()
    };
    let smooth = |t: f64| {
        let u = ((t - cfg.still_s) / ramp_s).clamp(0.0, 1.0);
        u * u * (3.0 - 2.0 * u)
    };
    let roll_at = |t: f64| smooth(t) * 0.03 * (0.31 * t).sin();
    let pitch_at = |t: f64| smooth(t) * 0.02 * (0.23 * t + 1.0).sin();

    // Truth at the IMU rate.
    let mut truth: Vec<TruthSample> = Vec::new();
    let mut yaw: f64 = 0.0;
    let mut pos = Vector3::new(0.0, 0.0, z0);
    let mut dist = 0.0;
    let mut t = 0.0;
    let mut k = 0usize;
    let tau0 = cfg.still_s + ramp_s;
    loop {
        let s = speed_at(t);
        let vz = (depth_at(t + 1e-3) - depth_at(t - 1e-3)) / 2e-3;
        let vel = Vector3::new(s * yaw.cos(), s * yaw.sin(), vz);
        let rot = Rotation3::from_euler_angles(roll_at(t), pitch_at(t), yaw).into_inner();
        truth.push(TruthSample { t_s: t, rot, pos_w_m: pos, vel_w_mps: vel });
        if dist >= cfg.distance_m {
            break;
        }
        // Advance.
        let t1 = (k + 1) as f64 * dt;
        let yaw1 = yaw + 0.5 * (path.yaw_rate(t - tau0) + path.yaw_rate(t1 - tau0)) * dt;
        let s1 = speed_at(t1);
        let vz1 = (depth_at(t1 + 1e-3) - depth_at(t1 - 1e-3)) / 2e-3;
        let vel1 = Vector3::new(s1 * yaw1.cos(), s1 * yaw1.sin(), vz1);
        let step = 0.5 * (vel + vel1) * dt;
        // Depth follows its profile exactly; horizontal by the trapezoid.
        pos = Vector3::new(pos.x + step.x, pos.y + step.y, depth_at(t1));
        dist += step.norm();
        yaw = yaw1;
        t = t1;
        k += 1;
    }

    // IMU.
    let grade = cfg.imu_grade();
    let bg = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0) * TURN_ON_BIAS_HALF_WIDTH.0);
    let ba = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0) * TURN_ON_BIAS_HALF_WIDTH.1);
    let mut errors = ImuErrors::new(grade, bg, ba, grade.white_sigmas(dt));
    let mut imu = Vec::with_capacity(truth.len());
    for i in 0..truth.len() {
        let (w, a) = if i + 1 < truth.len() {
            let (a0, a1) = (&truth[i], &truth[i + 1]);
            let acc_w = (a1.vel_w_mps - a0.vel_w_mps) / dt;
            (imu::body_rate_between(&a0.rot, &a1.rot, dt), imu::specific_force(&a0.rot, &acc_w, &gravity_w()))
        } else {
            (Vector3::zeros(), imu::specific_force(&truth[i].rot, &Vector3::zeros(), &gravity_w()))
        };
        let (gyro_radps, acc_mps2) = errors.measure(&w, &a, &mut rng, DrawOrder::GyroFirst);
        imu.push(ImuSample { t_s: truth[i].t_s, gyro_radps, acc_mps2 });
        errors.walk(&mut rng, dt, DrawOrder::GyroFirst);
    }

    // Stereo features.
    let cam = cfg.cam;
    let n_px = Normal::new(0.0, cam.sigma_norm()).unwrap_or(Normal::new(0.0, 1e-12).expect("valid"));
    let cam_every = ((cfg.imu_hz / cfg.cam_hz).round() as usize).max(1);
    let mut generation: HashMap<u64, u64> = HashMap::new();
    let mut frames = Vec::new();
    let t_end = truth.last().map_or(0.0, |s| s.t_s);
    for (fi, ti) in (0..truth.len()).step_by(cam_every).enumerate() {
        let tr = &truth[ti];
        let pose = cam.cam_pose(&tr.rot, &tr.pos_w_m);
        let (cx, cy) = (tr.pos_w_m.x.floor() as i64, tr.pos_w_m.y.floor() as i64);
        let mut cand: Vec<(u64, nalgebra::Vector4<f64>)> = Vec::new();
        for gx in cx - 8..=cx + 8 {
            for gy in cy - 8..=cy + 8 {
                for (id, p, _) in cell_points(gx, gy, cfg.seed, 1, 0xFEA7) {
                    let pc = cam.to_cam(&pose, &p);
                    if let Some(z) = cam.project(&pc)
                        && cam.in_view(&z)
                    {
                        cand.push((id, z));
                    }
                }
            }
        }
        cand.sort_by_key(|c| c.0);
        cand.truncate(cfg.max_features);
        let mut obs = Vec::with_capacity(cand.len());
        for (id, z) in cand {
            let g = generation.entry(id).or_insert(0);
            if rng.random::<f64>() < cfg.track_loss_per_frame {
                *g += 1;
            }
            let mut zn = z + nalgebra::Vector4::from_fn(|_, _| n_px.sample(&mut rng));
            if rng.random::<f64>() < cfg.outlier_fraction {
                zn[0] += 25.0 * cam.sigma_norm() * if rng.random::<bool>() { 1.0 } else { -1.0 };
                zn[2] = zn[0] - (z[0] - z[2]);
            }
            obs.push(((id >> 8) * 64 + (*g % 64), zn));
        }
        if in_outage(cfg, tr.t_s) {
            obs.clear();
        }
        frames.push(Frame { t_s: tr.t_s, frame_id: fi as u64, obs });
    }

    // Depth gauge: offset (surface pressure / ice draft), timestamps between IMU samples.
    let offset = 1.7;
    let mut depth = Vec::new();
    let mut td = 0.0023;
    while td < t_end {
        let i = ((td / dt).floor() as usize).min(truth.len() - 1);
        let j = (i + 1).min(truth.len() - 1);
        let u = (td - truth[i].t_s) / dt;
        let g = |s: &TruthSample| s.pos_w_m.z + (s.rot * cfg.depth.lever_b_m).z;
        let truth_d = g(&truth[i]) * (1.0 - u) + g(&truth[j]) * u;
        let frac = td / t_end;
        let sigma = if (0.33..0.66).contains(&frac) { 2.0 * cfg.depth_sigma_m } else { cfg.depth_sigma_m };
        let mut d = truth_d + offset + sigma * Normal::new(0.0, 1.0).expect("valid").sample(&mut rng);
        if rng.random::<f64>() < 0.01 {
            d += 0.5;
        }
        depth.push(DepthReading { t_s: td, depth_m: d });
        td += 1.0 / cfg.depth_hz;
    }

    // Sonar images.
    let mut sonar_frames = Vec::new();
    if cfg.sonar_images {
        let sc = cfg.sonar;
        let every = ((cfg.imu_hz / sc.rate_hz).round() as usize).max(1);
        let mount_b = Vector3::new(0.4, 0.0, 0.0);
        // Sonar frame: x boresight, y right, z completing (down-ish); body <- sonar.
        let rot_bs = Rotation3::from_euler_angles(0.0, sc.tilt_rad, 0.0).into_inner();
        let speckle = Normal::new(0.0, 0.05).expect("valid");
        for ti in (0..truth.len()).step_by(every) {
            let tr = &truth[ti];
            let mut img = Gray::zeros(sc.rows, sc.cols);
            let rot_ws: Matrix3<f64> = tr.rot * rot_bs;
            let origin = tr.pos_w_m + tr.rot * mount_b;
            let fwd = rot_ws.column(0).into_owned();
            let reach = sc.r_max_m.ceil() as i64;
            let (cx, cy) = (origin.x.floor() as i64, origin.y.floor() as i64);
            let bin = sc.range_bin_m();
            let dbeam = sc.hfov_rad / sc.cols as f64;
            for gx in cx - reach..=cx + reach {
                for gy in cy - reach..=cy + reach {
                    let centre = Vector3::new(gx as f64 + 0.5, gy as f64 + 0.5, 0.0);
                    let d = centre - origin;
                    if d.x * fwd.x + d.y * fwd.y < -1.0 {
                        continue;
                    }
                    for (_, p, strength) in cell_points(gx, gy, cfg.seed, 6, 0x50A4) {
                        let s = rot_ws.transpose() * (p - origin);
                        let r = s.norm();
                        if r >= sc.r_max_m - 2.0 * bin || r < 1.0 {
                            continue;
                        }
                        let bearing = s.y.atan2(s.x);
                        let elev = (-s.z).atan2(s.x.hypot(s.y));
                        if bearing.abs() >= sc.hfov_rad / 2.0 || elev.abs() >= sc.vfov_rad / 2.0 {
                            continue;
                        }
                        let (rf, cf) = (r / bin, (bearing + sc.hfov_rad / 2.0) / dbeam);
                        let (r0, c0) = (rf.round() as i64, cf.round() as i64);
                        for rr in r0 - 2..=r0 + 2 {
                            for cc in c0 - 2..=c0 + 2 {
                                if rr < 0 || cc < 0 || rr >= sc.rows as i64 || cc >= sc.cols as i64 {
                                    continue;
                                }
                                let w = (-((rr as f64 - rf).powi(2) + (cc as f64 - cf).powi(2)) / (2.0 * 0.7 * 0.7)).exp();
                                img.data[rr as usize * sc.cols + cc as usize] += strength * w;
                            }
                        }
                    }
                }
            }
            for v in &mut img.data {
                *v = (*v + speckle.sample(&mut rng)).abs();
            }
            sonar_frames.push((tr.t_s, img));
        }
    }

    let (frames, frontend) = if cfg.images {
        let (f, s) = image_frames(cfg, &truth);
        (f, Some(s))
    } else {
        (frames, None)
    };
    Dataset { imu, frames, depth, sonar_frames, sonar_velocity: Vec::new(), truth, cam, still_s: cfg.still_s, frontend, stereo: Vec::new() }
}

fn in_outage(cfg: &SimConfig, t_s: f64) -> bool {
    cfg.vision_outage.is_some_and(|(start, len)| t_s >= start && t_s < start + len)
}

/// Truth samples at the camera times (every `imu_hz / cam_hz`-th sample, as the synthetic tracks).
pub fn camera_samples<'a>(cfg: &SimConfig, truth: &'a [TruthSample]) -> impl Iterator<Item = (u64, &'a TruthSample)> {
    let every = ((cfg.imu_hz / cfg.cam_hz).round() as usize).max(1);
    truth.iter().step_by(every).enumerate().map(|(i, t)| (i as u64, t))
}

/// Render the stereo pair at every camera time into `dir/stereo/` as PNGs and list them in
/// `dir/stereo.csv` (the `--input` format's image form, see `data`).
pub fn write_stereo_images(cfg: &SimConfig, truth: &[TruthSample], dir: &std::path::Path) -> anyhow::Result<()> {
    use anyhow::Context as _;
    let sub = dir.join("stereo");
    std::fs::create_dir_all(&sub).with_context(|| format!("creating {}", sub.display()))?;
    let renderer = StereoRenderer::new(cfg.cam, cfg.water, cfg.seed);
    let mut list = String::from("t_s,left,right\n");
    for (fi, tr) in camera_samples(cfg, truth) {
        let (left, right) = renderer.render_pair(&tr.rot, &tr.pos_w_m, cfg.seed.wrapping_mul(0x1AA6_E5E5) ^ fi);
        let (l, r) = (format!("stereo/{fi:06}_l.png"), format!("stereo/{fi:06}_r.png"));
        super::data::write_png_u8(&dir.join(&l), &left)?;
        super::data::write_png_u8(&dir.join(&r), &right)?;
        list.push_str(&format!("{:.6},{l},{r}\n", tr.t_s));
    }
    std::fs::write(dir.join("stereo.csv"), list).with_context(|| format!("writing {}", dir.join("stereo.csv").display()))?;
    Ok(())
}

/// Render the stereo pair at every camera time and run the front end over them.
pub fn image_frames(cfg: &SimConfig, truth: &[TruthSample]) -> (Vec<Frame>, FrontendStats) {
    let renderer = StereoRenderer::new(cfg.cam, cfg.water, cfg.seed);
    let mut tracker = StereoTracker::new(cfg.cam, cfg.tracker);
    let mut frames = Vec::new();
    for (fi, tr) in camera_samples(cfg, truth) {
        let (left, right) = if in_outage(cfg, tr.t_s) {
            let (w, h) = renderer.size();
            let murk = image::GrayImage::from_pixel(w, h, image::Luma([(cfg.water.veiling * 255.0).round().clamp(0.0, 255.0) as u8]));
            (murk.clone(), murk)
        } else {
            renderer.render_pair(&tr.rot, &tr.pos_w_m, cfg.seed.wrapping_mul(0x1AA6_E5E5) ^ fi)
        };
        let obs = tracker.process(&left, &right);
        frames.push(Frame { t_s: tr.t_s, frame_id: fi, obs });
    }
    (frames, tracker.stats)
}
