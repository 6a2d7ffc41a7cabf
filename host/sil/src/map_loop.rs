//! The map in the loop: the camera's frames and the firmware's own telemetry go into the host's
//! topological mapper (`subnav_topo::live`), and its position fixes go back to the head over the
//! downlink, stamped with the image's time, so the head fuses each at that time.
//!
//! Timing (nothing reaches the estimator earlier than it would in the water):
//! - frame `n` is exposed at the head's trigger (the camera model sees the trigger line at the
//!   firmware's logical time); the host learns the frame's time only from the head's
//!   `Uplink::Trigger` for `n` and gives the mapper that time;
//! - the mapper takes the frame once the image is processed, `latency_s` after exposure, and
//!   uses the navigation solutions the head sent up to then (it waits for the solution that
//!   brackets the frame's time: under QEMU the telemetry comes on another thread);
//! - a fix is a downlink `PositionFix` delivered by the modem link (bridge UART 1) at exposure
//!   + `latency_s`: the same frames, parser and filter path as every command.
//!
//! Counting the firmware's information once: a node is placed from the firmware's own estimate,
//! so a fix built from it is correlated with the estimate it corrects. The mapper sends the
//! equivalent independent measurement of the loop closure: only the drift accumulated since the
//! node was placed is observed (see `subnav_topo::live`). The dive's consistency figures (the
//! fraction of samples within 3 sigma) check it.
//!
//! Sequence numbers of map fixes start at [`MAP_SEQ0`], so their `Ack`s are told apart from
//! those of other commands.

use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use serde::Serialize;
use subnav_topo::live::{CameraFrame, Closure, FrameOutcome, LiveConfig, LiveMapper, LiveNode, LiveStats, NavSample};
use subnav_topo::live_eval::{MapScore, MapScoreConfig, MapScorer};
use subnav_wire::{Downlink, NavMode, Uplink};

use crate::chips::camera::CameraCapture;

/// First sequence number of the map's fixes.
pub const MAP_SEQ0: u16 = 0x8000;

/// How the loop runs.
#[derive(Debug, Clone, Copy)]
pub struct MapLoopConfig {
    /// Send the fixes to the head (false: the map runs open loop, for comparison).
    pub send_fixes: bool,
    /// From exposure to the fix's arrival at the head, µs (image readout, features, mapping
    /// and the serial link).
    pub latency_us: u64,
    pub live: LiveConfig,
    /// Wall-clock bound on waiting for the telemetry a frame needs (QEMU); a frame that times
    /// out is processed with what has arrived and counted.
    pub nav_wait: Duration,
}

/// What the loop did, for the dive's report.
#[derive(Debug, Clone, Serialize, Default)]
pub struct MapLoopReport {
    pub mapper: LiveStats,
    /// The map against the simulator's truth (`subnav_topo::live_eval`: precision, recall).
    pub score: MapScore,
    /// Camera frames handed over, and those whose trigger message never came.
    pub captures: u64,
    pub captures_without_trigger: u64,
    /// Fixes sent to the head and what it answered.
    pub fixes_sent: u64,
    pub fixes_accepted: u64,
    pub fixes_refused: u64,
    /// Each answered fix: its time of validity (µs) and whether the head accepted it.
    pub fix_results: Vec<(u64, bool)>,
    /// Frames processed before their telemetry arrived (QEMU wall-clock bound hit; 0 in a
    /// deterministic run).
    pub nav_wait_timeouts: u64,
    pub nodes: Vec<LiveNode>,
    pub closures: Vec<Closure>,
}

struct State {
    mapper: LiveMapper,
    /// Scores the mapper's events against the camera's truth (outside the mapper).
    scorer: MapScorer,
    /// Frame number -> trigger time (µs), from the head's telemetry.
    triggers: BTreeMap<u32, u64>,
    /// Frames waiting for processing, with the simulator's exposure time.
    captures: VecDeque<(u64, CameraCapture)>,
    latest_nav_us: Option<u64>,
    next_seq: u16,
    /// Sent fixes awaiting their `Ack`.
    sent: BTreeMap<u16, u64>,
    closed: bool,
    /// A wait timed out and no solution has come since: frames are not waited for (a head whose
    /// telemetry stopped must not stall the run by `nav_wait` per frame).
    stalled: bool,
    report: MapLoopReport,
}

/// The loop's shared state: fed by the uplink (any thread), the camera and the modem (the
/// bridge thread).
#[derive(Clone)]
pub struct MapLoop {
    cfg: MapLoopConfig,
    inner: Arc<(Mutex<State>, Condvar)>,
}

fn nav_sample(n: &subnav_wire::NavSolution) -> NavSample {
    let [sn, se, _] = n.sigma_pos_m.map(f64::from);
    NavSample {
        t_us: n.t_us,
        pos_ned_m: n.pos_ned_m.map(f64::from),
        cov_ne_m2: [sn * sn, f64::from(n.cov_ne_m2), se * se],
        aided: n.mode == NavMode::Aided,
        vel_sigma_mps: f64::from(n.sigma_vel_mps[0].max(n.sigma_vel_mps[1])),
    }
}

impl MapLoop {
    pub fn new(cfg: MapLoopConfig) -> Self {
        let state = State {
            mapper: LiveMapper::new(cfg.live),
            scorer: MapScorer::new(&cfg.live, MapScoreConfig::default()),
            triggers: BTreeMap::new(),
            captures: VecDeque::new(),
            latest_nav_us: None,
            next_seq: MAP_SEQ0,
            sent: BTreeMap::new(),
            closed: false,
            stalled: false,
            report: MapLoopReport::default(),
        };
        Self { cfg, inner: Arc::new((Mutex::new(state), Condvar::new())) }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.inner.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A telemetry message from the head (in the order it was sent).
    pub fn on_uplink(&self, m: &Uplink) {
        let mut s = self.lock();
        match m {
            Uplink::Nav(n) => {
                let _ = s.mapper.on_nav(nav_sample(n));
                s.latest_nav_us = Some(n.t_us);
                s.stalled = false;
            }
            Uplink::Trigger(t) => {
                s.triggers.insert(t.frame, t.t_us);
                // Keep a bounded window (frames older than 4,096 triggers are never matched).
                while s.triggers.len() > 4096 {
                    s.triggers.pop_first();
                }
            }
            Uplink::Ack(a) => {
                if let Some(t) = s.sent.remove(&a.seq) {
                    s.report.fix_results.push((t, a.result.is_ok()));
                    if a.result.is_ok() {
                        s.report.fixes_accepted += 1;
                    } else {
                        s.report.fixes_refused += 1;
                    }
                }
            }
            _ => return,
        }
        drop(s);
        self.inner.1.notify_all();
    }

    /// The telemetry has ended (the run is over): waiting stops.
    pub fn close(&self) {
        self.lock().closed = true;
        self.inner.1.notify_all();
    }

    /// A frame from the camera.
    pub fn on_capture(&self, cap: CameraCapture) {
        let mut s = self.lock();
        s.report.captures += 1;
        s.captures.push_back((cap.exposed_us, cap));
    }

    /// Process every frame due by `now_us`; returns the downlink frames to deliver now.
    pub fn poll(&self, now_us: u64) -> Vec<Vec<u8>> {
        let mut out = Vec::new();
        let mut s = self.lock();
        loop {
            let Some(&(exposed_us, cap)) = s.captures.front() else { break };
            if exposed_us.saturating_add(self.cfg.latency_us) > now_us {
                break;
            }
            // Wait (QEMU: the telemetry thread) for the trigger message and a solution at or after it.
            let deadline = Instant::now() + self.cfg.nav_wait;
            loop {
                let trig = s.triggers.get(&cap.frame).copied();
                let covered = trig.is_some_and(|t| s.latest_nav_us.is_some_and(|n| n >= t));
                if covered || s.closed || s.stalled {
                    break;
                }
                let left = deadline.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    s.report.nav_wait_timeouts += 1;
                    s.stalled = true;
                    break;
                }
                s = self.inner.1.wait_timeout(s, left).map(|(g, _)| g).unwrap_or_else(|e| e.into_inner().0);
            }
            s.captures.pop_front();
            let Some(t_us) = s.triggers.get(&cap.frame).copied() else {
                s.report.captures_without_trigger += 1;
                continue;
            };
            let frame = CameraFrame { frame: cap.frame, t_us, features: cap.image.features };
            let truth = Some(cap.image.truth_ne_m);
            let State { mapper, scorer, .. } = &mut *s;
            let outcome = mapper.on_frame_observed(&frame, &mut |e| scorer.on_event(&e, truth));
            if let FrameOutcome::Fix(fix) = outcome {
                if self.cfg.send_fixes {
                    let seq = s.next_seq;
                    s.next_seq = s.next_seq.wrapping_add(1).max(MAP_SEQ0);
                    // Depth is the depth sensor's business: the firmware's own depth, with a
                    // variance that says nothing about it.
                    let cmd = fix.to_command(fix.prior_depth_m, 1.0e4);
                    let mut buf = [0u8; subnav_wire::MAX_DOWNLINK_FRAME];
                    if let Ok(bytes) = subnav_wire::encode(&Downlink { seq, command: cmd }, &mut buf) {
                        out.push(bytes.to_vec());
                        s.sent.insert(seq, fix.t_us);
                        s.report.fixes_sent += 1;
                    }
                }
            }
        }
        out
    }

    /// Fixes sent, fixes the head accepted, and nodes in the map (cheap: for a live status).
    pub fn counts(&self) -> (u64, u64, usize) {
        let s = self.lock();
        (s.report.fixes_sent, s.report.fixes_accepted, s.mapper.nodes().len())
    }

    /// The loop's figures so far (with the map's nodes and accepted closures).
    pub fn report(&self) -> MapLoopReport {
        let s = self.lock();
        let mut r = s.report.clone();
        r.mapper = s.mapper.stats();
        r.score = s.scorer.score();
        r.nodes = s.mapper.nodes().to_vec();
        r.closures = s.mapper.closures().to_vec();
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chips::camera::CameraImage;

    /// A head whose telemetry stopped: the first frame waits `nav_wait`, the next ones do not,
    /// and every frame without its trigger message is counted.
    #[test]
    fn silent_telemetry_costs_one_wait_not_one_per_frame() {
        let cfg =
            MapLoopConfig { send_fixes: true, latency_us: 500_000, live: LiveConfig::default(), nav_wait: Duration::from_millis(200) };
        let map = MapLoop::new(cfg);
        for k in 0..20u32 {
            let image = CameraImage { features: Some([0.0; 20]), truth_ne_m: [0.0; 2] };
            map.on_capture(CameraCapture { frame: k, exposed_us: u64::from(k) * 500_000, image });
        }
        let t0 = Instant::now();
        assert!(map.poll(60_000_000).is_empty());
        let waited = t0.elapsed();
        let r = map.report();
        assert!(waited < Duration::from_millis(1500), "waited {waited:?}");
        assert_eq!((r.nav_wait_timeouts, r.captures_without_trigger, r.captures), (1, 20, 20));
    }
}
