//! `subnav`: the host command-line tool. Each subcommand lives in `cli/<name>.rs` with its own
//! clap `Args` and a `run` function; this file only dispatches.

use clap::{Parser, Subcommand};
use subnav_host::cli;

#[derive(Parser)]
#[command(
    name = "subnav",
    version,
    about = "Underwater vehicle navigation: sensor-head telemetry, QEMU runs and host-side navigation methods"
)]
struct Cli {
    /// Output format for results.
    #[arg(long, global = true, value_enum, default_value_t = cli::Format::Text)]
    format: cli::Format,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Factor-graph INS/DVL/USBL navigation with abnormal-observation handling: replay a log, simulate, Monte Carlo.
    Fgo(cli::fgo::Args),
    /// Decode telemetry (and defmt logs) from a file, a TCP socket or a serial port.
    Decode(cli::decode::Args),
    /// Boot a firmware ELF in QEMU (mps2-an386) and print its decoded telemetry and logs live.
    Qemu(cli::qemu::Args),
    /// Bathymetric graph SLAM from multibeam soundings (CSV input or seeded simulated surveys).
    Bathy(cli::bathy::Args),
    /// The navigation filter on the host: replay a sensor log, simulate a dive, AUKF-vs-UKF Monte Carlo.
    Filter(cli::filter::Args),
    /// Apparent solar zenith and azimuth for a time and place (the sensor head's ephemeris).
    Sun(cli::sun::Args),
    /// Polarization compass on a simulated sky (heading Monte Carlo, sun geolocation) or on a CSV of raw counts.
    Compass(cli::compass::Args),
    /// Record telemetry live (TCP, serial, or RTT through a debug probe) to a lossless recording.
    Record(cli::record::Args),
    /// Export a recording to MCAP (Foxglove) and/or CSV per message kind.
    Export(cli::export::Args),
    /// Write a simulated dive scenario (survey, date, place, water, sensor grades, fixes, faults).
    Sim(cli::sim::Args),
    /// Run a dive scenario with the firmware in the loop (QEMU or native) and print error statistics.
    Run(cli::run::Args),
    /// Bridge a head (simulated, recorded or live) to an autopilot over MAVLink 2: its solution out, GPS back.
    Mavlink(cli::mavlink::Args),
    /// Calibrate a simulated head (polarization units, IMU) and write the calibrations to its store; compare mis-built heads.
    Calibrate(cli::calibrate::Args),
    /// Run the firmware's estimator on a recording's raw samples and commands and compare with the Nav solutions it sent
    Replay(cli::replay::Args),
    /// Mission report from a recording (+ truth): plots and a Markdown/HTML page.
    Report(cli::report::Args),
    /// LMNN metric learning on labelled CSV samples (fit a model, evaluate kNN accuracy).
    Lmnn(cli::lmnn::Args),
    /// Topological map from polarization images with AUKF-SLAM loop closures (simulated survey or recorded data).
    Map(cli::map::Args),
    /// Under-ice odometry (MSCKF: IMU, stereo, depth, imaging-sonar velocity): simulate and evaluate, or run on a data directory.
    Ice(cli::ice::Args),
    /// Translation between two images by phase correlation with a sub-pixel (DFT-upsampled) peak.
    Phasecorr(cli::phasecorr::Args),
    /// Flash a board's firmware through a debug probe (probe-rs) and optionally stay attached.
    #[cfg(feature = "probe")]
    Flash(cli::flash::Args),
    /// Attach to a running board through a debug probe: stream defmt (RTT) and telemetry.
    #[cfg(feature = "probe")]
    Attach(cli::attach::Args),
}

fn main() -> std::process::ExitCode {
    // `subnav ... | head` must end quietly when the reader goes away, like other Unix tools,
    // instead of panicking in println! on EPIPE.
    // SAFETY: restoring the default disposition of SIGPIPE before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let args = Cli::parse();
    let result = match args.command {
        Command::Decode(a) => cli::decode::run(a, args.format),
        Command::Fgo(a) => cli::fgo::run(a, args.format),
        Command::Qemu(a) => cli::qemu::run(a, args.format),
        Command::Bathy(a) => cli::bathy::run(a, args.format),
        Command::Filter(a) => cli::filter::run(a, args.format),
        Command::Sun(a) => cli::sun::run(a, args.format),
        Command::Compass(a) => cli::compass::run(a, args.format),
        Command::Record(a) => cli::record::run(a, args.format),
        Command::Export(a) => cli::export::run(a, args.format),
        Command::Report(a) => cli::report::run(a, args.format),
        Command::Replay(a) => cli::replay::run(a, args.format),
        Command::Sim(a) => cli::sim::run(a, args.format),
        Command::Run(a) => cli::run::run(a, args.format),
        Command::Mavlink(a) => cli::mavlink::run(a, args.format),
        Command::Calibrate(a) => cli::calibrate::run(a, args.format),
        Command::Lmnn(a) => cli::lmnn::run(a, args.format),
        Command::Map(a) => cli::map::run(a, args.format),
        Command::Ice(a) => cli::ice::run(a, args.format),
        Command::Phasecorr(a) => cli::phasecorr::run(a, args.format),
        #[cfg(feature = "probe")]
        Command::Flash(a) => cli::flash::run(a, args.format),
        #[cfg(feature = "probe")]
        Command::Attach(a) => cli::attach::run(a, args.format),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
