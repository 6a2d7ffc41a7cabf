//! CSV input/output, so the chain runs on users' own data.
//!
//! - Navigation (`--nav`): header `t_s,north_m,east_m,depth_m,heading_rad[,vel_sigma_mps]`
//!   (any column order; `vel_sigma_mps` defaults to 0.01 m/s, DVL bottom lock). Times ascending.
//! - Soundings (`--soundings`): header `t_s,beam_angle_rad,range_m`; rows with the same `t_s`
//!   form one ping. Each ping's pose is interpolated from the navigation (linear; heading along
//!   the shorter arc); pings outside the navigation's time span are an error.
//!
//! Bad input (empty file, missing column, unparsable or non-finite number, times going
//! backwards) gives an error naming the file and line. The plain comma-separated format needs
//! no quoting, so a CSV crate would add nothing here.

use super::{Beam, NavSample, Ping, Survey};
use anyhow::{Context, Result, bail};
use std::io::Write;
use std::path::Path;

struct Table {
    cols: Vec<String>,
    rows: Vec<(usize, Vec<f64>)>,
}

fn parse_table(text: &str, what: &str, required: &[&str]) -> Result<Table> {
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let Some((_, header)) = lines.next() else { bail!("{what}: file is empty (expected a header line with {})", required.join(",")) };
    let cols: Vec<String> = header.split(',').map(|s| s.trim().to_ascii_lowercase()).collect();
    for r in required {
        if !cols.iter().any(|c| c == r) {
            bail!("{what}: header lacks column '{r}' (found: {header})");
        }
    }
    let mut rows = vec![];
    for (ln, l) in lines {
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        if f.len() != cols.len() {
            bail!("{what} line {}: {} fields, header has {}", ln + 1, f.len(), cols.len());
        }
        let mut v = Vec::with_capacity(f.len());
        for (s, c) in f.iter().zip(&cols) {
            let x: f64 = s.parse().with_context(|| format!("{what} line {}: column '{c}': '{s}' is not a number", ln + 1))?;
            if !x.is_finite() {
                bail!("{what} line {}: column '{c}' is not finite ('{s}')", ln + 1);
            }
            v.push(x);
        }
        rows.push((ln + 1, v));
    }
    if rows.is_empty() {
        bail!("{what}: no data rows after the header");
    }
    Ok(Table { cols, rows })
}

impl Table {
    fn col(&self, name: &str) -> Option<usize> {
        self.cols.iter().position(|c| c == name)
    }
}

pub fn parse_nav(text: &str) -> Result<Vec<NavSample>> {
    let t = parse_table(text, "navigation CSV", &["t_s", "north_m", "east_m", "depth_m", "heading_rad"])?;
    let c = |n: &str| t.col(n).with_context(|| format!("navigation CSV: missing column {n}"));
    let (it, inn, ie, id, ih) = (c("t_s")?, c("north_m")?, c("east_m")?, c("depth_m")?, c("heading_rad")?);
    let is = t.col("vel_sigma_mps");
    let mut out: Vec<NavSample> = Vec::with_capacity(t.rows.len());
    for (ln, r) in &t.rows {
        let n = NavSample {
            t_s: r[it],
            north_m: r[inn],
            east_m: r[ie],
            depth_m: r[id],
            heading_rad: r[ih],
            vel_sigma_mps: is.map_or(0.01, |k| r[k]),
        };
        if n.vel_sigma_mps < 0.0 {
            bail!("navigation CSV line {ln}: vel_sigma_mps is negative");
        }
        if let Some(p) = out.last() {
            if n.t_s <= p.t_s {
                bail!("navigation CSV line {ln}: time {} does not increase (previous {})", n.t_s, p.t_s);
            }
        }
        out.push(n);
    }
    Ok(out)
}

/// Longest slant range accepted, m (the deepest ocean is 11 km).
pub const MAX_RANGE_M: f64 = 12_000.0;

pub fn parse_soundings(text: &str) -> Result<Vec<Ping>> {
    let t = parse_table(text, "soundings CSV", &["t_s", "beam_angle_rad", "range_m"])?;
    let (it, ia, ir) = (t.col("t_s").unwrap_or(0), t.col("beam_angle_rad").unwrap_or(1), t.col("range_m").unwrap_or(2));
    let mut pings: Vec<Ping> = vec![];
    for (ln, r) in &t.rows {
        if !(0.0..=MAX_RANGE_M).contains(&r[ir]) {
            bail!("soundings CSV line {ln}: range_m must be in 0..={MAX_RANGE_M} m, got {}", r[ir]);
        }
        let b = Beam { angle_rad: r[ia], range_m: r[ir] };
        match pings.last_mut() {
            Some(p) if p.t_s == r[it] => p.beams.push(b),
            Some(p) if r[it] < p.t_s => bail!("soundings CSV line {ln}: time {} goes backwards (previous ping {})", r[it], p.t_s),
            _ => pings.push(Ping { t_s: r[it], beams: vec![b] }),
        }
    }
    Ok(pings)
}

/// Pose at time `t` by linear interpolation of `nav` (sorted).
pub fn interpolate(nav: &[NavSample], t: f64) -> Option<NavSample> {
    let k = nav.partition_point(|n| n.t_s < t);
    if k < nav.len() && nav[k].t_s == t {
        return Some(nav[k]);
    }
    if k == 0 || k >= nav.len() {
        return None;
    }
    let (a, b) = (&nav[k - 1], &nav[k]);
    let w = (t - a.t_s) / (b.t_s - a.t_s);
    let dh = subnav_base::wrap_pi(b.heading_rad - a.heading_rad);
    Some(NavSample {
        t_s: t,
        north_m: a.north_m + w * (b.north_m - a.north_m),
        east_m: a.east_m + w * (b.east_m - a.east_m),
        depth_m: a.depth_m + w * (b.depth_m - a.depth_m),
        heading_rad: a.heading_rad + w * dh,
        vel_sigma_mps: a.vel_sigma_mps.max(b.vel_sigma_mps),
    })
}

/// Build a survey from parsed CSVs: one interpolated pose per ping.
pub fn survey_from(nav: &[NavSample], pings: Vec<Ping>) -> Result<Survey> {
    let mut s = Survey::default();
    for p in pings {
        let Some(n) = interpolate(nav, p.t_s) else {
            bail!(
                "ping at t = {} s lies outside the navigation time span [{}, {}] s",
                p.t_s,
                nav.first().map_or(f64::NAN, |n| n.t_s),
                nav.last().map_or(f64::NAN, |n| n.t_s)
            );
        };
        s.nav.push(n);
        s.pings.push(p);
    }
    // The step variance model needs dt and vel_sigma of each ping interval: with interpolated
    // poses this is exactly what the samples carry.
    Ok(s)
}

pub fn read_survey(soundings: &Path, nav: &Path) -> Result<Survey> {
    let nt = std::fs::read_to_string(nav).with_context(|| format!("reading {}", nav.display()))?;
    let st = std::fs::read_to_string(soundings).with_context(|| format!("reading {}", soundings.display()))?;
    let nav = parse_nav(&nt).with_context(|| format!("in {}", nav.display()))?;
    let pings = parse_soundings(&st).with_context(|| format!("in {}", soundings.display()))?;
    survey_from(&nav, pings)
}

pub fn write_nav(path: &Path, nav: &[NavSample]) -> Result<()> {
    write_nav_unnamed(path, nav).with_context(|| format!("writing {}", path.display()))
}

fn write_nav_unnamed(path: &Path, nav: &[NavSample]) -> Result<()> {
    let mut w = std::io::BufWriter::new(std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?);
    writeln!(w, "t_s,north_m,east_m,depth_m,heading_rad,vel_sigma_mps")?;
    for n in nav {
        writeln!(w, "{},{},{},{},{},{}", n.t_s, n.north_m, n.east_m, n.depth_m, n.heading_rad, n.vel_sigma_mps)?;
    }
    w.flush()?;
    Ok(())
}

pub fn write_soundings(path: &Path, pings: &[Ping]) -> Result<()> {
    write_soundings_unnamed(path, pings).with_context(|| format!("writing {}", path.display()))
}

fn write_soundings_unnamed(path: &Path, pings: &[Ping]) -> Result<()> {
    let mut w = std::io::BufWriter::new(std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?);
    writeln!(w, "t_s,beam_angle_rad,range_m")?;
    for p in pings {
        for b in &p.beams {
            writeln!(w, "{},{},{}", p.t_s, b.angle_rad, b.range_m)?;
        }
    }
    w.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_input_gives_clear_errors() {
        let e = |r: Result<Vec<NavSample>>| format!("{:#}", r.unwrap_err());
        assert!(e(parse_nav("")).contains("empty"));
        assert!(e(parse_nav("t_s,north_m,east_m,depth_m\n")).contains("heading_rad"));
        assert!(e(parse_nav("t_s,north_m,east_m,depth_m,heading_rad\n")).contains("no data rows"));
        assert!(e(parse_nav("t_s,north_m,east_m,depth_m,heading_rad\n0,1,2,3\n")).contains("line 2"));
        assert!(e(parse_nav("t_s,north_m,east_m,depth_m,heading_rad\n0,1,2,x,0\n")).contains("'x' is not a number"));
        assert!(e(parse_nav("t_s,north_m,east_m,depth_m,heading_rad\n0,NaN,2,3,0\n")).contains("not finite"));
        assert!(e(parse_nav("t_s,north_m,east_m,depth_m,heading_rad\n1,0,0,3,0\n0,0,0,3,0\n")).contains("does not increase"));
        let s = parse_soundings("t_s,beam_angle_rad,range_m\n0,0.1,inf\n");
        assert!(format!("{:#}", s.unwrap_err()).contains("not finite"));
        let s = parse_soundings("t_s,beam_angle_rad,range_m\n1,0.1,5\n0,0.1,5\n");
        assert!(format!("{:#}", s.unwrap_err()).contains("backwards"));
        let nav = parse_nav("t_s,north_m,east_m,depth_m,heading_rad\n0,0,0,3,0\n1,2,0,3,0\n").unwrap();
        let pings = parse_soundings("t_s,beam_angle_rad,range_m\n5,0.1,5\n").unwrap();
        assert!(format!("{:#}", survey_from(&nav, pings).unwrap_err()).contains("outside the navigation"));
    }

    #[test]
    fn interpolation_takes_the_short_way_round_in_heading() {
        let nav = parse_nav("t_s,heading_rad,north_m,east_m,depth_m,vel_sigma_mps\n0,3.0,0,0,10,0.01\n2,-3.0,4,2,12,0.2\n").unwrap();
        let m = interpolate(&nav, 1.0).unwrap();
        assert!((m.north_m - 2.0).abs() < 1e-12 && (m.east_m - 1.0).abs() < 1e-12 && (m.depth_m - 11.0).abs() < 1e-12);
        assert!((m.heading_rad.sin() - std::f64::consts::PI.sin()).abs() < 1e-9 && m.heading_rad.cos() < -0.99);
        assert_eq!(m.vel_sigma_mps, 0.2);
    }
}
