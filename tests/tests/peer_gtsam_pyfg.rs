//! Peer check of the range-aided 2-D graph (`subnav_fgo::range2d`) against GTSAM 4.3 on real AUV
//! data: GOATS 15 and 16 (`gtsam/Data/goats_1{5,6}.pyfg` of the wheel, read in place), beacons
//! known and unknown, with and without our range gate. For each case both sides start LM from
//! the same initial values (ours: dead reckoning, rigidly placed on the known beacons or with
//! multilaterated unknown ones) with the same factors (GTSAM's `BetweenFactorPose2`,
//! `RangeFactor2D`, `NonlinearEqualityPoint2` / `PriorFactorPose2`; the range variances the gate
//! left), and both run until no step lowers the cost. The problems are poorly conditioned
//! (smallest eigenvalue of the information 3.7e-4 with unknown beacons on GOATS 15, condition
//! 3e11): a 1e-5..1e-4 m move along the weakest direction changes the cost by ~1e-12 of it,
//! below what either LM's cost comparisons resolve, so the two LM results stop up to ~1e-4 m
//! apart (printed). The check is therefore: the final costs agree to 1e-12 (relative), the LM
//! results to 1e-3 m, and Gauss-Newton (exact steps, no cost test) from GTSAM's LM result lands
//! within 1e-6 m and 1e-6 rad of ours polished the same way: one stationary point.

use std::io::Write;
use std::process::{Command, Stdio};

use serde_json::{Value, json};
use subnav_fgo::kitti;
use subnav_fgo::nalgebra::Vector2;
use subnav_fgo::pyfg::{Pose2, PyFg};
use subnav_fgo::range2d::{Beacons, Graph2, Init, LmOptions2, RangeGate, wrap};

#[test]
fn goats_optimum_equals_gtsam_levenberg_marquardt() {
    let python = subnav_tests::peer_python();
    let dir = kitti::gtsam_data_dir(&python).expect("gtsam Data folder");
    // both sides run until no step lowers the cost (tolerances 0), so that neither stops on a
    // flat stretch of this poorly conditioned problem at a different point than the other
    let opts = LmOptions2 { max_iterations: 50, relative_tol: 0.0, absolute_tol: 0.0 };
    let mut problems = Vec::new();
    let mut ours: Vec<(String, Graph2, subnav_fgo::range2d::Lm2Report, Graph2)> = Vec::new();
    for set in ["goats_15", "goats_16"] {
        let file = dir.join(format!("{set}.pyfg"));
        let fg = PyFg::read(&file).expect("GOATS parses");
        for mode in [Beacons::Known, Beacons::Unknown] {
            for gated in [false, true] {
                let start = Graph2::from_pyfg(&fg, mode, Init::Odometry).expect("initial values");
                // the variances the gate leaves (its rounds start from `start` too)
                let mut gated_run = start.clone();
                let gate = RangeGate { enabled: gated, ..Default::default() };
                let (_, summary) = gated_run.solve_gated(&gate, &opts).expect("gated solve");
                let mut g = start.clone();
                for (r, v) in g.ranges.iter_mut().zip(&gated_run.ranges) {
                    r.3 = v.3;
                }
                let pose_init: Vec<[f64; 3]> = g.poses.iter().map(|p| [p.x_m, p.y_m, p.theta_rad]).collect();
                let beacon_init: Vec<[f64; 2]> = g.beacons.iter().map(|b| [b.x, b.y]).collect();
                let report = g.solve_lm(&opts).expect("LM");
                problems.push(json!({
                    "file": file, "beacons": if mode == Beacons::Known { "known" } else { "unknown" },
                    "poses": pose_init, "beacon_init": beacon_init,
                    "range_var": g.ranges.iter().map(|r| r.3).collect::<Vec<_>>(),
                    "prior0": g.prior0.map(|(m, s)| json!({"mean": [m.x_m, m.y_m, m.theta_rad], "sigmas": s})),
                    "lm": {"max_iterations": opts.max_iterations, "relative_tol": opts.relative_tol, "absolute_tol": opts.absolute_tol},
                }));
                let mut polished = g.clone();
                polished.polish_gauss_newton(5).expect("Gauss-Newton polish");
                ours.push((format!("{set} {mode:?} gated={gated} ({} inflated)", summary.inflated), g, report, polished));
            }
        }
    }
    let mut child = Command::new(&python)
        .arg(subnav_tests::peers_dir().join("gtsam_pyfg.py"))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("peer python runs");
    child.stdin.take().expect("stdin").write_all(json!({ "problems": problems }).to_string().as_bytes()).expect("write");
    let out = child.wait_with_output().expect("peer finished");
    assert!(out.status.success(), "gtsam_pyfg.py failed:\n{}", String::from_utf8_lossy(&out.stderr));
    let peer: Value = serde_json::from_slice(&out.stdout).expect("peer JSON");
    let peer = peer.as_array().expect("one result per problem");
    assert_eq!(peer.len(), ours.len());
    let f = |v: &Value| v.as_f64().expect("number");
    // largest position (m), heading (rad) and beacon (m) differences of `g` from a peer's lists
    let diff = |g: &Graph2, poses: &Value, beacons: &Value| -> (f64, f64, f64) {
        let mut dp = 0.0f64;
        let mut dth = 0.0f64;
        for (x, q) in g.poses.iter().zip(poses.as_array().expect("poses")) {
            dp = dp.max((x.x_m - f(&q[0])).abs()).max((x.y_m - f(&q[1])).abs());
            dth = dth.max(wrap(x.theta_rad - f(&q[2])).abs());
        }
        let mut db = 0.0f64;
        for (b, q) in g.beacons.iter().zip(beacons.as_array().expect("beacons")) {
            db = db.max((b.x - f(&q[0])).abs()).max((b.y - f(&q[1])).abs());
        }
        (dp, dth, db)
    };
    for ((name, g, report, polished), p) in ours.iter().zip(peer) {
        let (lp, lth, lb) = diff(g, &p["poses"], &p["beacons"]);
        let (dp, dth, db) = {
            // Gauss-Newton from GTSAM's optimum, compared with ours polished the same way
            let mut y = g.clone();
            for (q, v) in y.poses.iter_mut().zip(p["poses"].as_array().expect("poses")) {
                *q = Pose2::new(f(&v[0]), f(&v[1]), f(&v[2]));
            }
            for (b, v) in y.beacons.iter_mut().zip(p["beacons"].as_array().expect("beacons")) {
                *b = Vector2::new(f(&v[0]), f(&v[1]));
            }
            y.polish_gauss_newton(3).expect("Gauss-Newton from GTSAM's optimum");
            let as_json = |x: &Graph2| {
                (
                    json!(x.poses.iter().map(|q| [q.x_m, q.y_m, q.theta_rad]).collect::<Vec<_>>()),
                    json!(x.beacons.iter().map(|b| [b.x, b.y]).collect::<Vec<_>>()),
                )
            };
            let (yp, yb) = as_json(&y);
            diff(polished, &yp, &yb)
        };
        println!(
            "{name}: compared max |dp| {dp:.2e} m, |dtheta| {dth:.2e} rad, |dbeacon| {db:.2e} m (LM results as they stop: {lp:.1e} m, {lth:.1e} rad, {lb:.1e} m); cost ours {:.6e} -> {:.12e} ({} it), GTSAM {:.6e} -> {:.12e} ({} it, {:.3} s)",
            report.initial_cost,
            report.final_cost,
            report.iterations,
            f(&p["initial_error"]),
            f(&p["final_error"]),
            p["iterations"],
            f(&p["wall_s"])
        );
        assert!((report.initial_cost - f(&p["initial_error"])).abs() <= 1e-9 * report.initial_cost, "{name}: different problems");
        assert!((report.final_cost - f(&p["final_error"])).abs() <= 1e-12 * report.final_cost, "{name}: different minima");
        assert!(lp <= 1e-3 && lb <= 1e-3, "{name}: LM results far apart");
        assert!(dp <= 1e-6 && db <= 1e-6 && dth <= 1e-6, "{name}: optima differ");
    }
}
