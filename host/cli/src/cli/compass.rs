//! `subnav compass`: run the polarization compass (`subnav_core::compass`, the firmware's code)
//! on a simulated sky (heading Monte Carlo, sun-track geolocation) or on a CSV of raw counts.
//!
//! CSV (`compass csv FILE`): the raw-counts format of `subnav_compass::raw_csv`, one solve per
//! row; `compass simulate --emit-csv FILE` writes such a file (with a `true_yaw_deg` column).

use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use serde_json::json;
use subnav_core::compass::{self, CompassInput};
use subnav_core::ephemeris;

use super::Format;
use subnav_base::sky as sim;
use subnav_compass::{geoloc, montecarlo, raw_csv};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: Sub,
}

#[derive(Debug, clap::Subcommand)]
pub enum Sub {
    /// Heading Monte Carlo on the simulated sky.
    Simulate(SimulateArgs),
    /// Sun-track geolocation trials on the simulated sky.
    Geolocate(GeolocateArgs),
    /// The operating envelope: the moving-sea Monte Carlo over depth x wind x turbidity x sky;
    /// a PNG figure (heading RMSE and the fraction within 2 reported sigma) and its table.
    Envelope(EnvelopeArgs),
    /// Write the simulator's own downwelling Stokes field in the reference CSV format
    /// (`view_zenith_deg,rel_azimuth_deg,I,Q,U,...`, the OSOAA convention), and with
    /// --compare, how it differs from a reference field.
    Field(FieldArgs),
    /// Print the compass's AoP departure table (`shared/core/src/compass/departure_table.rs`) from
    /// the simulator's OSOAA table.
    DepartureTable,
    /// Run the compass on a CSV of raw channel counts, one solve per row.
    Csv {
        /// The CSV (header, then `time,lat_deg,lon_deg,ax_mps2,ay_mps2,az_mps2,u0_c0,...`).
        file: std::path::PathBuf,
    },
}

/// The simulated sensor head and water (both simulator modes).
#[derive(Debug, clap::Args)]
pub struct Sky {
    /// Sensor depth (m, 0..=1000).
    #[arg(long, default_value_t = 10.0, allow_hyphen_values = true, value_parser = super::args::f64_in(0.0..=1000.0))]
    pub depth_m: f64,
    /// Polarization units in the simulated head (default: the head's, 8,
    /// `subnav_core::head::POLARIZATION_UNITS`).
    #[arg(long)]
    pub units: Option<usize>,
    /// Gravity-vector tilt error, 1-sigma per axis (deg, 0..=10).
    #[arg(long, default_value_t = 0.01, allow_hyphen_values = true, value_parser = super::args::f64_in(0.0..=10.0))]
    pub tilt_sigma_deg: f64,
    /// RMS surface slope for a wavy surface (0 = flat; 16 facets per draw when > 0): i.i.d.
    /// facets, not a moving sea (see --wind-mps). 0..=1.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = super::args::f64_in(0.0..=1.0))]
    pub slope_rms: f64,
    /// A moving sea under this wind (m/s at 10 m, 0..=30): sessions of fixes over a moving sea
    /// with the wave tracker's sigma (`subnav_compass::montecarlo::SeaRun`). With --sky.
    #[arg(long, conflicts_with = "slope_rms", value_parser = super::args::f64_in(0.0..=30.0))]
    pub wind_mps: Option<f64>,
    /// The sky over a moving sea: clear, partly-cloudy, overcast, twilight (default clear when
    /// --wind-mps is given).
    #[arg(long, conflicts_with = "slope_rms", value_parser = super::args::parse_sky)]
    pub sky: Option<subnav_base::sky::SkyKind>,
    /// Water turbidity: the clear water's attenuation and scattering times this (1..=20).
    #[arg(long, default_value_t = 1.0, value_parser = super::args::f64_in(1.0..=20.0))]
    pub turbidity: f64,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    /// Monte Carlo draws (1..=10000000).
    #[arg(long, allow_hyphen_values = true, default_value_t = 1000, value_parser = super::args::int_in(1usize..=10_000_000))]
    pub draws: usize,
    /// Lower edge of the sun's apparent elevation band (deg, 0..=90, below the upper edge).
    #[arg(long, default_value_t = 20.0, allow_hyphen_values = true, value_parser = super::args::f64_in(0.0..=90.0))]
    pub min_elevation_deg: f64,
    /// Upper edge of the sun's apparent elevation band (deg, 0..=90).
    #[arg(long, default_value_t = 70.0, allow_hyphen_values = true, value_parser = super::args::f64_in(0.0..=90.0))]
    pub max_elevation_deg: f64,
    /// Also write the simulated raw counts as a CSV usable with `compass csv`.
    #[arg(long)]
    pub emit_csv: Option<std::path::PathBuf>,
    /// Look into this downwelling Stokes field instead of the simulator's: a CSV
    /// `view_zenith_deg,rel_azimuth_deg,I,Q,U[,...]` in the convention of an OSOAA run
    /// (rel_azimuth from the sun's azimuth; `subnav_compass::reference`). With --sun-zenith-deg
    /// and --depth-m saying what the file is. The head's units look into it at random
    /// headings and tilts (--max-tilt-deg) with sensor noise; the real solver gives the heading.
    #[arg(long, requires = "sun_zenith_deg", conflicts_with_all = ["emit_csv", "wind_mps", "sky", "slope_rms"])]
    pub reference_field: Option<std::path::PathBuf>,
    /// The sun's zenith angle in air (deg, 0..=89) the reference field was computed for.
    #[arg(long, requires = "reference_field", value_parser = super::args::f64_in(0.0..=89.0))]
    pub sun_zenith_deg: Option<f64>,
    /// With --reference-field: body tilts drawn within a cone of this half angle (deg, 0..=45);
    /// must keep the units on the file's view-zenith grid.
    #[arg(long, default_value_t = 5.0, value_parser = super::args::f64_in(0.0..=45.0))]
    pub max_tilt_deg: f64,
    /// With --reference-field: the single-scattering solver (the head's before issue 35,
    /// `head::compass_config_single_scattering`) instead of the head's (`head::compass_config`).
    #[arg(long, requires = "reference_field")]
    pub single_scattering_solver: bool,
    /// With --reference-field: the AoP departure table the solver subtracts: built from the
    /// other depths than --depth-m (leave-depth-out, the default: the honest check on OSOAA's
    /// own fields), the head's (every depth), or none.
    #[arg(long, value_enum, default_value_t = DepartureKind::LeaveDepthOut, requires = "reference_field")]
    pub departure: DepartureKind,
    #[command(flatten)]
    pub sky: Sky,
}

/// `compass simulate --reference-field --departure`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DepartureKind {
    LeaveDepthOut,
    Head,
    Off,
}

/// Water of `compass field`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum WaterKind {
    /// The simulator's clear oceanic water (`subnav_base::sky::Water::clear`).
    Clear,
    /// Clear oceanic water with the OSOAA clear case's optics (`subnav_base::sky::Water::oceanic`).
    Oceanic,
    /// Turbid coastal water (`subnav_base::sky::Water::turbid`: the OSOAA turbid case's optics).
    Turbid,
}

/// What `compass field --leave-out` removes from the departure table before simulating.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LeaveOutKind {
    /// The case itself (sun, wind, water, depth): its depth from the other depths.
    Depth,
    /// The case's wind for its water: the other wind's departure.
    Wind,
    /// The case's sun zenith for its water and wind: the other sun's departure.
    Sun,
    /// The case's water: the other water's departure.
    Water,
}

#[derive(Debug, clap::Args)]
pub struct FieldArgs {
    /// The sun's zenith angle in air (deg, 0..=89).
    #[arg(long, value_parser = super::args::f64_in(0.0..=89.0))]
    pub sun_zenith_deg: f64,
    /// Depth (m, 0..=1000).
    #[arg(long, value_parser = super::args::f64_in(0.0..=1000.0))]
    pub depth_m: f64,
    /// Wind (m/s at 10 m, 0..=30): the moving sea frozen at t = 0.
    #[arg(long, default_value_t = 0.0, value_parser = super::args::f64_in(0.0..=30.0))]
    pub wind_mps: f64,
    /// The water.
    #[arg(long, value_enum, default_value_t = WaterKind::Clear)]
    pub water: WaterKind,
    /// Write the CSV here (default: standard output).
    #[arg(long)]
    pub output: Option<std::path::PathBuf>,
    /// Compare with this reference field (same grid): AoP where its DoLP > --min-dolp, DoLP
    /// everywhere; printed (to standard error when the CSV goes to standard output).
    #[arg(long)]
    pub compare: Option<std::path::PathBuf>,
    /// DoLP above which the AoP is compared (0..=1).
    #[arg(long, default_value_t = 0.1, value_parser = super::args::f64_in(0.0..=1.0))]
    pub min_dolp: f64,
    /// Sea seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The pure single-scattering simulator (no departure table).
    #[arg(long, conflicts_with = "leave_out")]
    pub single_scattering: bool,
    /// Leave-one-out check of the departure table: simulate without the table's case(s) for
    /// these conditions (--sun-zenith-deg, --wind-mps, --water, --depth-m must be a table case:
    /// sun 30 or 60, wind 0 or 5, oceanic or turbid, depth 5, 10 or 20).
    #[arg(long, value_enum)]
    pub leave_out: Option<LeaveOutKind>,
}

#[derive(Debug, clap::Args)]
pub struct GeolocateArgs {
    /// Geolocation trials, each a simulated track (1..=100000).
    #[arg(long, allow_hyphen_values = true, default_value_t = 50, value_parser = super::args::int_in(1usize..=100_000))]
    pub trials: usize,
    /// Track length (s, 1..=864000: at most ten days).
    #[arg(long, allow_hyphen_values = true, default_value_t = 3600, value_parser = super::args::int_in(1i64..=864_000))]
    pub track_s: i64,
    /// Sample interval along the track (s, 1..=86400).
    #[arg(long, allow_hyphen_values = true, default_value_t = 60, value_parser = super::args::int_in(1i64..=86_400))]
    pub interval_s: i64,
    /// Heading knowledge 1-sigma (deg, 0..=180) used to turn relative azimuths into azimuths.
    #[arg(long, default_value_t = 0.5, allow_hyphen_values = true, value_parser = super::args::f64_in(0.0..=180.0))]
    pub heading_sigma_deg: f64,
    /// Trust the heading (do not fit a constant azimuth offset).
    #[arg(long)]
    pub known_heading: bool,
    #[command(flatten)]
    pub sky: Sky,
}

#[derive(Debug, clap::Args)]
pub struct EnvelopeArgs {
    /// Scored fixes per cell (1..=100000; sessions of 10).
    #[arg(long, default_value_t = 100, value_parser = super::args::int_in(1usize..=100_000))]
    pub draws_per_cell: usize,
    /// Depths (m, comma-separated, each 0..=1000).
    #[arg(long, value_delimiter = ',', default_values_t = [2.0, 5.0, 10.0, 20.0, 40.0], value_parser = super::args::f64_in(0.0..=1000.0))]
    pub depths_m: Vec<f64>,
    /// Winds (m/s at 10 m, comma-separated, each 0..=30).
    #[arg(long, value_delimiter = ',', default_values_t = [0.0, 3.0, 6.0, 9.0, 12.0], value_parser = super::args::f64_in(0.0..=30.0))]
    pub winds_mps: Vec<f64>,
    /// Turbidities (comma-separated, each 1..=20).
    #[arg(long, value_delimiter = ',', default_values_t = [1.0, 3.0], value_parser = super::args::f64_in(1.0..=20.0))]
    pub turbidities: Vec<f64>,
    /// Skies (comma-separated: clear, partly-cloudy, overcast, twilight).
    #[arg(long, value_delimiter = ',', default_value = "clear,partly-cloudy,overcast,twilight", value_parser = super::args::parse_sky)]
    pub skies: Vec<subnav_base::sky::SkyKind>,
    /// Write the figure here (PNG).
    #[arg(long)]
    pub png: Option<std::path::PathBuf>,
    /// Write the table here (Markdown).
    #[arg(long)]
    pub table: Option<std::path::PathBuf>,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    let check = |sky: &Sky| {
        let units = sky.units.unwrap_or(DEFAULT_UNITS);
        if !(3..=compass::MAX_UNITS).contains(&units) {
            bail!("--units must be within 3..={}", compass::MAX_UNITS);
        }
        Ok(())
    };
    match args.command {
        Sub::Simulate(a) if a.reference_field.is_some() => {
            check(&a.sky)?;
            reference(&a, format)
        }
        Sub::Simulate(a) => {
            check(&a.sky)?;
            if a.min_elevation_deg >= a.max_elevation_deg {
                bail!(
                    "--min-elevation-deg ({}) must be below --max-elevation-deg ({}): the sun is drawn in that band",
                    a.min_elevation_deg,
                    a.max_elevation_deg
                );
            }
            simulate(&a, format)
        }
        Sub::Geolocate(a) => {
            check(&a.sky)?;
            if a.sky.wind_mps.is_some() || a.sky.sky.is_some() {
                bail!("compass geolocate runs over a flat surface: leave out --wind-mps and --sky");
            }
            geolocate(&a, format)
        }
        Sub::Csv { file } => from_csv(&file, format),
        Sub::Field(a) => field(&a, format),
        Sub::DepartureTable => {
            let t = subnav_base::osoaa::Table::osoaa().context("the embedded departure table does not parse (a build defect)")?;
            print!("{}", subnav_compass::departure::table_source(&subnav_compass::departure::aop_departure(t, 1.34, None)));
            Ok(ExitCode::SUCCESS)
        }
        Sub::Envelope(a) => envelope(&a, format),
    }
}

fn envelope(args: &EnvelopeArgs, format: Format) -> Result<ExitCode> {
    use subnav_compass::envelope as env;
    if let (Some(png), Some(table)) = (&args.png, &args.table) {
        subnav_link::output::check_outputs(&[("--png", png), ("--table", table)], &[])?;
    }
    if let Some(p) = args.png.as_ref().filter(|p| !p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png"))) {
        // The encoder picks the format by the extension ("ImageError(Unsupported(...))").
        bail!("--png {}: the figure is written as PNG; give a path ending in .png", p.display());
    }
    for (what, empty) in [
        ("--depths-m", args.depths_m.is_empty()),
        ("--winds-mps", args.winds_mps.is_empty()),
        ("--turbidities", args.turbidities.is_empty()),
        ("--skies", args.skies.is_empty()),
    ] {
        if empty {
            bail!("{what} needs at least one value");
        }
    }
    let cfg = env::EnvelopeConfig {
        depths_m: args.depths_m.clone(),
        winds_mps: args.winds_mps.clone(),
        turbidities: args.turbidities.clone(),
        skies: args.skies.clone(),
        draws_per_cell: args.draws_per_cell,
        seed: args.seed,
        ..env::EnvelopeConfig::default()
    };
    let total = cfg.depths_m.len() * cfg.winds_mps.len() * cfg.turbidities.len() * cfg.skies.len();
    let bar = if args.quiet { indicatif::ProgressBar::hidden() } else { indicatif::ProgressBar::new(total as u64) };
    let cells = env::run(&cfg, |done, _| bar.set_position(done as u64));
    bar.finish_and_clear();
    let table = env::markdown_table(&cells, &cfg.winds_mps);
    if let Some(p) = &args.table {
        std::fs::write(p, &table).with_context(|| format!("writing the table {}", p.display()))?;
    }
    if let Some(p) = &args.png {
        subnav_compass::plot::envelope_png(p, &cells, &cfg).with_context(|| format!("writing the figure {}", p.display()))?;
    }
    match format {
        Format::Json => println!("{}", serde_json::to_string(&cells)?),
        Format::Text => print!("{table}"),
    }
    Ok(ExitCode::SUCCESS)
}

/// Units of the simulated head when --units is not given: the head's.
const DEFAULT_UNITS: usize = subnav_core::head::POLARIZATION_UNITS;

/// `compass simulate --reference-field`: the head's units and the real solver in a field from
/// outside (`subnav_compass::reference`).
fn reference(args: &SimulateArgs, format: Format) -> Result<ExitCode> {
    use subnav_compass::reference as rf;
    let path = args.reference_field.as_deref().context("--reference-field")?;
    let sza = args.sun_zenith_deg.context("--reference-field needs --sun-zenith-deg")?;
    let text = std::fs::read_to_string(path).with_context(|| format!("reading the reference field {}", path.display()))?;
    let field = rf::ReferenceField::parse(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let max_tilt = rf::max_tilt_on_grid_deg(&field);
    if args.max_tilt_deg > max_tilt + 1e-9 {
        bail!(
            "--max-tilt-deg {} would tilt the units beyond the file's largest view zenith ({:.1} deg in {}): at most {:.1} deg",
            args.max_tilt_deg,
            field.max_zenith_rad().to_degrees(),
            path.display(),
            max_tilt.max(0.0)
        );
    }
    let cfg = rf::ReferenceConfig {
        sun_zenith_deg: sza,
        depth_m: args.sky.depth_m,
        draws: args.draws,
        units: args.sky.units.unwrap_or(DEFAULT_UNITS),
        max_tilt_deg: args.max_tilt_deg,
        tilt_sigma_rad: args.sky.tilt_sigma_deg.to_radians(),
        seed: args.sky.seed,
        single_scattering_solver: args.single_scattering_solver,
        departure: match args.departure {
            DepartureKind::LeaveDepthOut => rf::DepartureTable::LeaveDepthOut,
            DepartureKind::Head => rf::DepartureTable::Head,
            DepartureKind::Off => rf::DepartureTable::Off,
        },
        ..rf::ReferenceConfig::default()
    };
    let r = rf::run(&field, &cfg);
    match format {
        Format::Json => {
            let mut v = serde_json::to_value(&r)?;
            v["file"] = json!(path.display().to_string());
            println!("{}", serde_json::to_string(&v)?)
        }
        Format::Text => {
            println!(
                "{}: sun zenith {} deg, depth {} m, {} units, {} draws (tilt <= {} deg): {} fixes ({:.1}% no fix), heading RMSE {:.3} deg, max |err| {:.3} deg, bias {:+.3} deg",
                path.display(),
                r.sun_zenith_deg,
                r.depth_m,
                r.units,
                r.draws,
                cfg.max_tilt_deg,
                r.fixes,
                100.0 * r.no_fix_fraction,
                r.rmse_deg,
                r.max_abs_err_deg,
                r.bias_deg
            );
            println!(
                "reported 1-sigma (RMS) {:.3} deg; {:.1}% of fixes within 2 sigma, {:.1}% within 3 sigma; mean unit DoLP {:.3}",
                r.rms_reported_sigma_deg,
                100.0 * r.within_2_sigma,
                100.0 * r.within_3_sigma,
                r.mean_dolp
            );
            for (k, v) in &r.no_fix {
                println!("  no fix {k}: {v}");
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// `compass field`: the simulator's field as a reference CSV, and its difference from one.
fn field(args: &FieldArgs, format: Format) -> Result<ExitCode> {
    use subnav_base::osoaa::{LeaveOut, Table};
    use subnav_compass::reference as rf;
    let water = match args.water {
        WaterKind::Clear => sim::Water::clear(),
        WaterKind::Oceanic => sim::Water::oceanic(),
        WaterKind::Turbid => sim::Water::turbid(),
    };
    let water = sim::Water { polarization_table: !args.single_scattering, ..water };
    let full = Table::osoaa().context("the embedded departure table does not parse (a build defect)")?;
    let left_out = match args.leave_out {
        None => None,
        Some(k) => {
            let turbid = match args.water {
                WaterKind::Oceanic => false,
                WaterKind::Turbid => true,
                WaterKind::Clear => bail!("--leave-out needs a table case: --water oceanic or turbid"),
            };
            let what = match k {
                LeaveOutKind::Depth => LeaveOut::Depth,
                LeaveOutKind::Wind => LeaveOut::Wind,
                LeaveOutKind::Sun => LeaveOut::Sun,
                LeaveOutKind::Water => LeaveOut::Water,
            };
            let t = full.without(args.sun_zenith_deg, args.wind_mps, turbid, args.depth_m, what);
            if t.cases.len() == full.cases.len() {
                bail!(
                    "--leave-out: no table case at sun zenith {} deg, wind {} m/s, {:?} water, {} m (cases: sun 30 or 60, wind 0 or 5, depth 5, 10 or 20)",
                    args.sun_zenith_deg,
                    args.wind_mps,
                    args.water,
                    args.depth_m
                );
            }
            Some(t)
        }
    };
    if let (Some(out), Some(input)) = (&args.output, &args.compare) {
        subnav_link::output::refuse_input_as_output("--output", out, &[input])?;
    }
    // Read the reference first: a bad file is refused before anything is written.
    let reference = match &args.compare {
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("reading the reference field {}", p.display()))?;
            Some((p, rf::ReferenceField::parse(&text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?))
        }
        None => None,
    };
    let table = if args.single_scattering { None } else { Some(left_out.as_ref().unwrap_or(full)) };
    let f = rf::ReferenceField::simulated_with(args.sun_zenith_deg, args.depth_m, args.wind_mps, water, args.seed, table);
    let csv = f.to_csv();
    match &args.output {
        // Whole or nothing (a device written in place).
        Some(p) => subnav_link::output::write_atomic(p, csv)?,
        None => print!("{csv}"),
    }
    if let Some((p, r)) = reference {
        let c = rf::compare(&f, &r, args.min_dolp, 80.0)
            .with_context(|| format!("{}: not on the simulator's grid (view zenith 0-80 by 5, azimuth 0-345 by 15)", p.display()))?;
        let text = match format {
            Format::Json => serde_json::to_string(&c)?,
            Format::Text => format!(
                "simulator vs {}: AoP (DoLP > {}) RMS {:.2} deg, max {:.2} deg over {} points; DoLP RMS {:.3}, max {:.3} over {} points",
                p.display(),
                args.min_dolp,
                c.aop_rms_deg,
                c.aop_max_abs_deg,
                c.aop_points,
                c.dolp_rms,
                c.dolp_max_abs,
                c.points
            ),
        };
        if args.output.is_some() { println!("{text}") } else { eprintln!("{text}") }
    }
    Ok(ExitCode::SUCCESS)
}

fn water(sky: &Sky) -> sim::Water {
    let flat = montecarlo::turbid_water(sky.turbidity);
    if sky.slope_rms > 0.0 { sim::Water { slope_rms: sky.slope_rms, facets: 16, ..flat } } else { flat }
}

fn sea_run(sky: &Sky) -> Option<montecarlo::SeaRun> {
    (sky.wind_mps.is_some() || sky.sky.is_some()).then(|| montecarlo::SeaRun::new(sky.wind_mps.unwrap_or(0.0), sky.sky.unwrap_or_default()))
}

fn simulate(args: &SimulateArgs, format: Format) -> Result<ExitCode> {
    let cfg = montecarlo::McConfig {
        draws: args.draws,
        depth_m: args.sky.depth_m,
        min_elevation_deg: args.min_elevation_deg,
        max_elevation_deg: args.max_elevation_deg,
        units: args.sky.units.unwrap_or(DEFAULT_UNITS),
        tilt_sigma_rad: args.sky.tilt_sigma_deg.to_radians(),
        water: water(&args.sky),
        seed: args.sky.seed,
        sea: sea_run(&args.sky),
        ..montecarlo::McConfig::default()
    };
    if cfg.sea.is_some() && args.emit_csv.is_some() {
        bail!("--emit-csv writes flat-surface draws: leave out --wind-mps and --sky");
    }
    if let Some(path) = &args.emit_csv {
        subnav_compass::raw_csv::write(&cfg, path).with_context(|| format!("writing {}", path.display()))?;
    }
    let r = montecarlo::run(&cfg);
    match format {
        Format::Json => println!("{}", serde_json::to_string(&r)?),
        Format::Text => {
            println!(
                "heading Monte Carlo: {} draws at {} m, sun {}-{} deg: {} fixes, RMSE {:.4} deg, mean {:+.4} deg, p95 |err| {:.4} deg, max {:.4} deg",
                r.draws,
                r.depth_m,
                r.elevation_deg[0],
                r.elevation_deg[1],
                r.fixes,
                r.rmse_deg,
                r.mean_error_deg,
                r.p95_abs_error_deg,
                r.max_abs_error_deg
            );
            println!(
                "reported 1-sigma (RMS) {:.4} deg, {:.1}% of errors within 2 sigma, mean unit DoLP {:.3}",
                r.rms_reported_sigma_deg,
                100.0 * r.within_2_sigma,
                r.mean_dolp
            );
            if let Some(s) = &r.sea {
                println!(
                    "moving sea: wind {} m/s, sky {}, {} sessions; {:.1}% within 2 of the solver's own sigma, RMS wave part {:.4} deg",
                    s.wind_mps,
                    s.sky,
                    s.sessions,
                    100.0 * s.within_2_solver_sigma,
                    s.rms_wave_sigma_deg
                );
            }
            for b in &r.bins {
                println!(
                    "  sun {:>5.1}-{:>5.1} deg: {:>5} fixes, RMSE {:.4} deg",
                    b.elevation_deg[0], b.elevation_deg[1], b.fixes, b.rmse_deg
                );
            }
            for (k, v) in &r.no_fix {
                println!("  no fix {k}: {v}");
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn geolocate(args: &GeolocateArgs, format: Format) -> Result<ExitCode> {
    let cfg = geoloc::GeoConfig {
        trials: args.trials,
        duration_s: args.track_s,
        interval_s: args.interval_s.max(1),
        depth_m: args.sky.depth_m,
        units: args.sky.units.unwrap_or(DEFAULT_UNITS),
        tilt_sigma_rad: args.sky.tilt_sigma_deg.to_radians(),
        heading_sigma_rad: args.heading_sigma_deg.to_radians(),
        fit_azimuth_offset: !args.known_heading,
        water: water(&args.sky),
        seed: args.sky.seed,
        ..geoloc::GeoConfig::default()
    };
    let r = geoloc::run(&cfg);
    if r.fitted == 0 {
        bail!("no trial of {} gave a position (no sun fixes to fit; refused: {:?}): no statistics", r.trials, r.no_fix);
    }
    match format {
        Format::Json => println!("{}", serde_json::to_string(&r)?),
        Format::Text => println!(
            "sun geolocation: {} trials of {} s tracks ({:.1} fixes each), heading 1-sigma {} deg {}, {} fitted: mean error {:.2} km, median {:.2} km, max {:.2} km",
            r.trials,
            r.duration_s,
            r.samples_per_trial,
            r.heading_sigma_deg,
            if r.fit_azimuth_offset { "(offset fitted)" } else { "(taken as known)" },
            r.fitted,
            r.mean_error_km,
            r.median_error_km,
            r.max_error_km
        ),
    }
    Ok(ExitCode::SUCCESS)
}

fn from_csv(path: &std::path::Path, format: Format) -> Result<ExitCode> {
    let text = std::fs::read_to_string(path).with_context(|| format!("read {}", path.display()))?;
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines.next().context("empty CSV")?;
    let raw_csv::Header { n_units, truth_col } = raw_csv::parse_header(header)?;
    let units = sim::default_units(n_units);
    let cfg = montecarlo::compass_config(&sim::Water::clear(), 0.01f64.to_radians());
    let (mut fixes, mut rows, mut bad) = (0usize, 0usize, 0usize);
    let mut sq = 0.0;
    for (i, line) in lines {
        rows += 1;
        let row = match raw_csv::parse_row(line, n_units) {
            Ok(r) => r,
            Err(e) => {
                // Bad rows are reported and skipped; the others still run.
                bad += 1;
                eprintln!("line {}: {e:#}", i + 1);
                continue;
            }
        };
        let dt = row.t.map_or(69.0, ephemeris::delta_t_estimate_s);
        let input = CompassInput { counts: &row.counts, accel_body_mps2: row.accel, unix_us: row.t, observer: row.obs, delta_t_s: dt };
        let res = compass::solve(&units, &input, &cfg);
        let truth = truth_col.and_then(|c| line.split(',').nth(c)).and_then(|s| s.trim().parse::<f64>().ok());
        match (&res, format) {
            (Ok(fx), Format::Text) => {
                let h = (fx.heading_rad as f64).to_degrees();
                let err = truth.map(|t| montecarlo::wrap_pi((h - t).to_radians()).to_degrees());
                println!(
                    "line {}: heading {:.3} deg +- {:.3} (1-sigma), sun rel. azimuth {:.3} deg, elevation {:.3} deg in water / {:.3} deg in air, {} units{}",
                    i + 1,
                    h,
                    (fx.sigma_heading_rad as f64).to_degrees(),
                    (fx.sun.rel_azimuth_rad as f64).to_degrees(),
                    (fx.sun.water_elevation_rad as f64).to_degrees(),
                    (fx.sun.air_elevation_rad as f64).to_degrees(),
                    fx.sun.sun.units_used,
                    err.map(|e| format!(", error {e:+.3} deg")).unwrap_or_default()
                );
            }
            (Ok(fx), Format::Json) => println!(
                "{}",
                json!({"line": i + 1, "heading_deg": (fx.heading_rad as f64).to_degrees(), "sigma_deg": (fx.sigma_heading_rad as f64).to_degrees(),
                       "rel_azimuth_deg": (fx.sun.rel_azimuth_rad as f64).to_degrees(), "water_elevation_deg": (fx.sun.water_elevation_rad as f64).to_degrees(),
                       "air_elevation_deg": (fx.sun.air_elevation_rad as f64).to_degrees(), "units_used": fx.sun.sun.units_used, "no_fix_reason": 0,
                       "true_yaw_deg": truth})
            ),
            (Err((r, _)), Format::Text) => println!("line {}: no fix ({}: {})", i + 1, r.code(), r.describe()),
            (Err((r, m)), Format::Json) => println!(
                "{}",
                json!({"line": i + 1, "no_fix_reason": r.code(), "no_fix": format!("{r:?}"),
                       "rel_azimuth_deg": m.map(|m| (m.rel_azimuth_rad as f64).to_degrees()),
                       "water_elevation_deg": m.map(|m| (m.water_elevation_rad as f64).to_degrees())})
            ),
        }
        if let Ok(fx) = &res {
            fixes += 1;
            if let Some(t) = truth {
                sq += montecarlo::wrap_pi(fx.heading_rad as f64 - t.to_radians()).powi(2);
            }
        }
    }
    if format == Format::Text {
        let rmse = if truth_col.is_some() && fixes > 0 {
            format!(", heading RMSE vs true_yaw_deg {:.4} deg", (sq / fixes as f64).sqrt().to_degrees())
        } else {
            String::new()
        };
        println!("{rows} rows, {fixes} fixes, {bad} unreadable{rmse}");
    }
    Ok(if bad > 0 { ExitCode::from(2) } else { ExitCode::SUCCESS })
}
