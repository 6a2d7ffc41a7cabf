//! The application: fixed-rate scheduling of the sensor-head tasks, downlink command handling
//! and telemetry. The board calls [`App::boot`] once, then [`App::poll`] whenever it wakes
//! (timer tick or received bytes) with its monotonic time.

use subnav_shared::wire::{
    Board, Command, CommandAck, ConfigItem, Decoded, Downlink, Fault, FaultKind, FaultSource,
    FilterHealth, FrameDecoder, MAX_DOWNLINK_FRAME, NavMode, NavSolution, Refusal, Uplink,
    boot_message,
};

use crate::telemetry::{Telemetry, TelemetrySink};
use crate::{FIRMWARE_VERSION, info, warn};

/// Run-time configuration (changed by downlink `SetConfig`, range-checked).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AppConfig {
    pub nav_rate_hz: u8,
    pub stream_raw: bool,
    pub water_density_kgm3: f32,
    pub origin: Option<(f64, f64, f32)>,
}

impl Default for AppConfig {
    fn default() -> Self {
        Self { nav_rate_hz: 10, stream_raw: true, water_density_kgm3: 1025.0, origin: None }
    }
}

/// What the board must do after a poll.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BoardRequest {
    None,
    /// Reboot (after the pending telemetry has been flushed).
    Reboot,
}

/// A periodic task: due every `period_us`, catching up without bursts after a stall.
#[derive(Debug, Clone, Copy)]
struct Periodic {
    period_us: u64,
    next_us: u64,
}

impl Periodic {
    const fn new(period_us: u64) -> Self {
        Self { period_us, next_us: 0 }
    }
    fn due(&mut self, now_us: u64) -> bool {
        if now_us < self.next_us {
            return false;
        }
        self.next_us = self.next_us.saturating_add(self.period_us);
        if self.next_us <= now_us {
            // Overran by more than one period: skip ahead instead of bursting.
            self.next_us = now_us.saturating_add(self.period_us);
        }
        true
    }
}

pub struct App {
    board: Board,
    pub config: AppConfig,
    telemetry: Telemetry,
    downlink: FrameDecoder<MAX_DOWNLINK_FRAME>,
    nav_task: Periodic,
    health_task: Periodic,
    /// UTC offset: utc_unix_us = t_us + utc_offset_us, once the host has set the time.
    pub utc_offset_us: Option<i64>,
    corrupt_downlink: u32,
    reported_drops: u32,
    cpu_load_permille: u16,
    request: BoardRequest,
}

impl App {
    pub fn new(board: Board) -> Self {
        let config = AppConfig::default();
        Self {
            board,
            config,
            telemetry: Telemetry::new(),
            downlink: FrameDecoder::new(),
            nav_task: Periodic::new(1_000_000 / config.nav_rate_hz as u64),
            health_task: Periodic::new(1_000_000),
            utc_offset_us: None,
            corrupt_downlink: 0,
            reported_drops: 0,
            cpu_load_permille: 0,
            request: BoardRequest::None,
        }
    }

    /// Send the boot message. Call once after reset, before anything else.
    pub fn boot(&mut self, now_us: u64, sink: &mut impl TelemetrySink) {
        let boot = boot_message(self.board, FIRMWARE_VERSION, now_us);
        info!("subnav firmware {=u8}.{=u8}.{=u8} booting, protocol {=u16}", FIRMWARE_VERSION[0], FIRMWARE_VERSION[1], FIRMWARE_VERSION[2], boot.protocol_version);
        self.telemetry.send(&Uplink::Boot(boot), sink);
    }

    /// The board's measured CPU load over its last period (per mille), reported in health.
    pub fn set_cpu_load(&mut self, permille: u16) {
        self.cpu_load_permille = permille.min(1000);
    }

    /// Feed bytes received on the downlink.
    pub fn on_downlink_bytes(&mut self, now_us: u64, bytes: &[u8], sink: &mut impl TelemetrySink) {
        for &b in bytes {
            match self.downlink.push::<Downlink>(b) {
                Decoded::Pending => {}
                Decoded::Message(cmd) => self.handle_command(now_us, cmd, sink),
                Decoded::Corrupt(_) => {
                    self.corrupt_downlink = self.corrupt_downlink.wrapping_add(1);
                    warn!("corrupt downlink frame ({=u32} so far)", self.corrupt_downlink);
                    let fault = Fault { t_us: now_us, source: FaultSource::Link, kind: FaultKind::CorruptFrame, count: self.corrupt_downlink };
                    self.telemetry.send(&Uplink::Fault(fault), sink);
                }
            }
        }
    }

    /// Run whatever tasks are due at `now_us`. Returns what the board must do next.
    pub fn poll(&mut self, now_us: u64, sink: &mut impl TelemetrySink) -> BoardRequest {
        if self.nav_task.due(now_us) {
            // No estimator is wired in yet: the solution says so (mode Uninitialised, infinite
            // sigmas) instead of pretending to navigate.
            let nav = NavSolution {
                t_us: now_us,
                mode: NavMode::Uninitialised,
                pos_ned_m: [0.0; 3],
                vel_ned_mps: [0.0; 3],
                att_nb_wxyz: [1.0, 0.0, 0.0, 0.0],
                sigma_pos_m: [f32::INFINITY; 3],
                sigma_vel_mps: [f32::INFINITY; 3],
                sigma_att_rad: [f32::INFINITY; 3],
            };
            self.telemetry.send(&Uplink::Nav(nav), sink);
        }
        if self.health_task.due(now_us) {
            let health = FilterHealth {
                t_us: now_us,
                nis: [f32::NAN; 4],
                lambda: 1.0,
                q_diag: [0.0; 5],
                r_diag: [0.0; 4],
                pd_repairs: 0,
                gate_rejects: 0,
                nonfinite_rejects: 0,
                cpu_load_permille: self.cpu_load_permille,
            };
            self.telemetry.send(&Uplink::Health(health), sink);
            info!("t={=u64} ms cpu={=u16} permille sent={=u32}", now_us / 1000, self.cpu_load_permille, self.telemetry.sent);
        }
        if self.telemetry.dropped != self.reported_drops {
            self.reported_drops = self.telemetry.dropped;
            let fault = Fault { t_us: now_us, source: FaultSource::Link, kind: FaultKind::TelemetryDropped, count: self.reported_drops };
            self.telemetry.send(&Uplink::Fault(fault), sink);
        }
        core::mem::replace(&mut self.request, BoardRequest::None)
    }

    fn handle_command(&mut self, now_us: u64, cmd: Downlink, sink: &mut impl TelemetrySink) {
        let result = self.apply(cmd.command);
        match result {
            Ok(()) => info!("command {=u16} accepted", cmd.seq),
            Err(_) => warn!("command {=u16} refused", cmd.seq),
        }
        let _ = now_us;
        self.telemetry.send(&Uplink::Ack(CommandAck { seq: cmd.seq, result }), sink);
    }

    fn apply(&mut self, command: Command) -> Result<(), Refusal> {
        match command {
            Command::SetConfig(item) => self.apply_config(item),
            Command::SetTime { t_us, utc_unix_us } => {
                let t = i64::try_from(t_us).map_err(|_| Refusal::OutOfRange)?;
                // 2000-01-01 .. 2200-01-01: anything else is a host bug.
                if !(946_684_800_000_000..=7_258_118_400_000_000).contains(&utc_unix_us) {
                    return Err(Refusal::OutOfRange);
                }
                self.utc_offset_us = Some(utc_unix_us - t);
                Ok(())
            }
            Command::PositionFix { pos_ned_m, cov_ned_m2, .. } => {
                if !pos_ned_m.iter().chain(cov_ned_m2.iter()).all(|v| v.is_finite()) {
                    return Err(Refusal::NotFinite);
                }
                if !covariance_is_pd(&cov_ned_m2) {
                    return Err(Refusal::NotPositiveDefinite);
                }
                // Valid, but this build has no estimator to apply it to.
                Err(Refusal::NotSupported)
            }
            Command::ResetFilter => Ok(()),
            Command::Reboot => {
                self.request = BoardRequest::Reboot;
                Ok(())
            }
        }
    }

    fn apply_config(&mut self, item: ConfigItem) -> Result<(), Refusal> {
        match item {
            ConfigItem::NavRateHz(hz) => {
                if !(1..=50).contains(&hz) {
                    return Err(Refusal::OutOfRange);
                }
                self.config.nav_rate_hz = hz;
                self.nav_task.period_us = 1_000_000 / u64::from(hz);
            }
            ConfigItem::StreamRaw(on) => self.config.stream_raw = on,
            ConfigItem::Origin { lat_rad, lon_rad, alt_m } => {
                if !(lat_rad.is_finite() && lon_rad.is_finite() && alt_m.is_finite()) {
                    return Err(Refusal::NotFinite);
                }
                if lat_rad.abs() > core::f64::consts::FRAC_PI_2 || lon_rad.abs() > core::f64::consts::PI || !(-12_000.0..=10_000.0).contains(&alt_m) {
                    return Err(Refusal::OutOfRange);
                }
                self.config.origin = Some((lat_rad, lon_rad, alt_m));
            }
            ConfigItem::WaterDensityKgm3(rho) => {
                if !rho.is_finite() {
                    return Err(Refusal::NotFinite);
                }
                if !(990.0..=1050.0).contains(&rho) {
                    return Err(Refusal::OutOfRange);
                }
                self.config.water_density_kgm3 = rho;
            }
        }
        Ok(())
    }
}

/// Positive definiteness of a symmetric 3x3 given as its upper triangle (xx, xy, xz, yy, yz, zz),
/// by Sylvester's criterion (leading principal minors > 0).
fn covariance_is_pd(c: &[f32; 6]) -> bool {
    let [xx, xy, xz, yy, yz, zz] = c.map(f64::from);
    let m1 = xx;
    let m2 = xx * yy - xy * xy;
    let m3 = xx * (yy * zz - yz * yz) - xy * (xy * zz - yz * xz) + xz * (xy * yz - yy * xz);
    m1 > 0.0 && m2 > 0.0 && m3 > 0.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use subnav_shared::wire::{self, MAX_DOWNLINK_FRAME, MAX_UPLINK_FRAME};

    fn decode_all(bytes: &[u8]) -> Vec<Uplink> {
        let mut dec = FrameDecoder::<MAX_UPLINK_FRAME>::new();
        bytes.iter().filter_map(|b| match dec.push::<Uplink>(*b) {
            Decoded::Message(m) => Some(m),
            Decoded::Corrupt(e) => panic!("firmware emitted a corrupt frame: {e}"),
            Decoded::Pending => None,
        }).collect()
    }

    fn cmd(seq: u16, command: Command) -> Vec<u8> {
        let mut buf = [0u8; MAX_DOWNLINK_FRAME];
        wire::encode(&Downlink { seq, command }, &mut buf).unwrap().to_vec()
    }

    #[test]
    fn boots_then_streams_nav_at_the_configured_rate() {
        let mut app = App::new(Board::QemuMps2An386);
        let mut out = Vec::new();
        app.boot(0, &mut out);
        for ms in 0..=2000u64 {
            app.poll(ms * 1000, &mut out);
        }
        let msgs = decode_all(&out);
        assert!(matches!(msgs[0], Uplink::Boot(b) if b.compatibility() == wire::Compatibility::Compatible));
        let navs: Vec<u64> = msgs.iter().filter_map(|m| if let Uplink::Nav(n) = m { Some(n.t_us) } else { None }).collect();
        assert_eq!(navs.len(), 21, "10 Hz for 2 s, both ends included");
        assert!(navs.windows(2).all(|w| w[1] - w[0] == 100_000));
        assert_eq!(msgs.iter().filter(|m| matches!(m, Uplink::Health(_))).count(), 3);
    }

    #[test]
    fn config_is_range_checked_and_acknowledged() {
        let mut app = App::new(Board::QemuMps2An386);
        let mut out = Vec::new();
        let mut bytes = cmd(1, Command::SetConfig(ConfigItem::NavRateHz(0)));
        bytes.extend(cmd(2, Command::SetConfig(ConfigItem::NavRateHz(20))));
        bytes.extend(cmd(3, Command::SetConfig(ConfigItem::WaterDensityKgm3(f32::NAN))));
        bytes.extend(cmd(4, Command::PositionFix { t_us: 0, pos_ned_m: [0.0; 3], cov_ned_m2: [1.0, 2.0, 0.0, 1.0, 0.0, 1.0] }));
        bytes.extend(cmd(5, Command::SetTime { t_us: 1_000, utc_unix_us: 1_790_000_000_000_000 }));
        app.on_downlink_bytes(0, &bytes, &mut out);
        let acks: Vec<CommandAck> = decode_all(&out).into_iter().filter_map(|m| if let Uplink::Ack(a) = m { Some(a) } else { None }).collect();
        assert_eq!(acks, vec![
            CommandAck { seq: 1, result: Err(Refusal::OutOfRange) },
            CommandAck { seq: 2, result: Ok(()) },
            CommandAck { seq: 3, result: Err(Refusal::NotFinite) },
            CommandAck { seq: 4, result: Err(Refusal::NotPositiveDefinite) },
            CommandAck { seq: 5, result: Ok(()) },
        ]);
        assert_eq!(app.config.nav_rate_hz, 20);
        assert_eq!(app.utc_offset_us, Some(1_790_000_000_000_000 - 1_000));
    }

    #[test]
    fn corrupt_downlink_is_reported_and_next_command_still_works() {
        let mut app = App::new(Board::QemuMps2An386);
        let mut out = Vec::new();
        let mut bytes = vec![0x11, 0x22, 0x33, 0x00];
        bytes.extend(cmd(9, Command::ResetFilter));
        app.on_downlink_bytes(5, &bytes, &mut out);
        let msgs = decode_all(&out);
        assert!(matches!(msgs[0], Uplink::Fault(Fault { kind: FaultKind::CorruptFrame, count: 1, .. })));
        assert_eq!(msgs[1], Uplink::Ack(CommandAck { seq: 9, result: Ok(()) }));
    }

    #[test]
    fn full_sink_drops_are_counted_and_reported() {
        struct Full(bool);
        impl TelemetrySink for Full {
            fn write_frame(&mut self, _: &[u8]) -> bool {
                self.0
            }
        }
        let mut app = App::new(Board::QemuMps2An386);
        let mut sink = Full(false);
        app.poll(0, &mut sink);
        assert!(app.telemetry.dropped >= 2);
        let mut out = Vec::new();
        app.poll(100_000, &mut out);
        let msgs = decode_all(&out);
        assert!(msgs.iter().any(|m| matches!(m, Uplink::Fault(Fault { kind: FaultKind::TelemetryDropped, .. }))));
    }

    #[test]
    fn sylvester() {
        assert!(covariance_is_pd(&[1.0, 0.0, 0.0, 1.0, 0.0, 1.0]));
        assert!(!covariance_is_pd(&[1.0, 0.0, 0.0, 1.0, 0.0, 0.0]));
        assert!(!covariance_is_pd(&[-1.0, 0.0, 0.0, 1.0, 0.0, 1.0]));
    }
}
