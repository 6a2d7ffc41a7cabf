//! Full real-data evaluation on the KITTI drive GTSAM ships (docs/PERFORMANCE.md, "Real data:
//! KITTI"): the factor graph against GTSAM's C++ factors (LM, ISAM2, fixed lag) side by side,
//! the navigation filter, and gated vs ungated with injected jumps and dropouts.
//!
//! `SUBNAV_PEER_PYTHON=<venv>/bin/python cargo run --release -p subnav-fgo --example kitti
//! [-- --duration-s S] [--fix-every K] [--gates-only]`
//! `--gates-only`: only the gate table (graph, seed's fixed gate vs adaptive vs off; no peer, no
//! filter). `--jump-seeds N`: the 20 % jumps case drawn with seeds 1..=N, gate on and off (the
//! table's jumps rows are seed 1: one draw of 8 jumps); `--first-seed K`: seeds K..K+N-1 instead
//! (other draws, to check a rule chosen on 1..=N); `--oracle`: the gate-on runs take each jumped
//! fix out when the next fix arrives (`kitti_run::Oracle::NextFix`, evaluation only);
//! `--no-neighbours`: the gate-on runs with the adaptive gate before the neighbours rule
//! (`GatingConfig { neighbours: false }`, the default until issue 36's fifth pass). The
//! `--jump-seeds` table starts with the clean drive's figures (gate on and off, and their ratio).
//! The data is read from that python's installed gtsam wheel (never copied).

use std::path::PathBuf;

use subnav_fgo::gating::GatingConfig;
use subnav_fgo::kitti;
use subnav_fgo::kitti_run::{self, Faults, KittiConfig, Oracle, Role};

fn arg(name: &str) -> Option<String> {
    let a: Vec<String> = std::env::args().collect();
    a.iter().position(|x| x == name).and_then(|i| a.get(i + 1).cloned())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let python = PathBuf::from(std::env::var_os("SUBNAV_PEER_PYTHON").ok_or("set SUBNAV_PEER_PYTHON to the peer venv's python")?);
    let dir = kitti::gtsam_data_dir(&python)?;
    let data = kitti::load_dir(&dir)?;
    let mut base = KittiConfig::default();
    if let Some(d) = arg("--duration-s") {
        base.duration_s = d.parse()?;
    }
    if let Some(k) = arg("--fix-every") {
        base.fix_every = k.parse()?;
    }
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/peers/gtsam_kitti.py");
    if let Some(n) = arg("--jump-seeds") {
        let first = arg("--first-seed").map_or(Ok(1), |k| k.parse())?;
        let oracle = if std::env::args().any(|a| a == "--oracle") { Oracle::NextFix } else { Oracle::None };
        let gate = GatingConfig { neighbours: !std::env::args().any(|a| a == "--no-neighbours"), ..Default::default() };
        return jump_seeds(&data, &base, first, n.parse()?, oracle, gate);
    }
    if std::env::args().any(|a| a == "--gates-only") {
        return gate_table(&data, &base);
    }

    // 1. graph vs GTSAM, clean fixes
    let sc = kitti_run::scenario(&data, &base)?;
    // timing: best of REPEAT runs on both sides (the machine is shared)
    const REPEAT: usize = 3;
    let mut run = kitti_run::run_graph(&data, &sc, &base)?;
    for _ in 1..REPEAT {
        let r = kitti_run::run_graph(&data, &sc, &base)?;
        run.batch_cpu_s = run.batch_cpu_s.min(r.batch_cpu_s);
        run.batch_wall_s = run.batch_wall_s.min(r.batch_wall_s);
        run.smoother_cpu_s = run.smoother_cpu_s.min(r.smoother_cpu_s);
        run.smoother_wall_s = run.smoother_wall_s.min(r.smoother_wall_s);
    }
    let mut problem = kitti_run::gtsam_problem(&data, &sc, &run, base.lag_s)?;
    problem["repeat"] = serde_json::json!(REPEAT);
    let g = kitti_run::run_python_peer(&python, &script, &problem)?;
    let [lp, ..] = kitti_run::max_state_diff(&run.batch, &g["lm"]["nodes"])?;
    let mut polished = run.batch.clone();
    kitti_run::polish(&mut polished, &run.factors)?;
    let [dp, dv, dr, db] = kitti_run::max_state_diff(&polished, &g["lm"]["polished"])?;
    let [ip, ..] = kitti_run::max_state_diff(&run.batch, &g["isam2"]["final"])?;
    let used = sc.epochs.iter().filter(|e| e.role == kitti_run::Role::Used).count();
    println!(
        "## KITTI: {} epochs over {:.0} s, {} fixes used (every {}), {} held out; {} factors",
        sc.epochs.len(),
        sc.epochs.last().map_or(0.0, |e| e.t_s) - sc.epochs[0].t_s,
        used,
        base.fix_every,
        sc.epochs.len() - used,
        run.factors.len()
    );
    println!(
        "batch vs GTSAM LM (both polished): max |dp| {dp:.2e} m, |dv| {dv:.2e} m/s, |dR| {dr:.2e} rad, |db| {db:.2e}; LM optima before the polish {lp:.2e} m apart; ISAM2 final vs batch {ip:.2e} m"
    );
    println!(
        "LM iterations ours {} GTSAM {}; cost ours {:.6e} -> {:.6e}, GTSAM {:.6e} -> {:.6e}",
        run.batch_report.iterations,
        g["lm"]["iterations"],
        run.batch_report.initial_cost,
        run.batch_report.final_cost,
        g["lm"]["initial_error"].as_f64().unwrap_or(f64::NAN),
        g["lm"]["final_error"].as_f64().unwrap_or(f64::NAN)
    );
    let f = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
    let s = |p: Vec<subnav_fgo::nalgebra::Vector3<f64>>| kitti_run::score(&sc.epochs, &p);
    println!("\n| estimate | held-out RMSE m | max m | used-epoch RMSE m |\n|---|---|---|---|");
    for (name, sc_) in [
        ("ours batch LM", s(kitti_run::positions(&run.batch))),
        ("GTSAM LM", s(kitti_run::peer_positions(&g["lm"]["nodes"]))),
        ("GTSAM ISAM2 final", s(kitti_run::peer_positions(&g["isam2"]["final"]))),
        ("ours fixed-lag, real time", s(kitti_run::positions(&run.realtime))),
        ("GTSAM ISAM2, real time", s(kitti_run::peer_positions(&g["isam2"]["realtime"]))),
        ("GTSAM fixed-lag, real time", s(kitti_run::peer_positions(&g["fixed_lag"]["realtime"]))),
    ] {
        println!("| {name} | {:.3} | {:.3} | {:.3} |", sc_.rmse_heldout_m, sc_.max_heldout_m, sc_.rmse_used_m);
    }
    println!("\ntimes: best of {REPEAT} runs each side, one thread each");
    println!("\n| solve | ours CPU s | GTSAM CPU s | ratio GTSAM/ours | ours wall s | GTSAM wall s |\n|---|---|---|---|---|---|");
    println!(
        "| batch LM | {:.4} | {:.4} | {:.2} | {:.4} | {:.4} |",
        run.batch_cpu_s,
        f(&g["lm"]["cpu_s"]),
        f(&g["lm"]["cpu_s"]) / run.batch_cpu_s,
        run.batch_wall_s,
        f(&g["lm"]["wall_s"])
    );
    for (name, key) in [("incremental: ours fixed-lag vs ISAM2", "isam2"), ("incremental: ours fixed-lag vs GTSAM fixed-lag", "fixed_lag")]
    {
        println!(
            "| {name} | {:.4} | {:.4} | {:.2} | {:.4} | {:.4} |",
            run.smoother_cpu_s,
            f(&g[key]["cpu_s"]),
            f(&g[key]["cpu_s"]) / run.smoother_cpu_s,
            run.smoother_wall_s,
            f(&g[key]["wall_s"])
        );
    }

    // 2. + 3. filter, and gated vs ungated under faults
    let jumps = Faults { jump_probability: 0.2, jump_m: 20.0, seed: 1, ..Default::default() };
    let drops = Faults { dropouts_s: vec![(100.0, 160.0), (300.0, 360.0)], seed: 1, ..Default::default() };
    let both = Faults { dropouts_s: drops.dropouts_s.clone(), ..jumps.clone() };
    println!(
        "\n| fixes | method | gate | held-out RMSE m | max m | NEES mean | NEES > chi2(3, 0.99) | fixes inflated/rejected | PD repairs | diverged |\n|---|---|---|---|---|---|---|---|---|---|"
    );
    for (fname, faults) in
        [("clean", Faults::default()), ("20 % jumps 10-20 m", jumps), ("2 x 60 s dropouts", drops), ("jumps + dropouts", both)]
    {
        for gate in [true, false] {
            let cfg = KittiConfig { faults: faults.clone(), gating: GatingConfig { enabled: gate, ..Default::default() }, ..base.clone() };
            let sc = kitti_run::scenario(&data, &cfg)?;
            let on = if gate { "on" } else { "off" };
            match kitti_run::run_graph(&data, &sc, &cfg) {
                Ok(r) => {
                    let b = kitti_run::score(&sc.epochs, &kitti_run::positions(&r.batch));
                    let t = kitti_run::score(&sc.epochs, &kitti_run::positions(&r.realtime));
                    println!(
                        "| {fname} | graph batch | {on} | {:.3} | {:.3} | | | {} | | |",
                        b.rmse_heldout_m,
                        b.max_heldout_m,
                        r.fixes_inflated()
                    );
                    println!(
                        "| {fname} | graph real time | {on} | {:.3} | {:.3} | | | {} | | |",
                        t.rmse_heldout_m,
                        t.max_heldout_m,
                        r.fixes_inflated()
                    );
                }
                Err(e) => println!("| {fname} | graph | {on} | error: {e} | | | | | | |"),
            }
            match kitti_run::run_filter(&data, &sc, &cfg, gate) {
                Ok(r) => println!(
                    "| {fname} | filter | {on} | {:.3} | {:.3} | {:.2} | {:.2} | {} | {} | {} |",
                    r.score.rmse_heldout_m,
                    r.score.max_heldout_m,
                    r.nees_mean,
                    r.nees_above_99,
                    r.fixes_rejected,
                    r.pd_repairs,
                    if r.diverged { "yes" } else { "no" }
                ),
                Err(e) => println!("| {fname} | filter | {on} | error: {e} | | | | | | |"),
            }
        }
    }
    Ok(())
}

/// Graph only: the seed's fixed gate, the adaptive gate and no gate, batch and real time, clean
/// and with injected faults.
fn gate_table(data: &kitti::KittiData, base: &KittiConfig) -> Result<(), Box<dyn std::error::Error>> {
    let jumps = Faults { jump_probability: 0.2, jump_m: 20.0, seed: 1, ..Default::default() };
    let drops = Faults { dropouts_s: vec![(100.0, 160.0), (300.0, 360.0)], seed: 1, ..Default::default() };
    let both = Faults { dropouts_s: drops.dropouts_s.clone(), ..jumps.clone() };
    println!(
        "| fixes | gate | batch held-out RMSE m | batch max m | real-time RMSE m | real-time max m | fixes inflated batch, real time / used | jumped fixes inflated batch, real time | real time, taken out one fix late (jumped) |\n|---|---|---|---|---|---|---|---|---|"
    );
    for (fname, faults) in
        [("clean", Faults::default()), ("20 % jumps 10-20 m", jumps), ("2 x 60 s dropouts", drops), ("jumps + dropouts", both)]
    {
        for (gname, gating) in [
            ("seed (fixed chi2)", GatingConfig { enabled: true, adaptive: false, ..Default::default() }),
            ("adaptive, fourth pass (no neighbours rule)", GatingConfig { neighbours: false, ..Default::default() }),
            ("adaptive + neighbours rule (default)", GatingConfig::default()),
            ("off", GatingConfig { enabled: false, ..Default::default() }),
        ] {
            let cfg = KittiConfig { faults: faults.clone(), gating, ..base.clone() };
            let sc = kitti_run::scenario(data, &cfg)?;
            let used = sc.epochs.iter().filter(|e| e.role == kitti_run::Role::Used).count();
            let r = kitti_run::run_graph(data, &sc, &cfg)?;
            let b = kitti_run::score(&sc.epochs, &kitti_run::positions(&r.batch));
            let t = kitti_run::score(&sc.epochs, &kitti_run::positions(&r.realtime));
            let jumped_t: Vec<f64> = sc.epochs.iter().filter(|e| e.jumped).map(|e| e.t_s).collect();
            let node_of = |t: f64| r.times.iter().position(|x| (x - t).abs() < 1e-9);
            let jumped_nodes: Vec<usize> = jumped_t.iter().filter_map(|t| node_of(*t)).collect();
            let jb = r
                .factors
                .iter()
                .filter(|f| matches!(f, subnav_fgo::factors::Factor::Usbl(u) if u.kappa > 1.0 && jumped_nodes.contains(&u.node)))
                .count();
            let jr = r.gate_log.decisions.iter().filter(|d| d.abnormal && jumped_t.iter().any(|t| (t - d.t_s).abs() < 1e-9)).count();
            let late = r.realtime_taken_out.len();
            let late_j = r.realtime_taken_out.iter().filter(|t| jumped_t.iter().any(|j| (*j - **t).abs() < 1e-9)).count();
            println!(
                "| {fname} | {gname} | {:.3} | {:.3} | {:.3} | {:.3} | {}, {} / {used} | {jb}, {jr} / {} | {late} ({late_j}) |",
                b.rmse_heldout_m,
                b.max_heldout_m,
                t.rmse_heldout_m,
                t.max_heldout_m,
                r.batch_inflated,
                r.fixes_inflated(),
                jumped_t.len()
            );
        }
    }
    // bounds: the jumps case with decisions that know which fixes jumped (real time only)
    println!("\n| 20 % jumps, knowing which fixes jumped | gate | real-time RMSE m | real-time max m |\n|---|---|---|---|");
    let jumps = Faults { jump_probability: 0.2, jump_m: 20.0, seed: 1, ..Default::default() };
    for (oname, oracle, never_used) in
        [("jumped fixes never used", Oracle::None, true), ("each jumped fix taken out when the next fix arrives", Oracle::NextFix, false)]
    {
        for (gname, gating) in
            [("default (neighbours rule)", GatingConfig::default()), ("off", GatingConfig { enabled: false, ..Default::default() })]
        {
            let cfg = KittiConfig { faults: jumps.clone(), gating, oracle, ..base.clone() };
            let mut sc = kitti_run::scenario(data, &cfg)?;
            let roles: Vec<Role> = sc.epochs.iter().map(|e| e.role).collect();
            if never_used {
                sc.epochs.iter_mut().filter(|e| e.jumped).for_each(|e| e.role = Role::Dropped);
            }
            let r = kitti_run::run_graph(data, &sc, &cfg)?;
            // scored on the same held-out epochs as the table above
            sc.epochs.iter_mut().zip(roles).for_each(|(e, r)| e.role = r);
            let t = kitti_run::score(&sc.epochs, &kitti_run::positions(&r.realtime));
            println!("| {oname} | {gname} | {:.3} | {:.3} |", t.rmse_heldout_m, t.max_heldout_m);
        }
    }
    Ok(())
}

/// The jumps case (20 % of the fixes, 10-20 m) over `n` draws from seed `first` on: held-out
/// RMSE of the batch and the real time, adaptive gate and off, per seed and the mean; with
/// `oracle` the gate-on runs also take out the jumped fixes as it says; `gate`: the gate-on
/// configuration.
fn jump_seeds(
    data: &kitti::KittiData,
    base: &KittiConfig,
    first: u64,
    n: u64,
    oracle: Oracle,
    gate: GatingConfig,
) -> Result<(), Box<dyn std::error::Error>> {
    let on = if oracle == Oracle::None { "on" } else { "on + oracle" };
    {
        let mut row = Vec::new();
        for enabled in [true, false] {
            let cfg = KittiConfig { gating: GatingConfig { enabled, ..gate }, ..base.clone() };
            let sc = kitti_run::scenario(data, &cfg)?;
            let r = kitti_run::run_graph(data, &sc, &cfg)?;
            row.push(kitti_run::score(&sc.epochs, &kitti_run::positions(&r.batch)).rmse_heldout_m);
            row.push(kitti_run::score(&sc.epochs, &kitti_run::positions(&r.realtime)).rmse_heldout_m);
        }
        println!(
            "clean: batch on {:.3} off {:.3} (ratio {:.3}); real time on {:.3} off {:.3} (ratio {:.3})\n",
            row[0],
            row[2],
            row[0] / row[2],
            row[1],
            row[3],
            row[1] / row[3]
        );
    }
    println!(
        "| seed | jumps | batch {on} | batch off | real time {on} | real time off | batch: fixes out (jumped) | real time: taken out one fix late (jumped) |\n|---|---|---|---|---|---|---|---|"
    );
    let mut sum = [0.0f64; 4];
    // better / worse than off by more than 1 mm (the table's last digit), else equal
    let (mut b_cmp, mut t_cmp) = ([0usize; 3], [0usize; 3]);
    let cmp = |on: f64, off: f64| {
        if on < off - 1e-3 {
            0
        } else if on > off + 1e-3 {
            2
        } else {
            1
        }
    };
    for seed in first..first + n {
        let faults = Faults { jump_probability: 0.2, jump_m: 20.0, seed, ..Default::default() };
        let mut row = Vec::new();
        let mut jumps = 0;
        let mut outs = String::new();
        for enabled in [true, false] {
            let cfg = KittiConfig {
                faults: faults.clone(),
                gating: GatingConfig { enabled, ..gate },
                oracle: if enabled { oracle } else { Oracle::None },
                ..base.clone()
            };
            let sc = kitti_run::scenario(data, &cfg)?;
            jumps = sc.epochs.iter().filter(|e| e.jumped).count();
            let r = kitti_run::run_graph(data, &sc, &cfg)?;
            row.push(kitti_run::score(&sc.epochs, &kitti_run::positions(&r.batch)).rmse_heldout_m);
            row.push(kitti_run::score(&sc.epochs, &kitti_run::positions(&r.realtime)).rmse_heldout_m);
            if enabled {
                let jumped = |t: f64| sc.epochs.iter().any(|e| e.jumped && (e.t_s - t).abs() < 1e-9);
                let b_out: Vec<f64> = r
                    .factors
                    .iter()
                    .filter_map(|f| match f {
                        subnav_fgo::factors::Factor::Usbl(u) if u.kappa >= subnav_fgo::gating::OUTLIER_KAPPA => Some(r.times[u.node]),
                        _ => None,
                    })
                    .collect();
                let bj = b_out.iter().filter(|t| jumped(**t)).count();
                let tj = r.realtime_taken_out.iter().filter(|t| jumped(**t)).count();
                outs = format!("{} ({bj}) | {} ({tj})", b_out.len(), r.realtime_taken_out.len());
            }
        }
        let (b_on, t_on, b_off, t_off) = (row[0], row[1], row[2], row[3]);
        b_cmp[cmp(b_on, b_off)] += 1;
        t_cmp[cmp(t_on, t_off)] += 1;
        for (s, x) in sum.iter_mut().zip([b_on, b_off, t_on, t_off]) {
            *s += x;
        }
        println!("| {seed} | {jumps} | {b_on:.3} | {b_off:.3} | {t_on:.3} | {t_off:.3} | {outs} |");
    }
    let m = |i: usize| sum[i] / n as f64;
    println!("| mean | | {:.3} | {:.3} | {:.3} | {:.3} |", m(0), m(1), m(2), m(3));
    println!(
        "gate {on} against off (better / equal to 1 mm / worse): batch {} / {} / {}, real time {} / {} / {} of {n} draws",
        b_cmp[0], b_cmp[1], b_cmp[2], t_cmp[0], t_cmp[1], t_cmp[2]
    );
    Ok(())
}
