//! The raw-counts CSV of the compass (`subnav compass csv FILE`, written by `subnav compass
//! simulate --emit-csv FILE`): a header line, then one solve per row:
//! `time,lat_deg,lon_deg,ax_mps2,ay_mps2,az_mps2,u0_c0,u0_c1,u0_c2,u0_c3,u1_c0,...`
//! `time` is POSIX microseconds or RFC 3339; empty lat/lon mean "position unknown" (the sun is
//! still measured, the reason is `NoTime`). The units are the default head of the simulator
//! (`subnav_base::sky::default_units`: a ring of N = (columns - 6) / 4 units, nominal
//! calibration). A simulated file has a `true_yaw_deg` column (the truth).

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result, bail};
use nalgebra::Rotation3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use subnav_base::sky as sim;
use subnav_core::compass::{self, CHANNELS};
use subnav_core::ephemeris::Observer;

use crate::montecarlo;

/// A time given as RFC 3339 (`2026-06-21T12:00:00Z`), as POSIX microseconds.
pub fn parse_time_us(s: &str) -> Result<i64> {
    let t = chrono::DateTime::parse_from_rfc3339(s.trim()).with_context(|| format!("not an RFC 3339 time: {s:?}"))?;
    t.timestamp_micros().checked_add(0).context("time out of range")
}

/// What the header line says: the number of units and the truth column, if any.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    pub n_units: usize,
    /// Column of `true_yaw_deg` (a simulated file's truth).
    pub truth_col: Option<usize>,
}

/// Reads the header line: 4 count columns per unit, 3 to `compass::MAX_UNITS` units.
pub fn parse_header(header: &str) -> Result<Header> {
    let cols: Vec<&str> = header.split(',').map(str::trim).collect();
    let n_count_cols = cols.iter().filter(|c| c.starts_with('u') && c.contains("_c")).count();
    if n_count_cols % CHANNELS != 0 || n_count_cols / CHANNELS < 3 {
        bail!("header must have 4 count columns per unit (u0_c0..u0_c3, ...) for at least 3 units, found {n_count_cols}");
    }
    let n_units = n_count_cols / CHANNELS;
    if n_units > compass::MAX_UNITS {
        bail!("at most {} units", compass::MAX_UNITS);
    }
    Ok(Header { n_units, truth_col: cols.iter().position(|c| *c == "true_yaw_deg") })
}

/// Writes simulated draws as a raw-counts CSV (same draws as the Monte Carlo would make with
/// another seed stream; the `true_yaw_deg` column is the truth).
pub fn write(cfg: &montecarlo::McConfig, path: &Path) -> Result<()> {
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0xC5F);
    let units = sim::default_units(cfg.units);
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).with_context(|| format!("create {}", path.display()))?);
    let mut header = String::from("time,lat_deg,lon_deg,ax_mps2,ay_mps2,az_mps2");
    for u in 0..units.len() {
        for c in 0..CHANNELS {
            header += &format!(",u{u}_c{c}");
        }
    }
    writeln!(f, "{header},true_yaw_deg")?;
    for _ in 0..cfg.draws {
        let (t, obs, p) = montecarlo::draw_sun(&mut rng, cfg.min_elevation_deg, cfg.max_elevation_deg);
        let field = montecarlo::calm_field(montecarlo::sun_ned(&p), cfg.water, cfg.depth_m, &mut rng);
        let mt = cfg.max_tilt_deg.to_radians();
        let (roll, pitch, yaw) = (rng.random_range(-mt..=mt), rng.random_range(-mt..=mt), rng.random_range(0.0..std::f64::consts::TAU));
        let r_nb = Rotation3::from_euler_angles(roll, pitch, yaw);
        let cal: Vec<_> = units.iter().map(|u| sim::true_channels(u, &cfg.errors, &mut rng)).collect();
        let counts = sim::counts(field.as_ref(), &r_nb, &units, &cal, &cfg.errors, &mut rng);
        let a = sim::accel(&r_nb, cfg.tilt_sigma_rad, &mut rng);
        let mut row = format!(
            "{t},{:.7},{:.7},{:.6},{:.6},{:.6}",
            (obs.lat_rad as f64).to_degrees(),
            (obs.lon_rad as f64).to_degrees(),
            a[0],
            a[1],
            a[2]
        );
        for c in counts.iter().flatten() {
            row += &format!(",{c}");
        }
        writeln!(f, "{row},{:.6}", yaw.to_degrees())?;
    }
    Ok(())
}

/// One parsed CSV row.
pub struct Row {
    /// POSIX microseconds (None: empty cell).
    pub t: Option<i64>,
    /// None: latitude or longitude empty (position unknown).
    pub obs: Option<Observer>,
    pub accel: [f32; 3],
    /// Raw counts per unit.
    pub counts: Vec<[i16; CHANNELS]>,
}

/// Parses a data row of `n_units` units (errors name the column).
pub fn parse_row(line: &str, n_units: usize) -> Result<Row> {
    let f: Vec<&str> = line.split(',').map(str::trim).collect();
    if f.len() < 6 + 4 * n_units {
        bail!("expected at least {} columns, found {}", 6 + 4 * n_units, f.len());
    }
    let t = if f[0].is_empty() {
        None
    } else if let Ok(us) = f[0].parse::<i64>() {
        Some(us)
    } else {
        Some(parse_time_us(f[0])?)
    };
    let num = |s: &str, what: &str| -> Result<f64> {
        let v: f64 = s.parse().with_context(|| format!("{what}: not a number: {s:?}"))?;
        if !v.is_finite() {
            bail!("{what}: not finite");
        }
        Ok(v)
    };
    let obs = if f[1].is_empty() || f[2].is_empty() {
        None
    } else {
        Some(Observer {
            lat_rad: num(f[1], "lat_deg")?.to_radians() as f32,
            lon_rad: num(f[2], "lon_deg")?.to_radians() as f32,
            height_m: 0.0,
        })
    };
    let accel = [num(f[3], "ax")? as f32, num(f[4], "ay")? as f32, num(f[5], "az")? as f32];
    let mut counts = Vec::with_capacity(n_units);
    for u in 0..n_units {
        let mut c = [0i16; CHANNELS];
        for (k, x) in c.iter_mut().enumerate() {
            let s = f[6 + 4 * u + k];
            *x = s.parse().with_context(|| format!("unit {u} channel {k}: not a 16-bit count: {s:?}"))?;
        }
        counts.push(c);
    }
    Ok(Row { t, obs, accel, counts })
}

#[cfg(test)]
mod tests {
    use super::*;
    use subnav_core::compass::CompassInput;

    #[test]
    fn csv_round_trip_and_bad_rows() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sim.csv");
        let cfg = montecarlo::McConfig { draws: 5, seed: 4, ..montecarlo::McConfig::default() };
        write(&cfg, &path).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let mut lines = text.lines();
        let header = lines.next().unwrap();
        assert!(header.starts_with("time,lat_deg,lon_deg,ax_mps2"));
        assert_eq!(parse_header(header).unwrap(), Header { n_units: 8, truth_col: Some(6 + 32) });
        let units = sim::default_units(8);
        let ccfg = montecarlo::compass_config(&sim::Water::clear(), 0.01f64.to_radians());
        for line in lines {
            let row = parse_row(line, 8).unwrap();
            let truth: f64 = line.rsplit(',').next().unwrap().parse().unwrap();
            let input =
                CompassInput { counts: &row.counts, accel_body_mps2: row.accel, unix_us: row.t, observer: row.obs, delta_t_s: 70.0 };
            let fx = compass::solve(&units, &input, &ccfg).unwrap();
            let err = montecarlo::wrap_pi((fx.heading_rad as f64) - truth.to_radians()).to_degrees();
            assert!(err.abs() < 1.0, "{err}");
        }
        assert!(parse_row("1,2,3", 8).is_err());
        let bad_count = format!("0,10,10,0,0,-9.8{}", ",70000".repeat(32));
        assert!(parse_row(&bad_count, 8).is_err());
        let nan = format!("0,10,10,NaN,0,-9.8{}", ",100".repeat(32));
        assert!(parse_row(&nan, 8).is_err());
    }
}
