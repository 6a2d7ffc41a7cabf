//! The image front end on rendered under-ice stereo pairs, checked against the simulator's truth
//! (an analytic reference: the ice surface and the camera poses are known exactly).
//!
//! Every track's first left observation is cast back through the known pose onto the ice surface;
//! that 3-D point, projected with the truth poses of the later frames (left and right camera,
//! through the same flat-port model), is where KLT should have found it. Then the odometry runs
//! on the image tracks.

use nalgebra::Vector3;
use subnav_ice::camera::StereoCamera;
use subnav_ice::frontend::refract_air_to_water;
use subnav_ice::montecarlo::{Variant, run_seed};
use subnav_ice::odometry::OdometryConfig;
use subnav_ice::render::intersect_ice;
use subnav_ice::sim::{SimConfig, camera_samples, image_frames, simulate};

fn percentile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// Normalized water-side observation -> pixel of the air-side image (inverse of the front end).
fn to_px(cam: &StereoCamera, x: f64, y: f64, n: f64) -> (f64, f64) {
    let (xa, ya) = refract_air_to_water(x, y, 1.0 / n).unwrap();
    (xa * cam.focal_px + (cam.width_px - 1.0) / 2.0, ya * cam.focal_px + (cam.height_px - 1.0) / 2.0)
}

#[test]
fn klt_tracks_follow_the_true_ice_points() {
    let sim = SimConfig { seed: 4, distance_m: 25.0, images: true, ..SimConfig::default() };
    // The synthetic tracks of `simulate` are not used here: render and track once, below.
    let data = simulate(&SimConfig { images: false, ..sim });
    let (frames, stats) = image_frames(&sim, &data.truth);
    eprintln!("{stats:?}");
    let cam = sim.cam;
    let poses: Vec<_> = camera_samples(&sim, &data.truth).map(|(_, t)| (t.rot, t.pos_w_m)).collect();
    assert_eq!(poses.len(), frames.len());
    let mut anchor: std::collections::HashMap<u64, Vector3<f64>> = Default::default();
    let (mut err_l, mut err_r, mut lengths) = (Vec::new(), Vec::new(), std::collections::HashMap::<u64, usize>::new());
    for (f, (rot, pos)) in frames.iter().zip(&poses) {
        let pose = cam.cam_pose(rot, pos);
        let rot_wc = pose.rot_cw.transpose();
        for (id, z) in &f.obs {
            *lengths.entry(*id).or_default() += 1;
            let Some(p) = anchor.get(id).copied() else {
                let d = rot_wc * Vector3::new(z[0], z[1], 1.0);
                let (_, p) = intersect_ice(&pose.pos_wc, &d).expect("looks up");
                anchor.insert(*id, p);
                continue;
            };
            let pc = cam.to_cam(&pose, &p);
            let h = cam.project(&pc).expect("in front");
            let n = sim.tracker.n_water;
            let (a, b) = (to_px(&cam, z[0], z[1], n), to_px(&cam, h[0], h[1], n));
            err_l.push((a.0 - b.0).hypot(a.1 - b.1));
            let (a, b) = (to_px(&cam, z[2], z[3], n), to_px(&cam, h[2], h[3], n));
            err_r.push((a.0 - b.0).hypot(a.1 - b.1));
        }
    }
    let long = lengths.values().filter(|&&n| n >= 3).count();
    let per_frame = stats.observations as f64 / stats.frames as f64;
    let (l50, l95) = (percentile(&mut err_l, 0.5), percentile(&mut err_l, 0.95));
    let (r50, r95) = (percentile(&mut err_r, 0.5), percentile(&mut err_r, 0.95));
    eprintln!(
        "{} frames, {per_frame:.1} obs/frame, {} tracks ({long} with >= 3 frames); left err median {l50:.3} px p95 {l95:.3}; right {r50:.3} / {r95:.3}",
        frames.len(),
        lengths.len()
    );
    assert!(per_frame > 30.0, "{per_frame} observations per frame");
    assert!(long > 100, "{long} tracks long enough for the MSCKF");
    assert!(l50 < 0.5 && l95 < 1.5, "left {l50} / {l95} px");
    assert!(r50 < 0.5 && r95 < 1.5, "right {r50} / {r95} px");
}

#[test]
fn odometry_on_image_tracks() {
    let sim = SimConfig { seed: 2, distance_m: 60.0, images: true, ..SimConfig::default() };
    let res = run_seed(&sim, &OdometryConfig::default(), &[Variant::Full]).unwrap();
    let m = &res[0].metrics;
    eprintln!("{m:?}\n{:?}", res[0].stats);
    assert!(m.distance_m > 55.0);
    assert!(m.drift_pct < 1.0, "drift {:.3} %", m.drift_pct);
}

#[test]
fn written_images_give_the_same_tracks_and_bad_images_are_errors() {
    let sim = SimConfig { seed: 9, distance_m: 6.0, images: true, ..SimConfig::default() };
    let data = simulate(&SimConfig { images: false, ..sim });
    let dir = tempfile::tempdir().unwrap();
    let mut on_disk = data.clone();
    on_disk.frames.clear();
    subnav_ice::sim::write_stereo_images(&sim, &data.truth, dir.path()).unwrap();
    on_disk.write_dir(dir.path()).unwrap();
    assert!(!dir.path().join("tracks.csv").exists());
    let mut back = subnav_ice::data::Dataset::read_dir(dir.path()).unwrap();
    back.track_images(sim.tracker).unwrap();
    let (frames, _) = image_frames(&sim, &data.truth);
    assert_eq!(back.frames.len(), frames.len());
    // PNG is lossless and the tracker deterministic: identical observations (times to 1 us).
    for (a, b) in back.frames.iter().zip(&frames) {
        assert_eq!(a.obs, b.obs);
        assert!((a.t_s - b.t_s).abs() < 1e-6);
    }
    assert!(back.frontend.unwrap().observations > 1000);
    // A missing image and an image of the wrong size are errors, not panics.
    let first = dir.path().join("stereo/000003_l.png");
    std::fs::remove_file(&first).unwrap();
    let mut missing = subnav_ice::data::Dataset::read_dir(dir.path()).unwrap();
    assert!(missing.track_images(sim.tracker).is_err());
    subnav_ice::data::write_png_u8(&first, &image::GrayImage::new(8, 8)).unwrap();
    let mut small = subnav_ice::data::Dataset::read_dir(dir.path()).unwrap();
    let err = small.track_images(sim.tracker).unwrap_err();
    assert!(format!("{err:#}").contains("camera.json"), "{err:#}");
}
