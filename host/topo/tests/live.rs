//! The online mapper fed by a (simulated) firmware navigation solution (`subnav_topo::live`):
//! the equivalent-measurement fix against an independent joint-Gaussian derivation, its
//! statistical consistency (NEES) against the naive fix, a rendered racetrack survey closed
//! through the fixes, and bad input.

use nalgebra::{DMatrix, DVector, Matrix2, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use subnav_topo::live::fix::{equivalent_fix, kalman_update, sym, tri};
use subnav_topo::live::*;
use subnav_topo::live_eval::ScoredMapper;
use subnav_topo::polar_image::{N_FEATURES, demosaic, features, stokes};
use subnav_topo::scene::{Scene, SceneConfig, coastal_water};
use subnav_topo::survey::Racetrack;

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    StandardNormal.sample(rng)
}

/// A random PD 2x2 with eigenvalues in about [lo, hi].
fn random_pd(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> Matrix2<f64> {
    let th: f64 = rng.random::<f64>() * std::f64::consts::PI;
    let (c, s) = (th.cos(), th.sin());
    let u = Matrix2::new(c, -s, s, c);
    let l = Matrix2::new(lo + (hi - lo) * rng.random::<f64>(), 0.0, 0.0, lo + (hi - lo) * rng.random::<f64>());
    let m = u * l * u.transpose();
    (m + m.transpose()) * 0.5
}

/// Sample of N(0, p) (2-D).
fn draw(rng: &mut ChaCha8Rng, p: &Matrix2<f64>) -> Vector2<f64> {
    let l = p.cholesky().expect("PD").l();
    l * Vector2::new(normal(rng), normal(rng))
}

fn close_m(a: &Matrix2<f64>, b: &Matrix2<f64>, tol: f64) -> bool {
    (a - b).abs().max() <= tol * (1.0 + b.abs().max())
}

fn close_v(a: &Vector2<f64>, b: &Vector2<f64>, tol: f64) -> bool {
    (a - b).abs().max() <= tol * (1.0 + b.abs().max())
}

/// The posterior of x(t1) from the joint Gaussian of (e0, d, v) conditioned on m = d + v: an
/// independent derivation of (mu, Sigma).
fn brute_force(x1: Vector2<f64>, m: Vector2<f64>, p0: &Matrix2<f64>, d: &Matrix2<f64>, v: &Matrix2<f64>) -> (Vector2<f64>, Matrix2<f64>) {
    let mut c = DMatrix::<f64>::zeros(6, 6);
    c.view_mut((0, 0), (2, 2)).copy_from(p0);
    c.view_mut((2, 2), (2, 2)).copy_from(d);
    c.view_mut((4, 4), (2, 2)).copy_from(v);
    let mut h = DMatrix::<f64>::zeros(2, 6);
    h[(0, 2)] = 1.0;
    h[(1, 3)] = 1.0;
    h[(0, 4)] = 1.0;
    h[(1, 5)] = 1.0;
    let s = &h * &c * h.transpose();
    let s_inv = s.try_inverse().expect("S invertible");
    let k = &c * h.transpose() * s_inv;
    let mv = DVector::from_column_slice(m.as_slice());
    let mean = &k * mv;
    let cov = &c - &k * &h * &c;
    // x(t1) = x1 - e1 = x1 - e0 - d.
    let mut t = DMatrix::<f64>::zeros(2, 6);
    t[(0, 0)] = 1.0;
    t[(1, 1)] = 1.0;
    t[(0, 2)] = 1.0;
    t[(1, 3)] = 1.0;
    let mu = x1 - Vector2::from_column_slice((&t * mean).as_slice());
    let sig = &t * cov * t.transpose();
    (mu, Matrix2::new(sig[(0, 0)], sig[(0, 1)], sig[(1, 0)], sig[(1, 1)]))
}

#[test]
fn equivalent_measurement_reproduces_the_joint_gaussian_posterior() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for case in 0..500 {
        let p0 = random_pd(&mut rng, 0.05, 9.0);
        let d = random_pd(&mut rng, 0.05, 9.0);
        let v = random_pd(&mut rng, 0.1, 4.0);
        let p1 = p0 + d;
        let x0 = Vector2::new(50.0 * normal(&mut rng), 50.0 * normal(&mut rng));
        let x1 = x0 + Vector2::new(3.0 * normal(&mut rng), 3.0 * normal(&mut rng));
        let fm = equivalent_fix(x0, &p0, x1, &p1, &v, 1e-9).unwrap_or_else(|e| panic!("case {case}: {e:?}"));
        assert!(close_m(&fm.drift, &d, 1e-9), "case {case}: drift {} vs {d}", fm.drift);
        // Fusing the equivalent measurement into the firmware's prior gives the posterior.
        let (xk, pk) = kalman_update(x1, &p1, fm.z, &fm.r).expect("update");
        assert!(close_v(&xk, &fm.mu, 1e-9), "case {case}: fused {xk} vs mu {}", fm.mu);
        assert!(close_m(&pk, &fm.sigma, 1e-9), "case {case}: fused {pk} vs Sigma {}", fm.sigma);
        // And the posterior is the joint-Gaussian one.
        let (mu_bf, sig_bf) = brute_force(x1, x1 - x0, &p0, &d, &v);
        assert!(close_v(&fm.mu, &mu_bf, 1e-9), "case {case}: mu {} vs brute force {mu_bf}", fm.mu);
        assert!(close_m(&fm.sigma, &sig_bf, 1e-9), "case {case}: Sigma {} vs brute force {sig_bf}", fm.sigma);
        // R = (Sigma^-1 - P1^-1)^-1 by definition, symmetric.
        let r_def = (fm.sigma.try_inverse().unwrap() - p1.try_inverse().unwrap()).try_inverse().unwrap();
        assert!(close_m(&fm.r, &r_def, 1e-7), "case {case}: R {} vs definition {r_def}", fm.r);
        assert_eq!(fm.r[(0, 1)], fm.r[(1, 0)]);
        assert_eq!(fm.sigma[(0, 1)], fm.sigma[(1, 0)]);
        let s_inv = (d + v).try_inverse().unwrap();
        let m = x1 - x0;
        assert!((fm.gate_d2 - (m.transpose() * s_inv * m)[(0, 0)]).abs() < 1e-9 * (1.0 + fm.gate_d2));
    }
    // P0 -> 0: the node is exactly known; the fix is the node with the recognition covariance.
    let v = Matrix2::new(1.0, 0.2, 0.2, 0.5);
    let d = Matrix2::new(2.0, -0.3, -0.3, 1.0);
    let p0 = Matrix2::identity() * 1e-12;
    let (x0, x1) = (Vector2::new(10.0, 5.0), Vector2::new(11.0, 4.0));
    let fm = equivalent_fix(x0, &p0, x1, &(p0 + d), &v, 1e-9).unwrap();
    assert!(close_m(&fm.r, &v, 1e-9), "R {} vs V {v}", fm.r);
    assert!(close_v(&fm.z, &x0, 1e-9), "z {} vs x0 {x0}", fm.z);
    // D -> 0: no new information, R grows without bound (and stays PD, finite).
    let p0 = Matrix2::new(2.0, 0.5, 0.5, 1.0);
    let mut last = 0.0;
    for e in [1e-2, 1e-4, 1e-6] {
        let fm = equivalent_fix(x0, &p0, x0, &(p0 + Matrix2::identity() * e), &v, 1e-12).unwrap();
        let lo = fm.r.symmetric_eigenvalues().min();
        assert!(lo > 0.5 / (e * e) * 1e-2 && lo > last, "D = {e} I: smallest eigenvalue of R {lo}");
        last = lo;
    }
    assert!(last > 1e9);
    // Bad inputs are refused, not NaN out.
    assert!(equivalent_fix(x0, &p0, Vector2::new(f64::NAN, 0.0), &p0, &v, 0.01).is_err());
    assert!(equivalent_fix(x0, &p0, x1, &Matrix2::new(1.0, 2.0, 2.0, 1.0), &v, 0.01).is_err());
    assert!(equivalent_fix(x0, &p0, x1, &(p0 + d), &Matrix2::zeros(), 0.01).is_err());
}

#[test]
fn fused_fix_is_consistent_and_the_naive_fix_is_overconfident() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let n = 20_000;
    // Node error dominant (the firmware had drifted before placing it), then little drift.
    let cases = [
        (Matrix2::new(4.0, 0.8, 0.8, 3.0), Matrix2::new(1.0, -0.2, -0.2, 0.7), Matrix2::identity() * 0.25),
        (Matrix2::new(2.0, 0.0, 0.0, 6.0), Matrix2::new(3.0, 1.0, 1.0, 2.0), Matrix2::identity() * 1.0),
    ];
    for (ci, (p0, d, v)) in cases.iter().enumerate() {
        let p1 = p0 + d;
        let (mut nees, mut nees_naive) = (0.0, 0.0);
        for _ in 0..n {
            let truth0 = Vector2::new(20.0, -7.0);
            let truth1 = truth0 + draw(&mut rng, v);
            let e0 = draw(&mut rng, p0);
            let dd = draw(&mut rng, d);
            let x0 = truth0 + e0;
            let x1 = truth1 + e0 + dd;
            let fm = equivalent_fix(x0, p0, x1, &p1, v, 1e-9).expect("fix");
            let (xp, pp) = kalman_update(x1, &p1, fm.z, &fm.r).expect("update");
            let e = xp - truth1;
            nees += (e.transpose() * pp.try_inverse().unwrap() * e)[(0, 0)];
            // Naive: the node position as an independent measurement of x(t1).
            let (xn, pn) = kalman_update(x1, &p1, x0, &(p0 + v)).expect("update");
            let e = xn - truth1;
            nees_naive += (e.transpose() * pn.try_inverse().unwrap() * e)[(0, 0)];
        }
        let (nees, nees_naive) = (nees / n as f64, nees_naive / n as f64);
        println!("case {ci}: mean NEES {nees:.3} (equivalent fix), {nees_naive:.3} (naive)");
        assert!((nees - 2.0).abs() < 0.06, "case {ci}: mean NEES {nees}, expected 2");
        assert!(nees_naive > 2.6, "case {ci}: the naive fix should be overconfident, NEES {nees_naive}");
    }
}

// ---------------------------------------------------------------------------------------------
// A simulated firmware: truth + a random-walk drift error, covariance growing accordingly; fixes
// fused with a Kalman update.

struct Firmware {
    err: Vector2<f64>,
    p: Matrix2<f64>,
    q_m2ps: f64,
}

impl Firmware {
    fn new(p0_m2: f64, q_m2ps: f64, rng: &mut ChaCha8Rng) -> Self {
        let p = Matrix2::identity() * p0_m2;
        Firmware { err: draw(rng, &p), p, q_m2ps }
    }

    fn step(&mut self, dt_s: f64, w: Vector2<f64>) {
        self.err += w * (self.q_m2ps * dt_s).sqrt();
        self.p += Matrix2::identity() * self.q_m2ps * dt_s;
    }

    fn sample(&self, t_us: u64, truth: [f64; 2]) -> NavSample {
        NavSample {
            t_us,
            pos_ned_m: [truth[0] + self.err[0], truth[1] + self.err[1], 10.0],
            cov_ne_m2: tri(&self.p),
            aided: true,
            vel_sigma_mps: 0.01,
        }
    }

    fn fuse(&mut self, truth: [f64; 2], fix: &MapFix) {
        let x = Vector2::new(truth[0], truth[1]) + self.err;
        let (xp, pp) = kalman_update(x, &self.p, Vector2::from(fix.pos_ne_m), &sym(fix.cov_ne_m2)).expect("fix PD");
        self.err = xp - Vector2::new(truth[0], truth[1]);
        self.p = pp;
    }

    fn nees(&self) -> f64 {
        (self.err.transpose() * self.p.try_inverse().unwrap() * self.err)[(0, 0)]
    }
}

#[test]
fn rendered_racetrack_closes_loops_through_the_firmware() {
    let started = std::time::Instant::now();
    let track = Racetrack { leg_m: 40.0, radius_m: 10.0, speed_mps: 1.0, depth_m: 10.0 };
    let lap_s = track.perimeter_m() / track.speed_mps;
    let duration_s = 6.0 * lap_s;
    let (frame_dt_us, nav_dt_us) = (500_000u64, 100_000u64);
    let mut rng = ChaCha8Rng::seed_from_u64(std::env::var("LIVE_SEED").ok().and_then(|v| v.parse().ok()).unwrap_or(3));
    let (el, az) = (50f64.to_radians(), 150f64.to_radians());
    let sun = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), -el.sin());
    let scene = Scene::new(SceneConfig::default(), coastal_water(), sun, track.depth_m, &mut rng);
    let cfg = LiveConfig { train_after_nodes: 24, ..LiveConfig::default() };
    let mut mapper = ScoredMapper::new(cfg);
    let q = 0.02;
    let mut fw = Firmware::new(0.25, q, &mut rng);
    let mut dr = Firmware { err: fw.err, p: fw.p, q_m2ps: q };
    let (mut sq_fw, mut sq_dr, mut nees_fw, mut n_last) = (0.0, 0.0, 0.0, 0usize);
    let mut fixes = 0;
    let mut frame_no = 0u32;
    let end_us = (duration_s * 1e6) as u64;
    let mut t_us = 0u64;
    while t_us <= end_us {
        let truth = track.at(t_us as f64 * 1e-6).0;
        mapper.on_nav(fw.sample(t_us, truth));
        if t_us % frame_dt_us == 0 {
            let (truth, yaw) = track.at(t_us as f64 * 1e-6);
            let mosaic = scene.render(truth[0], truth[1], yaw, &mut rng);
            let f: [f64; N_FEATURES] = features(&stokes(&demosaic(&mosaic)));
            let frame = CameraFrame { frame: frame_no, t_us, features: Some(f) };
            frame_no += 1;
            if let FrameOutcome::Fix(fix) = mapper.on_frame(&frame, Some(truth)) {
                // The downlink command carries the fix and the firmware's own depth (uninformative).
                let cmd = fix.to_command(fix.prior_depth_m, 1e4);
                let subnav_wire::Command::PositionFix { t_us: ct, pos_ned_m, cov_ned_m2 } = cmd else { panic!("{cmd:?}") };
                // Stamped with the frame that matched best, held at most `best_match_hold_s`
                // (this frame ends the hold: it matches worse, or another node, or none).
                let hold_us = (cfg.best_match_hold_s * 1e6) as u64 + frame_dt_us;
                assert!(ct <= t_us && t_us - ct <= hold_us, "fix of {ct} µs sent at {t_us} µs");
                assert_eq!(pos_ned_m, [fix.pos_ne_m[0] as f32, fix.pos_ne_m[1] as f32, 10.0]);
                assert_eq!(cov_ned_m2, [fix.cov_ne_m2[0] as f32, fix.cov_ne_m2[1] as f32, 0.0, fix.cov_ne_m2[2] as f32, 0.0, 1e4]);
                fw.fuse(truth, &fix);
                fixes += 1;
            }
            if t_us as f64 * 1e-6 > duration_s - lap_s {
                sq_fw += fw.err.norm_squared();
                sq_dr += dr.err.norm_squared();
                nees_fw += fw.nees();
                n_last += 1;
            }
        }
        t_us += nav_dt_us;
        let w = Vector2::new(normal(&mut rng), normal(&mut rng));
        fw.step(nav_dt_us as f64 * 1e-6, w);
        dr.step(nav_dt_us as f64 * 1e-6, w);
    }
    let (s, sc) = (mapper.stats(), mapper.score());
    let (rms_fw, rms_dr) = ((sq_fw / n_last as f64).sqrt(), (sq_dr / n_last as f64).sqrt());
    println!("{}", serde_json::to_string_pretty(&s).unwrap());
    println!(
        "last lap: rms error with fixes {rms_fw:.2} m, without {rms_dr:.2} m, mean NEES with fixes {:.2}; final sigma with fixes {:.2} m, without {:.2} m; {:.1} s",
        nees_fw / n_last as f64,
        fw.p.trace().sqrt(),
        dr.p.trace().sqrt(),
        started.elapsed().as_secs_f64()
    );
    assert!(s.trained, "the metric was never learned");
    assert!(s.recognitions >= 10, "too few recognitions: {}", s.recognitions);
    assert!(sc.precision.is_some_and(|p| p >= 0.9), "precision {:?}", sc.precision);
    assert!(sc.recall.is_some_and(|r| r > 0.2), "recall {:?}", sc.recall);
    assert!(fixes >= 5 && s.fixes == fixes as u64, "fixes {fixes}, stats {}", s.fixes);
    assert_eq!(mapper.closures().len(), fixes);
    assert!(rms_fw < 0.7 * rms_dr, "the fixes should reduce the error: {rms_fw} m vs {rms_dr} m without");
    assert!(fw.p.trace() < 0.5 * dr.p.trace());
    assert!(nees_fw / (n_last as f64) < 6.0, "the fused solution is overconfident: mean NEES {}", nees_fw / n_last as f64);

    // A frame whose features are copied from a far node's sample: appearance matches that node,
    // the position gate refuses it.
    let here = track.at(t_us as f64 * 1e-6).0;
    let far = mapper
        .nodes()
        .iter()
        .filter(|n| mapper.scorer.node_truth(n.id).is_some_and(|p| (p[0] - here[0]).hypot(p[1] - here[1]) > 30.0) && !n.samples.is_empty())
        .max_by(|a, b| {
            let d = |n: &LiveNode| (n.pos_ned_m[0] - here[0]).hypot(n.pos_ned_m[1] - here[1]);
            d(a).total_cmp(&d(b))
        })
        .expect("a far node");
    let (far_id, copied) = (far.id, far.samples[0]);
    let refusals = s.gate_refusals;
    mapper.on_nav(fw.sample(t_us, here));
    let out = mapper.on_frame(&CameraFrame { frame: frame_no, t_us, features: Some(copied) }, Some(here));
    println!("copied features of node {far_id}: {out:?}");
    assert_eq!(mapper.stats().gate_refusals, refusals + 1, "{out:?}");
    assert!(!matches!(out, FrameOutcome::Fix(f) if f.node == far_id), "{out:?}");
}

// ---------------------------------------------------------------------------------------------
// Synthetic places (no rendering): features a smooth function of the true position.

/// The first frame that matches a node is seen while the vehicle still approaches its place;
/// holding the recognition for the best-matching frame, and taking the place where that
/// frame's best-matching sample was taken, puts the recognised place closer to where the
/// vehicle is. The same frames and navigation (the mapper uses no randomness) with the hold off
/// and on: the mean distance from the recognised place to the vehicle (the navigation barely
/// drifts, so the navigation's own error cancels; the median) must halve.
#[test]
fn holding_a_recognition_for_its_best_frame_finds_the_place_closer() {
    let track = Racetrack { leg_m: 40.0, radius_m: 10.0, speed_mps: 1.0, depth_m: 10.0 };
    let duration_s = 3.0 * track.perimeter_m() / track.speed_mps;
    let mean_offset = |hold_s: f64| -> (f64, usize) {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (el, az) = (50f64.to_radians(), 150f64.to_radians());
        let sun = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), -el.sin());
        let scene = Scene::new(SceneConfig::default(), coastal_water(), sun, track.depth_m, &mut rng);
        // Drift floored at 1 m^2 so that fixes are computed although the navigation is good.
        let cfg = LiveConfig { train_after_nodes: 24, min_drift_m2: 1.0, best_match_hold_s: hold_s, ..LiveConfig::default() };
        let mut mapper = ScoredMapper::new(cfg);
        let fw = Firmware::new(1.0, 1e-6, &mut rng);
        let (mut offsets, mut frame_no, mut t_us) = (Vec::new(), 0u32, 0u64);
        while t_us as f64 * 1e-6 <= duration_s {
            let (truth, yaw) = track.at(t_us as f64 * 1e-6);
            mapper.on_nav(fw.sample(t_us, truth));
            if t_us % 500_000 == 0 {
                let f: [f64; N_FEATURES] = features(&stokes(&demosaic(&scene.render(truth[0], truth[1], yaw, &mut rng))));
                if let FrameOutcome::Fix(fix) = mapper.on_frame(&CameraFrame { frame: frame_no, t_us, features: Some(f) }, Some(truth)) {
                    offsets.push((fix.place_ne_m[0] - fix.prior_ne_m[0]).hypot(fix.place_ne_m[1] - fix.prior_ne_m[1]));
                }
                frame_no += 1;
            }
            t_us += 100_000;
        }
        // The median: a look-alike recognition (a few per cent) is metres off either way.
        offsets.sort_by(f64::total_cmp);
        (offsets.get(offsets.len() / 2).copied().unwrap_or(f64::NAN), offsets.len())
    };
    let (first, n_first) = mean_offset(0.0);
    let (best, n_best) = mean_offset(LiveConfig::default().best_match_hold_s);
    println!("recognised place to vehicle: first frame {first:.2} m ({n_first} fixes), best frame {best:.2} m ({n_best} fixes)");
    assert!(n_first >= 5 && n_best >= 5, "fixes {n_first} / {n_best}");
    assert!(best < 0.5 * first, "holding for the best frame: {best:.2} m against {first:.2} m for the first");
}

fn place_features(p: [f64; 2], rng: &mut ChaCha8Rng) -> [f64; N_FEATURES] {
    std::array::from_fn(|k| {
        let (a, b, ph) = (0.11 + 0.037 * k as f64, 0.07 * (k as f64 - 9.5), 0.7 * k as f64);
        (a * p[0] + b * p[1] + ph).sin() + 0.3 * (0.05 * (k as f64 + 1.0) * p[0] - 0.13 * p[1]).cos() + 0.02 * normal(rng)
    })
}

/// A square loop of side 30 m at 1 m/s, position at `t_s`.
fn square(t_s: f64) -> [f64; 2] {
    let s = t_s.rem_euclid(120.0);
    match (s / 30.0) as u32 {
        0 => [s, 0.0],
        1 => [30.0, s - 30.0],
        2 => [90.0 - s, 30.0],
        _ => [0.0, 120.0 - s],
    }
}

fn nav_at(t_us: u64, drift_m2ps: f64) -> NavSample {
    let p = square(t_us as f64 * 1e-6);
    let v = 0.1 + drift_m2ps * t_us as f64 * 1e-6;
    NavSample { t_us, pos_ned_m: [p[0], p[1], 5.0], cov_ne_m2: [v, 0.0, v], aided: true, vel_sigma_mps: 0.01 }
}

#[test]
fn bad_input_is_counted_and_survived() {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let cfg = LiveConfig { train_after_nodes: 1000, max_nodes: 12, ..LiveConfig::default() };
    let mut m = LiveMapper::new(cfg);
    let frame = |n: u32, t_us: u64, rng: &mut ChaCha8Rng| CameraFrame {
        frame: n,
        t_us,
        features: Some(place_features(square(t_us as f64 * 1e-6), rng)),
    };
    // No nav yet: retry later, nothing counted.
    assert_eq!(m.on_frame(&frame(0, 0, &mut rng)), FrameOutcome::NeedNav);
    assert_eq!(m.stats().frames, 0);
    let mut nav_t = 0u64;
    let mut feed_nav_to = |m: &mut LiveMapper, t_us: u64| {
        while nav_t <= t_us {
            assert_eq!(m.on_nav(nav_at(nav_t, 0.01)), NavOutcome::Accepted);
            nav_t += 100_000;
        }
    };
    feed_nav_to(&mut m, 1_000_000);
    assert_eq!(m.on_frame(&frame(0, 0, &mut rng)), FrameOutcome::Placed { node: 0 });
    assert_eq!(m.on_frame(&frame(1, 500_000, &mut rng)), FrameOutcome::Sampled { node: 0 });
    // Duplicate counter, counter going back, time going back.
    assert_eq!(m.on_frame(&frame(1, 500_000, &mut rng)), FrameOutcome::Ignored { reason: IgnoreReason::Duplicate });
    assert_eq!(m.on_frame(&frame(0, 600_000, &mut rng)), FrameOutcome::Ignored { reason: IgnoreReason::OutOfOrder });
    assert_eq!(m.on_frame(&frame(2, 400_000, &mut rng)), FrameOutcome::Ignored { reason: IgnoreReason::OutOfOrder });
    // Frame counter gap of 3 (frames 2..=4 never arrive).
    assert_eq!(m.on_frame(&frame(5, 1_000_000, &mut rng)), FrameOutcome::Sampled { node: 0 });
    let s = m.stats();
    assert_eq!((s.frames_duplicated, s.frames_out_of_order, s.frames_missing), (1, 2, 3), "{s:?}");
    // Nav ahead of the frames is needed: a frame past the newest nav sample waits.
    assert_eq!(m.on_frame(&frame(6, 1_500_000, &mut rng)), FrameOutcome::NeedNav);
    // Non-finite nav and covariances that are not PSD are refused; time going back ignored.
    let mut bad = nav_at(1_040_000, 0.01);
    bad.pos_ned_m[1] = f64::NAN;
    assert_eq!(m.on_nav(bad), NavOutcome::Refused);
    bad = nav_at(1_040_000, 0.01);
    bad.cov_ne_m2 = [1.0, 2.0, 1.0];
    assert_eq!(m.on_nav(bad), NavOutcome::Refused);
    bad.cov_ne_m2 = [f64::INFINITY, 0.0, 1.0];
    assert_eq!(m.on_nav(bad), NavOutcome::Refused);
    assert_eq!(m.on_nav(nav_at(500_000, 0.01)), NavOutcome::OutOfOrder);
    // Correlation one f32 rounding past 1: clamped, accepted.
    let mut edge = nav_at(1_050_000, 0.01);
    edge.cov_ne_m2 = [2.0, (2.0f32 * 3.0).sqrt() as f64 * (1.0 + 1e-7), 3.0];
    assert_eq!(m.on_nav(edge), NavOutcome::Accepted);
    let s = m.stats();
    assert_eq!((s.nav_refused, s.nav_out_of_order), (3, 1));
    // Non-finite features are refused.
    feed_nav_to(&mut m, 2_000_000);
    let mut f = frame(6, 1_500_000, &mut rng);
    f.features.as_mut().unwrap()[3] = f64::NAN;
    assert_eq!(m.on_frame(&f), FrameOutcome::Refused { reason: Refusal::NonFiniteFeatures });
    assert_eq!(m.stats().frames_nonfinite_features, 1);

    // Drive on: nodes every 6 m of travel.
    let mut n = 7u32;
    let mut t = 2_000_000u64;
    let mut run = |m: &mut LiveMapper, until_us: u64, blackout: Option<(u64, u64)>, rng: &mut ChaCha8Rng| {
        let mut placed = Vec::new();
        while t < until_us {
            feed_nav_to(m, t);
            let mut fr = frame(n, t, rng);
            if blackout.is_some_and(|(a, b)| t >= a && t < b) {
                fr.features = None;
            }
            if let FrameOutcome::Placed { node } = m.on_frame(&fr) {
                placed.push((node, t));
            }
            n += 1;
            t += 500_000;
        }
        placed
    };
    let placed = run(&mut m, 40_000_000, None, &mut rng);
    let spacing: Vec<u64> = placed.windows(2).map(|w| w[1].1 - w[0].1).collect();
    assert!(spacing.iter().all(|&dt| (6_000_000..=7_500_000).contains(&dt)), "node spacing in time at 1 m/s: {spacing:?}");
    // Blackout of 60 s: no nodes then; after it, a node as soon as images return.
    let before = m.stats();
    let placed = run(&mut m, 110_000_000, Some((45_000_000, 105_000_000)), &mut rng);
    let s = m.stats();
    assert_eq!(s.frames_without_features - before.frames_without_features, 120);
    assert!(placed.iter().all(|&(_, pt)| !(45_000_000..105_000_000).contains(&pt)), "{placed:?}");
    assert!(placed.iter().any(|&(_, pt)| pt == 105_000_000), "a node when images return: {placed:?}");
    // The node cap.
    let _ = run(&mut m, 200_000_000, None, &mut rng);
    let s = m.stats();
    assert_eq!(s.nodes, 12);
    assert_eq!(m.nodes().len(), 12);
    assert!(s.map_full_events > 3, "{s:?}");
    // A frame older than the nav window (nav 35 s ahead), and a frame across a nav gap.
    feed_nav_to(&mut m, t + 35_000_000);
    assert_eq!(m.on_frame(&frame(n, t, &mut rng)), FrameOutcome::Ignored { reason: IgnoreReason::NavExpired });
    assert_eq!(m.stats().frames_nav_expired, 1);
    let gap_end = nav_t + 5_000_000;
    assert_eq!(m.on_nav(nav_at(gap_end, 0.01)), NavOutcome::Accepted);
    let out = m.on_frame(&frame(n + 1, gap_end - 1_000_000, &mut rng));
    assert!(matches!(out, FrameOutcome::Refused { reason: Refusal::NavGap { .. } }), "{out:?}");
    assert_eq!(m.stats().frames_nav_gap, 1);
    let n = n + 1;
    // Unaided nav: no nodes, no recognition.
    let mut un = nav_at(gap_end + 100_000, 0.01);
    un.aided = false;
    m.on_nav(un);
    assert_eq!(m.on_frame(&frame(n + 1, gap_end + 50_000, &mut rng)), FrameOutcome::Ignored { reason: IgnoreReason::NotAided });
    assert_eq!(m.stats().frames_unaided, 1);
    // Camera restart: the counter starts again from 0 while time goes on. The first frames are out
    // of order; once `restart_frames` (3) agree, the new counter is accepted.
    let mut t = gap_end + 100_000;
    for _ in 0..6 {
        t += 100_000;
        let mut a = nav_at(t, 0.01);
        a.aided = false;
        m.on_nav(a);
    }
    let before = m.stats();
    let outs: Vec<FrameOutcome> = (0..4u32).map(|k| m.on_frame(&frame(k, gap_end + 150_000 + k as u64 * 100_000, &mut rng))).collect();
    let s = m.stats();
    assert_eq!(s.frames_out_of_order - before.frames_out_of_order, 2, "{outs:?}");
    assert_eq!(s.camera_restarts, 1);
    assert_eq!(outs[3], FrameOutcome::Ignored { reason: IgnoreReason::NotAided }, "accepted after the restart: {outs:?}");
    assert_eq!(s.frames_missing, before.frames_missing, "a restart is not a gap");
    // A lone low counter (corrupted) is ignored and does not reset anything.
    assert_eq!(m.on_frame(&frame(1, gap_end + 600_000, &mut rng)), FrameOutcome::Ignored { reason: IgnoreReason::OutOfOrder });
    assert_eq!(m.on_frame(&frame(4, gap_end + 650_000, &mut rng)), FrameOutcome::Ignored { reason: IgnoreReason::NotAided });
    assert_eq!(m.stats().camera_restarts, 1);
    // One nav sample stamped an hour in the future: the following good ones are out of order until
    // `nav_reset_samples` (10) agree, then the window starts again from them.
    let future = nav_at(t + 3_600_000_000, 0.01);
    assert_eq!(m.on_nav(future), NavOutcome::Accepted);
    let outs: Vec<NavOutcome> = (1..=10u64).map(|k| m.on_nav(nav_at(t + k * 100_000, 0.01))).collect();
    assert!(outs[..9].iter().all(|o| *o == NavOutcome::OutOfOrder), "{outs:?}");
    assert_eq!(outs[9], NavOutcome::TimeBaseReset);
    assert_eq!(m.on_nav(nav_at(t + 1_100_000, 0.01)), NavOutcome::Accepted);
    assert_eq!(m.stats().nav_time_resets, 1);
    let out = m.on_frame(&frame(5, t + 1_050_000, &mut rng));
    assert!(!matches!(out, FrameOutcome::NeedNav | FrameOutcome::Ignored { reason: IgnoreReason::NavExpired }), "{out:?}");
}

#[test]
fn fixes_need_drift_since_the_node_and_nan_never_comes_out() {
    // Laps of a square with synthetic features: with the covariance growing, revisits give fixes;
    // with a constant covariance (no drift since the nodes: nothing new), recognitions give none.
    for (drift, want_fixes) in [(0.02, true), (0.0, false)] {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let cfg = LiveConfig { train_after_nodes: 20, ..LiveConfig::default() };
        let mut m = ScoredMapper::new(cfg);
        let mut fixes = Vec::new();
        let mut nav_t = 0u64;
        for k in 0..(3 * 240u32) {
            let t = k as u64 * 500_000;
            while nav_t <= t {
                m.on_nav(nav_at(nav_t, drift));
                nav_t += 100_000;
            }
            let p = square(t as f64 * 1e-6);
            let out = m.on_frame(&CameraFrame { frame: k, t_us: t, features: Some(place_features(p, &mut rng)) }, Some(p));
            if let FrameOutcome::Fix(f) = out {
                assert!(f.pos_ne_m.iter().chain(f.cov_ne_m2.iter()).all(|v| v.is_finite()));
                let c = sym(f.cov_ne_m2);
                assert!(c[(0, 0)] > 0.0 && c.determinant() > 0.0);
                fixes.push(f);
            }
        }
        let s = m.stats();
        println!("drift {drift}: {}", serde_json::to_string(&s).unwrap());
        assert!(s.trained && s.recognitions > 20, "{s:?}");
        assert!(m.score().precision.is_some_and(|p| p >= 0.9), "{s:?} {:?}", m.score());
        if want_fixes {
            assert!(fixes.len() > 5, "{s:?}");
            // Isotropic covariances: the equivalent measurement is never more precise than the
            // recognition itself (R >= V).
            assert!(fixes.windows(2).all(|w| w[1].t_us - w[0].t_us >= 2_000_000), "fixes closer than min_fix_interval_s");
            for f in &fixes {
                assert!(sym(f.cov_ne_m2).symmetric_eigenvalues().min() >= 0.99 * cfg.recognition_sigma_m.powi(2), "{f:?}");
            }
        } else {
            assert!(fixes.is_empty(), "{fixes:?}");
            assert!(s.fixes_refused_no_information > 0, "{s:?}");
        }
    }
}

/// Two laps of the square, the second over the first's nodes. With the firmware's drift small
/// the second lap recognises them; with the drift since the nodes grown past `max_gate_sigma_m`
/// (the DVL lost for minutes, say) the same images are not recognised (the gate would admit
/// look-alikes), and each refusal is counted as a gate too wide.
#[test]
fn no_recognition_through_a_gate_wider_than_the_scene_repeats() {
    let run = |drift_m2ps: f64| {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let mut m = ScoredMapper::new(LiveConfig { train_after_nodes: 10, ..LiveConfig::default() });
        let mut nav_t = 0u64;
        for k in 0..480u32 {
            let t_us = u64::from(k) * 500_000;
            while nav_t <= t_us + 100_000 {
                assert_eq!(m.on_nav(nav_at(nav_t, drift_m2ps)), NavOutcome::Accepted);
                nav_t += 100_000;
            }
            let p = square(t_us as f64 * 1e-6);
            let f = CameraFrame { frame: k, t_us, features: Some(place_features(p, &mut rng)) };
            assert_ne!(m.on_frame(&f, Some(p)), FrameOutcome::NeedNav);
        }
        m.stats()
    };
    let small = run(0.002);
    let large = run(1.0);
    assert!(small.trained && large.trained);
    assert!(small.recognitions >= 20 && small.gate_too_wide == 0, "{small:?}");
    assert_eq!(large.recognitions, 0, "{large:?}");
    assert!(large.gate_too_wide >= 20, "{large:?}");
}

/// The laps of `fixes_need_drift_since_the_node_and_nan_never_comes_out` with the firmware's
/// velocity aided (sigma 0.01 m/s) and unaided (0.2 m/s, the DVL lost): the same recognitions,
/// but no fix while the velocity is unaided, each refusal counted; a NaN velocity sigma counts
/// as unaided.
#[test]
fn no_fix_while_the_firmwares_velocity_is_unaided() {
    let run = |vel_sigma_mps: f64| {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let mut m = ScoredMapper::new(LiveConfig { train_after_nodes: 20, ..LiveConfig::default() });
        let (mut fixes, mut nav_t) = (0, 0u64);
        for k in 0..(3 * 240u32) {
            let t = u64::from(k) * 500_000;
            while nav_t <= t {
                m.on_nav(NavSample { vel_sigma_mps, ..nav_at(nav_t, 0.02) });
                nav_t += 100_000;
            }
            let p = square(t as f64 * 1e-6);
            let out = m.on_frame(&CameraFrame { frame: k, t_us: t, features: Some(place_features(p, &mut rng)) }, Some(p));
            fixes += usize::from(matches!(out, FrameOutcome::Fix(_)));
        }
        (fixes, m.stats().clone())
    };
    let (aided, sa) = run(0.01);
    assert!(aided > 5 && sa.fixes_refused_velocity == 0, "{sa:?}");
    for unaided in [0.2, f64::NAN] {
        let (n, s) = run(unaided);
        assert_eq!(n, 0, "{s:?}");
        assert_eq!(s.recognitions, sa.recognitions, "recognition goes on");
        assert!(s.fixes_refused_velocity >= aided as u64, "{s:?}");
    }
}
