//! The odometry's inputs and the truth, in memory and as files. A directory holds:
//! - `imu.csv`: `t_s,gx,gy,gz,ax,ay,az` (rad/s, m/s^2, body FRD),
//! - `tracks.csv`: `t_s,frame_id,feature_id,ul,vl,ur,vr` (normalized stereo image coordinates, one
//!   row per feature and frame; a new id starts a new track),
//! - `depth.csv`: `t_s,depth_m`,
//! - `sonar_velocity.csv` (optional): `t_s,los_mps,peak` (line-of-sight speeds from the sonar
//!   images, as `ice::sonar::velocities` makes them),
//! - `camera.json`: the [`StereoCamera`], `meta.json`: `{"still_s": ..}`,
//! - `truth.csv` (optional): `t_s,qw,qx,qy,qz,x,y,z,vx,vy,vz` (body->world quaternion, NED).
//! - `stereo.csv` (instead of `tracks.csv`): `t_s,left,right` with PNG paths relative to the
//!   directory; the image front end (`frontend::StereoTracker`) makes the tracks from them.
//!
//! The back end therefore runs with or without images (feature tracks from a file or the simulator).
//! Times are written with 1 us resolution, so a written and re-read simulation is not bit-identical
//! to the in-memory one (the estimates agree to millimetres, `tests/ice_sim.rs`).

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Context, Result, bail};
use image::GrayImage;
use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3, Vector4};

use super::camera::{StereoCamera, StereoObs};
use super::frontend::{FrontendStats, StereoTracker, TrackerConfig};
use super::phasecorr::Gray;
use super::propagation::ImuSample;
use super::sonar::SonarVelocity;

#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub t_s: f64,
    pub frame_id: u64,
    pub obs: Vec<(u64, StereoObs)>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthReading {
    pub t_s: f64,
    pub depth_m: f64,
}

#[derive(Debug, Clone, PartialEq)]
pub struct TruthSample {
    pub t_s: f64,
    pub rot: Matrix3<f64>,
    pub pos_w_m: Vector3<f64>,
    pub vel_w_mps: Vector3<f64>,
}

#[derive(Debug, Clone)]
pub struct Dataset {
    pub imu: Vec<ImuSample>,
    pub frames: Vec<Frame>,
    pub depth: Vec<DepthReading>,
    /// Raw sonar images (simulator); turned into `sonar_velocity` by the sonar front end.
    pub sonar_frames: Vec<(f64, Gray)>,
    pub sonar_velocity: Vec<SonarVelocity>,
    pub truth: Vec<TruthSample>,
    pub cam: StereoCamera,
    /// The vehicle floats still for the first `still_s` seconds (static initialization).
    pub still_s: f64,
    /// Image front end counters when the frames came from images.
    pub frontend: Option<FrontendStats>,
    /// Stereo image pairs (`stereo.csv`) still to be tracked: `(t_s, left, right)`.
    pub stereo: Vec<(f64, std::path::PathBuf, std::path::PathBuf)>,
}

fn parse_rows(path: &Path, min_cols: usize) -> Result<Vec<Vec<f64>>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with('t') {
            continue;
        }
        let vals: Result<Vec<f64>, _> = line.split(',').map(|x| x.trim().parse::<f64>()).collect();
        let vals = vals.with_context(|| format!("{}:{}: not a number row: {line:?}", path.display(), i + 1))?;
        if vals.len() < min_cols {
            bail!("{}:{}: expected {min_cols} columns, got {}", path.display(), i + 1, vals.len());
        }
        if vals.iter().any(|v| !v.is_finite()) {
            bail!("{}:{}: NaN or infinite value", path.display(), i + 1);
        }
        rows.push(vals);
    }
    Ok(rows)
}

/// Frame and feature ids in `tracks.csv` are below this (2^64: they are `u64`).
const MAX_ID_EXCLUSIVE: f64 = 18_446_744_073_709_551_616.0;

impl Dataset {
    pub fn read_dir(dir: &Path) -> Result<Self> {
        let imu: Vec<ImuSample> = parse_rows(&dir.join("imu.csv"), 7)?
            .into_iter()
            .map(|r| ImuSample { t_s: r[0], gyro_radps: Vector3::new(r[1], r[2], r[3]), acc_mps2: Vector3::new(r[4], r[5], r[6]) })
            .collect();
        if imu.windows(2).any(|w| w[1].t_s <= w[0].t_s) {
            bail!("imu.csv: timestamps must increase strictly");
        }
        let mut frames: Vec<Frame> = Vec::new();
        let stereo = if !dir.join("tracks.csv").exists() && dir.join("stereo.csv").exists() { read_stereo_list(dir)? } else { Vec::new() };
        let tracks = if stereo.is_empty() { parse_rows(&dir.join("tracks.csv"), 7)? } else { Vec::new() };
        // Ids are whole numbers that fit a u64 (a negative frame number or a 1e30 id became 0
        // or saturated, and the run reported 0 poses as a success).
        let id = |v: f64, what: &str, row: usize| -> Result<u64> {
            if v >= 0.0 && v.fract() == 0.0 && v < MAX_ID_EXCLUSIVE {
                Ok(v as u64)
            } else {
                bail!(
                    "{}: data row {}: {what} must be a whole number in 0..={}, got {v}",
                    dir.join("tracks.csv").display(),
                    row + 1,
                    u64::MAX
                )
            }
        };
        for (i, r) in tracks.iter().enumerate() {
            let (fid, feature) = (id(r[1], "frame_id", i)?, id(r[2], "feature_id", i)?);
            let z = Vector4::new(r[3], r[4], r[5], r[6]);
            match frames.last_mut() {
                Some(f) if f.frame_id == fid => f.obs.push((feature, z)),
                _ => frames.push(Frame { t_s: r[0], frame_id: fid, obs: vec![(feature, z)] }),
            }
        }
        let depth = parse_rows(&dir.join("depth.csv"), 2)?.into_iter().map(|r| DepthReading { t_s: r[0], depth_m: r[1] }).collect();
        let sv = dir.join("sonar_velocity.csv");
        let sonar_velocity = if sv.exists() {
            parse_rows(&sv, 3)?.into_iter().map(|r| SonarVelocity { t_s: r[0], los_mps: r[1], peak: r[2] }).collect()
        } else {
            Vec::new()
        };
        let tp = dir.join("truth.csv");
        let truth = if tp.exists() {
            parse_rows(&tp, 11)?
                .into_iter()
                .map(|r| TruthSample {
                    t_s: r[0],
                    rot: UnitQuaternion::from_quaternion(Quaternion::new(r[1], r[2], r[3], r[4])).to_rotation_matrix().into_inner(),
                    pos_w_m: Vector3::new(r[5], r[6], r[7]),
                    vel_w_mps: Vector3::new(r[8], r[9], r[10]),
                })
                .collect()
        } else {
            Vec::new()
        };
        let (cam_p, meta_p) = (dir.join("camera.json"), dir.join("meta.json"));
        let cam: StereoCamera =
            serde_json::from_str(&std::fs::read_to_string(&cam_p).with_context(|| format!("reading {}", cam_p.display()))?)
                .with_context(|| format!("{} is not a stereo camera", cam_p.display()))?;
        let meta: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&meta_p).with_context(|| format!("reading {}", meta_p.display()))?)
                .with_context(|| format!("{} is not JSON", meta_p.display()))?;
        let still_s = meta.get("still_s").and_then(|v| v.as_f64()).with_context(|| format!("{}: still_s missing", meta_p.display()))?;
        let d = Self { imu, frames, depth, sonar_frames: Vec::new(), sonar_velocity, truth, cam, still_s, frontend: None, stereo };
        d.validate().with_context(|| format!("the data set {}", dir.display()))?;
        Ok(d)
    }

    /// Checks what the odometry relies on, each number against its range: a focal length,
    /// baseline or pixel noise of 0 ("0 features used"), a camera rotation that is not one, no
    /// feature tracks, a still period longer than the data or IMU samples closer than 10 us
    /// ("0 poses", exit 0) are errors naming the file and the bound.
    pub fn validate(&self) -> Result<()> {
        let c = &self.cam;
        let within = |what: &str, v: f64, lo: f64, hi: f64| -> Result<()> {
            if !(v > lo && v <= hi) {
                bail!("{what} must be > {lo} and <= {hi}, got {v}");
            }
            Ok(())
        };
        within("camera.json focal_px", c.focal_px, 0.0, 1e5)?;
        within("camera.json baseline_m", c.baseline_m, 0.0, 10.0)?;
        within("camera.json sigma_px", c.sigma_px, 0.0, 100.0)?;
        within("camera.json width_px", c.width_px, 0.0, f64::from(subnav_base::limits::MAX_IMAGE_SIDE))?;
        within("camera.json height_px", c.height_px, 0.0, f64::from(subnav_base::limits::MAX_IMAGE_SIDE))?;
        let r = c.rot_bc;
        let ortho = (r.transpose() * r - nalgebra::Matrix3::identity()).abs().max();
        if !(ortho < 1e-6 && (r.determinant() - 1.0).abs() < 1e-6 && c.pos_bc_m.iter().all(|v| v.is_finite())) {
            bail!(
                "camera.json rot_bc must be a rotation (orthonormal, determinant 1) and pos_bc_m finite (R^T R - I off by {ortho:.2e}, det {:.6})",
                r.determinant()
            );
        }
        if self.imu.len() < 2 {
            bail!("imu.csv has {} samples: at least 2 are needed", self.imu.len());
        }
        if let Some(w) = self.imu.windows(2).find(|w| w[1].t_s - w[0].t_s < 1e-5) {
            bail!("imu.csv: samples at {} s and {} s are closer than 10 us (at most 100 kHz)", w[0].t_s, w[1].t_s);
        }
        if self.frames.is_empty() && self.stereo.is_empty() {
            bail!("tracks.csv (or stereo.csv) has no feature observations");
        }
        let span = self.imu[self.imu.len() - 1].t_s - self.imu[0].t_s;
        if !(self.still_s >= 0.0 && self.still_s < span) {
            bail!("meta.json still_s must be in [0, {span}) s (the IMU's time span), got {}", self.still_s);
        }
        Ok(())
    }

    /// Run the image front end over the stereo pairs of `stereo.csv` (no-op without them): the
    /// frames are replaced by the tracked observations. A missing or unreadable image is an error.
    pub fn track_images(&mut self, cfg: TrackerConfig) -> Result<()> {
        if self.stereo.is_empty() {
            return Ok(());
        }
        let mut tracker = StereoTracker::new(self.cam, cfg);
        let mut frames = Vec::with_capacity(self.stereo.len());
        for (i, (t_s, l, r)) in self.stereo.iter().enumerate() {
            let (left, right) = (read_png_u8(l)?, read_png_u8(r)?);
            let (w, h) = (self.cam.width_px.round() as u32, self.cam.height_px.round() as u32);
            if left.dimensions() != (w, h) || right.dimensions() != (w, h) {
                bail!("{}: image is {:?}, camera.json says {w}x{h}", l.display(), left.dimensions());
            }
            frames.push(Frame { t_s: *t_s, frame_id: i as u64, obs: tracker.process(&left, &right) });
        }
        self.frames = frames;
        self.frontend = Some(tracker.stats);
        self.stereo.clear();
        Ok(())
    }

    pub fn write_dir(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        // Every write error names its file.
        let put = |name: &str, text: String| -> Result<()> {
            let p = dir.join(name);
            std::fs::write(&p, text).with_context(|| format!("writing {}", p.display()))
        };
        let mut s = String::from("t_s,gx,gy,gz,ax,ay,az\n");
        for m in &self.imu {
            let (g, a) = (m.gyro_radps, m.acc_mps2);
            let _ = writeln!(s, "{:.6},{:e},{:e},{:e},{:e},{:e},{:e}", m.t_s, g.x, g.y, g.z, a.x, a.y, a.z);
        }
        put("imu.csv", s)?;
        let mut s = String::from("t_s,frame_id,feature_id,ul,vl,ur,vr\n");
        for f in &self.frames {
            for (id, z) in &f.obs {
                let _ = writeln!(s, "{:.6},{},{},{:e},{:e},{:e},{:e}", f.t_s, f.frame_id, id, z[0], z[1], z[2], z[3]);
            }
        }
        if self.frames.iter().any(|f| !f.obs.is_empty()) || !dir.join("stereo.csv").exists() {
            put("tracks.csv", s)?;
        }
        let mut s = String::from("t_s,depth_m\n");
        for d in &self.depth {
            let _ = writeln!(s, "{:.6},{:.6}", d.t_s, d.depth_m);
        }
        put("depth.csv", s)?;
        let mut s = String::from("t_s,los_mps,peak\n");
        for v in &self.sonar_velocity {
            let _ = writeln!(s, "{:.6},{:e},{:e}", v.t_s, v.los_mps, v.peak);
        }
        put("sonar_velocity.csv", s)?;
        let mut s = String::from("t_s,qw,qx,qy,qz,x,y,z,vx,vy,vz\n");
        for t in &self.truth {
            let q = UnitQuaternion::from_matrix(&t.rot);
            let (p, v) = (t.pos_w_m, t.vel_w_mps);
            let _ = writeln!(
                s,
                "{:.6},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e}",
                t.t_s, q.w, q.i, q.j, q.k, p.x, p.y, p.z, v.x, v.y, v.z
            );
        }
        put("truth.csv", s)?;
        put("camera.json", serde_json::to_string_pretty(&self.cam)?)?;
        put("meta.json", serde_json::json!({"still_s": self.still_s}).to_string())?;
        Ok(())
    }
}

fn read_stereo_list(dir: &Path) -> Result<Vec<(f64, std::path::PathBuf, std::path::PathBuf)>> {
    let path = dir.join("stereo.csv");
    let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if line.trim().is_empty() {
            continue;
        }
        let [t, l, r] = f[..] else { bail!("{}:{}: expected t_s,left,right", path.display(), i + 1) };
        let t: f64 =
            t.parse().ok().filter(|t: &f64| t.is_finite()).with_context(|| format!("{}:{}: bad time {t:?}", path.display(), i + 1))?;
        if out.last().is_some_and(|p: &(f64, _, _)| p.0 >= t) {
            bail!("{}:{}: times must increase", path.display(), i + 1);
        }
        out.push((t, dir.join(l), dir.join(r)));
    }
    Ok(out)
}

fn read_png_u8(path: &Path) -> Result<GrayImage> {
    let g = read_png_gray(path)?;
    let data = g.data.iter().map(|v| (v * 255.0).round().clamp(0.0, 255.0) as u8).collect();
    GrayImage::from_raw(g.cols as u32, g.rows as u32, data).context("image size")
}

/// Write an 8-bit grey PNG.
pub fn write_png_u8(path: &Path, img: &GrayImage) -> Result<()> {
    let file = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), img.width(), img.height());
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header()?;
    w.write_image_data(img.as_raw())?;
    Ok(())
}

/// A PNG as a grey image (luma 0.299 R + 0.587 G + 0.114 B for colour), samples scaled to [0, 1].
pub fn read_png_gray(path: &Path) -> Result<Gray> {
    let file = std::fs::File::open(path).with_context(|| format!("opening {}", path.display()))?;
    let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
    decoder.set_transformations(png::Transformations::EXPAND);
    let mut reader = decoder.read_info().with_context(|| format!("{} is not a readable PNG", path.display()))?;
    let (w, h) = (reader.info().width, reader.info().height);
    subnav_base::limits::check_image_size(&path.display().to_string(), w, h).map_err(anyhow::Error::msg)?;
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).with_context(|| format!("decoding {}", path.display()))?;
    let (w, h) = (info.width as usize, info.height as usize);
    let channels = info.color_type.samples();
    let sample = |i: usize| -> f64 {
        match info.bit_depth {
            png::BitDepth::Sixteen => u16::from_be_bytes([buf[2 * i], buf[2 * i + 1]]) as f64 / 65535.0,
            _ => buf[i] as f64 / 255.0,
        }
    };
    let mut data = Vec::with_capacity(w * h);
    for p in 0..w * h {
        let base = p * channels;
        data.push(match channels {
            1 | 2 => sample(base),
            3 | 4 => 0.299 * sample(base) + 0.587 * sample(base + 1) + 0.114 * sample(base + 2),
            n => bail!("{}: unsupported PNG with {n} channels", path.display()),
        });
    }
    Ok(Gray::new(h, w, data)?)
}
