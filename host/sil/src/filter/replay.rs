//! Sensor-log replay: a CSV log in, the estimates out (CSV or JSON lines).
//!
//! Log format: one event per line, `#` comments and blank lines ignored, times in seconds:
//! ```text
//! t_s,init,n_m,e_m,d_m,yaw_rad[,vn,ve,vd] (optional, first: initial position, heading, NED velocity)
//! t_s,imu,gx,gy,gz,ax,ay,az             (rad/s, m/s^2, FRD body)
//! t_s,heading,heading_rad[,sigma_rad]
//! t_s,depth,depth_m[,sigma_m]
//! t_s,dvl,vx,vy,vz[,sigma_mps]          (FRD body, m/s)
//! t_s,fix,n,e,d,cxx,cxy,cxz,cyy,cyz,czz (NED m, covariance upper triangle m^2)
//! ```
//! A malformed line is an error with its line number (nothing is silently skipped); a
//! well-formed line with NaN values is passed to the filter, which rejects and counts it.

use std::fmt::Write as _;

use anyhow::{Context, bail};
use serde::Serialize;
use subnav_core::nav::NavConfig;
use subnav_wire::messages::{ImuSample, NavMode};

use super::sim::Event;
use super::{EventCounts, apply, start};

/// Initial position and heading of a log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LogInit {
    pub t_us: u64,
    pub pos_ned_m: [f32; 3],
    pub yaw_rad: f32,
    pub vel_ned_mps: [f32; 3],
}

/// Latest time a log may hold, s (about 317 years: Unix times fit; `1e300` saturated the
/// filter's microsecond clock and froze the position).
pub const MAX_LOG_TIME_S: f64 = 1e10;

/// Largest step forward in time from one event to the next, s (a day: a longer gap is a
/// damaged time).
pub const MAX_GAP_S: f64 = 86_400.0;

fn t_us(s: &str) -> anyhow::Result<u64> {
    let t: f64 = s.trim().parse().with_context(|| format!("bad time {s:?}"))?;
    if !(t.is_finite() && (0.0..=MAX_LOG_TIME_S).contains(&t)) {
        bail!("time must be in 0..={MAX_LOG_TIME_S:e} s, got {t}");
    }
    Ok((t * 1e6).round() as u64)
}

fn nums(fields: &[&str], n_min: usize, n_max: usize) -> anyhow::Result<Vec<f32>> {
    if fields.len() < n_min || fields.len() > n_max {
        bail!("expected {n_min}..={n_max} values, got {}", fields.len());
    }
    fields.iter().map(|f| f.trim().parse::<f32>().with_context(|| format!("bad number {f:?}"))).collect()
}

/// Parse a CSV sensor log.
pub fn parse_log(text: &str) -> anyhow::Result<(Option<LogInit>, Vec<Event>)> {
    let mut init = None;
    let mut events = Vec::new();
    let mut last_us: Option<u64> = None;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let f: Vec<&str> = line.split(',').collect();
        let mut parse = || -> anyhow::Result<Option<Event>> {
            if f.len() < 2 {
                bail!("expected `t_s,kind,...`");
            }
            let t = t_us(f[0])?;
            let v = &f[2..];
            Ok(Some(match f[1].trim() {
                "init" => {
                    let x = nums(v, 4, 7)?;
                    if x.len() != 4 && x.len() != 7 {
                        bail!("init takes n,e,d,yaw or n,e,d,yaw,vn,ve,vd");
                    }
                    let vel = if x.len() == 7 { [x[4], x[5], x[6]] } else { [0.0; 3] };
                    init = Some(LogInit { t_us: t, pos_ned_m: [x[0], x[1], x[2]], yaw_rad: x[3], vel_ned_mps: vel });
                    return Ok(None);
                }
                "imu" => {
                    let x = nums(v, 6, 6)?;
                    Event::Imu(ImuSample { t_us: t, gyro_radps: [x[0], x[1], x[2]], accel_mps2: [x[3], x[4], x[5]], temp_c: f32::NAN })
                }
                "heading" => {
                    let x = nums(v, 1, 2)?;
                    Event::Heading { t_us: t, heading_rad: x[0], sigma_rad: x.get(1).copied() }
                }
                "depth" => {
                    let x = nums(v, 1, 2)?;
                    Event::Depth { t_us: t, depth_m: x[0], sigma_m: x.get(1).copied() }
                }
                "dvl" => {
                    let x = nums(v, 3, 4)?;
                    Event::Dvl { t_us: t, vel_frd_mps: [x[0], x[1], x[2]], sigma_mps: x.get(3).copied() }
                }
                "fix" => {
                    let x = nums(v, 9, 9)?;
                    Event::Fix { t_us: t, pos_ned_m: [x[0], x[1], x[2]], cov_ned_m2: [x[3], x[4], x[5], x[6], x[7], x[8]] }
                }
                k => bail!("unknown event kind {k:?} (init, imu, heading, depth, dvl, fix)"),
            }))
        };
        if let Some(ev) = parse().with_context(|| format!("log line {}", i + 1))? {
            let t = match &ev {
                Event::Imu(m) => m.t_us,
                Event::Heading { t_us, .. } | Event::Depth { t_us, .. } | Event::Dvl { t_us, .. } | Event::Fix { t_us, .. } => *t_us,
            };
            if let Some(prev) = last_us
                && t.saturating_sub(prev) as f64 * 1e-6 > MAX_GAP_S
            {
                bail!(
                    "log line {}: time {} s is {} s after the line before, more than {MAX_GAP_S} s: a damaged time",
                    i + 1,
                    t as f64 * 1e-6,
                    (t - prev) as f64 * 1e-6
                );
            }
            last_us = Some(last_us.map_or(t, |p| p.max(t)));
            events.push(ev);
        }
    }
    Ok((init, events))
}

fn opt(v: Option<f32>) -> String {
    v.map(|s| format!(",{s}")).unwrap_or_default()
}

/// Write events as a CSV log (the inverse of [`parse_log`]).
pub fn write_log(init: Option<LogInit>, events: &[Event]) -> String {
    let mut s = String::from("# subnav sensor log: t_s,kind,values (see `subnav filter replay --help`)\n");
    let ts = |t: u64| t as f64 * 1e-6;
    if let Some(i) = init {
        let v = i.vel_ned_mps;
        let _ = writeln!(
            s,
            "{},init,{},{},{},{},{},{},{}",
            ts(i.t_us),
            i.pos_ned_m[0],
            i.pos_ned_m[1],
            i.pos_ned_m[2],
            i.yaw_rad,
            v[0],
            v[1],
            v[2]
        );
    }
    for ev in events {
        let _ = match *ev {
            Event::Imu(m) => writeln!(
                s,
                "{},imu,{},{},{},{},{},{}",
                ts(m.t_us),
                m.gyro_radps[0],
                m.gyro_radps[1],
                m.gyro_radps[2],
                m.accel_mps2[0],
                m.accel_mps2[1],
                m.accel_mps2[2]
            ),
            Event::Heading { t_us, heading_rad, sigma_rad } => writeln!(s, "{},heading,{}{}", ts(t_us), heading_rad, opt(sigma_rad)),
            Event::Depth { t_us, depth_m, sigma_m } => writeln!(s, "{},depth,{}{}", ts(t_us), depth_m, opt(sigma_m)),
            Event::Dvl { t_us, vel_frd_mps: v, sigma_mps } => writeln!(s, "{},dvl,{},{},{}{}", ts(t_us), v[0], v[1], v[2], opt(sigma_mps)),
            Event::Fix { t_us, pos_ned_m: p, cov_ned_m2: c } => {
                writeln!(s, "{},fix,{},{},{},{},{},{},{},{},{}", ts(t_us), p[0], p[1], p[2], c[0], c[1], c[2], c[3], c[4], c[5])
            }
        };
    }
    s
}

/// One output row.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct EstimateRow {
    pub t_s: f64,
    pub mode: &'static str,
    pub pos_ned_m: [f32; 3],
    pub vel_ned_mps: [f32; 3],
    pub roll_pitch_yaw_rad: [f32; 3],
    pub sigma_pos_m: [f32; 3],
    pub sigma_att_rad: [f32; 3],
    pub nis: [f32; 4],
    pub lambda: f32,
    pub r_diag: [f32; 4],
}

/// Result of a replay.
#[derive(Debug, Clone, Serialize)]
pub struct Replay {
    pub rows: Vec<EstimateRow>,
    pub counts: EventCounts,
    pub health: String,
}

/// Run a log through the filter; an estimate row every `out_every_s` of IMU time.
pub fn replay(cfg: NavConfig, init: Option<LogInit>, events: &[Event], out_every_s: f64) -> anyhow::Result<Replay> {
    let first_t = events.first().map(|e| e.t_us()).unwrap_or(0);
    let init = init.unwrap_or(LogInit { t_us: first_t, pos_ned_m: [0.0; 3], yaw_rad: 0.0, vel_ned_mps: [0.0; 3] });
    let mut nav = start(cfg, init.t_us, init.pos_ned_m, init.vel_ned_mps, init.yaw_rad)?;
    let mut counts = EventCounts::default();
    let mut rows = Vec::new();
    let step_us = (out_every_s.max(1e-6) * 1e6) as u64;
    let mut next_out = first_t;
    for ev in events {
        apply(&mut nav, ev, &mut counts);
        if let Event::Imu(s) = ev {
            if s.t_us >= next_out {
                next_out = s.t_us + step_us;
                let sol = nav.solution();
                let q = nav.nominal().att_nb;
                let (r, p, y) = q.euler_angles();
                rows.push(EstimateRow {
                    t_s: s.t_us as f64 * 1e-6,
                    mode: match sol.mode {
                        NavMode::Uninitialised => "uninitialised",
                        NavMode::Aligning => "aligning",
                        NavMode::Inertial => "inertial",
                        NavMode::Aided => "aided",
                    },
                    pos_ned_m: sol.pos_ned_m,
                    vel_ned_mps: sol.vel_ned_mps,
                    roll_pitch_yaw_rad: [r, p, y],
                    sigma_pos_m: sol.sigma_pos_m,
                    sigma_att_rad: sol.sigma_att_rad,
                    nis: nav.nis(),
                    lambda: nav.lambda(),
                    r_diag: nav.r_diag(),
                });
            }
        }
    }
    Ok(Replay { rows, counts, health: format!("{:?}", nav.health()) })
}

/// Rows as CSV.
pub fn rows_csv(rows: &[EstimateRow]) -> String {
    let mut s = String::from(
        "t_s,mode,n_m,e_m,d_m,vn_mps,ve_mps,vd_mps,roll_rad,pitch_rad,yaw_rad,sn_m,se_m,sd_m,sroll_rad,spitch_rad,syaw_rad,nis_heading,nis_depth,nis_vel,nis_pos,lambda,r_heading,r_depth,r_vel,r_pos\n",
    );
    for r in rows {
        let mut line = format!("{},{}", r.t_s, r.mode);
        for v in r
            .pos_ned_m
            .iter()
            .chain(&r.vel_ned_mps)
            .chain(&r.roll_pitch_yaw_rad)
            .chain(&r.sigma_pos_m)
            .chain(&r.sigma_att_rad)
            .chain(&r.nis)
        {
            let _ = write!(line, ",{v}");
        }
        let _ = write!(line, ",{}", r.lambda);
        for v in &r.r_diag {
            let _ = write!(line, ",{v}");
        }
        s.push_str(&line);
        s.push('\n');
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::sim::{DiveConfig, generate};

    #[test]
    fn log_round_trips_and_replays() {
        let cfg = DiveConfig { duration_s: 20.0, ..DiveConfig::default() };
        let dive = generate(&cfg, 7);
        let t0 = dive.truth[0];
        let init = LogInit {
            t_us: 0,
            pos_ned_m: [0.0, 0.0, 10.0],
            yaw_rad: dive.init_yaw_rad as f32,
            vel_ned_mps: t0.vel_ned_mps.map(|v| v as f32),
        };
        let text = write_log(Some(init), &dive.events);
        let (init2, events2) = parse_log(&text).unwrap();
        assert_eq!(init2, Some(init));
        assert_eq!(events2.len(), dive.events.len());
        let r = replay(NavConfig::default(), init2, &events2, 1.0).unwrap();
        assert_eq!(r.rows.len(), 21);
        assert!(r.counts.updates_accepted > 100, "{:?}", r.counts);
        let last = r.rows.last().unwrap();
        let t = dive.truth.last().unwrap();
        let err = ((last.pos_ned_m[0] as f64 - t.pos_ned_m[0]).powi(2) + (last.pos_ned_m[1] as f64 - t.pos_ned_m[1]).powi(2)).sqrt();
        assert!(err < 3.0, "position error after 20 s: {err} m");
    }

    /// One `1e300` time in a log saturated the microsecond clock and froze the position (exit
    /// 0): times are bounded and a jump of more than a day is a damaged line.
    #[test]
    fn a_damaged_time_is_an_error_not_a_frozen_clock() {
        let imu = |t: &str| format!("{t},imu,0,0,0,0,0,-9.81\n");
        let good = imu("0") + &imu("0.01");
        assert_eq!(parse_log(&good).unwrap().1.len(), 2);
        for (bad, needle) in
            [(imu("0") + &imu("1e300"), "0..=1e10"), (imu("0") + &imu("inf"), "0..=1e10"), (imu("0") + &imu("1e9"), "more than 86400")]
        {
            let e = format!("{:#}", parse_log(&bad).unwrap_err());
            assert!(e.contains("line 2") && e.contains(needle), "{e}");
        }
        let e = format!("{:#}", parse_log(&(imu("5") + "1e7,depth,10\n")).unwrap_err());
        assert!(e.contains("line 2") && e.contains("damaged time"), "{e}");
    }

    #[test]
    fn malformed_lines_are_errors_with_line_numbers() {
        let e = parse_log("0,imu,1,2,3\n").unwrap_err();
        assert!(format!("{e:#}").contains("line 1"), "{e:#}");
        let e = parse_log("# c\n0,bogus,1\n").unwrap_err();
        assert!(format!("{e:#}").contains("line 2"), "{e:#}");
        // NaN values parse, and the filter rejects them.
        let (_, ev) = parse_log("0,imu,0,0,0,0,0,-9.81\n0.01,imu,NaN,0,0,0,0,-9.81\n").unwrap();
        let r = replay(NavConfig::default(), None, &ev, 1.0).unwrap();
        assert_eq!(r.counts.rejected_nonfinite, 1);
    }
}
