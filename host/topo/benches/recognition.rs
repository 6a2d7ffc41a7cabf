//! Per-frame cost of the live mapper at the camera rate (2 Hz): one `on_frame` recognition (the
//! position gate over every node, the flat scan of every mapped node sample, the fix) on a map of
//! 1,200 nodes and on a full map (`max_nodes` = 8,192), with one nav sample per frame.
//!
//! Synthetic features (a smooth function of the true position plus noise; rendering is not what
//! is timed): a lawnmower survey at 1.5 m/s places the nodes (LMNN trained after the first 40),
//! then the vehicle hovers over an early node so every timed frame is a recognition.
//!
//! `cargo bench -p subnav-topo --bench recognition`

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use subnav_topo::live::{CameraFrame, FrameOutcome, LiveConfig, NavSample, Refusal};
use subnav_topo::live_eval::ScoredMapper;
use subnav_topo::polar_image::N_FEATURES;

const LINE_M: f64 = 600.0;
const LINE_SPACING_M: f64 = 12.0;
const SPEED_MPS: f64 = 1.5;
const DRIFT_M2PS: f64 = 0.01;

fn place_features(p: [f64; 2], rng: &mut ChaCha8Rng) -> [f64; N_FEATURES] {
    std::array::from_fn(|k| {
        let (a, b, ph) = (0.11 + 0.037 * k as f64, 0.07 * (k as f64 - 9.5), 0.7 * k as f64);
        let n: f64 = StandardNormal.sample(rng);
        (a * p[0] + b * p[1] + ph).sin() + 0.3 * (0.05 * (k as f64 + 1.0) * p[0] - 0.13 * p[1]).cos() + 0.02 * n
    })
}

/// Lawnmower: lines along north, `LINE_SPACING_M` apart to the east.
fn lawnmower(s_m: f64) -> [f64; 2] {
    let line = (s_m / LINE_M).floor();
    let along = s_m - line * LINE_M;
    let n = if line as i64 % 2 == 0 { along } else { LINE_M - along };
    [n, line * LINE_SPACING_M]
}

fn nav(t_us: u64, p: [f64; 2]) -> NavSample {
    let v = 0.1 + DRIFT_M2PS * t_us as f64 * 1e-6;
    NavSample { t_us, pos_ned_m: [p[0], p[1], 10.0], cov_ne_m2: [v, 0.0, v], aided: true, vel_sigma_mps: 0.01 }
}

struct Sim {
    m: ScoredMapper,
    t_us: u64,
    frame: u32,
    rng: ChaCha8Rng,
}

/// Survey until the map holds `nodes` nodes.
fn build(nodes: usize) -> Sim {
    let cfg = LiveConfig { max_nodes: nodes, train_after_nodes: 40, ..LiveConfig::default() };
    let mut sim = Sim { m: ScoredMapper::new(cfg), t_us: 0, frame: 0, rng: ChaCha8Rng::seed_from_u64(1) };
    let started = std::time::Instant::now();
    let mut trained_after = None;
    while sim.m.nodes().len() < nodes {
        let t_s = sim.t_us as f64 * 1e-6;
        for k in 0..5 {
            let tn = sim.t_us + k * 100_000;
            sim.m.on_nav(nav(tn, lawnmower(SPEED_MPS * tn as f64 * 1e-6)));
        }
        let p = lawnmower(SPEED_MPS * t_s);
        let f = place_features(p, &mut sim.rng);
        sim.m.on_frame(&CameraFrame { frame: sim.frame, t_us: sim.t_us, features: Some(f) }, Some(p));
        if trained_after.is_none() && sim.m.stats().trained {
            trained_after = Some(started.elapsed());
        }
        sim.frame += 1;
        sim.t_us += 500_000;
    }
    let s = sim.m.stats();
    eprintln!(
        "map of {} nodes built from {} frames in {:.1} s (LMNN training done {:.2} s in); recognitions {}, precision {:?}, fixes {}",
        s.nodes,
        s.frames,
        started.elapsed().as_secs_f64(),
        trained_after.map_or(f64::NAN, |d| d.as_secs_f64()),
        s.recognitions,
        sim.m.score().precision,
        s.fixes
    );
    sim
}

fn bench(c: &mut Criterion) {
    for nodes in [1_200usize, 8_192] {
        let mut sim = build(nodes);
        // Hover over the place of node 10 (placed long ago: its gate passes, its samples match).
        let here = sim.m.scorer.node_truth(10).expect("truth");
        let pool: Vec<[f64; N_FEATURES]> = (0..64).map(|_| place_features(here, &mut sim.rng)).collect();
        let step = |sim: &mut Sim, i: usize| {
            sim.t_us += 500_000;
            sim.frame += 1;
            sim.m.on_nav(nav(sim.t_us, here));
            sim.m.mapper.on_frame(&CameraFrame { frame: sim.frame, t_us: sim.t_us, features: Some(pool[i % pool.len()]) })
        };
        // The jump to the hover point places a node; let it collect its samples.
        for i in 0..10 {
            step(&mut sim, i);
        }
        let first = step(&mut sim, 0);
        assert!(
            matches!(first, FrameOutcome::Fix(_) | FrameOutcome::Refused { reason: Refusal::Refractory { .. } }),
            "the timed frame must be a recognition: {first:?}"
        );
        let samples: usize = sim.m.nodes().iter().map(|n| n.samples.len()).sum();
        let mut i = 0usize;
        c.bench_function(&format!("on_frame recognition, {nodes} nodes ({samples} samples)"), |b| {
            b.iter(|| {
                i += 1;
                black_box(step(&mut sim, i))
            })
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(50);
    targets = bench
}
criterion_main!(benches);
