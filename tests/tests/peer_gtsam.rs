//! Peer checks of the factor-graph navigator (host/src/fgo) against GTSAM 4.3 from PyPI:
//! 1. IMU preintegration equals GTSAM's `PreintegratedImuMeasurements` on the same samples and
//!    parameters: Delta R, v, p (and the tangent vector) to 1e-9, covariance to 1e-6 relative,
//!    the ImuFactor residual covariance to 1e-6 relative, and the bias-corrected prediction (bias
//!    Jacobians) to 1e-9.
//! 2. A batch problem built identically in both (IMU + bias random walk + DVL as a GTSAM
//!    CustomFactor + USBL + priors) optimises to the same states: position to 1e-6 m. The solve
//!    times are printed (`--nocapture`); the release-mode ratio is recorded in
//!    docs/PERFORMANCE.md.

use std::io::Write;
use std::process::{Command, Stdio};
use std::time::Instant;

use serde_json::{Value, json};
use subnav_base::so3;
use subnav_fgo::factors::Factor;
use subnav_fgo::nalgebra::{DMatrix, Matrix3, Vector3};
use subnav_fgo::preintegration::{ImuParams, Preintegrated};
use subnav_fgo::sim::{SimConfig, simulate};
use subnav_fgo::smoother::{self, SmootherConfig, imu_pieces};
use subnav_fgo::solver::{self, LmOptions};
use subnav_fgo::state::{ImuBias, NavState};

fn run_peer(script: &str, input: &Value) -> Value {
    let py = subnav_tests::peer_python();
    let path = subnav_tests::peers_dir().join(script);
    let mut child = Command::new(&py)
        .arg(&path)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot run {} {}: {e}", py.display(), path.display()));
    child.stdin.take().expect("stdin").write_all(input.to_string().as_bytes()).expect("write stdin");
    let out = child.wait_with_output().expect("peer finished");
    assert!(out.status.success(), "{script} failed:\n{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("peer JSON")
}

fn m3(m: &Matrix3<f64>) -> Value {
    json!([[m[(0, 0)], m[(0, 1)], m[(0, 2)]], [m[(1, 0)], m[(1, 1)], m[(1, 2)]], [m[(2, 0)], m[(2, 1)], m[(2, 2)]]])
}
fn dm(m: &DMatrix<f64>) -> Value {
    json!((0..m.nrows()).map(|r| (0..m.ncols()).map(|c| m[(r, c)]).collect::<Vec<_>>()).collect::<Vec<_>>())
}
fn v3(v: &Vector3<f64>) -> Value {
    json!([v.x, v.y, v.z])
}
fn get_m3(v: &Value) -> Matrix3<f64> {
    Matrix3::from_fn(|r, c| v[r][c].as_f64().expect("number"))
}
fn get_v(v: &Value) -> Vec<f64> {
    v.as_array().expect("array").iter().map(|x| x.as_f64().expect("number")).collect()
}
fn get_v3(v: &Value) -> Vector3<f64> {
    Vector3::from_vec(get_v(v))
}
fn params_json(p: &ImuParams) -> Value {
    json!({
        "gravity": p.gravity_enu_mps2,
        "acc_cov": m3(&p.acc_cov()),
        "gyro_cov": m3(&p.gyro_cov()),
        "int_cov": m3(&p.integration_cov()),
    })
}

fn preint_case(name: &str, pieces: &[[f64; 7]], bias_hat: ImuBias, params: ImuParams) {
    let mut pim = Preintegrated::new(params, bias_hat);
    for p in pieces {
        pim.integrate(&Vector3::new(p[0], p[1], p[2]), &Vector3::new(p[3], p[4], p[5]), p[6]).expect("valid sample");
    }
    let state_i = NavState::new(so3::exp(&Vector3::new(0.2, -0.1, 1.3)), Vector3::new(10.0, -20.0, -35.0), Vector3::new(1.2, 0.4, -0.05));
    let bias2 = ImuBias::new(bias_hat.acc_mps2 + Vector3::new(2e-3, -1e-3, 3e-3), bias_hat.gyro_radps + Vector3::new(-2e-4, 3e-4, 1e-4));
    let input = json!({
        "gravity": params.gravity_enu_mps2,
        "acc_cov": m3(&params.acc_cov()), "gyro_cov": m3(&params.gyro_cov()), "int_cov": m3(&params.integration_cov()),
        "bias_hat": bias_hat.to_array(),
        "samples": pieces,
        "predict": {"R": m3(&state_i.rot_enu_flu), "p": v3(&state_i.pos_enu_m), "v": v3(&state_i.vel_enu_mps), "bias": bias2.to_array()},
    });
    let g = run_peer("gtsam_preint.py", &input);
    let zeta = get_v(&g["preintegrated"]);
    let zeta_err = (0..9).map(|i| (zeta[i] - pim.zeta[i]).abs()).fold(0.0, f64::max);
    let r_err = (get_m3(&g["delta_R"]) - pim.delta_rot()).amax();
    let p_err = (get_v3(&g["delta_p"]) - pim.delta_pos()).amax();
    let v_err = (get_v3(&g["delta_v"]) - pim.delta_vel()).amax();
    let gc = &g["cov"];
    let cov_g = DMatrix::from_fn(9, 9, |r, c| gc[r][c].as_f64().expect("number"));
    let cov_m = DMatrix::from_fn(9, 9, |r, c| pim.cov[(r, c)]);
    let cov_rel = (&cov_g - &cov_m).amax() / cov_g.amax();
    let rc = &g["residual_cov"];
    let rcov_g = DMatrix::from_fn(9, 9, |r, c| rc[r][c].as_f64().expect("number"));
    let rcov = pim.residual_cov();
    let rcov_m = DMatrix::from_fn(9, 9, |r, c| rcov[(r, c)]);
    let rcov_rel = (&rcov_g - &rcov_m).amax() / rcov_g.amax();
    let diag_rel = (0..9).map(|i| ((cov_g[(i, i)] - cov_m[(i, i)]) / cov_g[(i, i)]).abs()).fold(0.0, f64::max);
    let pred = pim.predict(&state_i, &bias2);
    let pred_err = (get_v3(&g["predict_p"]) - pred.pos_enu_m)
        .amax()
        .max((get_v3(&g["predict_v"]) - pred.vel_enu_mps).amax())
        .max((get_m3(&g["predict_R"]) - pred.rot_enu_flu).amax());
    println!(
        "preintegration [{name}] {} pieces, {:.3} s: |dzeta| {zeta_err:.2e} |dR| {r_err:.2e} |dp| {p_err:.2e} |dv| {v_err:.2e} cov rel {cov_rel:.2e} (diag {diag_rel:.2e}) residual cov rel {rcov_rel:.2e} predict {pred_err:.2e}",
        pieces.len(),
        pim.delta_t_s
    );
    assert!((g["delta_t"].as_f64().expect("dt") - pim.delta_t_s).abs() < 1e-12);
    assert!(zeta_err < 1e-9 && r_err < 1e-9 && p_err < 1e-9 && v_err < 1e-9, "[{name}] increments differ from GTSAM");
    assert!(cov_rel < 1e-6 && diag_rel < 1e-6, "[{name}] covariance differs from GTSAM: {cov_rel:e} / {diag_rel:e}");
    assert!(rcov_rel < 1e-6, "[{name}] residual covariance differs from GTSAM: {rcov_rel:e}");
    assert!(pred_err < 1e-9, "[{name}] bias-corrected prediction differs: {pred_err:e}");
}

#[test]
fn preintegration_equals_gtsam() {
    let sim = simulate(&SimConfig { duration_s: 12.0, seed: 11, ..Default::default() });
    let params = sim.log.config.imu;
    let bias_hat = ImuBias::new(Vector3::new(0.01, -0.02, 0.015), Vector3::new(1e-3, -5e-4, 2e-4));
    // 1: a turn of the simulated mission, off-grid start and end (partial samples)
    let turn = imu_pieces(&sim.log.imu, 0.0037, 1.5021).expect("pieces");
    preint_case("mission 1.5 s", &turn, bias_hat, params);
    // 2: a long interval (10 s) through the 180-degree turn
    let long = imu_pieces(&sim.log.imu, 0.5, 10.5).expect("pieces");
    preint_case("mission 10 s", &long, bias_hat, params);
    // 3: aggressive rates and irregular dt
    let aggressive: Vec<[f64; 7]> = (0..300)
        .map(|k| {
            let t = k as f64 * 0.005;
            [3.0 * t.sin(), -2.0 * (2.0 * t).cos(), 9.81 + t, 1.5 * (3.0 * t).cos(), 0.8, -2.0 * t.sin(), 0.004 + 0.002 * ((k % 3) as f64)]
        })
        .collect();
    preint_case("aggressive", &aggressive, bias_hat, params);
    // 4: at rest with zero bias: theta stays ~0 (small-angle branches)
    let rest: Vec<[f64; 7]> = (0..100).map(|_| [0.0, 0.0, 9.81, 1e-9, -2e-9, 0.0, 0.01]).collect();
    preint_case("near zero rotation", &rest, ImuBias::default(), params);
}

#[test]
fn batch_lm_agrees_with_gtsam() {
    // FGO_PEER_DURATION_S makes the problem larger for the timing run in docs/PERFORMANCE.md.
    let duration_s = std::env::var("FGO_PEER_DURATION_S").ok().and_then(|s| s.parse().ok()).unwrap_or(20.0);
    let sim = simulate(&SimConfig { duration_s, seed: 5, ..Default::default() });
    let res = smoother::run(&sim.log, SmootherConfig::default(), false, |_, _| {}).expect("smoother runs");
    let est = res.batch;
    let mut factors = res.batch_factors;
    // the solver check is on the IMU noise as given (the adaptive gate may have scaled the
    // smoother's IMU factors, issue 36; GTSAM builds its factors from the parameters)
    factors.iter_mut().for_each(|f| f.set_imu_noise_scale(1.0));
    let params = sim.log.config.imu;
    let prior_cfg = sim.log.config.prior;
    let mut imu = Vec::new();
    let mut bias_rw = Vec::new();
    let mut dvl = Vec::new();
    let mut usbl = Vec::new();
    let mut n_prior = 0;
    for f in &factors {
        match f {
            Factor::Imu(x) => imu.push(json!({
                "i": x.node_i, "j": x.node_j, "bias_hat": x.pim.bias_hat.to_array(),
                "samples": imu_pieces(&sim.log.imu, est[x.node_i].t_s, est[x.node_j].t_s).expect("pieces"),
            })),
            Factor::BiasRw(x) => bias_rw.push(json!({"i": x.node_i, "j": x.node_j, "cov": dm(&x.noise.cov)})),
            Factor::Dvl(x) => dvl.push(json!({
                "node": x.node, "vel": v3(&x.vel_dvl_mps), "R_bd": m3(&x.rot_body_dvl), "lever": v3(&x.lever_body_m),
                "omega": v3(&x.omega_body_radps), "cov": dm(&x.noise.cov),
            })),
            Factor::Usbl(x) => {
                usbl.push(json!({"node": x.node, "pos": v3(&x.pos_enu_m), "lever": v3(&x.lever_body_m), "cov": dm(&x.noise.cov)}))
            }
            Factor::Prior(x) => {
                assert_eq!(x.node, 0);
                n_prior += 1;
            }
            Factor::Marginal(_) => panic!("batch problem must not contain marginal priors"),
            Factor::Range(_) => panic!("the simulated mission has no range factors"),
        }
    }
    assert_eq!(n_prior, 1);
    assert!(!usbl.is_empty() && !dvl.is_empty());
    let prior = factors.iter().find_map(|f| if let Factor::Prior(p) = f { Some(p.clone()) } else { None }).expect("prior factor");
    let problem = json!({
        "params": params_json(&params),
        "nodes": est.iter().map(|e| json!({
            "R": m3(&e.state.nav.rot_enu_flu), "p": v3(&e.state.nav.pos_enu_m), "v": v3(&e.state.nav.vel_enu_mps),
            "ba": v3(&e.state.bias.acc_mps2), "bg": v3(&e.state.bias.gyro_radps),
        })).collect::<Vec<_>>(),
        "prior": {
            "node": 0, "R": m3(&prior.mean.nav.rot_enu_flu), "p": v3(&prior.mean.nav.pos_enu_m), "v": v3(&prior.mean.nav.vel_enu_mps),
            "ba": v3(&prior.mean.bias.acc_mps2), "bg": v3(&prior.mean.bias.gyro_radps), "sigmas": prior_cfg.sigmas,
        },
        "imu": imu, "bias_rw": bias_rw, "dvl": dvl, "usbl": usbl,
    });
    let g = run_peer("gtsam_batch.py", &problem);
    let mut nodes: Vec<_> = est.iter().map(|e| e.state).collect();
    let t0 = Instant::now();
    let report = solver::solve_lm(&mut nodes, &factors, &LmOptions::default()).expect("LM");
    let ours_s = t0.elapsed().as_secs_f64();
    let gnodes = g["nodes"].as_array().expect("nodes");
    assert_eq!(gnodes.len(), nodes.len());
    let (mut dp, mut dv, mut dr, mut db) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (x, gn) in nodes.iter().zip(gnodes) {
        dp = dp.max((x.nav.pos_enu_m - get_v3(&gn["p"])).amax());
        dv = dv.max((x.nav.vel_enu_mps - get_v3(&gn["v"])).amax());
        dr = dr.max(so3::log(&(x.nav.rot_enu_flu.transpose() * get_m3(&gn["R"]))).amax());
        db = db.max((x.bias.acc_mps2 - get_v3(&gn["ba"])).amax()).max((x.bias.gyro_radps - get_v3(&gn["bg"])).amax());
    }
    let gtsam_s = g["solve_s"].as_f64().expect("time");
    println!(
        "batch LM: {} nodes, {} factors ({} DVL custom, {} USBL); max |dp| {dp:.2e} m |dv| {dv:.2e} m/s |dR| {dr:.2e} rad |db| {db:.2e}; \
         ours {} it {:.4} s (cost {:.6e} -> {:.6e}), GTSAM {} it {:.4} s (error {:.6e} -> {:.6e}); time ratio ours/GTSAM {:.3}; \
         GTSAM ImuFactor noise vs preintMeasCov max rel {:.1e}",
        nodes.len(),
        factors.len(),
        dvl.len(),
        usbl.len(),
        report.iterations,
        ours_s,
        report.initial_cost,
        report.final_cost,
        g["iterations"],
        gtsam_s,
        g["initial_error"].as_f64().unwrap_or(f64::NAN),
        g["final_error"].as_f64().unwrap_or(f64::NAN),
        ours_s / gtsam_s,
        g["imu_noise_vs_preint_cov_max_rel"].as_f64().unwrap_or(f64::NAN),
    );
    assert!(report.converged);
    // both minimise the same cost: GTSAM's error is 0.5 * sum |W r|^2 like ours
    let gi = g["initial_error"].as_f64().expect("error");
    assert!((gi - report.initial_cost).abs() <= 1e-6 * gi.abs().max(1.0), "initial costs differ: GTSAM {gi} ours {}", report.initial_cost);
    assert!(dp < 1e-6, "positions differ by {dp} m");
    assert!(dv < 1e-6 && dr < 1e-6, "velocity {dv} / attitude {dr} differ");
}
