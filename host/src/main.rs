//! `subnav`: the host command-line tool. Each subcommand lives in `cli/<name>.rs` with its own
//! clap `Args` and a `run` function; this file only dispatches.

use clap::{Parser, Subcommand};
use subnav_host::cli;

#[derive(Parser)]
#[command(name = "subnav", version, about = "Underwater vehicle navigation: sensor-head telemetry, QEMU runs and host-side navigation methods")]
struct Cli {
    /// Output format for results.
    #[arg(long, global = true, value_enum, default_value_t = cli::Format::Text)]
    format: cli::Format,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Factor-graph INS/DVL/USBL navigation with abnormal-observation handling (replay, simulate, Monte Carlo).
    Fgo(cli::fgo::Args),
    /// Decode telemetry (and defmt logs) from a file, a TCP socket or a serial port.
    Decode(cli::decode::Args),
    /// Boot a firmware ELF in QEMU (mps2-an386) and print its decoded telemetry and logs live.
    Qemu(cli::qemu::Args),
    /// Bathymetric graph SLAM from multibeam soundings (CSV input or seeded simulated surveys).
    Bathy(cli::bathy::Args),
    /// The navigation filter on the host: replay a sensor log, simulate a dive, AUKF-vs-UKF Monte Carlo.
    Filter(cli::filter::Args),
}

fn main() -> std::process::ExitCode {
    let args = Cli::parse();
    let result = match args.command {
        Command::Decode(a) => cli::decode::run(a, args.format),
        Command::Fgo(a) => cli::fgo::run(a, args.format),
        Command::Qemu(a) => cli::qemu::run(a, args.format),
        Command::Bathy(a) => cli::bathy::run(a, args.format),
        Command::Filter(a) => cli::filter::run(a, args.format),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
