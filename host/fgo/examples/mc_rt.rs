//! scratch: real-time gated smoother RMSE over the simulator's Monte Carlo seeds (issue 36 fourth pass)
use subnav_fgo::sim::{SimConfig, simulate};
use subnav_fgo::smoother::{self, SmootherConfig, position_rmse};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let n: u64 = a.get(1).and_then(|x| x.parse().ok()).unwrap_or(100);
    let mut v = Vec::new();
    for seed in 1..=n {
        let sim = simulate(&SimConfig { seed, duration_s: 300.0, abnormal_fraction: 0.1, ..Default::default() });
        let g = smoother::run(&sim.log, SmootherConfig::default(), false, |_, _| {}).expect("run");
        let r = position_rmse(&g.realtime, &sim.truth);
        println!("seed {seed} rt {r:.4} s {:.2}", g.realtime_imu_scale);
        v.push(r);
    }
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    v.sort_by(|a, b| a.total_cmp(b));
    println!("MEAN {mean:.4} median {:.4} max {:.4} n {}", v[v.len() / 2], v[v.len() - 1], v.len());
}
