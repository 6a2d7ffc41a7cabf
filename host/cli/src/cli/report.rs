//! `subnav report`: a recording (+ truth, when the dive was simulated) -> figures and a
//! Markdown/HTML page with error statistics.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use serde_json::json;

use super::Format;
use subnav_link::record::session::parse_truth_csv;
use subnav_report::{self as report, ImageFormat, ReportData};

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(subcommand)]
    pub command: Sub,
}

#[derive(clap::Subcommand, Debug)]
pub enum Sub {
    /// Report on a recording (from `subnav record`, `subnav qemu --record` or `subnav run --record`).
    Recording {
        /// The recording (.snrec).
        recording: PathBuf,
        #[command(flatten)]
        page: Page,
    },
    /// Simulate a dive (the host dive simulator through the shared navigation filter), write it
    /// to OUT/dive.snrec, and report on it with its truth.
    Simulate {
        /// Seed of the simulated dive.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Dive length, s (at most a day).
        #[arg(long, allow_hyphen_values = true, default_value_t = 300.0, value_parser = super::args::f64_positive_upto(super::args::MAX_SIM_DURATION_S))]
        duration_s: f64,
        #[command(flatten)]
        page: Page,
    },
}

/// Where the report goes and what it is drawn against (both modes).
#[derive(clap::Args, Debug)]
pub struct Page {
    /// Output directory for the figures, report.md and report.html.
    #[arg(long, short)]
    pub out: PathBuf,
    /// Truth CSV (`t_s,n_m,e_m,d_m,yaw_rad`, sensor-head seconds; `subnav filter simulate --truth`
    /// writes it). Default: the recording's truth stream, if any.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Firmware ELF to decode the defmt stream (default: the ELF named in the recording).
    #[arg(long)]
    pub elf: Option<PathBuf>,
    /// Image format.
    #[arg(long, value_enum, default_value_t = ImageFormat::Png)]
    pub images: ImageFormat,
    /// Page title.
    #[arg(long, default_value = "subnav mission report")]
    pub title: String,
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    let (recording, args) = match args.command {
        Sub::Recording { recording, page } => {
            // Before anything is read: the report's directory may not hold an input.
            let inputs: Vec<&std::path::Path> =
                [Some(recording.as_path()), page.truth.as_deref(), page.elf.as_deref()].into_iter().flatten().collect();
            subnav_link::output::refuse_dir_holding_input("--out", &page.out, &inputs)?;
            (recording, page)
        }
        Sub::Simulate { seed, duration_s, page } => {
            let inputs: Vec<&std::path::Path> = [page.truth.as_deref(), page.elf.as_deref()].into_iter().flatten().collect();
            subnav_link::output::refuse_dir_holding_input("--out", &page.out, &inputs)?;
            std::fs::create_dir_all(&page.out).with_context(|| format!("creating {}", page.out.display()))?;
            let p = page.out.join("dive.snrec");
            let bar = super::record::progress_bar(0, "simulating the dive");
            let opt = report::dive::DiveOptions { seed, duration_s, ..Default::default() };
            let s = report::dive::write_recording(&p, &opt)?;
            bar.finish_and_clear();
            eprintln!(
                "simulated dive: {} nav, {} health, {} fault messages, {} truth rows -> {}",
                s.nav,
                s.health,
                s.faults,
                s.truth_rows,
                p.display()
            );
            (p, page)
        }
    };
    let (mut session, note) = super::export::load_session(&recording, args.elf.as_deref())?;
    if let Some(n) = &note {
        eprintln!("note: {n}");
    }
    if let Some(before) = &session.meta.continues {
        eprintln!("note: this recording continues {before} (a restarted host); report on the first of the series for the whole dive");
    }
    // The recordings of a host restarted mid-dive: each names the one it continues.
    for k in 2.. {
        let next = subnav_link::record::series_member(&recording, k);
        let prev = subnav_link::record::series_member(&recording, k - 1);
        let Ok(loaded) = subnav_link::record::read_file(&next) else { break };
        let prev_name = prev.file_name().map(|n| n.to_string_lossy().into_owned());
        if loaded.meta.continues.is_none() || loaded.meta.continues != prev_name {
            break;
        }
        let (next_session, _) = super::export::load_session(&next, args.elf.as_deref())?;
        let gap = session.link.gap_to(&next_session.link).map_or(String::new(), |(a, b)| {
            format!(": {:.1} s of head time ({:.1}-{:.1} s) are in neither", (b - a) as f64 * 1e-6, a as f64 * 1e-6, b as f64 * 1e-6)
        });
        eprintln!("note: {} continues {} (a restarted host), included{gap}", next.display(), prev.display());
        session.append(next_session);
    }
    let truth = match &args.truth {
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("reading the truth file {}", p.display()))?;
            let (rows, bad) = parse_truth_csv(&text);
            if bad > 0 {
                eprintln!("warning: {bad} lines of {} are not `t_s,n_m,e_m,d_m,yaw_rad` rows and were skipped", p.display());
            }
            if rows.is_empty() {
                anyhow::bail!("{} has no truth rows (expected CSV lines t_s,n_m,e_m,d_m,yaw_rad)", p.display());
            }
            Some(rows)
        }
        None => None,
    };
    let data = ReportData::from_session(&session, truth);
    if !data.truth.is_empty() && data.stats.is_none() {
        let span = |v: &mut dyn Iterator<Item = f64>| v.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), t| (a.min(t), b.max(t)));
        let (t0, t1) = span(&mut data.truth.iter().map(|t| t.t_s));
        let (n0, n1) = span(&mut data.nav.iter().map(|n| n.t_s));
        eprintln!(
            "warning: the truth ({t0:.1}..{t1:.1} s) does not overlap the recording's solutions ({n0:.1}..{n1:.1} s): no error statistics"
        );
    }
    let bar = super::record::progress_bar(report::plot::FIGURES.len() as u64, "drawing");
    let written = report::write(&data, &args.out, args.images, &args.title, |name| {
        bar.set_message(name.to_string());
        bar.inc(1);
    })?;
    bar.finish_and_clear();
    match format {
        Format::Text => {
            println!("report: {} ({} figures), {}", written.markdown.display(), written.figures.len(), written.html.display());
            if let Some(s) = &written.stats {
                println!(
                    "errors vs truth ({} aided solutions): horizontal RMS {:.2} m (max {:.2}), depth RMSE {:.3} m, heading RMSE {:.3} deg (max {:.3}; over the {} converged; all aided {:.2} deg)",
                    s.scored,
                    s.horizontal_rms_err_m,
                    s.horizontal_max_err_m,
                    s.depth_rmse_m,
                    s.heading_rmse_deg,
                    s.heading_max_abs_err_deg,
                    s.heading_converged_epochs,
                    s.heading_rmse_all_aided_deg
                );
            }
        }
        Format::Json => println!("{}", json!({"report": written})),
    }
    Ok(ExitCode::SUCCESS)
}
