//! scratch: real-time gated smoother RMSE over the simulator's Monte Carlo seeds (issue 36 fourth pass)
use subnav_fgo::sim::{SimConfig, simulate};
use subnav_fgo::smoother::{self, SmootherConfig, position_rmse};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let n: u64 = a.get(1).and_then(|x| x.parse().ok()).unwrap_or(100);
    let mut v = Vec::new();
    let mut vb: Vec<f64> = Vec::new();
    for seed in 1..=n {
        let sim = simulate(&SimConfig { seed, duration_s: 300.0, abnormal_fraction: 0.1, ..Default::default() });
        let batch = std::env::var_os("MC_BATCH").is_some();
        let g = smoother::run(&sim.log, SmootherConfig::default(), batch, |_, _| {}).expect("run");
        let r = position_rmse(&g.realtime, &sim.truth);
        let b = if batch { position_rmse(&g.batch, &sim.truth) } else { f64::NAN };
        println!("seed {seed} rt {r:.4} s {:.2} batch {b:.4} bs {:.2}", g.realtime_imu_scale, g.batch_imu_scale);
        v.push(r);
        vb.push(b);
    }
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let mb = vb.iter().sum::<f64>() / vb.len() as f64;
    vb.sort_by(|a, b| a.total_cmp(b));
    println!("BATCH MEAN {mb:.4} median {:.4} max {:.4}", vb[vb.len() / 2], vb[vb.len() - 1]);
    v.sort_by(|a, b| a.total_cmp(b));
    println!("MEAN {mean:.4} median {:.4} max {:.4} n {}", v[v.len() / 2], v[v.len() - 1], v.len());
}
