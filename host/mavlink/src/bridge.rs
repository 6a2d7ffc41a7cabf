//! The bridge: the head's telemetry in, MAVLink to the autopilot out, GPS and origin back.
//!
//! The caller hands every uplink message to [`Bridge::on_uplink`] as it arrives (from a live
//! link, a recording replayed at its pace, or a simulated head run in this process); a
//! navigation solution is converted and sent at once from the caller's thread (the latency from
//! validity to send is measured per message). A receiver thread reads the autopilot, answers
//! and sends `TIMESYNC`, sends `HEARTBEAT` once a second, watches the autopilot's heartbeat and
//! turns its GPS into position fixes for the head, which the caller collects with
//! [`Bridge::take_commands`] and delivers over its downlink. Everything refused is counted by
//! reason in the [`BridgeSummary`]; nothing from the autopilot can panic the bridge or stop it.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use mavlink::dialects::ardupilotmega::{self as mav, MavMessage};
use mavlink::{MavHeader, Message as _};
use serde::Serialize;
use subnav_wire::{Command, Downlink, NavMode, NavSolution, Uplink};

use crate::clock::{HeadClock, TimeSync};
use crate::endpoint::{Endpoint, Transport};
use crate::mapping::{self, Geodetic, OdometryFrame, StampClock, Velocity};
use crate::scan::{ScanStats, Scanner, encode_v2};

/// Our component id by default: MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY (what ArduPilot and PX4
/// expect an external navigation source to use).
pub const DEFAULT_COMPONENT_ID: u8 = 197;
/// Downlink sequence numbers of the bridge's fixes (operators and USBL use 1.., the map 0x8000..).
pub const FIX_SEQ_FIRST: u16 = 0x4000;
const FIX_SEQ_LAST: u16 = 0x7FFF;

/// Which position source of the autopilot becomes fixes for the head.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
pub enum GpsInput {
    /// `GPS_RAW_INT`: the receiver's own fix (the default).
    RawInt,
    /// `GLOBAL_POSITION_INT`: the autopilot's fused position. It contains what we sent it:
    /// only for an autopilot that does not use us for position.
    GlobalPositionInt,
    /// No fixes from the autopilot.
    Off,
}

/// What the bridge does; see `subnav mavlink --help` for each option.
#[derive(Debug, Clone)]
pub struct BridgeConfig {
    pub endpoint: Endpoint,
    /// The vehicle's system id (the autopilot's; our messages carry it too).
    pub vehicle_system_id: u8,
    pub component_id: u8,
    /// Velocity withheld above this horizontal 1-sigma, m/s.
    pub max_velocity_sigma_mps: f32,
    /// The head's NED origin, when known (a simulated head's scenario, or `--origin`).
    pub head_origin: Option<Geodetic>,
    pub odometry_frame: OdometryFrame,
    /// The clock of the messages' time stamps (of validity).
    pub stamp_clock: StampClock,
    pub send_vision_position: bool,
    pub send_vision_speed: bool,
    pub send_odometry: bool,
    pub send_global_vision_position: bool,
    pub gps: GpsInput,
    /// Horizontal 1-sigma of a fix per unit of HDOP when the receiver gives no `h_acc`, m.
    pub gps_uere_m: f64,
    /// The head must be shallower than this (its own depth) for a GPS fix to be used, m.
    pub surface_depth_m: f32,
    /// Fixes and origins further than this from the head's origin are refused, m.
    pub max_distance_m: f64,
    /// Fixes older than this on arrival are refused (the head's history is 4 s), s.
    pub max_fix_age_s: f64,
    /// At most one fix per this interval, s.
    pub min_fix_interval_s: f64,
    /// The autopilot is declared lost after this long without its heartbeat, s.
    pub link_timeout_s: f64,
}

impl BridgeConfig {
    pub fn new(endpoint: Endpoint) -> Self {
        Self {
            endpoint,
            vehicle_system_id: 1,
            component_id: DEFAULT_COMPONENT_ID,
            max_velocity_sigma_mps: 0.3,
            head_origin: None,
            odometry_frame: OdometryFrame::LocalFrd,
            stamp_clock: StampClock::Companion,
            send_vision_position: true,
            send_vision_speed: true,
            send_odometry: true,
            send_global_vision_position: true,
            gps: GpsInput::RawInt,
            gps_uere_m: 2.5,
            surface_depth_m: 0.5,
            max_distance_m: 20_000.0,
            max_fix_age_s: 3.0,
            min_fix_interval_s: 0.2,
            link_timeout_s: 3.0,
        }
    }
}

/// Latency from a solution's time of validity to its send, µs (companion clock).
#[derive(Debug, Clone, Default, Serialize)]
pub struct Latency {
    pub count: u64,
    pub median_us: i64,
    pub p95_us: i64,
    pub max_us: i64,
}

/// What a bridge session did.
#[derive(Debug, Clone, Default, Serialize)]
pub struct BridgeSummary {
    pub endpoint: String,
    pub duration_s: f64,
    /// Messages sent by name, and per second of the session.
    pub sent: BTreeMap<String, u64>,
    pub rate_hz: BTreeMap<String, f64>,
    pub send_errors: u64,
    /// The clock of the stamps (`--mavlink-stamp-clock`).
    pub stamp_clock: StampClock,
    /// With `--mavlink-stamp-clock autopilot`: solutions whose pose went out stamped in our own
    /// clock (TIMESYNC not converged yet).
    pub stamped_own_clock: u64,
    /// Solutions not sent: the head aligning or not running, or non-finite.
    pub pose_withheld: u64,
    /// Solutions sent without a velocity: the head had none yet, or its sigma was over the bound.
    pub velocity_withheld_not_yet: u64,
    pub velocity_withheld_uncertain: u64,
    pub latency: Latency,
    pub reset_counter: u8,
    /// What incremented the reset counter.
    pub resets: BTreeMap<String, u32>,
    pub timesync: TimeSync,
    pub scan: ScanStats,
    /// Frames from another system than the vehicle's: ignored.
    pub foreign_system: u64,
    pub autopilot_heartbeats: u64,
    /// The autopilot's heartbeat lost for longer than the timeout (times), and now.
    pub link_lost: u32,
    pub link_alive: bool,
    pub receive_errors: u64,
    /// GPS fixes turned into position fixes for the head, refused by reason, and the head's
    /// answers to them.
    pub gps_sent: u64,
    pub gps_refused: BTreeMap<String, u64>,
    pub gps_acked: u64,
    pub gps_nacked: BTreeMap<String, u64>,
    pub origin: Option<Geodetic>,
    pub origin_changes: u32,
    pub origin_refused: BTreeMap<String, u64>,
    pub head_reboots: u32,
    /// Companion time (µs, `CLOCK_MONOTONIC`) of the head's time 0 as the bridge maps it at the end.
    pub head_t0_companion_us: Option<i64>,
}

impl BridgeSummary {
    /// A few lines for the end of a run.
    pub fn lines(&self) -> Vec<String> {
        let sent: Vec<String> =
            self.sent.iter().map(|(k, v)| format!("{k} {v} ({:.1} Hz)", self.rate_hz.get(k).copied().unwrap_or(0.0))).collect();
        let mut out = vec![
            format!("mavlink: {} for {:.1} s; sent {}", self.endpoint, self.duration_s, sent.join(", ")),
            format!(
                "mavlink: latency validity->send median {:.2} ms, p95 {:.2} ms, max {:.2} ms; timesync {} (offset {:?} us, rtt {:?} us, {} replies, {} refused); stamps in the {:?} clock ({} in ours before timesync)",
                self.latency.median_us as f64 / 1e3,
                self.latency.p95_us as f64 / 1e3,
                self.latency.max_us as f64 / 1e3,
                if self.timesync.converged() { "converged" } else { "NOT converged" },
                self.timesync.offset_us,
                self.timesync.rtt_us,
                self.timesync.replies,
                self.timesync.refused,
                self.stamp_clock,
                self.stamped_own_clock
            ),
            format!(
                "mavlink: withheld: pose {}, velocity not yet {}, velocity too uncertain {}; reset_counter {} ({:?})",
                self.pose_withheld, self.velocity_withheld_not_yet, self.velocity_withheld_uncertain, self.reset_counter, self.resets
            ),
            format!(
                "mavlink: autopilot heartbeats {}, link {} (lost {} times); in: {} frames, {} bad CRC, {} unknown, {} malformed, {} bytes skipped, {} from other systems, {} receive errors",
                self.autopilot_heartbeats,
                if self.link_alive { "alive" } else { "DEAD" },
                self.link_lost,
                self.scan.frames,
                self.scan.bad_crc,
                self.scan.unknown_message,
                self.scan.malformed,
                self.scan.skipped_bytes,
                self.foreign_system,
                self.receive_errors
            ),
            format!(
                "mavlink: GPS fixes to the head {} (acknowledged {}, refused by the head {:?}), refused here {:?}; origin {:?}, changes {}, refused {:?}",
                self.gps_sent, self.gps_acked, self.gps_nacked, self.gps_refused, self.origin, self.origin_changes, self.origin_refused
            ),
        ];
        if self.head_reboots > 0 {
            out.push(format!("mavlink: the head rebooted {} times", self.head_reboots));
        }
        out
    }
}

struct State {
    cfg: BridgeConfig,
    head_clock: HeadClock,
    summary: BridgeSummary,
    latencies: Vec<i64>,
    last_nav: Option<NavSolution>,
    /// Resets seen in the head's Health (position, heading, velocity).
    last_resets: Option<(u32, u32, u32)>,
    seen_nav: bool,
    last_velocity: Option<Velocity>,
    commands: Vec<Downlink>,
    next_seq: u16,
    pending_seqs: Vec<u16>,
    last_fix_us: Option<i64>,
    last_heartbeat_rx: Option<Instant>,
    texts: Vec<(mav::MavSeverity, String)>,
    converged_said: bool,
}

impl State {
    fn bump_reset(&mut self, why: &str) {
        self.summary.reset_counter = self.summary.reset_counter.wrapping_add(1);
        *self.summary.resets.entry(why.to_string()).or_default() += 1;
    }

    fn say(&mut self, sev: mav::MavSeverity, text: String) {
        if self.texts.len() < 32 {
            self.texts.push((sev, text));
        }
    }

    fn refuse_gps(&mut self, why: &str) {
        *self.summary.gps_refused.entry(why.to_string()).or_default() += 1;
    }
}

struct Shared {
    link: Transport,
    /// When the bridge started (for the session's duration).
    epoch: Instant,
    seq: AtomicU8,
    state: Mutex<State>,
    stop: AtomicBool,
}

impl Shared {
    fn now_us(&self) -> i64 {
        companion_now_us()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn send(&self, st: &mut State, m: &MavMessage) {
        let header = MavHeader {
            system_id: u32::from(st.cfg.vehicle_system_id),
            component_id: st.cfg.component_id,
            sequence: self.seq.fetch_add(1, Ordering::Relaxed),
        };
        match self.link.send(&encode_v2(header, m)) {
            Ok(true) => *st.summary.sent.entry(m.message_name().to_string()).or_default() += 1,
            Ok(false) => {}
            Err(_) => st.summary.send_errors += 1,
        }
    }
}

/// The companion's clock, µs: `CLOCK_MONOTONIC` (time since the host booted, as companion
/// computers stamp MAVLink; any process on the host reads the same clock). Never 0: TIMESYNC
/// reads 0 as "a request".
pub fn companion_now_us() -> i64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes the timespec it is given; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    (ts.tv_sec * 1_000_000 + ts.tv_nsec / 1000).max(1)
}

/// A running bridge.
pub struct Bridge {
    shared: Arc<Shared>,
    rx: Mutex<Option<JoinHandle<()>>>,
}

impl Bridge {
    /// Open the endpoint and start the receiver thread. `head_clock`: how the head's time maps
    /// to ours (see [`HeadClock`]; [`Bridge::set_head_clock`] can replace it at the run's start).
    pub fn start(cfg: BridgeConfig, head_clock: HeadClock) -> Result<Bridge> {
        crate::endpoint::check(&cfg.endpoint)?;
        let link = Transport::open(&cfg.endpoint)?;
        let summary = BridgeSummary { endpoint: cfg.endpoint.to_string(), stamp_clock: cfg.stamp_clock, ..Default::default() };
        let state = State {
            cfg,
            head_clock,
            summary,
            latencies: Vec::new(),
            last_nav: None,
            last_resets: None,
            seen_nav: false,
            last_velocity: None,
            commands: Vec::new(),
            next_seq: FIX_SEQ_FIRST,
            pending_seqs: Vec::new(),
            last_fix_us: None,
            last_heartbeat_rx: None,
            texts: Vec::new(),
            converged_said: false,
        };
        let shared =
            Arc::new(Shared { link, epoch: Instant::now(), seq: AtomicU8::new(0), state: Mutex::new(state), stop: AtomicBool::new(false) });
        let sh = shared.clone();
        let rx =
            std::thread::Builder::new().name("mavlink-rx".into()).spawn(move || receive(&sh)).context("starting the MAVLink receiver")?;
        Ok(Bridge { shared, rx: Mutex::new(Some(rx)) })
    }

    /// Our clock now, µs.
    pub fn now_us(&self) -> i64 {
        self.shared.now_us()
    }

    pub fn set_head_clock(&self, c: HeadClock) {
        self.shared.lock().head_clock = c;
    }

    /// The local address of a UDP endpoint.
    pub fn local_addr(&self) -> Option<std::net::SocketAddr> {
        self.shared.link.local_addr()
    }

    /// One uplink message, arrived now.
    pub fn on_uplink(&self, m: &Uplink) {
        if self.shared.stop.load(Ordering::Relaxed) {
            return;
        }
        let now = self.shared.now_us();
        let mut st = self.shared.lock();
        if let Some(t) = m.t_us() {
            st.head_clock.observe(t, now);
        }
        match m {
            Uplink::Boot(_) if st.seen_nav => {
                st.summary.head_reboots += 1;
                st.bump_reset("head reboot");
                st.last_resets = None;
            }
            Uplink::Health(h) => {
                let now_resets = (h.position_resets, h.heading_resets, h.aid.dvl.resets);
                if let Some(prev) = st.last_resets {
                    if now_resets.0 > prev.0 {
                        st.bump_reset("head position reset");
                    }
                    if now_resets.1 > prev.1 {
                        st.bump_reset("head heading reset");
                    }
                    if now_resets.2 > prev.2 {
                        st.bump_reset("head velocity reset");
                    }
                }
                st.last_resets = Some(now_resets);
            }
            Uplink::Ack(a) => {
                if let Some(k) = st.pending_seqs.iter().position(|&s| s == a.seq) {
                    st.pending_seqs.remove(k);
                    match a.result {
                        Ok(()) => st.summary.gps_acked += 1,
                        Err(r) => *st.summary.gps_nacked.entry(format!("{r:?}")).or_default() += 1,
                    }
                }
            }
            Uplink::Nav(n) => {
                st.seen_nav = true;
                st.last_nav = Some(*n);
                self.send_solution(&mut st, n, now);
            }
            _ => {}
        }
    }

    fn send_solution(&self, st: &mut State, n: &NavSolution, arrived_us: i64) {
        if !mapping::pose_usable(n) {
            st.summary.pose_withheld += 1;
            return;
        }
        let Some(valid_us) = st.head_clock.to_companion_us(n.t_us) else {
            st.summary.pose_withheld += 1;
            return;
        };
        let to_autopilot = match st.cfg.stamp_clock {
            StampClock::Companion => None,
            StampClock::Autopilot => Some(st.summary.timesync.to_autopilot_us(valid_us)),
        };
        let stamp = match to_autopilot {
            None => valid_us,
            Some(Some(t)) => {
                if !st.converged_said {
                    st.converged_said = true;
                    let o = st.summary.timesync.offset_us.unwrap_or(0);
                    st.say(mav::MavSeverity::MAV_SEVERITY_INFO, format!("subnav: timesync ok, offset {:.3} s", o as f64 * 1e-6));
                }
                t
            }
            Some(None) => {
                st.summary.stamped_own_clock += 1;
                valid_us
            }
        };
        let stamp = u64::try_from(stamp).unwrap_or(0);
        // Output frame: the autopilot's origin when both origins are known, else the head's.
        let (pos, global) = match (st.cfg.head_origin, st.summary.origin) {
            (Some(h), Some(a)) => {
                let p = a.ned_of(&h.at_ned(n.pos_ned_m.map(f64::from)));
                (p.map(|v| v as f32), true)
            }
            _ => (n.pos_ned_m, false),
        };
        let velocity = mapping::velocity_usable(n, st.cfg.max_velocity_sigma_mps);
        match velocity {
            Velocity::Usable => {}
            Velocity::NotYet => st.summary.velocity_withheld_not_yet += 1,
            Velocity::TooUncertain => st.summary.velocity_withheld_uncertain += 1,
        }
        if st.last_velocity != Some(velocity) {
            if st.last_velocity.is_some() || velocity != Velocity::Usable {
                let text = match velocity {
                    Velocity::Usable => "subnav: velocity back".to_string(),
                    Velocity::NotYet => "subnav: no velocity yet".to_string(),
                    Velocity::TooUncertain => format!("subnav: velocity withheld, sigma > {:.2} m/s", st.cfg.max_velocity_sigma_mps),
                };
                st.say(mav::MavSeverity::MAV_SEVERITY_WARNING, text);
            }
            st.last_velocity = Some(velocity);
        }
        let out = mapping::outgoing(n, pos, stamp, st.summary.reset_counter, velocity, global, st.cfg.odometry_frame);
        let mut msgs = Vec::with_capacity(4);
        if st.cfg.send_vision_position {
            msgs.push(MavMessage::VISION_POSITION_ESTIMATE(out.vision_position));
        }
        if let (true, Some(g)) = (st.cfg.send_global_vision_position, out.global_vision_position) {
            msgs.push(MavMessage::GLOBAL_VISION_POSITION_ESTIMATE(g));
        }
        if let (true, Some(s)) = (st.cfg.send_vision_speed, out.vision_speed) {
            msgs.push(MavMessage::VISION_SPEED_ESTIMATE(s));
        }
        if let (true, Some(o)) = (st.cfg.send_odometry, out.odometry) {
            msgs.push(MavMessage::ODOMETRY(o));
        }
        for m in &msgs {
            self.shared.send(st, m);
        }
        let sent_us = self.shared.now_us();
        let _ = arrived_us;
        st.latencies.push(sent_us - valid_us);
    }

    /// Downlink commands for the head (position fixes from the autopilot's GPS) since the last call.
    pub fn take_commands(&self) -> Vec<Downlink> {
        std::mem::take(&mut self.shared.lock().commands)
    }

    /// The summary so far.
    pub fn summary(&self) -> BridgeSummary {
        let st = self.shared.lock();
        let mut s = st.summary.clone();
        s.duration_s = self.shared.epoch.elapsed().as_secs_f64();
        s.rate_hz = s.sent.iter().map(|(k, v)| (k.clone(), *v as f64 / s.duration_s.max(1e-9))).collect();
        let mut l = st.latencies.clone();
        l.sort_unstable();
        if !l.is_empty() {
            let at = |q: f64| l[((l.len() - 1) as f64 * q).round() as usize];
            s.latency = Latency { count: l.len() as u64, median_us: at(0.5), p95_us: at(0.95), max_us: *l.last().unwrap_or(&0) };
        }
        s.head_t0_companion_us = st.head_clock.to_companion_us(0);
        s.link_alive = st.last_heartbeat_rx.is_some_and(|t| t.elapsed().as_secs_f64() < st.cfg.link_timeout_s);
        s
    }

    /// Stop the receiver and return the summary (the bridge sends nothing after this).
    pub fn finish(&self) -> BridgeSummary {
        let s = self.summary();
        self.stop();
        s
    }

    fn stop(&self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.rx.lock().unwrap_or_else(|e| e.into_inner()).take() {
            let _ = h.join();
        }
    }

    /// Replace what the bridge does with the autopilot's GPS (e.g. `Off` where no downlink reaches the head).
    pub fn set_gps_input(&self, g: GpsInput) {
        self.shared.lock().cfg.gps = g;
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        self.stop();
    }
}

/// The receiver thread: frames in, TIMESYNC and HEARTBEAT out, the link's health.
fn receive(sh: &Shared) {
    let mut scanner = Scanner::default();
    let mut buf = [0u8; 2048];
    let mut next_heartbeat = Instant::now();
    let mut next_timesync = Instant::now();
    while !sh.stop.load(Ordering::Relaxed) {
        match sh.link.recv(&mut buf) {
            Ok((n, datagram)) => {
                if n > 0 {
                    scanner.push(&buf[..n]);
                    while let Some((h, m)) = scanner.next_frame() {
                        inbound(sh, &h, &m);
                    }
                    if datagram {
                        scanner.end_of_datagram();
                    }
                }
            }
            Err(_) => {
                sh.lock().summary.receive_errors += 1;
                std::thread::sleep(crate::endpoint::POLL);
            }
        }
        let now = Instant::now();
        let mut st = sh.lock();
        st.summary.scan = scanner.stats;
        if now >= next_heartbeat {
            next_heartbeat = now + Duration::from_secs(1);
            let hb = MavMessage::HEARTBEAT(mav::HEARTBEAT_DATA {
                custom_mode: 0,
                mavtype: mav::MavType::MAV_TYPE_ONBOARD_CONTROLLER,
                autopilot: mav::MavAutopilot::MAV_AUTOPILOT_INVALID,
                base_mode: mav::MavModeFlag::empty(),
                system_status: match st.last_nav.map(|n| n.mode) {
                    Some(NavMode::Aided) => mav::MavState::MAV_STATE_ACTIVE,
                    Some(NavMode::Inertial) => mav::MavState::MAV_STATE_CRITICAL,
                    _ => mav::MavState::MAV_STATE_BOOT,
                },
                mavlink_version: 3,
            });
            sh.send(&mut st, &hb);
            // The autopilot's heartbeat lost: say so once per loss.
            let alive = st.last_heartbeat_rx.is_some_and(|t| t.elapsed().as_secs_f64() < st.cfg.link_timeout_s);
            if st.summary.link_alive && !alive {
                st.summary.link_lost += 1;
            }
            st.summary.link_alive = alive;
        }
        if now >= next_timesync {
            // Four a second until converged, then one.
            next_timesync = now + if st.summary.timesync.converged() { Duration::from_secs(1) } else { Duration::from_millis(250) };
            let (tc1, ts1) = st.summary.timesync.request(sh.now_us() * 1000);
            let (ts, tc) = (st.cfg.vehicle_system_id, 0);
            sh.send(&mut st, &MavMessage::TIMESYNC(mav::TIMESYNC_DATA { tc1, ts1, target_system: ts, target_component: tc }));
        }
        for (severity, text) in std::mem::take(&mut st.texts) {
            let t: String = text.chars().take(50).collect();
            sh.send(&mut st, &MavMessage::STATUSTEXT(mav::STATUSTEXT_DATA { severity, text: t.as_str().into(), id: 0, chunk_seq: 0 }));
        }
    }
}

/// One frame from the autopilot's side. `SET_GPS_GLOBAL_ORIGIN` is deprecated in favour of
/// `MAV_CMD_DO_SET_GLOBAL_ORIGIN` but is what BlueOS and ground stations send today: both are read.
#[allow(deprecated)]
fn inbound(sh: &Shared, h: &MavHeader, m: &MavMessage) {
    let now_us = sh.now_us();
    let mut st = sh.lock();
    if h.system_id != u32::from(st.cfg.vehicle_system_id) {
        st.summary.foreign_system += 1;
        return;
    }
    match m {
        MavMessage::HEARTBEAT(hb) if hb.autopilot != mav::MavAutopilot::MAV_AUTOPILOT_INVALID => {
            st.summary.autopilot_heartbeats += 1;
            st.last_heartbeat_rx = Some(Instant::now());
            st.summary.link_alive = true;
        }
        MavMessage::TIMESYNC(t) => {
            let for_us = t.target_component == 0 || t.target_component == st.cfg.component_id;
            if t.tc1 == 0 {
                // The autopilot's request: answer with our clock.
                let reply = mav::TIMESYNC_DATA {
                    tc1: now_us * 1000,
                    ts1: t.ts1,
                    target_system: h.system_id as u8,
                    target_component: h.component_id,
                };
                sh.send(&mut st, &MavMessage::TIMESYNC(reply));
            } else if for_us {
                st.summary.timesync.on_reply(t.tc1, t.ts1, now_us * 1000);
            }
        }
        MavMessage::GPS_RAW_INT(g) if st.cfg.gps == GpsInput::RawInt => {
            let fix_ok = matches!(
                g.fix_type,
                mav::GpsFixType::GPS_FIX_TYPE_3D_FIX
                    | mav::GpsFixType::GPS_FIX_TYPE_DGPS
                    | mav::GpsFixType::GPS_FIX_TYPE_RTK_FLOAT
                    | mav::GpsFixType::GPS_FIX_TYPE_RTK_FIXED
                    | mav::GpsFixType::GPS_FIX_TYPE_PPP
            );
            let sigma_m = if g.h_acc > 0 {
                f64::from(g.h_acc) * 1e-3
            } else if g.eph != u16::MAX {
                f64::from(g.eph) * 1e-2 * st.cfg.gps_uere_m
            } else {
                f64::NAN
            };
            gps_fix(sh, &mut st, now_us, g.time_usec as i64, fix_ok, Geodetic::from_e7(g.lat, g.lon, g.alt), sigma_m);
        }
        MavMessage::GLOBAL_POSITION_INT(g) if st.cfg.gps == GpsInput::GlobalPositionInt => {
            let sigma_m = st.cfg.gps_uere_m;
            gps_fix(sh, &mut st, now_us, i64::from(g.time_boot_ms) * 1000, true, Geodetic::from_e7(g.lat, g.lon, g.alt), sigma_m);
        }
        MavMessage::SET_GPS_GLOBAL_ORIGIN(o) if o.target_system == 0 || o.target_system == st.cfg.vehicle_system_id => {
            set_origin(&mut st, Geodetic::from_e7(o.latitude, o.longitude, o.altitude));
        }
        MavMessage::GPS_GLOBAL_ORIGIN(o) => set_origin(&mut st, Geodetic::from_e7(o.latitude, o.longitude, o.altitude)),
        MavMessage::COMMAND_INT(c)
            if c.command == mav::MavCmd::MAV_CMD_DO_SET_GLOBAL_ORIGIN
                && (c.target_system == 0 || c.target_system == st.cfg.vehicle_system_id) =>
        {
            let alt_mm = (f64::from(c.z) * 1e3).clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32;
            set_origin(&mut st, Geodetic::from_e7(c.x, c.y, alt_mm));
        }
        _ => {}
    }
}

fn set_origin(st: &mut State, g: Option<Geodetic>) {
    let Some(g) = g else {
        *st.summary.origin_refused.entry("bad coordinates".into()).or_default() += 1;
        return;
    };
    if let Some(h) = st.cfg.head_origin {
        let d = h.ned_of(&g);
        if d[0].hypot(d[1]) > st.cfg.max_distance_m {
            *st.summary.origin_refused.entry("far from the head's origin".into()).or_default() += 1;
            return;
        }
    }
    if let Some(cur) = st.summary.origin {
        let d = cur.ned_of(&g);
        if d[0].hypot(d[1]).hypot(d[2]) < 0.01 {
            return;
        }
    }
    st.summary.origin = Some(g);
    st.summary.origin_changes += 1;
    st.bump_reset("origin set");
    let text = format!("subnav: origin {:.6} {:.6}, re-based", g.lat_deg, g.lon_deg);
    st.say(mav::MavSeverity::MAV_SEVERITY_NOTICE, text);
}

/// A GPS position from the autopilot (its clock `t_ap_us`) -> a position fix for the head.
fn gps_fix(sh: &Shared, st: &mut State, now_us: i64, t_ap_us: i64, fix_ok: bool, g: Option<Geodetic>, sigma_m: f64) {
    let _ = sh;
    if !fix_ok {
        return st.refuse_gps("no 3D fix");
    }
    let Some(g) = g else { return st.refuse_gps("bad coordinates") };
    if !(sigma_m.is_finite() && sigma_m > 0.0) {
        return st.refuse_gps("no accuracy");
    }
    let Some(t_us) = st.summary.timesync.to_companion_us(t_ap_us) else { return st.refuse_gps("timesync not converged") };
    if t_us > now_us + 200_000 {
        return st.refuse_gps("from the future");
    }
    if (now_us - t_us) as f64 > st.cfg.max_fix_age_s * 1e6 {
        return st.refuse_gps("too old");
    }
    let Some(head_t_us) = st.head_clock.to_head_us(t_us) else { return st.refuse_gps("head clock unknown") };
    let Some(origin) = st.cfg.head_origin else { return st.refuse_gps("head origin unknown") };
    let ned = origin.ned_of(&g);
    if ned[0].hypot(ned[1]) > st.cfg.max_distance_m {
        return st.refuse_gps("far from the head's origin");
    }
    let Some(n) = st.last_nav else { return st.refuse_gps("head not running") };
    if !matches!(n.mode, NavMode::Aided | NavMode::Inertial) {
        return st.refuse_gps("head not running");
    }
    if n.pos_ned_m[2] > st.cfg.surface_depth_m {
        return st.refuse_gps("head under water");
    }
    if st.last_fix_us.is_some_and(|l| ((now_us - l) as f64) < st.cfg.min_fix_interval_s * 1e6) {
        return st.refuse_gps("rate limit");
    }
    st.last_fix_us = Some(now_us);
    let s2 = (sigma_m * sigma_m) as f32;
    // The GPS measures the antenna's horizontal position; the depth is the head's own (a wide
    // variance: the fix says nothing about it).
    let command = Command::PositionFix {
        t_us: head_t_us,
        pos_ned_m: [ned[0] as f32, ned[1] as f32, n.pos_ned_m[2]],
        cov_ned_m2: [s2, 0.0, 0.0, s2, 0.0, 100.0],
    };
    let seq = st.next_seq;
    st.next_seq = if seq >= FIX_SEQ_LAST { FIX_SEQ_FIRST } else { seq + 1 };
    st.pending_seqs.push(seq);
    if st.pending_seqs.len() > 64 {
        st.pending_seqs.remove(0);
    }
    st.commands.push(Downlink { seq, command });
    st.summary.gps_sent += 1;
}
