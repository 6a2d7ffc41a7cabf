//! The KITTI drive GTSAM ships through the head's estimator (moving start, fixes every 10 s,
//! the rest held out), gate on and off, clean and with injected jumps (docs/PERFORMANCE.md,
//! "Never lost"). The old direct-filter run (`subnav_fgo::kitti_run::run_filter`) side by side.
//!
//! `SUBNAV_PEER_PYTHON=target/peers-venv/bin/python cargo run --release -p subnav-sil --example kitti_estimator [-- --duration-s S]`

use std::path::PathBuf;

use subnav_fgo::kitti;
use subnav_fgo::kitti_run::{self, Faults, KittiConfig};

fn main() -> anyhow::Result<()> {
    let python = PathBuf::from(
        std::env::var_os("SUBNAV_PEER_PYTHON").ok_or_else(|| anyhow::anyhow!("set SUBNAV_PEER_PYTHON to the peer venv's python"))?,
    );
    let data = kitti::load_dir(&kitti::gtsam_data_dir(&python)?)?;
    let args: Vec<String> = std::env::args().collect();
    let mut base = KittiConfig::default();
    if let Some(d) = args.iter().position(|a| a == "--duration-s").and_then(|i| args.get(i + 1)) {
        base.duration_s = d.parse()?;
    }
    println!(
        "| fixes | estimator | gate | held-out RMSE m | max m | NEES (3) | >99 % | fused / refused (gate refused) | resets pos / vel | IMU Q scale | diverged |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for (name, faults) in [
        ("clean", Faults::default()),
        ("jumps 15-30 m, p 0.35", Faults { jump_probability: 0.35, jump_m: 30.0, seed: 4, ..Default::default() }),
    ] {
        let cfg = KittiConfig { faults, ..base.clone() };
        let sc = kitti_run::scenario(&data, &cfg)?;
        for gate in [true, false] {
            let r = subnav_sil::kitti::run_estimator(&data, &sc, &cfg, gate)?;
            println!(
                "| {name} | Estimator (moving start) | {} | {:.2} | {:.2} | {:.2} | {:.2} | {} / {} ({}) | {} / {} | {:.1} | {} |",
                if gate { "on" } else { "off" },
                r.score.rmse_heldout_m,
                r.score.max_heldout_m,
                r.nees_mean,
                r.nees_above_99,
                r.fixes_fused,
                r.fixes_refused,
                r.fixes_gate_refused,
                r.position_resets,
                r.velocity_resets,
                r.imu_q_scale,
                r.diverged
            );
            let f = kitti_run::run_filter(&data, &sc, &cfg, gate)?;
            println!(
                "| {name} | NavFilter direct (truth start) | {} | {:.2} | {:.2} | {:.2} | {:.2} | {} / {} | - | - | {} |",
                if gate { "on" } else { "off" },
                f.score.rmse_heldout_m,
                f.score.max_heldout_m,
                f.nees_mean,
                f.nees_above_99,
                f.fixes_fused,
                f.fixes_rejected,
                f.diverged
            );
        }
    }
    Ok(())
}
