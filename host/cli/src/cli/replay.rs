//! `subnav replay`: run the firmware's own estimator (its application core, compiled for the
//! host) on a recording's raw samples and downlink commands, and compare every Nav solution it
//! produces with the one the firmware sent (`subnav_sil::replay`).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Result, bail};

use super::Format;
use subnav_sil::replay::{
    DEFAULT_TOLERANCE_REL, FLOOR_ATTITUDE, FLOOR_POSITION_M, FLOOR_SIGMA, FLOOR_VELOCITY_MPS, GroupDiff, ReplayReport, replay_file,
};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The recording (`subnav run ... --record`, `subnav record`), made with raw streaming on
    /// (the firmware's default).
    pub recording: PathBuf,
    /// Relative difference allowed per Nav value: |replayed - recorded| / max(|recorded|, floor),
    /// floors 1 m (position), 0.1 m/s (velocity), 1 (quaternion), 1e-4 (sigmas).
    #[arg(long, default_value_t = DEFAULT_TOLERANCE_REL)]
    pub tolerance: f64,
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    if !(args.tolerance >= 0.0 && args.tolerance.is_finite()) {
        bail!("--tolerance must be a finite number >= 0, got {}", args.tolerance);
    }
    let r = replay_file(&args.recording, args.tolerance)?;
    match format {
        Format::Json => println!("{}", serde_json::to_string(&r)?),
        Format::Text => print_text(&r),
    }
    if !r.reproduced() {
        eprintln!("error: the replay did not reproduce the recorded Nav solutions within {:e} relative", r.tolerance_rel);
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}

fn group(name: &str, floor: f64, g: &GroupDiff) {
    println!("{name:<10} max abs {:.3e}  max rel {:.3e} (floor {floor})  beyond tolerance {}", g.max_abs, g.max_rel, g.beyond_tolerance);
}

fn print_text(r: &ReplayReport) {
    println!(
        "nav compared {} of {} recorded ({} bit-identical, {} beyond {:e} relative)",
        r.nav_compared, r.nav_recorded, r.nav_identical, r.nav_beyond_tolerance, r.tolerance_rel
    );
    group("position", FLOOR_POSITION_M, &r.position);
    group("velocity", FLOOR_VELOCITY_MPS, &r.velocity);
    group("attitude", FLOOR_ATTITUDE, &r.attitude);
    group("sigmas", FLOOR_SIGMA, &r.sigmas);
    println!(
        "inputs     {} raw samples, {} commands applied ({} acks differ, {} downlink commands without ack), replayed to {:.3} s",
        r.raw_samples,
        r.commands_applied,
        r.ack_mismatches,
        r.commands_unacked,
        r.replayed_to_us as f64 * 1e-6
    );
    println!(
        "compass    {} of {} reports differ; fault reports: {} extra, {} not reproduced",
        r.compass_differ, r.compass_compared, r.faults_extra, r.faults_missing
    );
    if let Some(m) = &r.first_mismatch {
        println!(
            "first mismatch: nav #{} at {} us, {}: replayed {} recorded {} (relative {:.3e})",
            m.index, m.t_us, m.field, m.replayed, m.recorded, m.rel
        );
    }
    if let Some(d) = &r.diverged {
        println!("diverged: {d}");
    }
    for l in &r.limitations {
        println!("limitation: {l}");
    }
}
