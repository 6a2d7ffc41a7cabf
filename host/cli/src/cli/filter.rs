//! `subnav filter`: the sensor head's navigation filter (`subnav_core::nav`) on the host.
//!
//! - `simulate`: write a simulated dive as a CSV sensor log (and its truth).
//! - `replay`: run a CSV sensor log through the filter, write estimates (CSV or JSON lines).
//! - `monte-carlo`: AUKF vs plain UKF over seeded simulated dives (docs/PERFORMANCE.md).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use subnav_core::nav::NavConfig;

use super::Format;
use super::args::{self, Seeds};
use subnav_sil::filter::{montecarlo, replay, sim};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: Sub,
}

#[derive(Debug, clap::Subcommand)]
pub enum Sub {
    /// Write a simulated dive (noise changes mid-run) as a CSV sensor log.
    Simulate {
        /// Output log (CSV).
        #[arg(long)]
        out: PathBuf,
        /// Truth output (CSV: t_s,n_m,e_m,d_m,yaw_rad).
        #[arg(long)]
        truth: Option<PathBuf>,
        /// Seed of the simulated dive.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Dive length, s (at most a day).
        #[arg(long, allow_hyphen_values = true, default_value_t = 600.0, value_parser = args::f64_positive_upto(args::MAX_SIM_DURATION_S))]
        duration_s: f64,
    },
    /// Replay a CSV sensor log (format in `subnav_sil::filter::replay`) through the filter.
    Replay {
        /// Input log (CSV).
        log: PathBuf,
        /// Estimates output: `.json` gives JSON lines, anything else CSV.
        #[arg(long)]
        out: PathBuf,
        /// Use the adaptive filter (Sage-Husa R + fading factor).
        #[arg(long)]
        adaptive: bool,
        /// Output interval (s of IMU time, > 0 and at most a day).
        #[arg(long, allow_hyphen_values = true, default_value_t = 0.1, value_parser = args::f64_positive_upto(86_400.0))]
        every_s: f64,
    },
    /// AUKF vs plain UKF over seeded simulated dives.
    MonteCarlo {
        /// Seeds of the simulated dives: `N`, `A..B` (B exclusive) or `A..=B`.
        #[arg(long, default_value = "0..500", value_parser = args::parse_seeds)]
        seeds: Seeds,
        /// Worker threads.
        #[arg(long, allow_hyphen_values = true, default_value_t = 2, value_parser = args::int_in(1usize..=256))]
        threads: usize,
        /// Dive length, s (at most a day).
        #[arg(long, allow_hyphen_values = true, default_value_t = 600.0, value_parser = args::f64_positive_upto(args::MAX_SIM_DURATION_S))]
        duration_s: f64,
        /// AUKF without the fading factor (Sage-Husa R only).
        #[arg(long)]
        no_fading: bool,
        /// AUKF with the seed's fading factor: its divergence test alone, without the
        /// persistence test on the innovation mean (`subnav_core::ukf::adapt`).
        #[arg(long, conflicts_with = "no_fading")]
        seed_fading: bool,
        /// A step in the z gyro bias, rad/s (genuine state divergence; none by default).
        #[arg(long, allow_hyphen_values = true, value_parser = args::f64_in(-1.0..=1.0))]
        gyro_step_radps: Option<f64>,
        /// Time of the gyro bias step, s.
        #[arg(long, allow_hyphen_values = true, default_value_t = 300.0, value_parser = args::f64_in(0.0..=args::MAX_SIM_DURATION_S))]
        gyro_step_at_s: f64,
        /// Sage-Husa forgetting factor b of the AUKF, in (0, 1).
        #[arg(long)]
        b: Option<f32>,
    },
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    match args.command {
        Sub::Simulate { out, truth, seed, duration_s } => {
            if let Some(t) = &truth {
                subnav_link::output::check_outputs(&[("--out", &out), ("--truth", t)], &[])?;
            }
            let cfg = sim::DiveConfig { duration_s, ..sim::DiveConfig::default() };
            let dive = sim::generate(&cfg, seed);
            let t0 = dive.truth.first().context("empty dive")?;
            let init = replay::LogInit {
                t_us: t0.t_us,
                pos_ned_m: t0.pos_ned_m.map(|v| v as f32),
                yaw_rad: dive.init_yaw_rad as f32,
                vel_ned_mps: t0.vel_ned_mps.map(|v| v as f32),
            };
            subnav_link::output::write_atomic(&out, replay::write_log(Some(init), &dive.events))
                .with_context(|| format!("writing {}", out.display()))?;
            if let Some(p) = truth {
                let mut s = String::from("t_s,n_m,e_m,d_m,yaw_rad\n");
                for t in &dive.truth {
                    s.push_str(&format!(
                        "{},{},{},{},{}\n",
                        t.t_us as f64 * 1e-6,
                        t.pos_ned_m[0],
                        t.pos_ned_m[1],
                        t.pos_ned_m[2],
                        t.yaw_rad
                    ));
                }
                subnav_link::output::write_atomic(&p, s).with_context(|| format!("writing {}", p.display()))?;
            }
            eprintln!("wrote {} events to {}", dive.events.len(), out.display());
            Ok(ExitCode::SUCCESS)
        }
        Sub::Replay { log, out, adaptive, every_s } => {
            subnav_link::output::refuse_input_as_output("--out", &out, &[&log])?;
            let text = std::fs::read_to_string(&log).with_context(|| format!("reading {}", log.display()))?;
            let (init, events) = replay::parse_log(&text).with_context(|| format!("parsing {}", log.display()))?;
            let cfg = if adaptive { NavConfig::default().adaptive() } else { NavConfig::default() };
            let r = replay::replay(cfg, init, &events, every_s)?;
            if r.rows.is_empty() {
                anyhow::bail!(
                    "{} gave no estimates: it has no IMU samples the filter could run on (see `subnav filter simulate` for the format)",
                    log.display()
                );
            }
            let body = if out.extension().is_some_and(|e| e == "json") {
                let mut s = String::new();
                for row in &r.rows {
                    s.push_str(&serde_json::to_string(row)?);
                    s.push('\n');
                }
                s
            } else {
                replay::rows_csv(&r.rows)
            };
            subnav_link::output::write_atomic(&out, body.as_bytes())?;
            match format {
                Format::Text => {
                    println!("{} estimates written to {}; events: {:?}; health: {}", r.rows.len(), out.display(), r.counts, r.health)
                }
                Format::Json => println!(
                    "{}",
                    serde_json::json!({"rows": r.rows.len(), "out": out.display().to_string(), "counts": r.counts, "health": r.health})
                ),
            }
            Ok(ExitCode::SUCCESS)
        }
        Sub::MonteCarlo { seeds, threads, duration_s, no_fading, seed_fading, gyro_step_radps, gyro_step_at_s, b } => {
            let (runs, first_seed) = (seeds.count, seeds.first);
            let gyro_bias_step = gyro_step_radps.map(|bz| (gyro_step_at_s, [0.0, 0.0, bz]));
            let cfg = sim::DiveConfig { duration_s, gyro_bias_step, ..sim::DiveConfig::default() };
            let started = std::time::Instant::now();
            let mut aukf = NavConfig::default().adaptive();
            aukf.ukf.adapt.fading = !no_fading;
            if seed_fading {
                aukf.ukf.adapt.fading_persist = 0.0;
            }
            if let Some(b) = b {
                anyhow::ensure!(b > 0.0 && b < 1.0, "--b must be in (0, 1)");
                aukf.ukf.adapt.b = b;
            }
            let c = montecarlo::compare(&cfg, NavConfig::default(), aukf, first_seed, runs, threads)?;
            let secs = started.elapsed().as_secs_f64();
            match format {
                Format::Text => {
                    println!("{runs} seeded dives (seeds {first_seed}..{}), {duration_s} s each, {secs:.1} s wall", first_seed + runs);
                    for (name, s) in [("UKF ", &c.ukf), ("AUKF", &c.aukf)] {
                        println!(
                            "{name}: position RMSE {:.3} m, heading RMSE {:.3} deg, divergences {}/{}, mean final horizontal error {:.2} m, worst horizontal {:.2} m, worst heading {:.2} deg, gated {} of {} updates",
                            s.position_rmse_m,
                            s.heading_rmse_deg,
                            s.divergences,
                            s.runs,
                            s.mean_final_horizontal_m,
                            s.worst_horizontal_m,
                            s.worst_heading_deg,
                            s.gated,
                            s.gated + s.accepted
                        );
                    }
                    println!("AUKF position RMSE reduction vs UKF: {:.1} %", 100.0 * c.position_rmse_reduction);
                }
                Format::Json => println!("{}", serde_json::to_string(&c)?),
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}
