//! AUKF vs plain UKF on simulated dives whose noise statistics change mid-run.
//!
//! Both filters are the same `NavFilter15` code: "UKF" is [`NavConfig::default`] (adaptive layer
//! off, gates on), "AUKF" is [`NavConfig::adaptive`] of it (Sage-Husa R + fading factor).
//! Each seed generates one dive ([`super::sim::generate`]); both filters see the same log.
//!
//! Metrics, over all runs and all truth samples (1 Hz): 3-D position RMSE, heading RMSE.
//!
//! **Divergence** (stated in docs/PERFORMANCE.md): a run diverges if at any truth sample the
//! estimate is not finite, the heading error exceeds 10 degrees, or the horizontal position
//! error exceeds 20 m (about 2 % of the 900 m travelled in the 600 s dive).

use std::sync::Mutex;

use serde::Serialize;
use subnav_core::nav::{NavConfig, NavFilter15};
use subnav_core::ukf::wrap_pi;

use super::sim::{Dive, DiveConfig, Event, generate};
use super::{EventCounts, apply, start};

/// Divergence thresholds.
pub const DIVERGED_HEADING_RAD: f64 = 10.0 * std::f64::consts::PI / 180.0;
pub const DIVERGED_HORIZONTAL_M: f64 = 20.0;

/// Errors of one filter on one dive.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct RunErrors {
    pub sum_pos_sq: f64,
    pub sum_heading_sq: f64,
    pub samples: u64,
    pub max_horizontal_m: f64,
    pub max_heading_rad: f64,
    pub final_horizontal_m: f64,
    pub diverged: bool,
    pub counts: EventCounts,
}

/// Run `cfg` over a dive and compare with its truth.
pub fn evaluate(cfg: NavConfig, dive: &Dive) -> anyhow::Result<RunErrors> {
    let t0 = dive.truth.first().ok_or_else(|| anyhow::anyhow!("empty dive"))?;
    let mut nav = start(cfg, t0.t_us, t0.pos_ned_m.map(|v| v as f32), t0.vel_ned_mps.map(|v| v as f32), dive.init_yaw_rad as f32)?;
    let mut out = RunErrors::default();
    let mut truth = dive.truth.iter().peekable();
    for ev in &dive.events {
        apply(&mut nav, ev, &mut out.counts);
        if let Event::Imu(s) = ev {
            while let Some(t) = truth.peek() {
                if t.t_us > s.t_us {
                    break;
                }
                if t.t_us == s.t_us {
                    score(&nav, t, &mut out);
                }
                truth.next();
            }
        }
    }
    Ok(out)
}

fn score(nav: &NavFilter15, t: &super::sim::Truth, out: &mut RunErrors) {
    let n = nav.nominal();
    let d = [n.pos_ned_m.x as f64 - t.pos_ned_m[0], n.pos_ned_m.y as f64 - t.pos_ned_m[1], n.pos_ned_m.z as f64 - t.pos_ned_m[2]];
    let yaw_err = wrap_pi(n.yaw_rad() as f64 - t.yaw_rad);
    let horiz = (d[0] * d[0] + d[1] * d[1]).sqrt();
    let finite = d.iter().all(|v| v.is_finite()) && yaw_err.is_finite();
    out.sum_pos_sq += d.iter().map(|v| v * v).sum::<f64>();
    out.sum_heading_sq += yaw_err * yaw_err;
    out.samples += 1;
    out.max_horizontal_m = out.max_horizontal_m.max(horiz);
    out.max_heading_rad = out.max_heading_rad.max(yaw_err.abs());
    out.final_horizontal_m = horiz;
    if !finite || yaw_err.abs() > DIVERGED_HEADING_RAD || horiz > DIVERGED_HORIZONTAL_M {
        out.diverged = true;
    }
}

/// Aggregate of one filter over all runs.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Summary {
    pub runs: u64,
    pub position_rmse_m: f64,
    pub heading_rmse_deg: f64,
    pub divergences: u64,
    pub mean_final_horizontal_m: f64,
    pub worst_horizontal_m: f64,
    pub worst_heading_deg: f64,
    pub gated: u64,
    pub accepted: u64,
}

#[derive(Default)]
struct Acc {
    sum_pos_sq: f64,
    sum_heading_sq: f64,
    samples: u64,
    runs: u64,
    div: u64,
    final_sum: f64,
    worst_h: f64,
    worst_yaw: f64,
    gated: u64,
    accepted: u64,
}

impl Acc {
    fn add(&mut self, r: &RunErrors) {
        self.sum_pos_sq += r.sum_pos_sq;
        self.sum_heading_sq += r.sum_heading_sq;
        self.samples += r.samples;
        self.runs += 1;
        self.div += r.diverged as u64;
        self.final_sum += r.final_horizontal_m;
        self.worst_h = self.worst_h.max(r.max_horizontal_m);
        self.worst_yaw = self.worst_yaw.max(r.max_heading_rad);
        self.gated += r.counts.updates_gated;
        self.accepted += r.counts.updates_accepted;
    }
    fn summary(&self) -> Summary {
        let n = self.samples.max(1) as f64;
        Summary {
            runs: self.runs,
            position_rmse_m: (self.sum_pos_sq / n).sqrt(),
            heading_rmse_deg: (self.sum_heading_sq / n).sqrt().to_degrees(),
            divergences: self.div,
            mean_final_horizontal_m: self.final_sum / self.runs.max(1) as f64,
            worst_horizontal_m: self.worst_h,
            worst_heading_deg: self.worst_yaw.to_degrees(),
            gated: self.gated,
            accepted: self.accepted,
        }
    }
}

/// Result of a Monte Carlo comparison.
#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    pub first_seed: u64,
    pub ukf: Summary,
    pub aukf: Summary,
    /// `1 - RMSE_aukf / RMSE_ukf` for position.
    pub position_rmse_reduction: f64,
}

/// Run `runs` seeded dives (seeds `first_seed..first_seed+runs`) on `threads` threads.
pub fn compare(
    dive_cfg: &DiveConfig,
    ukf_cfg: NavConfig,
    aukf_cfg: NavConfig,
    first_seed: u64,
    runs: u64,
    threads: usize,
) -> anyhow::Result<Comparison> {
    let acc = Mutex::new((Acc::default(), Acc::default()));
    let next = Mutex::new(first_seed);
    let end = first_seed + runs;
    std::thread::scope(|s| -> anyhow::Result<()> {
        let mut handles = Vec::new();
        for _ in 0..threads.max(1) {
            handles.push(s.spawn(|| -> anyhow::Result<()> {
                loop {
                    let seed = {
                        let mut n = next.lock().map_err(|_| anyhow::anyhow!("poisoned"))?;
                        if *n >= end {
                            return Ok(());
                        }
                        *n += 1;
                        *n - 1
                    };
                    let dive = generate(dive_cfg, seed);
                    let u = evaluate(ukf_cfg, &dive)?;
                    let a = evaluate(aukf_cfg, &dive)?;
                    let mut g = acc.lock().map_err(|_| anyhow::anyhow!("poisoned"))?;
                    g.0.add(&u);
                    g.1.add(&a);
                }
            }));
        }
        for h in handles {
            h.join().map_err(|_| anyhow::anyhow!("worker panicked"))??;
        }
        Ok(())
    })?;
    let (u, a) = acc.into_inner().map_err(|_| anyhow::anyhow!("poisoned"))?;
    let (ukf, aukf) = (u.summary(), a.summary());
    let red = 1.0 - aukf.position_rmse_m / ukf.position_rmse_m.max(f64::MIN_POSITIVE);
    Ok(Comparison { first_seed, ukf, aukf, position_rmse_reduction: red })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Small asserted version of the Monte Carlo (the full one is `subnav filter monte-carlo
    /// --seeds 0..500`, results in docs/PERFORMANCE.md): 6 seeded 240 s dives with a 60 s heading
    /// noise x10 period and two DVL bursts x20. The adaptive filter must beat the plain one on
    /// position RMSE and must not diverge.
    #[test]
    fn aukf_beats_ukf_on_short_dives_with_noise_changes() {
        let cfg = DiveConfig {
            duration_s: 240.0,
            heading_burst: (60.0, 120.0, 10.0),
            dvl_bursts: vec![(150.0, 160.0, 20.0), (200.0, 210.0, 20.0)],
            ..DiveConfig::default()
        };
        let c = compare(&cfg, NavConfig::default(), NavConfig::default().adaptive(), 1000, 6, 2).unwrap();
        println!("{}", serde_json::to_string(&c).unwrap());
        assert_eq!(c.ukf.runs, 6);
        assert_eq!(c.aukf.divergences, 0, "{c:?}");
        assert!(c.aukf.position_rmse_m < c.ukf.position_rmse_m, "{c:?}");
        assert!(c.aukf.heading_rmse_deg < c.ukf.heading_rmse_deg, "{c:?}");
    }

    /// The fading factor's variants on the same dives: `(off, on)` where off is Sage-Husa R
    /// alone and on is [`NavConfig::adaptive`] (fading factor with its persistence test).
    fn fading_off_on(cfg: &DiveConfig, first_seed: u64, runs: u64) -> Comparison {
        let on = NavConfig::default().adaptive();
        let mut off = on;
        off.ukf.adapt.fading = false;
        let c = compare(cfg, off, on, first_seed, runs, 2).unwrap();
        println!("fading off: {}\nfading on:  {}", serde_json::to_string(&c.ukf).unwrap(), serde_json::to_string(&c.aukf).unwrap());
        c
    }

    /// Genuine state divergence, what the fading factor is for: the z gyro bias steps by
    /// 0.01 rad/s (0.57 deg/s, 10 sigma of the turn-on bias) at 100 s, far outside the filter's
    /// bias random walk. Without fading the bias estimate is slow to follow and Sage-Husa reads
    /// the biased heading innovations as compass noise; with it the heading and position errors
    /// must be lower. (The same case over 8 dives with the noise changes too: `subnav filter
    /// monte-carlo --seeds 0..8 --duration-s 300 --gyro-step-radps 0.01 --gyro-step-at-s 100`,
    /// with and without `--no-fading`; docs/PERFORMANCE.md.)
    #[test]
    fn fading_beats_no_fading_on_a_gyro_bias_step() {
        let cfg = DiveConfig {
            duration_s: 300.0,
            heading_burst: (0.0, 0.0, 1.0),
            dvl_bursts: vec![],
            gyro_bias_step: Some((100.0, [0.0, 0.0, 0.01])),
            ..DiveConfig::default()
        };
        let c = fading_off_on(&cfg, 0, 4);
        let (off, on) = (&c.ukf, &c.aukf);
        assert!(
            on.heading_rmse_deg < off.heading_rmse_deg,
            "heading RMSE: fading on {} vs off {}",
            on.heading_rmse_deg,
            off.heading_rmse_deg
        );
        assert!(on.position_rmse_m < off.position_rmse_m, "position RMSE: fading on {} vs off {}", on.position_rmse_m, off.position_rmse_m);
        assert_eq!(on.divergences, 0, "{c:?}");
    }

    /// Sensor noise steps (heading x10 for 60 s, two DVL bursts x20) and no divergence: the
    /// fading factor must not read them as divergence, i.e. it must not make things worse than
    /// Sage-Husa R alone (within 5 % on both RMSEs, no divergence).
    #[test]
    fn fading_does_not_hurt_on_noise_steps() {
        let cfg = DiveConfig {
            duration_s: 240.0,
            heading_burst: (60.0, 120.0, 10.0),
            dvl_bursts: vec![(150.0, 160.0, 20.0), (200.0, 210.0, 20.0)],
            ..DiveConfig::default()
        };
        let c = fading_off_on(&cfg, 1000, 6);
        let (off, on) = (&c.ukf, &c.aukf);
        assert_eq!(on.divergences, 0, "{c:?}");
        assert!(
            on.position_rmse_m <= off.position_rmse_m * 1.05,
            "position RMSE: fading on {} vs off {}",
            on.position_rmse_m,
            off.position_rmse_m
        );
        assert!(
            on.heading_rmse_deg <= off.heading_rmse_deg * 1.05,
            "heading RMSE: fading on {} vs off {}",
            on.heading_rmse_deg,
            off.heading_rmse_deg
        );
    }
}
