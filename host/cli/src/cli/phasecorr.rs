//! `subnav phasecorr A.png B.png [--upsample N]`: the translation that registers B with A by
//! phase correlation with a DFT-upsampled sub-pixel peak (`ice::phasecorr`, the sonar-velocity
//! step of the under-ice odometry). Colour images are converted to luma.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Result, bail};
use serde_json::json;

use super::Format;
use subnav_ice::data::read_png_gray;
use subnav_ice::phasecorr::{PhaseCorrelator, Refinement};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Reference image (PNG, grey or colour, 8 or 16 bit).
    pub reference: PathBuf,
    /// Moving image, same size.
    pub moving: PathBuf,
    /// Sub-pixel resolution 1/N pixel (1: integer shift only), 1..=1000.
    #[arg(long, allow_hyphen_values = true, default_value_t = 100, value_parser = super::args::int_in(1usize..=1000))]
    pub upsample: usize,
    /// Search every sample of the upsampled neighbourhood (as scikit-image does) instead of coarse-to-fine.
    #[arg(long)]
    pub full_search: bool,
    /// Time the registration: repeat it N times (one core) and report the mean time per pair
    /// (0..=10000).
    #[arg(long, default_value_t = 0, value_parser = super::args::int_in(0u32..=super::args::MAX_REPEATS))]
    pub time_repeat: u32,
}

/// Smallest image side phase correlation is run on, pixels.
const MIN_SIDE_PX: usize = 8;

/// CPU time of this process, seconds.
fn cpu_time_s() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes into the timespec we own.
    unsafe {
        libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts);
    }
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    let a = read_png_gray(&args.reference)?;
    let b = read_png_gray(&args.moving)?;
    // A shift needs texture on both axes: a uniform image, or one a few pixels wide, has no
    // correlation peak and gave a meaningless -0.75 px "shift" (peak 0).
    for (img, path) in [(&a, &args.reference), (&b, &args.moving)] {
        if img.rows < MIN_SIDE_PX || img.cols < MIN_SIDE_PX {
            bail!("{} is {} x {} pixels: phase correlation needs at least {MIN_SIDE_PX} a side", path.display(), img.cols, img.rows);
        }
        let first = img.data[0];
        if img.data.iter().all(|&v| v == first) {
            bail!("{} is uniform (every pixel {first}): it has no texture to register", path.display());
        }
    }
    let mode = if args.full_search { Refinement::Full } else { Refinement::CoarseToFine };
    let mut pc = PhaseCorrelator::new(a.rows, a.cols);
    let s = pc.register(&a, &b, args.upsample, mode)?;
    let mut us_per_pair = None;
    if args.time_repeat > 0 {
        // Process CPU time, not wall time: the figure must not depend on other load on the machine.
        let t0 = cpu_time_s();
        for _ in 0..args.time_repeat {
            std::hint::black_box(pc.register(std::hint::black_box(&a), &b, args.upsample, mode)?);
        }
        us_per_pair = Some((cpu_time_s() - t0) * 1e6 / args.time_repeat as f64);
    }
    match format {
        Format::Text => {
            println!("shift rows {:.4} px, cols {:.4} px (peak {:.3})", s.rows_px, s.cols_px, s.peak);
            if let Some(us) = us_per_pair {
                println!("{us:.1} us CPU per pair ({}x{}, upsample {}, {} repeats)", a.rows, a.cols, args.upsample, args.time_repeat);
            }
        }
        Format::Json => println!(
            "{}",
            json!({"rows_px": s.rows_px, "cols_px": s.cols_px, "peak": s.peak, "upsample": args.upsample, "us_per_pair": us_per_pair})
        ),
    }
    Ok(ExitCode::SUCCESS)
}
