//! A simulated dive with the firmware in the loop: boot the QEMU firmware with the scenario's
//! configured start (UTC, origin), answer its bus transactions with [`SimHead`], collect its
//! telemetry and compare the navigation solution with the truth trajectory.

use std::path::Path;
use std::time::Duration;

use anyhow::Result;
use nalgebra::{Quaternion, UnitQuaternion};
use serde::Serialize;
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
    /// Nav messages in `Aided` mode (the statistics below are over these).
    pub aided_messages: usize,
    pub first_aided_s: Option<f64>,
    /// Heading statistics over the aided samples whose reported yaw 1-sigma is at most
    /// [`HEADING_CONVERGED_SIGMA_DEG`] (before that the filter itself says it has no heading:
    /// after an alignment without a compass fix its yaw sigma is 86 deg).
    pub heading_converged_s: Option<f64>,
    pub heading_rmse_deg: f64,
    pub heading_max_abs_err_deg: f64,
    /// Fraction of those samples whose heading error is within 3 reported sigma.
    pub heading_within_3_sigma: f64,
    /// Heading RMSE over every aided sample (including the unconverged start).
    pub heading_rmse_all_aided_deg: f64,
    pub horizontal_rms_err_m: f64,
    pub horizontal_final_err_m: f64,
    pub horizontal_max_err_m: f64,
    /// Horizontal distance the truth travelled from boot to the last aided sample, m.
    pub distance_m: f64,
    /// `horizontal_final_err_m` as a percentage of `distance_m`.
    pub final_err_pct_of_distance: f64,
    pub depth_rmse_m: f64,
    /// Fraction of aided samples whose horizontal error is within 3 sigma of the filter's own
    /// reported position uncertainty (per axis, north and east).
    pub within_3_sigma: f64,
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
}

/// Yaw 1-sigma (deg) below which the heading counts as converged in [`DiveResult`].
pub const HEADING_CONVERGED_SIGMA_DEG: f64 = 5.0;

fn wrap_deg(x: f64) -> f64 {
    (x + 180.0).rem_euclid(360.0) - 180.0
}

/// Whether [`evaluate`] reads this message (runs that are not recorded keep only these).
pub fn scored(m: &Uplink) -> bool {
    matches!(m, Uplink::Nav(_) | Uplink::Raw(subnav_wire::RawSample::Depth(_)) | Uplink::Compass(_) | Uplink::Fault(_))
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

/// How to run a dive.
#[derive(Default)]
pub struct DiveOptions<'a> {
    /// Write a lossless recording (uplink, defmt and downlink) of the run here.
    pub record: Option<&'a Path>,
    /// Wall-clock limit (QEMU); default 15 minutes.
    pub timeout: Option<Duration>,
    /// Called with every navigation message's status (progress display).
    pub progress: Option<&'a dyn Fn(&LiveStatus)>,
    /// Called with every uplink message as it is decoded, and the map in the loop (a live view:
    /// `subnav run --foxglove`). It only watches.
    pub observer: Option<&'a dyn Fn(&Uplink, Option<&crate::map_loop::MapLoop>)>,
}

/// Run `sc` with the QEMU firmware `elf`.
pub fn run_dive(elf: &Path, sc: &Scenario, opts: &DiveOptions) -> Result<DiveResult> {
    let mut cfg = QemuConfig::new(elf);
    cfg.run_ms = Some((sc.duration_s * 1000.0) as u64);
    cfg.timeout = opts.timeout.unwrap_or(Duration::from_secs(900));
    cfg.board_args = sc.board_args();
    let recorder = opts.record.map(|p| QemuRecorder::start(&mut cfg, p)).transpose()?;
    let mut msgs = Vec::new();
    // Fixes reach the firmware through the bridge's modem (UART 1) at their arrival time; the
    // recording gets each delivered frame in its downlink stream.
    let tap = cfg.raw_tap.clone().map(|tx| {
        let tx = std::sync::Mutex::new(tx);
        Box::new(move |_t: u64, f: &[u8]| {
            if let Ok(tx) = tx.lock() {
                let _ = tx.send(RawBytes::Downlink(f.to_vec()));
            }
        }) as crate::chips::modem::DeliveryTap
    });
    let map = sc.map_loop();
    let head = SimHead::build(sc, tap, map.clone());
    let result = run_with_bus(&cfg, Box::new(head), |e, _down| {
        if let QemuEvent::Link(LinkEvent::Message(m)) = e {
            if let Some(map) = &map {
                map.on_uplink(&m);
            }
            if let Some(obs) = opts.observer {
                obs(&m, map.as_ref());
            }
            if !scored(&m) {
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
    if let Some(r) = recorder {
        r.finish()?;
    }
    if let Some(m) = &map {
        m.close();
    }
    let outcome = result?;
    if outcome.timed_out {
        anyhow::bail!("the dive did not finish within {} s of wall time; QEMU was stopped", cfg.timeout.as_secs());
    }
    let mut r = evaluate(sc, &msgs, outcome.exit_code, outcome.link.frames_bad, outcome.bus_transactions);
    r.map = map.map(|m| m.report());
    Ok(r)
}

/// The truth of a dive as CSV (`t_s,n_m,e_m,d_m,yaw_rad`, the format `subnav report --truth`
/// reads), every `step_s`.
pub fn truth_csv(sc: &Scenario, step_s: f64) -> String {
    let traj = sc.trajectory();
    let mut out = String::from("t_s,n_m,e_m,d_m,yaw_rad\n");
    let n = (sc.duration_s / step_s).floor() as u64;
    for k in 0..=n {
        let t = k as f64 * step_s;
        let tr = traj.at(t);
        let yaw = subnav_base::wrap_pi(tr.yaw_rad);
        out.push_str(&format!("{t:.3},{:.4},{:.4},{:.4},{yaw:.6}\n", tr.pos_ned_m.x, tr.pos_ned_m.y, tr.pos_ned_m.z));
    }
    out
}

/// Error statistics of a dive's telemetry `msgs` against the scenario's truth.
pub fn evaluate(sc: &Scenario, msgs: &[Uplink], exit_code: Option<i32>, corrupt_frames: u64, bus_transactions: u64) -> DiveResult {
    let traj = sc.trajectory();
    let mut r = DiveResult {
        exit_code,
        nav_messages: 0,
        aided_messages: 0,
        first_aided_s: None,
        heading_converged_s: None,
        heading_rmse_deg: f64::NAN,
        heading_max_abs_err_deg: 0.0,
        heading_within_3_sigma: f64::NAN,
        heading_rmse_all_aided_deg: f64::NAN,
        horizontal_rms_err_m: f64::NAN,
        horizontal_final_err_m: f64::NAN,
        horizontal_max_err_m: 0.0,
        distance_m: 0.0,
        final_err_pct_of_distance: f64::NAN,
        depth_rmse_m: f64::NAN,
        within_3_sigma: f64::NAN,
        nonfinite_values: 0,
        compass_fixes: 0,
        compass_no_fix: 0,
        compass_rmse_deg: f64::NAN,
        raw_depth_rmse_m: f64::NAN,
        faults: Vec::new(),
        corrupt_frames,
        bus_transactions,
        map: None,
    };
    let (mut sh, mut sp, mut sd, mut inside) = (0.0, 0.0, 0.0, 0usize);
    let (mut sh_conv, mut n_conv, mut h_inside) = (0.0, 0usize, 0usize);
    let (mut sc2, mut sr, mut nr) = (0.0, 0.0, 0usize);
    let mut last_aided_s = 0.0f64;
    for m in msgs {
        match m {
            Uplink::Nav(n) => {
                r.nav_messages += 1;
                let values = n.pos_ned_m.iter().chain(&n.vel_ned_mps).chain(&n.att_nb_wxyz);
                r.nonfinite_values += values.filter(|v| !v.is_finite()).count();
                if n.mode != NavMode::Aided {
                    continue;
                }
                let t = n.t_us as f64 * 1e-6;
                r.first_aided_s.get_or_insert(t);
                let truth = traj.at(t);
                let [w, x, y, z] = n.att_nb_wxyz.map(f64::from);
                let q = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
                let yaw = q.euler_angles().2.to_degrees();
                let eh = wrap_deg(yaw - truth.yaw_rad.to_degrees());
                let (en, ee) = (n.pos_ned_m[0] as f64 - truth.pos_ned_m.x, n.pos_ned_m[1] as f64 - truth.pos_ned_m.y);
                let ed = n.pos_ned_m[2] as f64 - truth.pos_ned_m.z;
                r.aided_messages += 1;
                sh += eh * eh;
                sp += en * en + ee * ee;
                sd += ed * ed;
                let sigma_yaw_deg = (n.sigma_att_rad[2] as f64).to_degrees();
                if sigma_yaw_deg <= HEADING_CONVERGED_SIGMA_DEG {
                    r.heading_converged_s.get_or_insert(t);
                    sh_conv += eh * eh;
                    n_conv += 1;
                    r.heading_max_abs_err_deg = r.heading_max_abs_err_deg.max(eh.abs());
                    if eh.abs() <= 3.0 * sigma_yaw_deg {
                        h_inside += 1;
                    }
                }
                r.horizontal_final_err_m = (en * en + ee * ee).sqrt();
                r.horizontal_max_err_m = r.horizontal_max_err_m.max(r.horizontal_final_err_m);
                last_aided_s = t;
                if en.abs() <= 3.0 * n.sigma_pos_m[0] as f64 && ee.abs() <= 3.0 * n.sigma_pos_m[1] as f64 {
                    inside += 1;
                }
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
    if r.aided_messages > 0 {
        let n = r.aided_messages as f64;
        r.heading_rmse_all_aided_deg = (sh / n).sqrt();
        r.horizontal_rms_err_m = (sp / n).sqrt();
        r.depth_rmse_m = (sd / n).sqrt();
        r.within_3_sigma = inside as f64 / n;
    }
    // Distance: the truth's horizontal speed integrated at 0.1 s.
    let steps = (last_aided_s / 0.1).floor() as u64;
    r.distance_m = (0..steps).map(|k| traj.at(k as f64 * 0.1 + 0.05).vel_ned_mps.xy().norm() * 0.1).sum();
    if r.distance_m > 0.0 {
        r.final_err_pct_of_distance = 100.0 * r.horizontal_final_err_m / r.distance_m;
    }
    if n_conv > 0 {
        r.heading_rmse_deg = (sh_conv / n_conv as f64).sqrt();
        r.heading_within_3_sigma = h_inside as f64 / n_conv as f64;
    }
    r
}
