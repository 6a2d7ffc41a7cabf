//! The factor graph and the navigation filter on real data: the first 60 s of the KITTI drive
//! GTSAM ships in its wheel (read from the installed wheel, never committed; CC BY-NC-SA 3.0),
//! positions used as USBL-like fixes every 10 s, the others held out.
//! 1. Our batch optimum equals GTSAM's (same graph from GTSAM's C++ factors only: ImuFactor,
//!    BetweenFactorConstantBias, GPSFactor, priors; LM, then both polished by iterating to no
//!    further decrease) to 1e-6 m / 1e-6 rad, and the
//!    incremental solvers (ISAM2, IncrementalFixedLagSmoother) run on it in the same run.
//! 2. The sensor head's navigation filter on the same IMU and fixes stays finite and bounded.
//! 3. The graph's gate makes one decision per fix after the first, and none without the gate;
//!    with multipath-like jumps the gated and ungated batch tracks are printed, not compared (on
//!    this 60-s stretch the default gate, issue 36's neighbours rule, gives the held-out RMSE of
//!    no gate, 21.89 m). The gate's check is the whole-drive test at the end.
//! The full 470-s run with its tables: `cargo run --release -p subnav-fgo --example kitti`
//! (docs/PERFORMANCE.md, "Real data: KITTI").

use subnav_fgo::gating::GatingConfig;
use subnav_fgo::kitti::{self, KittiData};
use subnav_fgo::kitti_run::{self, Faults, KittiConfig, Role};

fn data() -> KittiData {
    let dir = kitti::gtsam_data_dir(&subnav_tests::peer_python()).expect("gtsam wheel with its Data directory");
    kitti::load_dir(&dir).expect("KITTI files parse")
}

fn short() -> KittiConfig {
    KittiConfig { duration_s: 60.0, ..Default::default() }
}

#[test]
fn kitti_60s_graph_agrees_with_gtsam_cpp() {
    let data = data();
    let cfg = short();
    let sc = kitti_run::scenario(&data, &cfg).expect("scenario");
    // 1 Hz positions; the file has a missing second in the first minute
    assert!(sc.epochs.len() >= 55, "{} epochs", sc.epochs.len());
    let run = kitti_run::run_graph(&data, &sc, &cfg).expect("graph runs");
    assert!(run.batch_report.converged);
    let problem = kitti_run::gtsam_problem(&data, &sc, &run, cfg.lag_s).expect("problem");
    let script = subnav_tests::peers_dir().join("gtsam_kitti.py");
    let g = kitti_run::run_python_peer(&subnav_tests::peer_python(), &script, &problem).expect("GTSAM peer");
    let mut polished = run.batch.clone();
    kitti_run::polish(&mut polished, &run.factors).expect("polish");
    let [dp, dv, dr, db] = kitti_run::max_state_diff(&polished, &g["lm"]["polished"]).expect("peer nodes");
    let gi = g["lm"]["initial_error"].as_f64().expect("error");
    let ours = kitti_run::score(&sc.epochs, &kitti_run::positions(&run.batch));
    let rt = kitti_run::score(&sc.epochs, &kitti_run::positions(&run.realtime));
    let isam_rt = kitti_run::score(&sc.epochs, &kitti_run::peer_positions(&g["isam2"]["realtime"]));
    let [ip, ..] = kitti_run::max_state_diff(&run.batch, &g["isam2"]["final"]).expect("isam nodes");
    println!(
        "KITTI 60 s: {} nodes, {} factors; batch vs GTSAM LM max |dp| {dp:.2e} m |dv| {dv:.2e} m/s |dR| {dr:.2e} rad |db| {db:.2e}; \
         ISAM2 final vs our batch {ip:.2e} m; held-out RMSE batch {:.3} m, our real time {:.3} m, ISAM2 real time {:.3} m; \
         cost ours {:.6e} GTSAM {gi:.6e}; CPU ours LM {:.4} s GTSAM LM {:.4} s, ours smoother {:.4} s ISAM2 {:.4} s fixed-lag {:.4} s (dev build)",
        run.batch.len(),
        run.factors.len(),
        ours.rmse_heldout_m,
        rt.rmse_heldout_m,
        isam_rt.rmse_heldout_m,
        run.batch_report.initial_cost,
        run.batch_cpu_s,
        g["lm"]["cpu_s"].as_f64().unwrap_or(f64::NAN),
        run.smoother_cpu_s,
        g["isam2"]["cpu_s"].as_f64().unwrap_or(f64::NAN),
        g["fixed_lag"]["cpu_s"].as_f64().unwrap_or(f64::NAN),
    );
    assert!(
        (gi - run.batch_report.initial_cost).abs() <= 1e-6 * gi.abs().max(1.0),
        "initial costs differ: GTSAM {gi} ours {}",
        run.batch_report.initial_cost
    );
    assert!(dp < 1e-6, "positions differ from GTSAM by {dp} m");
    assert!(dr < 1e-6, "attitudes differ from GTSAM by {dr} rad");
    assert!(dv < 1e-6, "velocities differ from GTSAM by {dv} m/s");
    // the smoothed track follows the held-out fixes; ISAM2 ends near the same optimum
    assert!(ours.rmse_heldout_m < 5.0, "batch held-out RMSE {} m", ours.rmse_heldout_m);
    assert!(ip < 0.5, "ISAM2's final estimate is {ip} m from the batch optimum");
    assert_eq!(g["isam2"]["realtime"].as_array().map(Vec::len), Some(sc.epochs.len()));
    assert_eq!(g["fixed_lag"]["realtime"].as_array().map(Vec::len), Some(sc.epochs.len()));
}

#[test]
fn kitti_60s_filter_runs_and_gate_handles_a_jump() {
    let data = data();
    let cfg = short();
    let sc = kitti_run::scenario(&data, &cfg).expect("scenario");
    let f = kitti_run::run_filter(&data, &sc, &cfg, true).expect("filter runs");
    println!(
        "filter 60 s: held-out RMSE {:.2} m max {:.2} m, NEES mean {:.2} (>99 %: {:.2}), fused {} rejected {} errors {}, PD repairs {}, diverged {}",
        f.score.rmse_heldout_m,
        f.score.max_heldout_m,
        f.nees_mean,
        f.nees_above_99,
        f.fixes_fused,
        f.fixes_rejected,
        f.update_errors,
        f.pd_repairs,
        f.diverged
    );
    assert_eq!(f.pos_enu_m.len(), sc.epochs.len());
    assert!(f.pos_enu_m.iter().all(|p| p.iter().all(|x| x.is_finite())));
    assert_eq!(f.fixes_fused + f.fixes_rejected + f.update_errors, sc.epochs.iter().filter(|e| e.role == Role::Used).count() - 1);
    assert!(f.score.rmse_heldout_m.is_finite());

    // one fix in three jumps by 15-30 m
    let faults = Faults { jump_probability: 0.35, jump_m: 30.0, seed: 4, ..Default::default() };
    let gated = KittiConfig { faults: faults.clone(), ..short() };
    let ungated = KittiConfig { faults, gating: GatingConfig { enabled: false, ..Default::default() }, ..short() };
    let sc = kitti_run::scenario(&data, &gated).expect("scenario");
    let jumps = sc.epochs.iter().filter(|e| e.jumped).count();
    assert!(jumps >= 1, "the seed gives at least one jump");
    let g = kitti_run::run_graph(&data, &sc, &gated).expect("gated");
    let u = kitti_run::run_graph(&data, &sc, &ungated).expect("ungated");
    let (sg, su) =
        (kitti_run::score(&sc.epochs, &kitti_run::positions(&g.batch)), kitti_run::score(&sc.epochs, &kitti_run::positions(&u.batch)));
    println!(
        "graph with {jumps} jumps: gated batch {:.2} m ({} inflated), ungated {:.2} m",
        sg.rmse_heldout_m,
        g.fixes_inflated(),
        su.rmse_heldout_m
    );
    // jumps are flagged once the track has converged (the first ones fall within the early,
    // large predicted covariance: at 20 s a 20-m jump had gamma 1.3)
    let flagged = sc
        .epochs
        .iter()
        .filter(|e| e.jumped)
        .filter(|e| g.gate_log.decisions.iter().any(|d| (d.t_s - e.t_s).abs() < 1e-9 && d.abnormal && d.kappa > 10.0))
        .count();
    println!("jumps flagged by the gate: {flagged} of {jumps}");
    let used = sc.epochs.iter().filter(|e| e.role == Role::Used).count();
    assert_eq!(g.gate_log.decisions.len(), used - 1, "one gate decision per fix after the first");
    assert_eq!(u.fixes_inflated(), 0);
    let at_jumps = |r: &kitti_run::GraphRun| -> f64 {
        sc.epochs
            .iter()
            .zip(&r.batch)
            .filter(|(e, _)| e.jumped)
            .map(|(e, x)| (x.nav.pos_enu_m - e.recorded.pos_enu_m).norm())
            .fold(0.0, f64::max)
    };
    println!("worst error at a jumped epoch: gated {:.2} m, ungated {:.2} m", at_jumps(&g), at_jumps(&u));
}

/// Issue 36's gate item on the whole drive (470 s), with the default gate (adaptive, neighbours
/// rule): with clean fixes it costs at most 10 % of held-out RMSE against no gate, in the batch
/// and in real time (measured: 1.395 vs 1.395 m and 13.441 vs 12.274 m, docs/PERFORMANCE.md);
/// with 20 % of the fixes jumped by 10-20 m it beats no gate on the mean over draws 1-8 of the
/// jumps (the first eight, not chosen), in the batch and in real time (measured 5.017 vs 5.358 m
/// and 22.279 vs 22.599 m; better in 5 and 6 of the 8 draws, worse in 1 and 2; draws 9-24 in
/// docs/PERFORMANCE.md: `--example kitti -- --jump-seeds 8 --first-seed 9|17`). One draw alone
/// does not decide it: on draw 1 the real time loses (24.88 vs 22.79 m).
#[test]
fn kitti_full_clean_gate_costs_little_and_beats_off_with_jumps_over_draws() {
    let data = data();
    let on = KittiConfig::default();
    let off = KittiConfig { gating: GatingConfig { enabled: false, ..Default::default() }, ..Default::default() };
    let score = |cfg: &KittiConfig| {
        let sc = kitti_run::scenario(&data, cfg).expect("scenario");
        let r = kitti_run::run_graph(&data, &sc, cfg).expect("graph");
        let b = kitti_run::score(&sc.epochs, &kitti_run::positions(&r.batch)).rmse_heldout_m;
        let t = kitti_run::score(&sc.epochs, &kitti_run::positions(&r.realtime)).rmse_heldout_m;
        (b, t, r)
    };
    let (b_on, t_on, r) = score(&on);
    let (b_off, t_off, _) = score(&off);
    println!(
        "KITTI clean, held-out RMSE: batch gate on {b_on:.3} off {b_off:.3} m; real time on {t_on:.3} off {t_off:.3} m; IMU noise scale {:.1} (tests only); taken out late {:?}",
        r.estimated_imu_scale, r.realtime_taken_out
    );
    assert!(b_on <= 1.10 * b_off, "batch: gate on {b_on} m, off {b_off} m");
    assert!(t_on <= 1.10 * t_off, "real time: gate on {t_on} m, off {t_off} m");
    assert!(
        r.estimated_imu_scale > 1.0,
        "the IMU noise of the metadata is too tight for this drive: estimated scale {}",
        r.estimated_imu_scale
    );

    const DRAWS: u64 = 8;
    // better than off by more than 1 mm (the printed digit), as the example counts
    let (mut sum, mut wins) = ([0.0f64; 4], [0usize; 2]);
    for seed in 1..=DRAWS {
        let faults = Faults { jump_probability: 0.2, jump_m: 20.0, seed, ..Default::default() };
        let (b_on, t_on, _) = score(&KittiConfig { faults: faults.clone(), ..on.clone() });
        let (b_off, t_off, _) = score(&KittiConfig { faults, ..off.clone() });
        println!("KITTI 20 % jumps, draw {seed}: batch on {b_on:.3} off {b_off:.3} m; real time on {t_on:.3} off {t_off:.3} m");
        for (s, x) in sum.iter_mut().zip([b_on, b_off, t_on, t_off]) {
            *s += x / DRAWS as f64;
        }
        wins[0] += usize::from(b_on < b_off - 1e-3);
        wins[1] += usize::from(t_on < t_off - 1e-3);
    }
    let [b_on, b_off, t_on, t_off] = sum;
    println!(
        "KITTI 20 % jumps, mean over draws 1-{DRAWS}: batch on {b_on:.3} off {b_off:.3} m ({} of {DRAWS} better); real time on {t_on:.3} off {t_off:.3} m ({} of {DRAWS})",
        wins[0], wins[1]
    );
    assert!(b_on < b_off, "with the jumps, batch: gate on {b_on} m, off {b_off} m (mean of {DRAWS} draws)");
    assert!(t_on < t_off, "with the jumps, real time: gate on {t_on} m, off {t_off} m (mean of {DRAWS} draws)");
}
