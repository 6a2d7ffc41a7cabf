//! Peer check of `subnav_topo::lmnn` against metric-learn 0.7.0 LMNN (scikit-learn < 1.8):
//! stratified 70/30 splits with seeds 0-9 (made by scikit-learn in `tests/peers/metric_learn_lmnn.py`),
//! StandardScaler fitted on the training part, LMNN with k = 3 and the default tuning, 3-NN on the
//! test part. The Rust side fits on exactly the same splits.
//!
//! - CI: iris and wine, all 10 seeds, side by side: mean accuracy within 1 point of metric-learn's.
//! - CI: digits, seed 0, Rust only (metric-learn took 2-10 min per digits fit on our shared machine):
//!   LMNN must beat the Euclidean 3-NN on the same split and stay within 1 point of the
//!   issue's metric-learn mean (98.3 %).
//! - Digits side by side (`SUBNAV_LMNN_SEEDS`, default all 10 seeds; minutes of metric-learn per
//!   seed), plus the two tests above, in release:
//!   `SUBNAV_LMNN_SEEDS=0,1 SUBNAV_PEER_PYTHON=target/peers-venv/bin/python CARGO_PROFILE_RELEASE_LTO=false CARGO_PROFILE_RELEASE_CODEGEN_UNITS=16 CARGO_PROFILE_RELEASE_OPT_LEVEL=3 cargo test --release -p subnav-tests --test peer_metric_learn -- --include-ignored --nocapture --test-threads 1`
//!   Results are recorded in docs/PERFORMANCE.md.

use std::process::Command;

use serde_json::Value;
use subnav_core::ukf::nalgebra::DMatrix;
use subnav_fgo::smoother::thread_cpu_s;
use subnav_topo::lmnn::{LmnnConfig, Scaler, accuracy, fit, predict};

struct Split {
    seed: i64,
    rust_acc: f64,
    rust_fit_s: f64,
    euclid_acc: f64,
    peer: Option<(f64, f64)>, // (accuracy, fit s)
}

fn run_peer(dataset: &str, seeds: &[u32], no_fit: bool) -> Value {
    let python = subnav_tests::peer_python();
    let script = subnav_tests::peers_dir().join("metric_learn_lmnn.py");
    let mut cmd = Command::new(&python);
    cmd.arg(&script);
    // One BLAS thread on the Python side: our fit is single-threaded.
    for var in ["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"] {
        cmd.env(var, "1");
    }
    if no_fit {
        cmd.arg("--no-fit");
    }
    cmd.arg(dataset).args(seeds.iter().map(|s| s.to_string()));
    let out = cmd.output().unwrap_or_else(|e| panic!("cannot run {}: {e}", python.display()));
    assert!(out.status.success(), "peer failed: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("peer JSON")
}

fn rows(v: &Value, idx: &[usize]) -> DMatrix<f64> {
    let x = v["x"].as_array().expect("x");
    let d = x[0].as_array().expect("row").len();
    DMatrix::from_fn(idx.len(), d, |r, c| x[idx[r]][c].as_f64().expect("number"))
}

fn evaluate(v: &Value) -> Vec<Split> {
    let y: Vec<i64> = v["y"].as_array().expect("y").iter().map(|l| l.as_i64().expect("label")).collect();
    let mut out = Vec::new();
    for s in v["splits"].as_array().expect("splits") {
        let train: Vec<usize> = s["train"].as_array().expect("train").iter().map(|i| i.as_u64().expect("index") as usize).collect();
        let test: Vec<usize> = (0..y.len()).filter(|i| train.binary_search(i).is_err()).collect();
        let (xtr, xte) = (rows(v, &train), rows(v, &test));
        let (ytr, yte): (Vec<i64>, Vec<i64>) = (train.iter().map(|&i| y[i]).collect(), test.iter().map(|&i| y[i]).collect());
        let sc = Scaler::fit(&xtr);
        let (xtr, xte) = (sc.transform(&xtr), sc.transform(&xte));
        let cpu0 = thread_cpu_s().expect("thread CPU clock");
        let (l, _rep) = fit(&xtr, &ytr, &LmnnConfig::default()).expect("fit");
        let rust_fit_s = thread_cpu_s().expect("thread CPU clock") - cpu0;
        let pred = predict(&(&xtr * l.transpose()), &ytr, &(&xte * l.transpose()), 3);
        let euclid = accuracy(&predict(&xtr, &ytr, &xte, 3), &yte);
        let peer_euclid = s["euclid_acc"].as_f64().expect("euclid_acc");
        assert!((euclid - peer_euclid).abs() < 1e-12, "Euclidean 3-NN differs from scikit-learn's: {euclid} vs {peer_euclid}");
        let peer = s.get("lmnn_acc").and_then(Value::as_f64).zip(s.get("fit_s").and_then(Value::as_f64));
        out.push(Split { seed: s["seed"].as_i64().expect("seed"), rust_acc: accuracy(&pred, &yte), rust_fit_s, euclid_acc: euclid, peer });
    }
    out
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    s / n.max(1) as f64
}

/// Print the side-by-side table and check the accuracy bound.
fn side_by_side(dataset: &str, splits: &[Split]) {
    for s in splits {
        let (pa, pt) = s.peer.expect("peer figures");
        println!(
            "{dataset} seed {}: rust {:.4} ({:.3} s CPU) metric-learn {:.4} ({:.2} s CPU) euclid {:.4}",
            s.seed, s.rust_acc, s.rust_fit_s, pa, pt, s.euclid_acc
        );
    }
    let rust = mean(splits.iter().map(|s| s.rust_acc));
    let peer = mean(splits.iter().map(|s| s.peer.map_or(f64::NAN, |p| p.0)));
    let euclid = mean(splits.iter().map(|s| s.euclid_acc));
    let (tr, tp) = (splits.iter().map(|s| s.rust_fit_s).sum::<f64>(), splits.iter().map(|s| s.peer.map_or(f64::NAN, |p| p.1)).sum::<f64>());
    println!(
        "{dataset} ({} splits): mean accuracy rust {:.2} % metric-learn {:.2} % euclid {:.2} %; fit CPU time rust {:.3} s metric-learn {:.2} s, ratio {:.1}x",
        splits.len(),
        rust * 100.0,
        peer * 100.0,
        euclid * 100.0,
        tr,
        tp,
        tp / tr
    );
    assert!((rust - peer).abs() <= 0.01, "{dataset}: rust {rust} vs metric-learn {peer}");
}

#[test]
fn iris_and_wine_match_metric_learn() {
    let seeds: Vec<u32> = (0..10).collect();
    for dataset in ["iris", "wine"] {
        let v = run_peer(dataset, &seeds, false);
        let splits = evaluate(&v);
        assert_eq!(splits.len(), 10);
        side_by_side(dataset, &splits);
    }
}

#[test]
fn digits_seed0_beats_euclidean_and_is_near_the_reference() {
    let v = run_peer("digits", &[0], true);
    let s = evaluate(&v);
    println!("digits seed 0: rust {:.4} ({:.2} s CPU) euclid {:.4}", s[0].rust_acc, s[0].rust_fit_s, s[0].euclid_acc);
    assert!(s[0].rust_acc > s[0].euclid_acc, "LMNN does not improve on Euclidean 3-NN");
    assert!(s[0].rust_acc >= 0.983 - 0.01, "digits accuracy {} more than 1 point below metric-learn's 98.3 %", s[0].rust_acc);
}

/// The full digits comparison (metric-learn takes ~10 min per seed): see the module doc.
#[test]
#[ignore]
fn digits_match_metric_learn() {
    let seeds: Vec<u32> = std::env::var("SUBNAV_LMNN_SEEDS")
        .ok()
        .map(|s| s.split(',').map(|x| x.trim().parse().expect("seed")).collect())
        .unwrap_or_else(|| (0..10).collect());
    let v = run_peer("digits", &seeds, false);
    side_by_side("digits", &evaluate(&v));
}
