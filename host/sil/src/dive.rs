//! A simulated dive with the firmware in the loop: boot the QEMU firmware with the scenario's
//! configured start (UTC, origin), answer its bus transactions with [`SimHead`], collect its
//! telemetry and compare the navigation solution with the truth trajectory.

use std::path::Path;
use std::time::Duration;

use anyhow::Result;
use serde::Serialize;
use subnav_base::wrap_deg;
use subnav_link::record::session::TruthRow;
use subnav_link::score::{self, Score, Scorer, Truth};
use subnav_wire::{NavMode, Uplink};

use super::head::{Scenario, SimHead};
use subnav_link::LinkEvent;
use subnav_link::qemu::{QemuConfig, QemuEvent, RawBytes, run_with_bus};
use subnav_link::record::tap::QemuRecorder;

/// Error statistics of one dive.
#[derive(Debug, Clone, Serialize)]
pub struct DiveResult {
    pub exit_code: Option<i32>,
    pub nav_messages: usize,
    /// The navigation figures (the one scoring, `subnav_link::score`: the aided epochs, the
    /// heading over those whose yaw 1-sigma is at most [`HEADING_CONVERGED_SIGMA_DEG`]: after an
    /// alignment without a compass fix the filter itself says it has no heading, 86 deg).
    #[serde(flatten)]
    pub score: Score,
    /// Horizontal distance the truth travelled from boot to the last aided sample, m.
    pub distance_m: f64,
    /// `horizontal_final_err_m` as a percentage of `distance_m`.
    pub final_err_pct_of_distance: f64,
    /// Non-finite values seen in any navigation message.
    pub nonfinite_values: usize,
    pub compass_fixes: usize,
    pub compass_no_fix: usize,
    /// The sensors alone: compass heading fixes and raw depth samples against the truth.
    pub compass_rmse_deg: f64,
    pub raw_depth_rmse_m: f64,
    /// (source, kind, latest count) of every fault reported.
    pub faults: Vec<(String, String, u32)>,
    pub corrupt_frames: u64,
    pub bus_transactions: u64,
    /// The map in the loop (scenarios with a camera).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub map: Option<crate::map_loop::MapLoopReport>,
    /// Longest stretch without a navigation message the host received, s (a host outage shows
    /// here; 1 / nav rate otherwise).
    pub longest_nav_gap_s: f64,
    /// Each fault class the scenario injects: whether the head (or the map) reported it, and how
    /// long the estimate took to be consistent again after it (see [`fault_classes`]).
    pub fault_classes: Vec<FaultClassReport>,
    /// The head's re-acquisitions (its latest `Health`): heading and position resets.
    pub heading_resets: u32,
    pub position_resets: u32,
    /// The recordings the host wrote (more than one when it was restarted mid-dive).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub recordings: Vec<RecordingSpan>,
    /// The aided samples, for the map's classes' recovery times.
    #[serde(skip)]
    consistency: Vec<Sample>,
}

/// One injected fault class in a dive's score.
#[derive(Debug, Clone, Serialize)]
pub struct FaultClassReport {
    pub class: &'static str,
    /// Its window, s (None: throughout the dive, or from `start` to the end).
    pub window_s: Option<(f64, f64)>,
    /// What shows it was noticed (the fault messages, compass reports, map counters...).
    pub evidence: String,
    pub reported: bool,
    /// After the window: seconds until the horizontal position and the heading are within 3
    /// reported sigma for 10 s in a row (0: they never left); None for classes without an end
    /// or if that never happened before the dive ended.
    pub recovery_s: Option<f64>,
    /// After the window: seconds until the reported horizontal position and heading sigmas are
    /// back within 10 % of their values just before the fault (0: they never grew that much).
    pub sigma_recovery_s: Option<f64>,
}

/// One recording of a dive, as a later reader finds it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RecordingSpan {
    pub path: std::path::PathBuf,
    /// Head time of its first and last message, s.
    pub first_head_s: f64,
    pub last_head_s: f64,
    /// It starts without the head's Boot: its host joined a running head.
    pub joined_running_head: bool,
    /// The head time between the previous recording's end and this one's start, s (when it
    /// continues the same boot).
    pub gap_before_s: Option<f64>,
}

impl RecordingSpan {
    /// Read each recording's uplink for its span and the gaps between them.
    /// A recording written into a device or a FIFO (`--record /dev/null`) cannot be read back
    /// and has no span.
    pub fn of(paths: &[std::path::PathBuf]) -> Result<Vec<RecordingSpan>> {
        let paths: Vec<std::path::PathBuf> = paths.iter().filter(|p| !subnav_link::output::is_special(p)).cloned().collect();
        let stats = paths.iter().map(|p| subnav_link::record::uplink_stats(p)).collect::<Result<Vec<_>>>()?;
        Ok(paths
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let s = &stats[k];
                let gap = k.checked_sub(1).and_then(|j| stats[j].gap_to(s));
                RecordingSpan {
                    path: p.clone(),
                    first_head_s: s.first_head_us.map_or(f64::NAN, |t| t as f64 * 1e-6),
                    last_head_s: s.last_head_us.map_or(f64::NAN, |t| t as f64 * 1e-6),
                    joined_running_head: s.joined_running_head,
                    gap_before_s: gap.map(|(a, b)| (b - a) as f64 * 1e-6),
                }
            })
            .collect())
    }
}

impl DiveResult {
    /// Attach the recordings the host wrote; a restarted host's shows in its fault class.
    pub fn with_recordings(mut self, paths: &[std::path::PathBuf]) -> Result<Self> {
        self.recordings = RecordingSpan::of(paths)?;
        if let (Some(c), Some(r)) =
            (self.fault_classes.iter_mut().find(|c| c.class == HOST_RESTARTED), self.recordings.iter().find(|r| r.gap_before_s.is_some()))
        {
            c.evidence.push_str(&format!(
                "; the restarted host's recording {} joined the running head at {:.1} s, {:.1} s after the one before ends",
                r.path.file_name().map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
                r.first_head_s,
                r.gap_before_s.unwrap_or(f64::NAN)
            ));
        }
        Ok(self)
    }

    /// Attach the map's report, and score the camera's fault classes from its counters.
    pub fn with_map(mut self, map: Option<crate::map_loop::MapLoopReport>, sc: &Scenario) -> Self {
        if let (Some(m), Some(c)) = (&map, &sc.camera) {
            let s = &m.mapper;
            let samples = std::mem::take(&mut self.consistency);
            let classes = &mut self.fault_classes;
            let mut push = |class: &'static str, window_s: Option<(f64, f64)>, n: u64, what: &str| {
                let recovery_s = window_s.and_then(|(_, b)| recovery_after(&samples, b));
                let sigma_recovery_s = window_s.and_then(|w| sigma_recovery(&samples, w));
                classes.push(FaultClassReport {
                    class,
                    window_s,
                    evidence: format!("{n} {what}"),
                    reported: n > 0,
                    recovery_s,
                    sigma_recovery_s,
                });
            };
            if let Some(w) = c.blackout_s {
                push("camera blackout", Some(w), s.frames_without_features, "frames without features (the descent's included)");
            }
            if c.far_image_probability > 0.0 {
                push("false recognitions far away", None, s.gate_refusals, "appearance matches refused by the position gate");
            }
            if c.drop_probability > 0.0 {
                push("camera frames dropped", None, s.frames_missing, "frames missing");
            }
            if c.duplicate_probability > 0.0 {
                push("camera frames duplicated", None, s.frames_duplicated, "frames duplicated");
            }
            if c.reorder_probability > 0.0 {
                push("camera frames out of order", None, s.frames_out_of_order, "frames out of order");
            }
        }
        self.map = map;
        self
    }
}

/// Yaw 1-sigma (deg) at or below which the heading counts as converged in [`DiveResult`].
pub use subnav_link::score::HEADING_CONVERGED_SIGMA_DEG;

/// The scenario's truth at the time of validity of `n`, for [`score`].
pub fn truth_at(traj: &subnav_base::trajectory::Trajectory, n: &subnav_wire::NavSolution) -> Truth {
    let tr = traj.at(n.t_us as f64 * 1e-6);
    Truth { pos_ned_m: [tr.pos_ned_m.x, tr.pos_ned_m.y, tr.pos_ned_m.z], yaw_rad: tr.yaw_rad }
}

/// Whether [`evaluate`] reads this message (runs that are not recorded keep only these).
pub fn scored(m: &Uplink) -> bool {
    matches!(m, Uplink::Nav(_) | Uplink::Raw(subnav_wire::RawSample::Depth(_)) | Uplink::Compass(_) | Uplink::Fault(_) | Uplink::Health(_))
}

/// What the host process sees of the head's telemetry: nothing while it is down
/// ([`crate::FaultPlan::host_outage_s`]; the bytes the head sends then are lost). A message
/// without a time (an `Ack`) counts at the time of the one before it.
pub struct HostView {
    faults: crate::FaultPlan,
    last_t_us: u64,
}

impl HostView {
    pub fn new(sc: &Scenario) -> Self {
        Self { faults: sc.faults, last_t_us: 0 }
    }
    /// Whether the host is down at `t_us`.
    pub fn down_at(&self, t_us: u64) -> bool {
        self.faults.host_down(t_us as f64 * 1e-6)
    }
    /// Whether the host receives `m`.
    pub fn receives(&mut self, m: &Uplink) -> bool {
        if let Some(t) = m.t_us() {
            self.last_t_us = t;
        }
        !self.faults.host_down(self.last_t_us as f64 * 1e-6)
    }
}

/// What a live display shows during a run (from the latest navigation solution).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiveStatus {
    pub t_s: f64,
    pub mode: NavMode,
    pub sigma_heading_deg: f64,
    /// Horizontal position 1-sigma (root of the N and E variances' sum), m.
    pub sigma_horizontal_m: f64,
    /// Map fixes sent and accepted by the head, and the map's nodes (0 without a camera).
    pub fixes_sent: u64,
    pub fixes_accepted: u64,
    pub map_nodes: usize,
}

impl LiveStatus {
    pub fn new(n: &subnav_wire::NavSolution, map: Option<&crate::map_loop::MapLoop>) -> Self {
        let (fixes_sent, fixes_accepted, map_nodes) = map.map_or((0, 0, 0), |m| m.counts());
        let [sn, se, _] = n.sigma_pos_m.map(f64::from);
        LiveStatus {
            t_s: n.t_us as f64 * 1e-6,
            mode: n.mode,
            sigma_heading_deg: f64::from(n.sigma_att_rad[2]).to_degrees(),
            sigma_horizontal_m: (sn * sn + se * se).sqrt(),
            fixes_sent,
            fixes_accepted,
            map_nodes,
        }
    }
}

/// The fault class of a host process killed and started again mid-dive.
pub const HOST_RESTARTED: &str = "host killed and restarted";

/// How [`run_qemu`] runs (the QEMU side of [`crate::run::HeadRun`]).
pub(crate) struct QemuRun<'a> {
    pub record: Option<&'a Path>,
    pub timeout: Duration,
    pub progress: Option<&'a dyn Fn(&LiveStatus)>,
    pub observer: Option<crate::run::Observer<'a>>,
    pub keep_all: bool,
    pub board_args: Vec<String>,
    pub run_ms: Option<u64>,
    pub hook: Option<crate::run::QemuHook<'a>>,
}

/// Run `sc` with the QEMU firmware `elf`, on `head` or the scenario's own head (with its map in
/// the loop and the recording's downlink tap).
pub(crate) fn run_qemu(elf: &Path, sc: &Scenario, head: Option<SimHead>, mut opts: QemuRun) -> Result<crate::run::RunOutput> {
    let mut cfg = QemuConfig::new(elf);
    cfg.run_ms = Some(opts.run_ms.unwrap_or((sc.duration_s * 1000.0).round() as u64));
    cfg.timeout = opts.timeout;
    cfg.board_args = sc.board_args();
    cfg.board_args.extend(opts.board_args.iter().cloned());
    let outage_head_us = sc.faults.host_outage_s.map(|(a, b)| ((a * 1e6) as u64, (b * 1e6) as u64));
    let recorder = opts.record.map(|p| QemuRecorder::start_with_host_outage(&mut cfg, p, outage_head_us)).transpose()?;
    let mut msgs = Vec::new();
    let (head, map) = match head {
        Some(h) => (h, None),
        None => {
            // Fixes reach the firmware through the bridge's modem (UART 1) at their arrival time;
            // the recording gets each delivered frame in its downlink stream.
            let tap = cfg.raw_tap.clone().map(|tx| {
                let tx = std::sync::Mutex::new(tx);
                Box::new(move |_t: u64, f: &[u8]| {
                    if let Ok(tx) = tx.lock() {
                        let _ = tx.send(RawBytes::Downlink(f.to_vec()));
                    }
                }) as crate::chips::modem::DeliveryTap
            });
            let map = sc.map_loop();
            (SimHead::build(sc, tap, map.clone()), map)
        }
    };
    let mut host = HostView::new(sc);
    let mut last_t_us = 0u64;
    let result = run_with_bus(&cfg, Box::new(head), |e, down| {
        if let Some(hook) = opts.hook.as_mut() {
            hook(&e, down);
        }
        if let QemuEvent::Link(LinkEvent::Message(m)) = e {
            last_t_us = m.t_us().unwrap_or(last_t_us);
            if !host.receives(&m) {
                return;
            }
            if let Some(map) = &map {
                map.on_uplink(&m);
            }
            if let Some(obs) = opts.observer {
                obs(last_t_us, &m, map.as_ref());
            }
            if !opts.keep_all && !scored(&m) {
                return;
            }
            if let (Uplink::Nav(n), Some(p)) = (&m, opts.progress) {
                p(&LiveStatus::new(n, map.as_ref()));
            }
            msgs.push(m);
        }
    });
    cfg.raw_tap = None;
    // The runner hands the chip models back; their modem holds a clone of the recording's tap,
    // which must be gone before the recording can finish.
    let result = result.map(|(outcome, _head)| outcome);
    let recordings = recorder.map(QemuRecorder::finish).transpose()?.unwrap_or_default();
    if let Some(m) = &map {
        m.close();
    }
    let outcome = result?;
    if outcome.timed_out {
        anyhow::bail!("the dive did not finish within {} s of wall time; QEMU was stopped", cfg.timeout.as_secs());
    }
    Ok(crate::run::RunOutput {
        messages: msgs,
        frames: Vec::new(),
        downlink: Vec::new(),
        exit_code: outcome.exit_code,
        corrupt_frames: outcome.link.frames_bad,
        bus_transactions: outcome.bus_transactions,
        map: map.map(|m| m.report()),
        recordings,
    })
}

/// The truth of a dive every `step_s` (yaw wrapped to (-pi, pi]): what `subnav run` writes
/// as CSV (`subnav_link::record::session::truth_csv`) and gives its report.
pub fn truth_rows(sc: &Scenario, step_s: f64) -> Vec<TruthRow> {
    let traj = sc.trajectory();
    let n = (sc.duration_s / step_s).floor() as u64;
    (0..=n)
        .map(|k| {
            let t = k as f64 * step_s;
            let tr = traj.at(t);
            TruthRow { t_s: t, pos_ned_m: [tr.pos_ned_m.x, tr.pos_ned_m.y, tr.pos_ned_m.z], yaw_rad: subnav_base::wrap_pi(tr.yaw_rad) }
        })
        .collect()
}

/// Error statistics of a dive's telemetry `msgs` against the scenario's truth.
pub(crate) fn evaluate(sc: &Scenario, msgs: &[Uplink], exit_code: Option<i32>, corrupt_frames: u64, bus_transactions: u64) -> DiveResult {
    let traj = sc.trajectory();
    let mut r = DiveResult {
        exit_code,
        nav_messages: 0,
        score: Scorer::new().score(),
        distance_m: 0.0,
        final_err_pct_of_distance: f64::NAN,
        nonfinite_values: 0,
        compass_fixes: 0,
        compass_no_fix: 0,
        compass_rmse_deg: f64::NAN,
        raw_depth_rmse_m: f64::NAN,
        faults: Vec::new(),
        corrupt_frames,
        bus_transactions,
        map: None,
        longest_nav_gap_s: 0.0,
        fault_classes: Vec::new(),
        heading_resets: 0,
        position_resets: 0,
        recordings: Vec::new(),
        consistency: Vec::new(),
    };
    let mut last_nav_s: Option<f64> = None;
    let mut scorer = Scorer::new();
    let (mut sc2, mut sr, mut nr) = (0.0, 0.0, 0usize);
    for m in msgs {
        match m {
            Uplink::Nav(n) => {
                r.nav_messages += 1;
                let t = n.t_us as f64 * 1e-6;
                if let Some(t0) = last_nav_s {
                    r.longest_nav_gap_s = r.longest_nav_gap_s.max(t - t0);
                }
                last_nav_s = Some(t);
                let values = n.pos_ned_m.iter().chain(&n.vel_ned_mps).chain(&n.att_nb_wxyz);
                r.nonfinite_values += values.filter(|v| !v.is_finite()).count();
                scorer.add(n, &truth_at(&traj, n));
            }
            Uplink::Raw(subnav_wire::RawSample::Depth(d)) => {
                let e = d.depth_m as f64 - traj.at(d.t_us as f64 * 1e-6).pos_ned_m.z;
                sr += e * e;
                nr += 1;
            }
            Uplink::Compass(c) => {
                if let Some(h) = c.heading_rad {
                    let e = wrap_deg((h as f64).to_degrees() - traj.at(c.t_us as f64 * 1e-6).yaw_rad.to_degrees());
                    sc2 += e * e;
                    r.compass_fixes += 1;
                } else {
                    r.compass_no_fix += 1;
                }
            }
            Uplink::Fault(f) => {
                let (s, k) = (format!("{:?}", f.source), format!("{:?}", f.kind));
                match r.faults.iter_mut().find(|e| e.0 == s && e.1 == k) {
                    Some(e) => e.2 = e.2.max(f.count),
                    None => r.faults.push((s, k, f.count)),
                }
            }
            _ => {}
        }
    }
    if r.compass_fixes > 0 {
        r.compass_rmse_deg = (sc2 / r.compass_fixes as f64).sqrt();
    }
    if nr > 0 {
        r.raw_depth_rmse_m = (sr / nr as f64).sqrt();
    }
    r.score = scorer.score();
    let last_aided_s = r.score.last_aided_s.unwrap_or(0.0);
    // Distance: the truth's horizontal speed integrated at 0.1 s.
    let steps = (last_aided_s / 0.1).floor() as u64;
    r.distance_m = (0..steps).map(|k| traj.at(k as f64 * 0.1 + 0.05).vel_ned_mps.xy().norm() * 0.1).sum();
    if r.distance_m > 0.0 {
        r.final_err_pct_of_distance = 100.0 * r.score.horizontal_final_err_m / r.distance_m;
    }
    r.fault_classes = fault_classes(sc, msgs, r.longest_nav_gap_s);
    if let Some(h) = msgs.iter().rev().find_map(|m| if let Uplink::Health(h) = m { Some(h) } else { None }) {
        (r.heading_resets, r.position_resets) = (h.heading_resets, h.position_resets);
    }
    r.consistency = consistency(sc, msgs);
    r
}

/// An aided sample: time, whether the horizontal position (per axis) and the heading (once
/// converged) are within 3 reported sigma, and the reported horizontal and heading sigmas.
#[derive(Debug, Clone, Copy)]
struct Sample {
    t: f64,
    ok: bool,
    sigma_h_m: f64,
    sigma_yaw_deg: f64,
}

fn consistency(sc: &Scenario, msgs: &[Uplink]) -> Vec<Sample> {
    let traj = sc.trajectory();
    msgs.iter()
        .filter_map(|m| if let Uplink::Nav(n) = m { Some(n) } else { None })
        .filter(|n| n.mode == NavMode::Aided)
        .map(|n| {
            let e = score::epoch(n, &truth_at(&traj, n));
            let heading_ok = !e.heading_converged || e.heading_within_3_sigma;
            Sample {
                t: e.t_s,
                ok: e.horizontal_within_3_sigma && heading_ok,
                sigma_h_m: e.sigma_horizontal_m,
                sigma_yaw_deg: e.sigma_heading_deg,
            }
        })
        .collect()
}

/// Seconds from `end_s` until both sigmas are within 10 % of their values at `start_s`.
fn sigma_recovery(samples: &[Sample], (start_s, end_s): (f64, f64)) -> Option<f64> {
    let before = samples.iter().rev().find(|s| s.t < start_s)?;
    samples
        .iter()
        .filter(|s| s.t >= end_s)
        .find(|s| s.sigma_h_m <= 1.1 * before.sigma_h_m && s.sigma_yaw_deg <= 1.1 * before.sigma_yaw_deg)
        .map(|s| s.t - end_s)
}

/// Seconds from `end_s` until the estimate is consistent for 10 s in a row.
fn recovery_after(samples: &[Sample], end_s: f64) -> Option<f64> {
    const HOLD_S: f64 = 10.0;
    let mut start: Option<f64> = None;
    for &Sample { t, ok, .. } in samples.iter().filter(|s| s.t >= end_s) {
        match (ok, start) {
            (true, None) => start = Some(t),
            (true, Some(t0)) if t - t0 >= HOLD_S => return Some(t0 - end_s),
            (false, _) => start = None,
            _ => {}
        }
    }
    None
}

/// Every fault class `sc` injects, with the evidence in the telemetry the host received that it
/// was noticed: the head's fault messages (in the fault's window, a second of rate limit
/// allowed), compass reports without a heading while the sun is lost, gate rejects in the head's
/// health after multipath fixes, a gap in the navigation stream while the host is down (and
/// messages after it: the head kept streaming), and the map's counters for camera faults.
pub fn fault_classes(sc: &Scenario, msgs: &[Uplink], longest_nav_gap_s: f64) -> Vec<FaultClassReport> {
    let samples = consistency(sc, msgs);
    let faults: Vec<&subnav_wire::Fault> = msgs.iter().filter_map(|m| if let Uplink::Fault(f) = m { Some(f) } else { None }).collect();
    let fault_in = |src: &str, kind: &str, w: Option<(f64, f64)>| {
        faults
            .iter()
            .filter(|f| format!("{:?}", f.source).starts_with(src) && format!("{:?}", f.kind) == kind)
            .filter(|f| w.is_none_or(|(a, b)| (a..=b + 1.5).contains(&(f.t_us as f64 * 1e-6))))
            .count()
    };
    let mut out = Vec::new();
    let mut push = |class: &'static str, window_s: Option<(f64, f64)>, n: usize, what: String, recovers: bool| {
        let recovery_s = if recovers { window_s.and_then(|(_, b)| recovery_after(&samples, b)) } else { None };
        let sigma_recovery_s = if recovers { window_s.and_then(|w| sigma_recovery(&samples, w)) } else { None };
        out.push(FaultClassReport { class, window_s, evidence: format!("{n} {what}"), reported: n > 0, recovery_s, sigma_recovery_s });
    };
    let f = &sc.faults;
    if let Some(w) = f.imu_nack_s {
        push("imu bus NACKs", Some(w), fault_in("Imu", "BusNack", Some(w)), "Imu BusNack reports".into(), true);
    }
    if let Some(w) = f.imu_timeout_s {
        push("imu bus timeouts", Some(w), fault_in("Imu", "BusTimeout", Some(w)), "Imu BusTimeout reports".into(), true);
    }
    if let Some((t, axis)) = f.imu_stuck_axis {
        let w = Some((t, sc.duration_s));
        push("imu stuck axis", w, fault_in("Imu", "Stuck", w), format!("Imu Stuck reports (axis {axis})"), false);
    }
    if f.imu_spike_probability > 0.0 {
        push("imu NaN / out-of-range samples", None, fault_in("Imu", "Saturated", None), "Imu Saturated reports".into(), false);
    }
    if let Some((a, b, u)) = f.occluded_unit {
        let src = format!("Polarization {{ unit: {u} }}");
        push("polarization unit occluded", Some((a, b)), fault_in(&src, "Occluded", Some((a, b))), format!("{src} Occluded reports"), true);
    }
    if let Some((a, b)) = f.sun_lost_s {
        let (none, all) = msgs
            .iter()
            .filter_map(|m| if let Uplink::Compass(c) = m { Some(c) } else { None })
            .filter(|c| (a + 1.0..b).contains(&(c.t_us as f64 * 1e-6)))
            .fold((0, 0), |(n, k), c| (n + usize::from(c.heading_rad.is_none()), k + 1));
        let n = if all > 0 && none == all { none } else { 0 };
        push("sun lost under cloud", Some((a, b)), n, format!("of {all} compass reports in the window without a heading"), true);
    }
    if f.depth_nack_probability > 0.0 {
        push("depth bus NACKs", None, fault_in("Depth", "BusNack", None), "Depth BusNack reports".into(), false);
    }
    if let Some(w) = f.host_outage_s {
        let after = msgs.iter().any(|m| matches!(m, Uplink::Nav(n) if n.t_us as f64 * 1e-6 >= w.1));
        let n = usize::from(after && longest_nav_gap_s >= w.1 - w.0 - 1.0);
        push(
            HOST_RESTARTED,
            Some(w),
            n,
            format!("gap in the received navigation of {longest_nav_gap_s:.1} s (streaming resumed: {after})"),
            true,
        );
    }
    if let Some(d) = &sc.dvl {
        if let Some(w) = d.lock_lost_s {
            push("dvl bottom lock lost", Some(w), fault_in("Dvl", "Invalid", Some(w)), "Dvl Invalid reports".into(), true);
        }
        if let Some(w) = d.silent_s {
            push("dvl silent", Some(w), 1, "(a silent DVL is not a fault the head can see; scored for recovery)".into(), true);
        }
        if d.bad_checksum_probability > 0.0 || d.truncate_probability > 0.0 {
            let n = fault_in("Dvl", "BadCrc", None) + fault_in("Dvl", "Malformed", None);
            push("dvl malformed data", None, n, "Dvl BadCrc + Malformed reports".into(), false);
        }
    }
    if let Some(p) = &sc.position_fixes {
        if p.multipath_probability > 0.0 {
            let outliers: Vec<f64> = sc.fixes().iter().filter(|x| x.outlier).map(|x| x.arrival_s).collect();
            let health: Vec<(f64, u32)> = msgs
                .iter()
                .filter_map(|m| if let Uplink::Health(h) = m { Some((h.t_us as f64 * 1e-6, h.gate_rejects)) } else { None })
                .collect();
            let rejects_at = |t: f64| health.iter().rev().find(|(th, _)| *th <= t).map_or(0, |(_, g)| *g);
            let seen = outliers.iter().filter(|&&t| rejects_at(t + 1.5) > rejects_at(t - 0.01)).count();
            push("usbl multipath fixes", None, seen, format!("of {} outlier fixes followed by a gate reject", outliers.len()), false);
        }
    }
    out
}
