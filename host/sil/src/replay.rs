//! Replay of a recording through the firmware's own application core: the [`App`] (and so the
//! [`Estimator`](subnav_firmware::estimator::Estimator) the sensor head runs: alignment, compass
//! model error, heading re-acquisition) is fed the recording's raw samples and its downlink
//! commands, tick by tick in the boards' order, and every Nav solution it produces is compared
//! with the one the firmware sent.
//!
//! How the inputs are put back: the boards' own loop (`subnav_firmware::board_loop`, the code
//! both boards and the native run (`crate::sil`) run) with the recording as the board
//! ([`ReplayBoard`]): boot, then per 1 ms tick the downlink (the seq-0 start commands, then the
//! recorded commands, each framed again and fed as bytes), `sensor_tick`, the store (none),
//! `poll`:
//! - a [`SensorSuite`] answers each read from the recorded stream: a read succeeds with the
//!   recorded sample when the next recorded message is that raw sample (for the IMU and the
//!   polarization units also stamped with this tick), otherwise it fails (the board's read failed:
//!   the fault path, IMU coasting included, runs as it did); a DVL report is served at the tick
//!   that completed it (`rx_us`);
//! - a command is applied at the first tick whose recorded stream continues with its `Ack`: the
//!   uplink order says when the firmware handled it (between the messages around the Ack; any
//!   tick in that window gives the same state, except a past-stamped fix handled in a window that
//!   also holds a failed IMU read). Commands come from the recording's downlink (matched to the
//!   Ack by sequence number) and, for the seq-0 Acks at boot, from the board's start arguments in
//!   the recording's metadata ([`boot_commands`]);
//! - the replayed telemetry is matched message by message with the recorded one; fault reports
//!   are matched loosely (their kind is not always recoverable and does not reach the estimator).
//!
//! Host and target: the replay runs on the host what the Cortex-M4F ran. Both use the `libm`
//! crate wherever the core calls it; where nalgebra's `RealField` is called generically, the
//! host build routes to the host's maths library and the target to `libm`. In the navigation
//! path that was `atan2` of the heading update's circular mean (glibc's differs from libm's by
//! 1 ulp for ~0.3 % of inputs), which now calls `libm` on every build; `powi` of the Sage-Husa Q
//! weight differs too, but Q adaptation is off in the head's configuration. Measured on a 120-s
//! QEMU dive: 1201 of 1201 Nav solutions bit-identical (with glibc's atan2, one differed by
//! 1 ulp, 7e-11 relative).
//!
//! What cannot be replayed is an error naming the cause (not a recording, damage mid-file,
//! corrupt uplink frames, no boot, no raw samples, dropped telemetry) or a reported limitation
//! with the replay stopping there (raw streaming switched off, a reboot, a truncated end).

use std::cell::RefCell;
use std::collections::VecDeque;
use std::path::Path;

use anyhow::{Context, Result, bail};
use serde::Serialize;
use subnav_firmware::App;
use subnav_firmware::TelemetrySink;
use subnav_firmware::board_loop::{BoardIo, BoardLoop, BoardParts, CatchUp, PassEnd};
use subnav_firmware::sensors::{SensorFault, SensorSuite};
use subnav_firmware::store::NoStore;
use subnav_link::record::session::Session;
use subnav_link::record::{Loaded, read_bytes};
use subnav_wire::{
    Board, Command, CompassReport, ConfigItem, Decoded, DepthSample, Downlink, DvlSample, FaultKind, FaultSource, FrameDecoder, ImuSample,
    MAX_DOWNLINK_FRAME, MAX_UPLINK_FRAME, NavSolution, RawSample, Uplink,
};

/// Default tolerance: relative difference allowed per Nav value (see [`rel_diff`]).
pub const DEFAULT_TOLERANCE_REL: f64 = 1e-5;

/// Floors of the relative difference per field group: `|a - b| / max(|b|, floor)`. Values near
/// zero are compared against the floor (a velocity of 1e-6 m/s at rest is not a scale).
pub const FLOOR_POSITION_M: f64 = 1.0;
pub const FLOOR_VELOCITY_MPS: f64 = 0.1;
/// Quaternion components: the quaternion is unit, its natural scale is 1.
pub const FLOOR_ATTITUDE: f64 = 1.0;
/// Sigmas (m, m/s, rad): positive and far above this in any run.
pub const FLOOR_SIGMA: f64 = 1e-4;

/// The seq-0 commands a board applies at boot from its start arguments, in its order (time,
/// then origin). Mirrors `run_options` and `main` of `firmware/src/bin/qemu/main.rs`: a word that
/// does not parse is ignored, the last of a key wins, the origin needs both coordinates; the
/// conversions (integer to f64, one f64 product by the same constant) are exact IEEE operations,
/// so the values are bit for bit those the board computed. The native SIL applies these too.
pub fn boot_commands(board_args: &[String]) -> Vec<Command> {
    fn parse_u64(s: &str) -> Option<u64> {
        if s.is_empty() || !s.bytes().all(|c| c.is_ascii_digit()) {
            return None;
        }
        s.parse().ok()
    }
    fn parse_i64(s: &str) -> Option<i64> {
        match s.strip_prefix('-') {
            Some(rest) => parse_u64(rest).and_then(|v| i64::try_from(v).ok()).map(|v| -v),
            None => parse_u64(s).and_then(|v| i64::try_from(v).ok()),
        }
    }
    let (mut utc, mut lat, mut lon) = (None, None, None);
    for word in board_args.iter().flat_map(|a| a.split([' ', '\0'])) {
        if let Some(v) = word.strip_prefix("utc_unix_us=") {
            utc = parse_u64(v);
        } else if let Some(v) = word.strip_prefix("lat_e7=") {
            lat = parse_i64(v);
        } else if let Some(v) = word.strip_prefix("lon_e7=") {
            lon = parse_i64(v);
        }
    }
    let mut out = Vec::new();
    if let Some(utc) = utc.and_then(|u| i64::try_from(u).ok()) {
        out.push(Command::SetTime { t_us: 0, utc_unix_us: utc });
    }
    if let (Some(lat), Some(lon)) = (lat, lon) {
        let deg = core::f64::consts::PI / 180.0 * 1e-7;
        out.push(Command::SetConfig(ConfigItem::Origin { lat_rad: lat as f64 * deg, lon_rad: lon as f64 * deg, alt_m: 0.0 }));
    }
    out
}

/// Largest differences of one field group over all compared Nav solutions.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct GroupDiff {
    pub max_abs: f64,
    pub max_rel: f64,
    /// Values beyond the tolerance.
    pub beyond_tolerance: usize,
}

/// The first Nav value beyond the tolerance (or a mode / time difference).
#[derive(Debug, Clone, Serialize)]
pub struct NavMismatch {
    /// Index among the recorded Nav solutions.
    pub index: usize,
    pub t_us: u64,
    /// e.g. `pos_ned_m[1]`, `mode`, `t_us`.
    pub field: String,
    pub replayed: String,
    pub recorded: String,
    pub rel: f64,
}

/// The result of a replay.
#[derive(Debug, Clone, Serialize)]
pub struct ReplayReport {
    pub tolerance_rel: f64,
    pub nav_recorded: usize,
    pub nav_compared: usize,
    /// Nav solutions equal bit for bit (every field).
    pub nav_identical: usize,
    pub nav_beyond_tolerance: usize,
    pub position: GroupDiff,
    pub velocity: GroupDiff,
    pub attitude: GroupDiff,
    pub sigmas: GroupDiff,
    pub first_mismatch: Option<NavMismatch>,
    /// Raw samples served to the firmware, commands applied (downlink and boot).
    pub raw_samples: usize,
    pub commands_applied: usize,
    /// Acks whose result differs from the recorded one.
    pub ack_mismatches: usize,
    /// Compass reports that differ from the recorded ones (not bit for bit).
    pub compass_differ: usize,
    pub compass_compared: usize,
    /// Fault reports produced without a recorded one, and recorded ones not reproduced.
    pub faults_extra: usize,
    pub faults_missing: usize,
    /// Downlink commands the recording has no Ack for (sent at its end, or lost).
    pub commands_unacked: usize,
    /// Firmware time replayed (last tick, µs).
    pub replayed_to_us: u64,
    /// The replayed telemetry stopped matching the recorded stream (message index and why).
    pub diverged: Option<String>,
    /// What the replay could not cover, and why (it stopped there).
    pub limitations: Vec<String>,
}

impl ReplayReport {
    /// Every Nav reproduced within the tolerance, the streams matched to the end, the acks agree.
    pub fn reproduced(&self) -> bool {
        self.nav_beyond_tolerance == 0 && self.diverged.is_none() && self.ack_mismatches == 0 && self.nav_compared > 0
    }
}

/// `|a - b| / max(|b|, floor)`; 0 for equal values (infinities and NaN included), infinite when
/// only one of them is finite.
pub fn rel_diff(replayed: f32, recorded: f32, floor: f64) -> (f64, f64) {
    let (a, b) = (f64::from(replayed), f64::from(recorded));
    if a == b || (a.is_nan() && b.is_nan()) {
        return (0.0, 0.0);
    }
    if !(a.is_finite() && b.is_finite()) {
        return (f64::INFINITY, f64::INFINITY);
    }
    let abs = (a - b).abs();
    (abs, abs / b.abs().max(floor))
}

/// Read and replay a recording file.
pub fn replay_file(path: &Path, tolerance_rel: f64) -> Result<ReplayReport> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let loaded = read_bytes(&bytes).with_context(|| format!("{} cannot be replayed", path.display()))?;
    replay_loaded(&loaded, tolerance_rel).with_context(|| format!("{} cannot be replayed", path.display()))
}

/// Replay a recording read into memory.
pub fn replay_loaded(loaded: &Loaded, tolerance_rel: f64) -> Result<ReplayReport> {
    if tolerance_rel.is_nan() || tolerance_rel < 0.0 {
        bail!("the tolerance must be a number >= 0, got {tolerance_rel}");
    }
    let mut limitations = Vec::new();
    for d in &loaded.damage {
        if d.reason.starts_with("truncated final chunk") {
            limitations.push(format!(
                "the recording was cut short ({} bytes at offset {} lost); the replay covers what is there",
                d.len, d.offset
            ));
        } else {
            bail!(
                "the recording is damaged at offset {} ({} bytes: {}): the samples in it are lost, so the estimator's inputs are incomplete",
                d.offset,
                d.len,
                d.reason
            );
        }
    }
    let session = Session::decode(loaded, None);
    if let Some(c) = session.corrupt.first() {
        bail!(
            "{} uplink frames are corrupt (first: {}): the samples they carried are lost, so the estimator's inputs are incomplete",
            session.corrupt.len(),
            c.item
        );
    }
    if let Some(c) = session.incompatible.first() {
        bail!("the recording holds an incompatible boot message ({}): another firmware protocol", c.item);
    }
    let msgs: Vec<Uplink> = session.messages.iter().map(|m| m.item).collect();
    let Some(first) = msgs.first() else { bail!("the recording holds no uplink telemetry") };
    if !matches!(first, Uplink::Boot(_)) {
        bail!(
            "the recording does not start at the firmware's boot (first message: {} at {:?} us, no Boot before it): the replay needs the whole run from reset",
            first.kind(),
            first.t_us()
        );
    }
    // One boot only: a second one is a reboot (the replay stops there).
    let mut end = msgs.len();
    if let Some(k) = msgs.iter().skip(1).position(|m| matches!(m, Uplink::Boot(_))) {
        end = k + 1;
        limitations.push(format!("the firmware rebooted after {} messages (a second Boot); the replay covers the first run only", end));
    }
    let msgs = &msgs[..end];
    if let Some(f) = msgs.iter().find_map(|m| match m {
        Uplink::Fault(f) if f.kind == FaultKind::TelemetryDropped => Some(*f),
        _ => None,
    }) {
        bail!(
            "the firmware dropped {} telemetry frames (reported at {} us): raw samples are missing, so the estimator's inputs are incomplete",
            f.count,
            f.t_us
        );
    }
    if !msgs.iter().any(|m| matches!(m, Uplink::Raw(_))) {
        bail!("the recording holds no raw samples: raw streaming was off (SetConfig StreamRaw) or the board ran without sensors");
    }
    if !msgs.iter().any(|m| matches!(m, Uplink::Nav(_))) {
        bail!("the recording holds no Nav solution to compare");
    }
    let boot = boot_commands(&session.meta.board_args);
    let seq0_acks = msgs.iter().filter(|m| matches!(m, Uplink::Ack(a) if a.seq == 0)).count();
    let seq0_down = session.downlink.iter().filter(|d| d.item.seq == 0).count();
    if seq0_acks > boot.len() + seq0_down {
        bail!(
            "the firmware acknowledged {seq0_acks} seq-0 commands but the recording names {} (start arguments {:?} in its metadata): it does not say how the board was started (recorded by an older subnav?)",
            boot.len() + seq0_down,
            session.meta.board_args
        );
    }
    run(msgs, boot, &session.downlink.iter().map(|d| d.item).collect::<Vec<_>>(), tolerance_rel, limitations)
}

/// The shared state of the replay: the recorded stream and its cursor, the comparison.
struct State<'a> {
    rec: &'a [Uplink],
    i: usize,
    dec: FrameDecoder<MAX_UPLINK_FRAME>,
    report: ReplayReport,
    nav_index: usize,
    tolerance: f64,
    /// Latest recorded fault kind per source (the kind a failed read is given).
    fault_kinds: Vec<(FaultSource, FaultKind)>,
}

impl State<'_> {
    /// The next recorded message that is not a fault report.
    fn peek(&self) -> Option<&Uplink> {
        self.rec.get(self.i..)?.iter().find(|m| !matches!(m, Uplink::Fault(_)))
    }

    fn take_fault(&mut self) {
        if let Some(Uplink::Fault(f)) = self.rec.get(self.i) {
            match self.fault_kinds.iter_mut().find(|e| e.0 == f.source) {
                Some(e) => e.1 = f.kind,
                None => self.fault_kinds.push((f.source, f.kind)),
            }
        }
        self.i += 1;
    }

    fn fault_for(&self, source: FaultSource) -> SensorFault {
        // A reported fault for this source coming next gives the kind; else the last one seen.
        let next = self.rec.get(self.i..).unwrap_or(&[]).iter().take_while(|m| matches!(m, Uplink::Fault(_))).find_map(|m| match m {
            Uplink::Fault(f) if f.source == source => Some(f.kind),
            _ => None,
        });
        let last = self.fault_kinds.iter().find(|e| e.0 == source).map(|e| e.1);
        SensorFault { source, kind: next.or(last).unwrap_or(FaultKind::BusTimeout) }
    }

    fn diverge(&mut self, why: String) {
        if self.report.diverged.is_none() {
            self.report.diverged = Some(why);
        }
    }

    fn on_produced(&mut self, m: Uplink) {
        loop {
            let Some(r) = self.rec.get(self.i).copied() else { return }; // past the recording's end
            match (&m, &r) {
                (Uplink::Fault(_), Uplink::Fault(_)) => {
                    self.take_fault();
                    return;
                }
                (Uplink::Fault(_), _) => {
                    self.report.faults_extra += 1;
                    return;
                }
                (_, Uplink::Fault(_)) => {
                    self.report.faults_missing += 1;
                    self.take_fault();
                }
                (Uplink::Nav(a), Uplink::Nav(b)) => {
                    self.compare_nav(a, b);
                    self.nav_index += 1;
                    self.i += 1;
                    return;
                }
                (Uplink::Ack(a), Uplink::Ack(b)) => {
                    if a != b {
                        self.report.ack_mismatches += 1;
                    }
                    self.i += 1;
                    return;
                }
                (Uplink::Compass(a), Uplink::Compass(b)) => {
                    self.report.compass_compared += 1;
                    if !same_compass(a, b) {
                        self.report.compass_differ += 1;
                    }
                    self.i += 1;
                    return;
                }
                (a, b) if a.kind() == b.kind() => {
                    self.i += 1;
                    return;
                }
                (a, b) => {
                    let why = format!(
                        "at recorded message {} the firmware sent {} (t {:?} us) but the replay produced {} (t {:?} us)",
                        self.i,
                        b.kind(),
                        b.t_us(),
                        a.kind(),
                        a.t_us()
                    );
                    self.diverge(why);
                    return;
                }
            }
        }
    }

    fn compare_nav(&mut self, a: &NavSolution, b: &NavSolution) {
        let r = &mut self.report;
        r.nav_compared += 1;
        let tol = self.tolerance;
        let mut first: Option<NavMismatch> = None;
        let mut beyond = false;
        let mut note = |field: String, ra: String, rb: String, rel: f64| {
            if first.is_none() {
                first = Some(NavMismatch { index: self.nav_index, t_us: b.t_us, field, replayed: ra, recorded: rb, rel });
            }
        };
        if a.t_us != b.t_us {
            beyond = true;
            note("t_us".into(), a.t_us.to_string(), b.t_us.to_string(), f64::INFINITY);
        }
        if a.mode != b.mode {
            beyond = true;
            note("mode".into(), format!("{:?}", a.mode), format!("{:?}", b.mode), f64::INFINITY);
        }
        let groups: [FieldGroup; 6] = [
            ("pos_ned_m", &a.pos_ned_m, &b.pos_ned_m, FLOOR_POSITION_M, 0),
            ("vel_ned_mps", &a.vel_ned_mps, &b.vel_ned_mps, FLOOR_VELOCITY_MPS, 1),
            ("att_nb_wxyz", &a.att_nb_wxyz, &b.att_nb_wxyz, FLOOR_ATTITUDE, 2),
            ("sigma_pos_m", &a.sigma_pos_m, &b.sigma_pos_m, FLOOR_SIGMA, 3),
            ("sigma_vel_mps", &a.sigma_vel_mps, &b.sigma_vel_mps, FLOOR_SIGMA, 3),
            ("sigma_att_rad", &a.sigma_att_rad, &b.sigma_att_rad, FLOOR_SIGMA, 3),
        ];
        for (name, va, vb, floor, gi) in groups {
            let g = match gi {
                0 => &mut r.position,
                1 => &mut r.velocity,
                2 => &mut r.attitude,
                _ => &mut r.sigmas,
            };
            for (k, (x, y)) in va.iter().zip(vb).enumerate() {
                let (abs, rel) = rel_diff(*x, *y, floor);
                g.max_abs = g.max_abs.max(abs);
                g.max_rel = g.max_rel.max(rel);
                if rel > tol {
                    g.beyond_tolerance += 1;
                    beyond = true;
                    note(format!("{name}[{k}]"), x.to_string(), y.to_string(), rel);
                }
            }
        }
        if nav_bits(a) == nav_bits(b) {
            r.nav_identical += 1;
        }
        if beyond {
            r.nav_beyond_tolerance += 1;
            if r.first_mismatch.is_none() {
                r.first_mismatch = first;
            }
        }
    }
}

/// Every field's bits (NaN equals itself).
fn nav_bits(n: &NavSolution) -> (u64, subnav_wire::NavMode, Vec<u32>) {
    let values = n.pos_ned_m.iter().chain(&n.vel_ned_mps).chain(&n.att_nb_wxyz).chain(&n.sigma_pos_m).chain(&n.sigma_vel_mps);
    (n.t_us, n.mode, values.chain(&n.sigma_att_rad).map(|v| v.to_bits()).collect())
}

/// Bit for bit (a NaN field, e.g. the sun's position without a time, equals itself).
fn same_compass(a: &CompassReport, b: &CompassReport) -> bool {
    let bits = |c: &CompassReport| {
        (
            c.t_us,
            c.heading_rad.map(f32::to_bits),
            c.sigma_heading_rad.to_bits(),
            c.sun_rel_azimuth_rad.to_bits(),
            c.sun_elevation_rad.to_bits(),
            c.no_fix_reason,
            c.units_used,
        )
    };
    bits(a) == bits(b)
}

/// (name, replayed, recorded, relative floor, report group: 0 position, 1 velocity, 2 attitude, 3 sigmas).
type FieldGroup<'n> = (&'static str, &'n [f32], &'n [f32], f64, usize);

struct Sink<'s, 'a>(&'s RefCell<State<'a>>);

impl TelemetrySink for Sink<'_, '_> {
    fn write_frame(&mut self, frame: &[u8]) -> bool {
        let mut st = self.0.borrow_mut();
        for &b in frame {
            match st.dec.push::<Uplink>(b) {
                Decoded::Message(m) => st.on_produced(m),
                Decoded::Corrupt(e) => st.diverge(format!("the replayed firmware wrote a frame it cannot decode ({e:?})")),
                Decoded::Pending => {}
            }
        }
        true
    }
}

/// Serves the recorded raw samples (see the module doc).
struct Suite<'s, 'a>(&'s RefCell<State<'a>>);

impl SensorSuite for Suite<'_, '_> {
    fn read_imu(&mut self, t_us: u64) -> Result<ImuSample, SensorFault> {
        let mut st = self.0.borrow_mut();
        match st.peek() {
            Some(Uplink::Raw(RawSample::Imu(s))) if s.t_us == t_us => {
                let s = *s;
                st.report.raw_samples += 1;
                Ok(s)
            }
            _ => Err(st.fault_for(FaultSource::Imu)),
        }
    }
    fn read_polarization(&mut self, t_us: u64, unit: u8) -> Result<[i16; 4], SensorFault> {
        let mut st = self.0.borrow_mut();
        match st.peek() {
            Some(Uplink::Raw(RawSample::Polarization(p))) if p.t_us == t_us && p.unit == unit => {
                let c = p.counts;
                st.report.raw_samples += 1;
                Ok(c)
            }
            _ => Err(st.fault_for(FaultSource::Polarization { unit })),
        }
    }
    fn read_depth(&mut self, _t_us: u64, _water_density_kgm3: f32) -> Result<DepthSample, SensorFault> {
        // The sample carries its conversion time, not the read's: the stream order places it.
        let mut st = self.0.borrow_mut();
        match st.peek() {
            Some(Uplink::Raw(RawSample::Depth(d))) => {
                let d = *d;
                st.report.raw_samples += 1;
                Ok(d)
            }
            _ => Err(st.fault_for(FaultSource::Depth)),
        }
    }
    fn trigger_camera(&mut self, t_us: u64) -> Result<bool, SensorFault> {
        // The recorded head had a camera when it announced a frame at this tick.
        let st = self.0.borrow();
        Ok(matches!(st.peek(), Some(Uplink::Trigger(t)) if t.t_us == t_us))
    }
    fn poll_dvl(&mut self, t_us: u64) -> Result<Option<DvlSample>, SensorFault> {
        // A report completed at this tick; sentences the firmware refused (malformed, bad
        // checksum) never reached the estimator and are not replayed (their faults match loosely).
        let mut st = self.0.borrow_mut();
        match st.peek() {
            Some(Uplink::Raw(RawSample::Dvl(d))) if d.rx_us == t_us => {
                let d = *d;
                st.report.raw_samples += 1;
                Ok(Some(d))
            }
            _ => Ok(None),
        }
    }
}

/// The recording as a board (see the module doc): its clock is the replay's tick, its downlink
/// the recorded commands (each delivered as its frame at the tick whose recorded stream continues
/// with its `Ack`), its sensors and sink the recorded stream; no store, no kept memory.
struct ReplayBoard<'s, 'a> {
    t_us: u64,
    state: &'s RefCell<State<'a>>,
    /// The seq-0 start commands, then the recording's downlink (taken when delivered).
    boot: VecDeque<Command>,
    down: Vec<Option<Downlink>>,
    /// The rest of the frame being delivered.
    pending: VecDeque<u8>,
    last_seq: Option<u16>,
    suite: Suite<'s, 'a>,
    sink: Sink<'s, 'a>,
    store: NoStore,
    /// Why the replay stops (a limitation) or cannot go on (an error).
    stop: Option<String>,
    error: Option<String>,
}

impl<'s, 'a> BoardIo for ReplayBoard<'s, 'a> {
    type Sensors = Suite<'s, 'a>;
    type Sink = Sink<'s, 'a>;
    fn now_us(&mut self) -> u64 {
        self.t_us
    }
    fn read_downlink(&mut self, t_us: u64, buf: &mut [u8]) -> usize {
        if self.pending.is_empty() {
            // Commands whose Ack comes next were handled at the start of this tick.
            let next = self.state.borrow().peek().copied();
            let Some(Uplink::Ack(ack)) = next else { return 0 };
            let cmd = if ack.seq == 0 && !self.boot.is_empty() {
                self.boot.pop_front().map(|c| Downlink { seq: 0, command: c })
            } else {
                self.down.iter_mut().find(|d| d.is_some_and(|d| d.seq == ack.seq)).and_then(Option::take)
            };
            let Some(cmd) = cmd else {
                self.error = Some(format!(
                    "the firmware acknowledged command seq {} at about {t_us} us but the recording's downlink holds no such command",
                    ack.seq
                ));
                return 0;
            };
            let mut frame = [0u8; MAX_DOWNLINK_FRAME];
            match subnav_wire::encode(&cmd, &mut frame) {
                Ok(f) => self.pending.extend(f.iter()),
                Err(e) => {
                    self.error = Some(format!("command seq {} cannot be framed again ({e:?})", cmd.seq));
                    return 0;
                }
            }
            self.last_seq = Some(cmd.seq);
            self.state.borrow_mut().report.commands_applied += 1;
        }
        let n = buf.len().min(self.pending.len());
        for (dst, src) in buf.iter_mut().zip(self.pending.drain(..n)) {
            *dst = src;
        }
        n
    }
    fn parts(&mut self) -> BoardParts<'_, Self::Sensors, Self::Sink> {
        BoardParts { sensors: Some(&mut self.suite), store: &mut self.store, warm: None, sink: &mut self.sink }
    }
    fn halt(&mut self, app: &App) -> bool {
        if self.pending.is_empty() && self.stop.is_none() && !app.config.stream_raw {
            let t_us = self.t_us;
            self.stop = Some(format!(
                "raw streaming was switched off by command seq {} at about {t_us} us; the replay stops there",
                self.last_seq.unwrap_or(0)
            ));
        }
        self.stop.is_some() || self.error.is_some()
    }
    fn reboot(&mut self) {
        let t_us = self.t_us;
        self.stop = Some(format!("the firmware was asked to reboot at {t_us} us; the replay stops there"));
    }
}

fn run(rec: &[Uplink], boot: Vec<Command>, downlink: &[Downlink], tolerance: f64, limitations: Vec<String>) -> Result<ReplayReport> {
    let report = ReplayReport {
        tolerance_rel: tolerance,
        nav_recorded: rec.iter().filter(|m| matches!(m, Uplink::Nav(_))).count(),
        nav_compared: 0,
        nav_identical: 0,
        nav_beyond_tolerance: 0,
        position: GroupDiff::default(),
        velocity: GroupDiff::default(),
        attitude: GroupDiff::default(),
        sigmas: GroupDiff::default(),
        first_mismatch: None,
        raw_samples: 0,
        commands_applied: 0,
        ack_mismatches: 0,
        compass_differ: 0,
        compass_compared: 0,
        faults_extra: 0,
        faults_missing: 0,
        commands_unacked: 0,
        replayed_to_us: 0,
        diverged: None,
        limitations,
    };
    let state = RefCell::new(State { rec, i: 0, dec: FrameDecoder::new(), report, nav_index: 0, tolerance, fault_kinds: Vec::new() });
    let board = match rec.first() {
        Some(Uplink::Boot(b)) => b.board,
        _ => Board::QemuMps2An386,
    };
    let mut app = App::new(board);
    let last_us = rec.iter().filter_map(|m| m.t_us()).max().unwrap_or(0);
    let mut board = ReplayBoard {
        t_us: 0,
        state: &state,
        boot: boot.into(),
        down: downlink.iter().copied().map(Some).collect(),
        pending: VecDeque::new(),
        last_seq: None,
        suite: Suite(&state),
        sink: Sink(&state),
        store: NoStore,
        stop: None,
        error: None,
    };
    app.boot(0, &mut board.sink);
    // The boards' loop, on the replay's logical time: one tick per pass.
    let mut board_loop = BoardLoop::new(CatchUp::EveryTick);
    let mut t_us = 0u64;
    while state.borrow().report.diverged.is_none() {
        if state.borrow().peek().is_none() {
            break; // the recording ends here (fault reports left over do not count)
        }
        if t_us > last_us.saturating_add(1_000_000) {
            let st = state.borrow();
            let m = &rec[st.i.min(rec.len() - 1)];
            let why = format!(
                "the replay ran 1 s past the recording's last message without reproducing recorded message {} ({} at {:?} us)",
                st.i,
                m.kind(),
                m.t_us()
            );
            drop(st);
            state.borrow_mut().diverge(why);
            break;
        }
        board.t_us = t_us;
        let end = board_loop.pass(&mut app, &mut board);
        if let Some(e) = board.error.take() {
            bail!(e);
        }
        if end == PassEnd::Halted {
            break; // stopped after a command, before the tick's sensors
        }
        state.borrow_mut().report.replayed_to_us = t_us;
        if end == PassEnd::Reboot {
            break;
        }
        t_us += 1000;
    }
    let ReplayBoard { down, stop, .. } = board;
    let mut report = state.into_inner().report;
    report.commands_unacked = down.iter().filter(|d| d.is_some()).count();
    if let Some(s) = stop {
        report.limitations.push(s);
    }
    Ok(report)
}
