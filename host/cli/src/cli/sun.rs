//! `subnav sun`: apparent solar zenith and azimuth for a time and place, from the same MCU
//! ephemeris the sensor head runs (`subnav_core::ephemeris`).

use std::process::ExitCode;

use anyhow::{Result, bail};
use serde_json::json;
use subnav_core::ephemeris::{self, Atmosphere, Observer};

use super::Format;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// UTC instant, RFC 3339 (e.g. 2003-10-17T12:30:30-07:00).
    #[arg(long)]
    pub time: String,
    /// Latitude (deg, north positive).
    #[arg(long, allow_hyphen_values = true)]
    pub lat: f64,
    /// Longitude (deg, east positive).
    #[arg(long, allow_hyphen_values = true)]
    pub lon: f64,
    /// Height above sea level (m, -500..=9000).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = super::args::f64_in(-500.0..=9000.0))]
    pub elevation_m: f64,
    /// Air pressure (hPa, 300..=1100) for the refraction correction.
    #[arg(long, default_value_t = 1013.25, allow_hyphen_values = true, value_parser = super::args::f64_in(300.0..=1100.0))]
    pub pressure_hpa: f64,
    /// Air temperature (C, -90..=60) for the refraction correction.
    #[arg(long, default_value_t = 12.0, allow_hyphen_values = true, value_parser = super::args::f64_in(-90.0..=60.0))]
    pub temp_c: f64,
    /// TT - UT1 (s); default: the Espenak & Meeus polynomial.
    #[arg(long)]
    pub delta_t: Option<f64>,
    /// Skip the refraction correction.
    #[arg(long)]
    pub no_refraction: bool,
}

/// POSIX microseconds of an RFC 3339 time.
pub use subnav_compass::raw_csv::parse_time_us;

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    let t = parse_time_us(&args.time)?;
    if !(-90.0..=90.0).contains(&args.lat) || !(-180.0..=360.0).contains(&args.lon) {
        bail!("latitude must be within [-90, 90] and longitude within [-180, 360] deg");
    }
    let obs = Observer { lat_rad: args.lat.to_radians() as f32, lon_rad: args.lon.to_radians() as f32, height_m: args.elevation_m as f32 };
    let atm = Atmosphere { pressure_hpa: args.pressure_hpa as f32, temp_c: args.temp_c as f32 };
    let dt = args.delta_t.map_or_else(|| ephemeris::delta_t_estimate_s(t), |d| d as f32);
    let p = ephemeris::sun_position(t, &obs, (!args.no_refraction).then_some(&atm), dt)
        .map_err(|e| anyhow::anyhow!("ephemeris refused the input: {e}"))?;
    let d = |x: f32| (x as f64).to_degrees();
    match format {
        Format::Text => println!(
            "apparent zenith {:.5} deg, azimuth {:.5} deg (geometric zenith {:.5} deg, apparent elevation {:.5} deg, declination {:.5} deg, delta T {:.1} s)",
            d(p.apparent_zenith_rad),
            d(p.azimuth_rad),
            d(p.zenith_rad),
            90.0 - d(p.apparent_zenith_rad),
            d(p.declination_rad),
            dt
        ),
        Format::Json => println!(
            "{}",
            json!({
                "time": args.time, "unix_us": t, "lat_deg": args.lat, "lon_deg": args.lon,
                "apparent_zenith_deg": d(p.apparent_zenith_rad), "zenith_deg": d(p.zenith_rad),
                "azimuth_deg": d(p.azimuth_rad), "apparent_elevation_deg": 90.0 - d(p.apparent_zenith_rad),
                "declination_deg": d(p.declination_rad), "distance_au": p.distance_au, "delta_t_s": dt,
            })
        ),
    }
    Ok(ExitCode::SUCCESS)
}
