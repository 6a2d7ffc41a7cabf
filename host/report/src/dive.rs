//! A simulated dive as a recording: the host's dive simulator (`filter::sim`, a lawnmower with
//! heading/DVL noise bursts) through the shared navigation filter (the firmware's code), written
//! as the sensor head would send it: `Boot`, `Nav` at 10 Hz, `Health` at 1 Hz, and a `Fault`
//! (Filter/NonFinite) whenever the filter rejects a non-finite sample, plus the simulator's truth
//! in the truth stream. A few NaN depth samples are injected (`nan_depth_at_s`) so the report's
//! fault timeline and the filter's NaN handling show up.

use std::path::Path;

use anyhow::{Context, Result};
use subnav_core::nav::NavConfig;
use subnav_wire::{self as wire, Board, Fault, FaultKind, FaultSource, MAX_UPLINK_FRAME, Uplink, boot_message};

use subnav_link::record::{Meta, Stream, Writer};
use subnav_sil::filter::sim::{DiveConfig, Event, generate};
use subnav_sil::filter::{EventCounts, apply, start};

/// Options of the simulated dive.
#[derive(Debug, Clone)]
pub struct DiveOptions {
    pub seed: u64,
    pub duration_s: f64,
    pub adaptive: bool,
    /// Sensor-head times (s) of injected NaN depth samples.
    pub nan_depth_at_s: Vec<f64>,
}

impl Default for DiveOptions {
    fn default() -> Self {
        Self { seed: 1, duration_s: 300.0, adaptive: true, nan_depth_at_s: vec![60.0, 61.0, 200.0] }
    }
}

/// What was written.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct DiveSummary {
    pub nav: u64,
    pub health: u64,
    pub faults: u64,
    pub truth_rows: u64,
    pub counts: EventCounts,
}

/// Simulate the dive and write it as a recording at `path`.
pub fn write_recording(path: &Path, opt: &DiveOptions) -> Result<DiveSummary> {
    let cfg = DiveConfig { duration_s: opt.duration_s, ..DiveConfig::default() };
    let mut dive = generate(&cfg, opt.seed);
    for t in opt.nan_depth_at_s.iter().filter(|t| **t < opt.duration_s) {
        let t_us = (t * 1e6) as u64;
        let at = dive.events.partition_point(|e| e.t_us() <= t_us);
        dive.events.insert(at, Event::Depth { t_us, depth_m: f32::NAN, sigma_m: None });
    }
    let t0 = dive.truth.first().context("the simulated dive is empty")?;
    let nav_cfg = if opt.adaptive { NavConfig::default().adaptive() } else { NavConfig::default() };
    let mut nav = start(nav_cfg, t0.t_us, t0.pos_ned_m.map(|v| v as f32), t0.vel_ned_mps.map(|v| v as f32), dive.init_yaw_rad as f32)?;

    let mut meta =
        Meta::new(format!("simulated dive seed {} ({} s, {})", opt.seed, opt.duration_s, if opt.adaptive { "AUKF" } else { "UKF" }));
    // Host time: a fixed epoch plus sensor time, so the recording is reproducible.
    meta.start_unix_us = 1_700_000_000_000_000;
    let host = |t_us: u64| meta.start_unix_us + t_us;
    let mut w = Writer::create(path, &meta)?;
    let mut buf = [0u8; MAX_UPLINK_FRAME];
    let mut frame = |w: &mut Writer<std::fs::File>, m: &Uplink, t_us: u64| -> Result<()> {
        let f = wire::encode(m, &mut buf).map_err(|e| anyhow::anyhow!("encoding: {e}"))?;
        w.chunk(Stream::Uplink, host(t_us), f)
    };
    frame(
        &mut w,
        &Uplink::Boot(boot_message(
            Board::QemuMps2An386,
            [0, 1, 0],
            t0.t_us,
            subnav_wire::CalibrationInUse::NO_STORE,
            subnav_wire::ResetCause::PowerOn,
        )),
        t0.t_us,
    )?;
    let mut truth = String::from("t_s,n_m,e_m,d_m,yaw_rad\n");
    for t in &dive.truth {
        truth.push_str(&format!("{},{},{},{},{}\n", t.t_us as f64 * 1e-6, t.pos_ned_m[0], t.pos_ned_m[1], t.pos_ned_m[2], t.yaw_rad));
    }
    w.chunk(Stream::Truth, host(t0.t_us), truth.as_bytes())?;

    let mut counts = EventCounts::default();
    let (mut next_nav, mut next_health) = (t0.t_us, t0.t_us);
    let mut s = DiveSummary { nav: 0, health: 0, faults: 0, truth_rows: dive.truth.len() as u64, counts };
    for ev in &dive.events {
        let before = counts.rejected_nonfinite;
        apply(&mut nav, ev, &mut counts);
        let t = ev.t_us();
        if counts.rejected_nonfinite > before {
            let fault = Fault { t_us: t, source: FaultSource::Filter, kind: FaultKind::NonFinite, count: counts.rejected_nonfinite as u32 };
            frame(&mut w, &Uplink::Fault(fault), t)?;
            s.faults += 1;
        }
        if matches!(ev, Event::Imu(_)) && t >= next_nav {
            next_nav = t + 100_000;
            frame(&mut w, &Uplink::Nav(nav.solution()), t)?;
            s.nav += 1;
            if t >= next_health {
                next_health = t + 1_000_000;
                frame(&mut w, &Uplink::Health(nav.health()), t)?;
                s.health += 1;
            }
        }
    }
    w.flush()?;
    s.counts = counts;
    Ok(s)
}
