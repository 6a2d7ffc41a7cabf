//! Monte Carlo evaluation: seeded simulated missions with abnormal DVL/USBL observations; position
//! RMSE of the gated vs ungated graph (batch and real-time smoother), of the INS/DVL/USBL UKF
//! built on the shared UKF (`subnav_core::ukf`, see [`super::ukf_baseline`]), and the smoother's
//! per-update latency distribution. Single-threaded, so the latencies are one core's.

use serde::Serialize;

use super::FgoError;
use super::gating::{GatingConfig, Sensor};
use super::sim::{SimConfig, SimStats, simulate};
use super::smoother::{self, SmootherConfig, position_rmse};
use super::ukf_baseline;

#[derive(Debug, Clone, Copy, Serialize)]
pub struct RunMetrics {
    pub seed: u64,
    pub rmse_batch_gated_m: f64,
    pub rmse_batch_ungated_m: f64,
    pub rmse_rt_gated_m: f64,
    pub rmse_rt_ungated_m: f64,
    pub rmse_ukf_m: f64,
    pub flagged_dvl: usize,
    pub flagged_usbl: usize,
    pub stats: SimStats,
}

#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub runs: usize,
    pub duration_s: f64,
    pub abnormal_fraction: f64,
    pub mean: Means,
    /// 1 - mean(gated) / mean(ungated), batch and real time.
    pub reduction_batch: f64,
    pub reduction_rt: f64,
    /// Runs where gated batch RMSE < ungated batch RMSE.
    pub runs_gated_better: usize,
    /// Wall-clock time per update (inflated when the machine is shared).
    pub latency_ms: Percentiles,
    /// Thread CPU time per update: the one-core latency.
    pub cpu_ms: Percentiles,
    pub updates: usize,
    pub per_run: Vec<RunMetrics>,
}

#[derive(Debug, Clone, Copy, Serialize, Default)]
pub struct Means {
    pub batch_gated_m: f64,
    pub batch_ungated_m: f64,
    pub rt_gated_m: f64,
    pub rt_ungated_m: f64,
    pub ukf_m: f64,
    pub abnormal_dvl_injected: f64,
    pub abnormal_usbl_injected: f64,
    pub flagged_dvl: f64,
    pub flagged_usbl: f64,
}

#[derive(Debug, Clone, Copy, Serialize, Default)]
pub struct Percentiles {
    pub p50: f64,
    pub p90: f64,
    pub p99: f64,
    pub p999: f64,
    pub max: f64,
    pub mean: f64,
}

pub fn percentiles(mut v: Vec<f64>) -> Percentiles {
    if v.is_empty() {
        return Percentiles::default();
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let q = |p: f64| v[((v.len() as f64 - 1.0) * p).round() as usize];
    Percentiles {
        p50: q(0.5),
        p90: q(0.9),
        p99: q(0.99),
        p999: q(0.999),
        max: v[v.len() - 1],
        mean: v.iter().sum::<f64>() / v.len() as f64,
    }
}

/// One seeded run.
pub fn run_one(seed: u64, base: &SimConfig, latency_s: &mut Vec<f64>, cpu_s: &mut Vec<f64>) -> Result<RunMetrics, FgoError> {
    let sim = simulate(&SimConfig { seed, ..*base });
    let gated = smoother::run(&sim.log, SmootherConfig::default(), true, |_, _| {})?;
    let off = SmootherConfig { gating: GatingConfig { enabled: false, ..Default::default() }, ..Default::default() };
    let ungated = smoother::run(&sim.log, off, true, |_, _| {})?;
    latency_s.extend_from_slice(&gated.latency_s);
    cpu_s.extend_from_slice(&gated.cpu_s);
    let ukf = ukf_baseline::run(&sim.log)?;
    Ok(RunMetrics {
        seed,
        rmse_batch_gated_m: position_rmse(&gated.batch, &sim.truth),
        rmse_batch_ungated_m: position_rmse(&ungated.batch, &sim.truth),
        rmse_rt_gated_m: position_rmse(&gated.realtime, &sim.truth),
        rmse_rt_ungated_m: position_rmse(&ungated.realtime, &sim.truth),
        rmse_ukf_m: position_rmse(&ukf, &sim.truth),
        flagged_dvl: gated.gate_log.count(Sensor::Dvl, true),
        flagged_usbl: gated.gate_log.count(Sensor::Usbl, true),
        stats: sim.stats,
    })
}

/// `runs` seeded runs starting at `first_seed`.
pub fn run_all(runs: usize, first_seed: u64, base: &SimConfig, mut progress: impl FnMut(usize)) -> Result<Summary, FgoError> {
    let mut per_run = Vec::with_capacity(runs);
    let mut lat = Vec::new();
    let mut cpu = Vec::new();
    for i in 0..runs {
        per_run.push(run_one(first_seed + i as u64, base, &mut lat, &mut cpu)?);
        progress(i + 1);
    }
    let n = runs.max(1) as f64;
    let mean = |f: &dyn Fn(&RunMetrics) -> f64| per_run.iter().map(f).sum::<f64>() / n;
    let means = Means {
        batch_gated_m: mean(&|r| r.rmse_batch_gated_m),
        batch_ungated_m: mean(&|r| r.rmse_batch_ungated_m),
        rt_gated_m: mean(&|r| r.rmse_rt_gated_m),
        rt_ungated_m: mean(&|r| r.rmse_rt_ungated_m),
        ukf_m: mean(&|r| r.rmse_ukf_m),
        abnormal_dvl_injected: mean(&|r| r.stats.dvl_abnormal as f64),
        abnormal_usbl_injected: mean(&|r| r.stats.usbl_abnormal as f64),
        flagged_dvl: mean(&|r| r.flagged_dvl as f64),
        flagged_usbl: mean(&|r| r.flagged_usbl as f64),
    };
    Ok(Summary {
        runs,
        duration_s: base.duration_s,
        abnormal_fraction: base.abnormal_fraction,
        reduction_batch: 1.0 - means.batch_gated_m / means.batch_ungated_m,
        reduction_rt: 1.0 - means.rt_gated_m / means.rt_ungated_m,
        runs_gated_better: per_run.iter().filter(|r| r.rmse_batch_gated_m < r.rmse_batch_ungated_m).count(),
        mean: means,
        updates: lat.len(),
        latency_ms: percentiles(lat.iter().map(|s| s * 1e3).collect()),
        cpu_ms: percentiles(cpu.iter().map(|s| s * 1e3).collect()),
        per_run,
    })
}
