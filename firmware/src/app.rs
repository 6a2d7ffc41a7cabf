//! The application: fixed-rate scheduling of the sensor-head tasks, the store's records at boot,
//! and telemetry; downlink commands and their duplicate filter are in `app::commands`. The board
//! calls [`App::boot`] (or [`App::boot_with_store`]) once, then runs the board loop
//! (`crate::board_loop`), which calls the rest in its order on every 1-ms tick.
//!
//! Rates: IMU 200 Hz, polarization 10 Hz, depth 10 Hz (`subnav_core::head`), the DVL at its own
//! rate (2-15 Hz, polled every tick), navigation telemetry `nav_rate_hz` (configurable 1..=50),
//! health 1 Hz, the camera trigger `head::CAMERA_RATE_HZ` (when the suite has a camera: each
//! pulse is announced by an `Uplink::Trigger` with its time and frame number). A failed read is counted and reported as a fault (rate-limited) and the
//! estimator goes on with the other sensors.
//!
//! Time of validity: DVL reports and position fixes arrive after the instant they describe; the
//! estimator fuses each at that instant (the filter keeps a short history). A fix older than
//! the history or stamped too far ahead is refused with its reason in the `Ack`; a DVL report
//! refused for its time is a counted `TooOld` / `FromFuture` fault.

use subnav_wire::{
    Board, Decoded, Downlink, Fault, FaultKind, FaultSource, FilterHealth, FrameDecoder, MAX_DOWNLINK_FRAME, Refusal, ResetCause, Uplink,
    boot_message,
};

use subnav_core::ephemeris::Observer;
use subnav_core::head;
use subnav_core::nav::NavError;
use subnav_wire::{CalibrationInUse, CameraTrigger, DvlSample, PolarizationSample, RawSample, Record, RecordKey, StoreStatus};

use crate::calibration;
use crate::config::AppConfig;
use crate::store::{RecordStore, StoreError};

mod commands;
use commands::{ACK_EMPTY, RecentCommands, StoreJob};
pub use commands::{RECENT_COMMANDS, STORE_QUEUE, StoreCommand};

use crate::estimator::Estimator;
use crate::estimator::warm::{WARM_RECORD_BYTES, WARM_RECORD_PERIOD_US, WarmStart, WarmStartError};
use crate::sensors::{FaultLog, SensorFault, SensorSuite};
use crate::telemetry::{Telemetry, TelemetrySink};
use crate::{FIRMWARE_VERSION, info, warn};

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
    estimator: Estimator,
    imu_task: Periodic,
    polarization_task: Periodic,
    depth_task: Periodic,
    dvl_task: Periodic,
    camera_task: Periodic,
    /// Camera frames triggered since boot (the next frame's number).
    camera_frames: u32,
    faults: FaultLog,
    boot_us: u64,
    /// Whether a working store is attached (store commands are refused without one).
    store: StoreState,
    /// Store commands waiting for the board's next [`App::service_store`], acknowledged then:
    /// one record to save (it is the large one: one slot keeps the `App`, which sits in the
    /// board loop's frame at the stack peak, small) and a few reads and erases.
    pending_save: Option<(u16, Record)>,
    store_jobs: heapless::Deque<StoreJob, STORE_QUEUE>,
    /// The run configuration changed and is not stored yet.
    config_dirty: bool,
    /// Why the board started, reported in `Boot`.
    reset_cause: ResetCause,
    /// The last sequenced commands received (see [`RecentCommands`]).
    recent: RecentCommands,
    /// Warm start (`estimator::warm`): armed at boot from a valid record, holding the bound of
    /// the reset's duration (s; negative: not armed; a plain number, not an `Option`, so the
    /// `App` is still built in place), started by [`App::service_warm_record`] once the IMU has
    /// levelled; and the period of the record the board keeps.
    warm_armed_gap_s: f32,
    warm_task: Periodic,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum StoreState {
    Absent,
    Working,
    Failed,
}

/// Every key the head knows, in the order they are loaded at boot.
pub fn record_keys() -> impl Iterator<Item = RecordKey> {
    [RecordKey::RunConfig, RecordKey::Imu, RecordKey::DvlMounting]
        .into_iter()
        .chain((0..head::POLARIZATION_UNITS as u8).map(|unit| RecordKey::Polarization { unit }))
}

/// After boot, "no data yet" from a sensor is not reported as a fault for this long (µs).
pub const SENSOR_WARMUP_US: u64 = 200_000;

/// DVL reports taken per poll at most (the DVL sends at most 15 a second).
const DVL_REPORTS_PER_POLL: usize = 4;

/// Serial instruments (the DVL; on the simulated boards also the modem that brings the host's
/// fixes) are polled this often, µs. The DVL driver stamps a report's time of validity from the
/// poll that completes it, so this is also the bound of that stamp's error (at 1 m/s and a
/// 0.1 rad/s turn, 5 ms is 0.5 mrad of attitude: far below the DVL's noise). 115200 baud brings
/// 58 bytes in 5 ms: a UART with DMA or a 64-byte FIFO keeps up.
pub const SERIAL_POLL_US: u64 = 5_000;

/// Why the filter refused a sensor's measurement, as a fault kind.
fn fault_kind(e: NavError) -> FaultKind {
    match e {
        NavError::TooOld => FaultKind::TooOld,
        NavError::FromFuture => FaultKind::FromFuture,
        NavError::NonFinite | NavError::BadConfig | NavError::BadTime | NavError::Filter(_) => FaultKind::NonFinite,
    }
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
            estimator: Estimator::default(),
            imu_task: Periodic::new(1_000_000 / head::IMU_RATE_HZ as u64),
            polarization_task: Periodic::new(1_000_000 / head::POLARIZATION_RATE_HZ as u64),
            depth_task: Periodic::new(1_000_000 / head::DEPTH_RATE_HZ as u64),
            dvl_task: Periodic::new(SERIAL_POLL_US),
            camera_task: Periodic::new(1_000_000 / head::CAMERA_RATE_HZ as u64),
            camera_frames: 0,
            faults: FaultLog::new(),
            boot_us: 0,
            store: StoreState::Absent,
            pending_save: None,
            store_jobs: heapless::Deque::new(),
            config_dirty: false,
            reset_cause: ResetCause::PowerOn,
            recent: RecentCommands {
                seq: [0; RECENT_COMMANDS],
                digest: [0; RECENT_COMMANDS],
                ack: [ACK_EMPTY; RECENT_COMMANDS],
                next: 0,
                duplicates: 0,
            },
            warm_armed_gap_s: -1.0,
            warm_task: Periodic::new(WARM_RECORD_PERIOD_US),
        }
    }

    /// Duplicate commands received (and not applied again) since boot.
    pub fn duplicate_commands(&self) -> u32 {
        self.recent.duplicates
    }

    /// Why the board started (read from its reset flags before [`App::boot`]; default power-on).
    pub fn set_reset_cause(&mut self, cause: ResetCause) {
        self.reset_cause = cause;
    }

    /// After a reset in motion: arm a warm start from `kept`, the record the board kept across
    /// the reset (see `estimator::warm`), when the reset was a watchdog's, a brown-out or a
    /// commanded reboot (never after a power-on: that memory holds nothing) and the record is
    /// whole and valid; otherwise the head aligns cold, as before. `reset_gap_max_s`: the board's
    /// bound of the time from the head's stop to this boot (a watchdog's two periods). Call after
    /// [`App::set_reset_cause`], before the board loop; the warm start itself happens in
    /// [`App::service_warm_record`] once the IMU has levelled.
    pub fn warm_start_at_boot(&mut self, kept: &[u8], reset_gap_max_s: f32) -> Result<(), WarmStartError> {
        self.warm_armed_gap_s = -1.0;
        if !matches!(self.reset_cause, ResetCause::Watchdog | ResetCause::Brownout | ResetCause::Software) {
            return Err(WarmStartError::NoRecord);
        }
        if !(reset_gap_max_s >= 0.0 && reset_gap_max_s.is_finite()) {
            return Err(WarmStartError::Gap);
        }
        let _record_ms = WarmStart::decode(kept)?.t_us / 1000;
        info!("warm start armed: record of t={=u64} ms, reset gap <= {=f32} s", _record_ms, reset_gap_max_s);
        self.warm_armed_gap_s = reset_gap_max_s;
        Ok(())
    }

    /// Every tick, with the board's memory that survives a reset (at least
    /// `WARM_RECORD_BYTES`): while a warm start is armed, try it from the record there (the gap
    /// bound: the record's period, the reset, the time since boot); otherwise keep the record
    /// there every `WARM_RECORD_PERIOD_US` (zeros while the filter is not running, so an old
    /// record never outlives a filter reset).
    #[inline(never)] // keeps the record's temporaries out of the board loop's stack frame
    pub fn service_warm_record(&mut self, now_us: u64, kept: &mut [u8]) {
        if self.warm_armed_gap_s >= 0.0 {
            let gap_s = WARM_RECORD_PERIOD_US as f32 * 1e-6 + self.warm_armed_gap_s + now_us as f32 * 1e-6;
            match WarmStart::decode(kept).and_then(|rec| self.estimator.warm_start(&rec, gap_s)) {
                Err(WarmStartError::NotYet) => {}
                Ok(()) => {
                    info!("warm started at t={=u64} ms (gap <= {=f32} s)", now_us / 1000, gap_s);
                    self.warm_armed_gap_s = -1.0;
                }
                Err(_e) => {
                    warn!("warm start refused ({=?}): aligning cold", _e);
                    self.warm_armed_gap_s = -1.0;
                }
            }
            return;
        }
        if self.warm_task.due(now_us) {
            if let Some(dst) = kept.get_mut(..WARM_RECORD_BYTES) {
                match self.estimator.warm_start_record(now_us) {
                    Some(rec) => dst.copy_from_slice(&rec.encode()),
                    None => dst.fill(0),
                }
            }
        }
    }

    /// Whether a warm start is armed and not yet done.
    pub fn warm_start_armed(&self) -> bool {
        self.warm_armed_gap_s >= 0.0
    }

    /// The estimator (for inspection in tests and by boards).
    pub fn estimator(&self) -> &Estimator {
        &self.estimator
    }

    /// The estimator, to change its evaluation switches (e.g. `Estimator::set_wave_sigma`).
    pub fn estimator_mut(&mut self) -> &mut Estimator {
        &mut self.estimator
    }

    /// UTC now, if the host has set the time.
    fn utc_unix_us(&self, t_us: u64) -> Option<i64> {
        self.utc_offset_us.and_then(|o| i64::try_from(t_us).ok().map(|t| t.saturating_add(o)))
    }

    fn observer(&self) -> Option<Observer> {
        self.config.origin.map(|(lat, lon, alt)| Observer { lat_rad: lat as f32, lon_rad: lon as f32, height_m: alt })
    }

    fn fault(&mut self, t_us: u64, f: SensorFault, sink: &mut impl TelemetrySink) {
        // No data yet right after boot (first IMU sample, ADC scan, depth conversion) is not a fault.
        if f.kind == FaultKind::BusTimeout && t_us < self.boot_us.saturating_add(SENSOR_WARMUP_US) {
            return;
        }
        if let Some(count) = self.faults.record(t_us, f) {
            warn!("sensor fault at {=u64} us ({=u32} so far)", t_us, count);
            self.telemetry.send(&Uplink::Fault(Fault { t_us, source: f.source, kind: f.kind, count }), sink);
        }
    }

    /// A fault the board itself saw (a receive queue that overflowed, a UART framing error:
    /// `subnav_firmware::uart_queue`): counted and reported like the sensors' own.
    pub fn board_fault(&mut self, t_us: u64, source: FaultSource, kind: FaultKind, sink: &mut impl TelemetrySink) {
        self.fault(t_us, SensorFault { source, kind }, sink);
    }

    /// Read the sensors that are due at `now_us` and run the estimator on them.
    #[inline(never)] // keeps its temporaries out of the board loop's stack frame (see PERFORMANCE.md, stack)
    pub fn sensor_tick(&mut self, now_us: u64, sensors: &mut impl SensorSuite, sink: &mut impl TelemetrySink) {
        sensors.service(now_us);
        if self.imu_task.due(now_us) {
            match sensors.read_imu(now_us) {
                Ok(s) => {
                    if self.config.stream_raw {
                        self.telemetry.send(&Uplink::Raw(RawSample::Imu(s)), sink);
                    }
                    if self.estimator.on_imu(&s).is_err() {
                        self.fault(now_us, SensorFault { source: FaultSource::Imu, kind: FaultKind::NonFinite }, sink);
                    }
                }
                Err(f) => {
                    self.fault(now_us, f, sink);
                    match sensors.take_degraded_imu().filter(|_| f.kind == FaultKind::Stuck) {
                        Some((s, stuck_gyro)) => {
                            if self.estimator.on_imu_degraded(&s, stuck_gyro).is_err() {
                                self.fault(now_us, SensorFault { source: FaultSource::Imu, kind: FaultKind::NonFinite }, sink);
                            }
                        }
                        None => self.estimator.on_imu_unavailable(now_us),
                    }
                }
            }
        }
        if self.depth_task.due(now_us) {
            match sensors.read_depth(now_us, self.config.water_density_kgm3) {
                Ok(d) => {
                    if self.config.stream_raw {
                        self.telemetry.send(&Uplink::Raw(RawSample::Depth(d)), sink);
                    }
                    if self.estimator.on_depth(now_us, d.depth_m).is_err() {
                        self.fault(now_us, SensorFault { source: FaultSource::Depth, kind: FaultKind::NonFinite }, sink);
                    }
                }
                Err(f) => self.fault(now_us, f, sink),
            }
        }
        if self.dvl_task.due(now_us) {
            for _ in 0..DVL_REPORTS_PER_POLL {
                match sensors.poll_dvl(now_us) {
                    Ok(Some(d)) => self.on_dvl(now_us, &d, sink),
                    Ok(None) => break,
                    Err(f) => self.fault(now_us, f, sink),
                }
            }
        }
        if self.camera_task.due(now_us) {
            match sensors.trigger_camera(now_us) {
                Ok(true) => {
                    let trigger = CameraTrigger { t_us: now_us, frame: self.camera_frames };
                    self.camera_frames = self.camera_frames.wrapping_add(1);
                    self.telemetry.send(&Uplink::Trigger(trigger), sink);
                }
                Ok(false) => {}
                Err(f) => self.fault(now_us, f, sink),
            }
        }
        if self.polarization_task.due(now_us) {
            let mut readings: heapless::Vec<(usize, [i16; 4]), { head::POLARIZATION_UNITS }> = heapless::Vec::new();
            for unit in 0..head::POLARIZATION_UNITS {
                match sensors.read_polarization(now_us, unit as u8) {
                    Ok(counts) => {
                        if self.config.stream_raw {
                            let raw = PolarizationSample { t_us: now_us, unit: unit as u8, counts };
                            self.telemetry.send(&Uplink::Raw(RawSample::Polarization(raw)), sink);
                        }
                        let _ = readings.push((unit, counts));
                    }
                    Err(f) => self.fault(now_us, f, sink),
                }
            }
            let dark = occluded_units(&readings);
            if dark != 0 {
                for unit in 0..head::POLARIZATION_UNITS {
                    if dark & (1 << unit) != 0 {
                        let f = SensorFault { source: FaultSource::Polarization { unit: unit as u8 }, kind: FaultKind::Occluded };
                        self.fault(now_us, f, sink);
                    }
                }
                readings.retain(|(u, _)| dark & (1 << u) == 0);
            }
            let utc = self.utc_unix_us(now_us);
            let observer = self.observer();
            let report = self.estimator.on_polarization(now_us, &readings, utc, observer);
            self.telemetry.send(&Uplink::Compass(report), sink);
        }
    }

    fn on_dvl(&mut self, now_us: u64, d: &DvlSample, sink: &mut impl TelemetrySink) {
        if self.config.stream_raw {
            self.telemetry.send(&Uplink::Raw(RawSample::Dvl(*d)), sink);
        }
        if !d.valid {
            self.fault(now_us, SensorFault { source: FaultSource::Dvl, kind: FaultKind::Invalid }, sink);
            return;
        }
        if let Err(e) = self.estimator.on_dvl(d) {
            self.fault(now_us, SensorFault { source: FaultSource::Dvl, kind: fault_kind(e) }, sink);
        }
    }

    /// Send the boot message of a head without a store. Call once after reset, before anything else.
    pub fn boot(&mut self, now_us: u64, sink: &mut impl TelemetrySink) {
        self.send_boot(now_us, CalibrationInUse::NO_STORE, sink);
    }

    /// Load the configuration and calibrations from `store`, then send the boot message saying
    /// which are in use, and a `Store` fault for anything that could not be used. A store that
    /// is damaged beyond repair is erased (defaults in use, reported as `Reformatted`); one that
    /// does not answer leaves the defaults in use and refuses store commands. Call once after
    /// reset, before anything else.
    pub fn boot_with_store(&mut self, now_us: u64, store: &mut dyn RecordStore, sink: &mut impl TelemetrySink) {
        let mut cal = CalibrationInUse::NO_STORE;
        let mut faults: heapless::Vec<FaultKind, 8> = heapless::Vec::new();
        self.store = StoreState::Absent;
        if store.present() {
            self.store = StoreState::Working;
            cal.store = StoreStatus::Empty;
            for key in record_keys() {
                match store.load(key) {
                    Ok(Some(r)) => match self.use_record(&r) {
                        Ok(()) => mark_in_use(&mut cal, key, true),
                        Err(_) => {
                            let _ = faults.push(FaultKind::Malformed);
                        }
                    },
                    Ok(None) => {}
                    Err(StoreError::BadRecord(_)) => {
                        let _ = faults.push(FaultKind::BadCrc);
                    }
                    Err(StoreError::Corrupted) => {
                        let _ = faults.push(FaultKind::BadCrc);
                        self.use_defaults();
                        cal = CalibrationInUse { store: StoreStatus::Reformatted, ..CalibrationInUse::NO_STORE };
                        if let Err(e) = store.format() {
                            let _ = faults.push(e.fault_kind());
                            cal.store = StoreStatus::Failed;
                            self.store = StoreState::Failed;
                        }
                        break;
                    }
                    Err(e) => {
                        let _ = faults.push(e.fault_kind());
                        self.use_defaults();
                        cal = CalibrationInUse { store: StoreStatus::Failed, ..CalibrationInUse::NO_STORE };
                        self.store = StoreState::Failed;
                        break;
                    }
                }
            }
            let any = cal.config_stored || cal.imu_stored || cal.dvl_stored || cal.polarization_units_stored != 0;
            if cal.store == StoreStatus::Empty && any {
                cal.store = StoreStatus::Ok;
            }
        }
        self.send_boot(now_us, cal, sink);
        for kind in faults {
            self.store_fault(now_us, kind, sink);
        }
    }

    fn store_fault(&mut self, now_us: u64, kind: FaultKind, sink: &mut impl TelemetrySink) {
        let f = SensorFault { source: FaultSource::Store, kind };
        if let Some(count) = self.faults.record(now_us, f) {
            warn!("store fault at {=u64} us ({=u32} so far)", now_us, count);
            self.telemetry.send(&Uplink::Fault(Fault { t_us: now_us, source: f.source, kind, count }), sink);
        }
    }

    /// Put a (checked) record in use.
    fn use_record(&mut self, r: &Record) -> Result<(), Refusal> {
        match r {
            Record::RunConfig(c) => {
                let c = calibration::run_config(c)?;
                self.config = c;
                self.nav_task.period_us = 1_000_000 / u64::from(c.nav_rate_hz.max(1));
            }
            Record::Polarization(p) => {
                let m = calibration::unit_model(p)?;
                self.estimator.set_polarization_unit(usize::from(p.unit), Some(m));
            }
            Record::Imu(c) => self.estimator.set_imu_correction(Some(calibration::ImuCorrection::new(c)?)),
            Record::DvlMounting(d) => self.estimator.set_dvl_mounting(Some(calibration::dvl_mounting(d)?)),
        }
        Ok(())
    }

    /// Put the defaults of `key` in use.
    fn use_default(&mut self, key: RecordKey) {
        match key {
            RecordKey::RunConfig => {
                self.config = AppConfig::default();
                self.nav_task.period_us = 1_000_000 / u64::from(self.config.nav_rate_hz);
            }
            RecordKey::Polarization { unit } => self.estimator.set_polarization_unit(usize::from(unit), None),
            RecordKey::Imu => self.estimator.set_imu_correction(None),
            RecordKey::DvlMounting => self.estimator.set_dvl_mounting(None),
        }
    }

    fn use_defaults(&mut self) {
        for key in record_keys() {
            self.use_default(key);
        }
    }

    fn send_boot(&mut self, now_us: u64, calibration: CalibrationInUse, sink: &mut impl TelemetrySink) {
        self.boot_us = now_us;
        let boot = boot_message(self.board, FIRMWARE_VERSION, now_us, calibration, self.reset_cause);
        info!(
            "subnav firmware {=u8}.{=u8}.{=u8} booting, protocol {=u16}",
            FIRMWARE_VERSION[0], FIRMWARE_VERSION[1], FIRMWARE_VERSION[2], boot.protocol_version
        );
        self.telemetry.send(&Uplink::Boot(boot), sink);
    }

    /// The board's measured CPU load over its last period (per mille), reported in health.
    pub fn set_cpu_load(&mut self, permille: u16) {
        self.cpu_load_permille = permille.min(1000);
    }

    /// Feed bytes received on the downlink.
    #[inline(never)] // keeps its temporaries out of the board loop's stack frame (see PERFORMANCE.md, stack)
    pub fn on_downlink_bytes(&mut self, now_us: u64, bytes: &[u8], sink: &mut impl TelemetrySink) {
        for &b in bytes {
            match self.downlink.push::<Downlink>(b) {
                Decoded::Pending => {}
                Decoded::Message(cmd) => self.handle_command(now_us, cmd, sink),
                Decoded::Corrupt(_) => {
                    self.corrupt_downlink = self.corrupt_downlink.wrapping_add(1);
                    warn!("corrupt downlink frame ({=u32} so far)", self.corrupt_downlink);
                    let fault =
                        Fault { t_us: now_us, source: FaultSource::Link, kind: FaultKind::CorruptFrame, count: self.corrupt_downlink };
                    self.telemetry.send(&Uplink::Fault(fault), sink);
                }
            }
        }
    }

    /// Run whatever tasks are due at `now_us`. Returns what the board must do next.
    #[inline(never)] // keeps its temporaries out of the board loop's stack frame (see PERFORMANCE.md, stack)
    pub fn poll(&mut self, now_us: u64, sink: &mut impl TelemetrySink) -> BoardRequest {
        if self.nav_task.due(now_us) {
            let nav = self.estimator.solution(now_us);
            self.telemetry.send(&Uplink::Nav(nav), sink);
        }
        if self.health_task.due(now_us) {
            let mut health: FilterHealth = self.estimator.health(now_us);
            health.t_us = now_us;
            health.cpu_load_permille = self.cpu_load_permille;
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
}

// `CalibrationInUse::polarization_units_stored` has a bit per unit.
const _: () = assert!(head::POLARIZATION_UNITS <= 8);

fn mark_in_use(cal: &mut CalibrationInUse, key: RecordKey, stored: bool) {
    match key {
        RecordKey::RunConfig => cal.config_stored = stored,
        RecordKey::Imu => cal.imu_stored = stored,
        RecordKey::DvlMounting => cal.dvl_stored = stored,
        RecordKey::Polarization { unit } if unit < 8 => {
            if stored {
                cal.polarization_units_stored |= 1 << unit;
            } else {
                cal.polarization_units_stored &= !(1 << unit);
            }
        }
        RecordKey::Polarization { .. } => {}
    }
}

/// Light (mean counts above the dark offset) a unit must have, as a fraction of the brightest
/// unit's, not to count as occluded; and the brightest unit's light below which the scene is
/// simply dark (night, deep water) and nothing is flagged. The units look in different
/// directions, so their light differs by a factor of a few, never by 10.
const OCCLUDED_FRACTION: f32 = 0.1;
const MIN_LIGHT_COUNTS: f32 = 50.0;

/// Bit mask of the units in `readings` that read no light while another unit does.
fn occluded_units(readings: &[(usize, [i16; 4])]) -> u8 {
    let light = |c: &[i16; 4]| c.iter().map(|&v| f32::from(v)).sum::<f32>() / 4.0 - head::POLARIZATION_OFFSET_COUNTS;
    let brightest = readings.iter().map(|(_, c)| light(c)).fold(0.0f32, f32::max);
    if brightest < MIN_LIGHT_COUNTS {
        return 0;
    }
    readings.iter().filter(|(u, c)| *u < 8 && light(c) < OCCLUDED_FRACTION * brightest).fold(0u8, |m, (u, _)| m | (1 << u))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::commands::covariance_is_pd;
    use super::*;
    use subnav_wire::{self as wire, MAX_DOWNLINK_FRAME, MAX_UPLINK_FRAME, NavSolution};
    use subnav_wire::{Command, CommandAck, ConfigItem, RecordReport};

    /// Every message of an uplink byte stream; a corrupt frame fails the test.
    pub(crate) fn decode_all(bytes: &[u8]) -> Vec<Uplink> {
        let mut dec = FrameDecoder::<MAX_UPLINK_FRAME>::new();
        bytes
            .iter()
            .filter_map(|b| match dec.push::<Uplink>(*b) {
                Decoded::Message(m) => Some(m),
                Decoded::Corrupt(e) => panic!("firmware emitted a corrupt frame: {e}"),
                Decoded::Pending => None,
            })
            .collect()
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
        assert!(
            matches!(msgs[0], Uplink::Boot(b) if b.compatibility() == wire::Compatibility::Compatible && b.reset_cause == ResetCause::PowerOn)
        );
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
        let acks: Vec<CommandAck> =
            decode_all(&out).into_iter().filter_map(|m| if let Uplink::Ack(a) = m { Some(a) } else { None }).collect();
        assert_eq!(
            acks,
            vec![
                CommandAck { seq: 1, result: Err(Refusal::OutOfRange) },
                CommandAck { seq: 2, result: Ok(()) },
                CommandAck { seq: 3, result: Err(Refusal::NotFinite) },
                CommandAck { seq: 4, result: Err(Refusal::NotPositiveDefinite) },
                CommandAck { seq: 5, result: Ok(()) },
            ]
        );
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

    /// A head at rest at 12 m with polarization unit 2 NACKing and every 50th IMU read timing out.
    struct StillHead {
        imu_reads: u32,
    }

    impl SensorSuite for StillHead {
        fn read_imu(&mut self, t_us: u64) -> Result<subnav_wire::ImuSample, SensorFault> {
            self.imu_reads += 1;
            if self.imu_reads % 50 == 0 {
                return Err(SensorFault { source: FaultSource::Imu, kind: FaultKind::BusTimeout });
            }
            Ok(subnav_wire::ImuSample { t_us, gyro_radps: [0.0; 3], accel_mps2: [0.0, 0.0, -9.81], temp_c: 15.0 })
        }
        fn read_polarization(&mut self, _t_us: u64, unit: u8) -> Result<[i16; 4], SensorFault> {
            if unit == 2 {
                return Err(SensorFault { source: FaultSource::Polarization { unit }, kind: FaultKind::BusNack });
            }
            Ok([1000, 1000, 1000, 1000])
        }
        fn read_depth(&mut self, t_us: u64, _rho: f32) -> Result<subnav_wire::DepthSample, SensorFault> {
            Ok(subnav_wire::DepthSample { t_us, pressure_pa: 101_325.0 + 12.0 * 1025.0 * 9.81, temp_c: 10.0, depth_m: 12.0 })
        }
    }

    /// The board's record cycle: a running head keeps its record (zeros before it runs and after
    /// a filter reset); after a watchdog reset the next head warm starts from it (at 12 m, not
    /// aligning for a second at the origin); after a power-on, or with a corrupted record, it
    /// aligns cold.
    #[test]
    fn the_kept_record_warm_starts_the_next_boot_only_after_a_reset_and_only_when_whole() {
        use crate::estimator::warm::{WARM_RECORD_BYTES, WarmStart, WarmStartError};
        let mut kept = [0xA5u8; WARM_RECORD_BYTES];
        let mut app = App::new(Board::QemuMps2An386);
        let mut head = StillHead { imu_reads: 0 };
        let mut out = Vec::new();
        app.boot(0, &mut out);
        app.service_warm_record(0, &mut kept);
        assert_eq!(kept, [0u8; WARM_RECORD_BYTES], "cleared while aligning");
        for ms in 0..=15_000u64 {
            app.sensor_tick(ms * 1000, &mut head, &mut out);
            app.service_warm_record(ms * 1000, &mut kept);
        }
        let rec = WarmStart::decode(&kept).expect("a running head keeps its record");
        assert!((rec.pos_ned_m[2] - 12.0).abs() < 0.5 && rec.written_us == 15_000_000, "{rec:?}");

        let boot = |cause: ResetCause, kept: &mut [u8; WARM_RECORD_BYTES]| {
            let mut app = App::new(Board::QemuMps2An386);
            app.set_reset_cause(cause);
            let mut out = Vec::new();
            app.boot(0, &mut out);
            let armed = app.warm_start_at_boot(kept.as_slice(), 1.0);
            let mut head = StillHead { imu_reads: 0 };
            let mut running_at = None;
            for ms in 0..=1_000u64 {
                app.sensor_tick(ms * 1000, &mut head, &mut out);
                app.service_warm_record(ms * 1000, kept);
                if running_at.is_none() && app.estimator().solution(0).sigma_pos_m[0].is_finite() {
                    running_at = Some(ms);
                }
            }
            (armed, running_at, app)
        };
        let good = kept;
        // Power-on: never (that memory holds nothing the head wrote).
        assert_eq!(boot(ResetCause::PowerOn, &mut kept.clone()).0, Err(WarmStartError::NoRecord));
        // Corrupted: a flipped bit, cold alignment (the still head aligns after 10 s without a compass).
        let mut bad = good;
        bad[40] ^= 0x10;
        let (armed, running_at, _) = boot(ResetCause::Watchdog, &mut bad);
        assert_eq!((armed, running_at), (Err(WarmStartError::Corrupt), None));
        // Watchdog: warm started after the levelling, from the record, and keeps a new one.
        let mut kept = good;
        let (armed, running_at, app) = boot(ResetCause::Watchdog, &mut kept);
        assert_eq!(armed, Ok(()));
        assert!(running_at.is_some_and(|ms| (200..=260).contains(&ms)), "running at {running_at:?} ms");
        assert!(!app.warm_start_armed());
        let s = app.estimator().solution(0);
        assert!((s.pos_ned_m[2] - 12.0).abs() < 0.5 && s.sigma_pos_m[0] < 10.0, "{s:?}");
        let written = WarmStart::decode(&kept).map(|r| r.written_us);
        assert!(written.is_ok_and(|t| t > 900_000), "the new boot's record, every 100 ms: {written:?}");
        // A filter reset clears the record.
        let mut app = app;
        app.handle_command(1_000_000, Downlink { seq: 0, command: Command::ResetFilter }, &mut Vec::new());
        app.service_warm_record(1_100_000, &mut kept);
        assert_eq!(WarmStart::decode(&kept), Err(WarmStartError::NoRecord));
    }

    #[test]
    fn sensors_feed_the_estimator_and_faults_are_reported_without_stopping_it() {
        let mut app = App::new(Board::QemuMps2An386);
        let mut head = StillHead { imu_reads: 0 };
        let mut out = Vec::new();
        app.boot(0, &mut out);
        for ms in 0..=15_000u64 {
            app.sensor_tick(ms * 1000, &mut head, &mut out);
            app.poll(ms * 1000, &mut out);
        }
        let msgs = decode_all(&out);
        let faults: Vec<&Fault> = msgs.iter().filter_map(|m| if let Uplink::Fault(f) = m { Some(f) } else { None }).collect();
        assert!(faults.iter().any(|f| f.source == FaultSource::Polarization { unit: 2 } && f.kind == FaultKind::BusNack));
        assert!(faults.iter().any(|f| f.source == FaultSource::Imu && f.kind == FaultKind::BusTimeout));
        assert!(faults.len() < 100, "faults must be rate-limited, got {}", faults.len());
        let navs: Vec<&NavSolution> = msgs.iter().filter_map(|m| if let Uplink::Nav(n) = m { Some(n) } else { None }).collect();
        let last = navs.last().unwrap();
        assert_eq!(last.mode, subnav_wire::NavMode::Aided);
        assert!(navs.iter().all(|n| n.pos_ned_m.iter().chain(n.vel_ned_mps.iter()).chain(n.att_nb_wxyz.iter()).all(|v| v.is_finite())));
        assert!((last.pos_ned_m[2] - 12.0).abs() < 0.2, "{:?}", last.pos_ned_m);
        // Unpolarized light gives no compass fix, with a reason.
        assert!(msgs.iter().any(|m| matches!(m, Uplink::Compass(c) if c.heading_rad.is_none() && c.no_fix_reason != 0)));
        let imu_raw = msgs.iter().filter(|m| matches!(m, Uplink::Raw(RawSample::Imu(_)))).count();
        assert!((2900..=3001).contains(&imu_raw), "raw IMU at 200 Hz minus failed reads: {imu_raw}");
    }

    /// A head with a camera whose trigger line fails on the 3rd pulse.
    struct CameraHead {
        still: StillHead,
        pulses: Vec<u64>,
    }

    impl SensorSuite for CameraHead {
        fn read_imu(&mut self, t_us: u64) -> Result<subnav_wire::ImuSample, SensorFault> {
            self.still.read_imu(t_us)
        }
        fn read_polarization(&mut self, t_us: u64, unit: u8) -> Result<[i16; 4], SensorFault> {
            self.still.read_polarization(t_us, unit)
        }
        fn read_depth(&mut self, t_us: u64, rho: f32) -> Result<subnav_wire::DepthSample, SensorFault> {
            self.still.read_depth(t_us, rho)
        }
        fn trigger_camera(&mut self, t_us: u64) -> Result<bool, SensorFault> {
            self.pulses.push(t_us);
            if self.pulses.len() == 3 {
                return Err(SensorFault { source: FaultSource::Camera, kind: FaultKind::BusNack });
            }
            Ok(true)
        }
    }

    #[test]
    fn camera_is_triggered_at_its_rate_and_each_frame_announced_with_its_time() {
        let mut app = App::new(Board::QemuMps2An386);
        let mut head = CameraHead { still: StillHead { imu_reads: 0 }, pulses: Vec::new() };
        let mut out = Vec::new();
        app.boot(0, &mut out);
        for ms in 0..=3_000u64 {
            app.sensor_tick(ms * 1000, &mut head, &mut out);
            app.poll(ms * 1000, &mut out);
        }
        let period = 1_000_000 / u64::from(head::CAMERA_RATE_HZ);
        assert_eq!(head.pulses, (0..=3_000_000 / period).map(|k| k * period).collect::<Vec<_>>());
        let msgs = decode_all(&out);
        let trig: Vec<CameraTrigger> = msgs.iter().filter_map(|m| if let Uplink::Trigger(t) = m { Some(*t) } else { None }).collect();
        // The failed pulse is a fault, not a frame: numbers stay consecutive over real frames.
        let expect: Vec<CameraTrigger> = head
            .pulses
            .iter()
            .enumerate()
            .filter(|(k, _)| *k != 2)
            .enumerate()
            .map(|(n, (_, &t))| CameraTrigger { t_us: t, frame: n as u32 })
            .collect();
        assert_eq!(trig, expect);
        assert!(msgs.iter().any(|m| matches!(m, Uplink::Fault(f) if f.source == FaultSource::Camera)));
    }

    fn acks(out: &[u8]) -> Vec<CommandAck> {
        decode_all(out).into_iter().filter_map(|m| if let Uplink::Ack(a) = m { Some(a) } else { None }).collect()
    }

    #[test]
    fn a_late_fix_is_fused_at_its_time_and_bad_times_are_refused_with_a_reason() {
        let mut app = App::new(Board::QemuMps2An386);
        let mut head = StillHead { imu_reads: 0 };
        let mut out = Vec::new();
        app.boot(0, &mut out);
        let run = |app: &mut App, head: &mut StillHead, out: &mut Vec<u8>, from_ms: u64, to_ms: u64| {
            for ms in from_ms..to_ms {
                app.sensor_tick(ms * 1000, head, out);
                app.poll(ms * 1000, out);
            }
        };
        let fix = |t_us: u64| Command::PositionFix { t_us, pos_ned_m: [2.0, 0.0, 12.0], cov_ned_m2: [1.0, 0.0, 0.0, 1.0, 0.0, 1.0] };
        // Before the filter runs: busy.
        app.handle_command(0, Downlink { seq: 1, command: fix(0) }, &mut out);
        run(&mut app, &mut head, &mut out, 0, 14_000);
        let before = app.estimator().solution(14_000_000);
        // A fix 2 m north (inside the gate) valid 1.5 s ago: fused now, at its time.
        app.handle_command(14_000_000, Downlink { seq: 2, command: fix(12_500_000) }, &mut out);
        let after = app.estimator().solution(14_000_000);
        assert!(after.pos_ned_m[0] - before.pos_ned_m[0] > 0.5, "the fix pulls the position north: {:?}", after.pos_ned_m);
        // Older than the history, and far in the future: refused, state untouched.
        app.handle_command(14_000_000, Downlink { seq: 3, command: fix(1_000_000) }, &mut out);
        app.handle_command(14_000_000, Downlink { seq: 4, command: fix(20_000_000) }, &mut out);
        let untouched = app.estimator().solution(14_000_000);
        assert_eq!(untouched.pos_ned_m, after.pos_ned_m);
        assert_eq!(
            acks(&out),
            vec![
                CommandAck { seq: 1, result: Err(Refusal::Busy) },
                CommandAck { seq: 2, result: Ok(()) },
                CommandAck { seq: 3, result: Err(Refusal::TooOld) },
                CommandAck { seq: 4, result: Err(Refusal::FromFuture) },
            ]
        );
        let h = app.estimator().health(14_000_000);
        assert_eq!((h.late_fused, h.late_refused), (1, 2), "{h:?}");
    }

    /// A still head with a DVL that reports zero velocity 0.2 s after each ping at 5 Hz, every
    /// 7th report flagged invalid and every 11th a malformed sentence.
    struct DvlHead {
        still: StillHead,
        next_ping_us: u64,
        n: u32,
    }

    impl SensorSuite for DvlHead {
        fn read_imu(&mut self, t_us: u64) -> Result<subnav_wire::ImuSample, SensorFault> {
            self.still.read_imu(t_us)
        }
        fn read_polarization(&mut self, t_us: u64, unit: u8) -> Result<[i16; 4], SensorFault> {
            self.still.read_polarization(t_us, unit)
        }
        fn read_depth(&mut self, t_us: u64, rho: f32) -> Result<subnav_wire::DepthSample, SensorFault> {
            self.still.read_depth(t_us, rho)
        }
        fn poll_dvl(&mut self, t_us: u64) -> Result<Option<DvlSample>, SensorFault> {
            if t_us < self.next_ping_us + 200_000 {
                return Ok(None);
            }
            let ping = self.next_ping_us;
            self.next_ping_us += 200_000;
            self.n += 1;
            if self.n % 11 == 0 {
                return Err(SensorFault { source: FaultSource::Dvl, kind: FaultKind::Malformed });
            }
            Ok(Some(DvlSample {
                t_us: ping,
                rx_us: t_us,
                tracking: subnav_wire::DvlTracking::Bottom,
                valid: self.n % 7 != 0,
                vel_dvl_mps: [0.0; 3],
                fom_mps: 0.005,
                altitude_m: 8.0,
                covariance_m2ps2: None,
            }))
        }
    }

    #[test]
    fn dvl_reports_are_fused_late_and_invalid_or_malformed_ones_counted_not_fused() {
        let mut app = App::new(Board::QemuMps2An386);
        let mut head = DvlHead { still: StillHead { imu_reads: 0 }, next_ping_us: 0, n: 0 };
        let mut out = Vec::new();
        app.boot(0, &mut out);
        for ms in 0..=30_000u64 {
            app.sensor_tick(ms * 1000, &mut head, &mut out);
            app.poll(ms * 1000, &mut out);
        }
        let msgs = decode_all(&out);
        let raw = msgs.iter().filter(|m| matches!(m, Uplink::Raw(RawSample::Dvl(_)))).count();
        assert!((135..=140).contains(&raw), "5 Hz for 30 s minus the malformed ones: {raw}");
        assert!(msgs.iter().any(|m| matches!(m, Uplink::Fault(Fault { source: FaultSource::Dvl, kind: FaultKind::Invalid, .. }))));
        assert!(msgs.iter().any(|m| matches!(m, Uplink::Fault(Fault { source: FaultSource::Dvl, kind: FaultKind::Malformed, .. }))));
        let e = app.estimator();
        // Fused: the valid reports after the alignment (10 s here: no compass fix in unpolarized light).
        assert!(e.dvl_fused > 70 && e.dvl_fused < 130, "{}", e.dvl_fused);
        let h = e.health(30_000_000);
        assert!(h.late_fused >= e.dvl_fused, "every DVL report is 0.2 s late: {h:?}");
        let nav = e.solution(30_000_000);
        assert!(nav.sigma_vel_mps.iter().all(|s| *s < 0.05), "the DVL holds the velocity: {:?}", nav.sigma_vel_mps);
    }

    #[test]
    fn a_dark_unit_among_lit_ones_is_occluded_but_a_dark_scene_is_not() {
        let lit = [2000i16, 2400, 2100, 1800];
        let dark = [300i16, 301, 299, 302];
        assert_eq!(occluded_units(&[(0, lit), (1, dark), (2, lit), (3, lit)]), 0b0010);
        assert_eq!(occluded_units(&[(0, dark), (1, dark), (2, dark), (3, dark)]), 0);
        // Dimmer by a factor of 3 (another direction) is not occluded.
        assert_eq!(occluded_units(&[(0, lit), (1, [900, 950, 880, 1000]), (3, lit)]), 0);
    }

    /// A store in RAM, with the failures a flash has.
    #[derive(Default)]
    struct MemStore {
        records: std::collections::BTreeMap<u8, Record>,
        corrupted: bool,
        bad_key: Option<u8>,
        fail_writes: bool,
        formats: u32,
    }

    impl RecordStore for MemStore {
        fn load(&mut self, key: RecordKey) -> Result<Option<Record>, StoreError> {
            if self.corrupted {
                return Err(StoreError::Corrupted);
            }
            if self.bad_key == Some(key.id()) {
                return Err(StoreError::BadRecord(subnav_wire::StoredError::Crc));
            }
            Ok(self.records.get(&key.id()).copied())
        }
        fn save(&mut self, r: &Record) -> Result<(), StoreError> {
            if self.fail_writes {
                return Err(StoreError::Bus(FaultKind::BusTimeout));
            }
            self.records.insert(r.key().id(), *r);
            Ok(())
        }
        fn erase(&mut self, key: RecordKey) -> Result<(), StoreError> {
            self.records.remove(&key.id());
            Ok(())
        }
        fn format(&mut self) -> Result<(), StoreError> {
            self.records.clear();
            self.corrupted = false;
            self.formats += 1;
            Ok(())
        }
    }

    fn boot_of(msgs: &[Uplink]) -> wire::Boot {
        match msgs.first() {
            Some(Uplink::Boot(b)) => *b,
            other => panic!("first message is not Boot: {other:?}"),
        }
    }

    fn acks_of(msgs: &[Uplink]) -> Vec<CommandAck> {
        msgs.iter().filter_map(|m| if let Uplink::Ack(a) = m { Some(*a) } else { None }).collect()
    }

    fn polarization(unit: u8, gain: f32) -> Record {
        Record::Polarization(wire::PolarizationCalibration {
            unit,
            gain: [gain; 4],
            offset_counts: [head::POLARIZATION_OFFSET_COUNTS; 4],
            polarizer_rad: core::array::from_fn(|k| (k as f32 * 45.0).to_radians()),
            extinction_ratio: [head::POLARIZER_EXTINCTION_RATIO; 4],
        })
    }

    #[test]
    fn boot_uses_and_reports_the_stored_records() {
        let mut store = MemStore::default();
        let cfg = wire::RunConfigRecord { nav_rate_hz: 25, stream_raw: false, water_density_kgm3: 1010.0, origin: None };
        store.save(&Record::RunConfig(cfg)).unwrap();
        store.save(&polarization(2, 1.05)).unwrap();
        let mut app = App::new(Board::QemuMps2An386);
        app.set_reset_cause(ResetCause::Watchdog);
        let mut out = Vec::new();
        app.boot_with_store(0, &mut store, &mut out);
        let b = boot_of(&decode_all(&out));
        assert_eq!(b.reset_cause, ResetCause::Watchdog);
        assert_eq!(b.calibration.store, StoreStatus::Ok);
        assert!(b.calibration.config_stored && !b.calibration.imu_stored);
        assert_eq!(b.calibration.polarization_units_stored, 0b0100);
        assert_eq!(app.config.nav_rate_hz, 25);
        assert!(!app.config.stream_raw);
    }

    #[test]
    fn records_are_set_read_back_erased_and_bad_ones_refused_with_reasons() {
        let mut store = MemStore::default();
        let mut app = App::new(Board::QemuMps2An386);
        let mut out = Vec::new();
        app.boot_with_store(0, &mut store, &mut out);
        assert_eq!(boot_of(&decode_all(&out)).calibration.store, StoreStatus::Empty);
        let mut bad = polarization(1, 1.0);
        if let Record::Polarization(p) = &mut bad {
            p.polarizer_rad[2] = f32::NAN;
        }
        let mut bytes = cmd(1, Command::SetRecord(polarization(1, 3.0))); // gain out of range
        bytes.extend(cmd(2, Command::SetRecord(bad)));
        bytes.extend(cmd(3, Command::ReadRecord(RecordKey::Polarization { unit: head::POLARIZATION_UNITS as u8 })));
        bytes.extend(cmd(4, Command::SetRecord(polarization(1, 0.95))));
        bytes.extend(cmd(5, Command::ReadRecord(RecordKey::Polarization { unit: 1 })));
        let mut out = Vec::new();
        app.on_downlink_bytes(10, &bytes, &mut out);
        app.service_store(11, &mut store, &mut out);
        let msgs = decode_all(&out);
        assert_eq!(
            acks_of(&msgs),
            vec![
                CommandAck { seq: 1, result: Err(Refusal::OutOfRange) },
                CommandAck { seq: 2, result: Err(Refusal::NotFinite) },
                CommandAck { seq: 3, result: Err(Refusal::OutOfRange) },
                CommandAck { seq: 4, result: Ok(()) },
                CommandAck { seq: 5, result: Ok(()) },
            ]
        );
        let key = RecordKey::Polarization { unit: 1 };
        let report = msgs.iter().find_map(|m| if let Uplink::Record(r) = m { Some(*r) } else { None }).unwrap();
        assert_eq!(report, RecordReport { t_us: 11, key, stored: Some(polarization(1, 0.95)) });
        assert_eq!(app.estimator.units_model(1).map(|m| m.channels[0].gain), Some(0.95));
        // Erase: defaults again, and nothing stored.
        let mut out = Vec::new();
        app.on_downlink_bytes(20, &cmd(6, Command::EraseRecord(key)), &mut out);
        app.on_downlink_bytes(20, &cmd(7, Command::ReadRecord(key)), &mut out);
        app.service_store(21, &mut store, &mut out);
        let msgs = decode_all(&out);
        assert!(acks_of(&msgs).iter().all(|a| a.result.is_ok()));
        assert!(msgs.iter().any(|m| matches!(m, Uplink::Record(RecordReport { stored: None, .. }))));
        assert_eq!(app.estimator.units_model(1).map(|m| m.channels[0].gain), Some(head::POLARIZATION_GAIN_COUNTS));
    }

    #[test]
    fn duplicated_and_replayed_commands_are_acknowledged_again_and_not_applied_twice() {
        let mut store = MemStore::default();
        let mut app = App::new(Board::QemuMps2An386);
        let mut out = Vec::new();
        app.boot_with_store(0, &mut store, &mut out);
        let reset = cmd(1, Command::ResetFilter);
        let rate = cmd(2, Command::SetConfig(ConfigItem::NavRateHz(5)));
        let save = cmd(3, Command::SetRecord(polarization(1, 0.95)));
        let mut out = Vec::new();
        // The same frame twice in a row (a retransmission), and a store command duplicated
        // while it is still queued: one application each.
        for f in [&reset, &reset, &rate, &save, &save] {
            app.on_downlink_bytes(1, f, &mut out);
        }
        assert_eq!(app.duplicate_commands(), 2);
        app.service_store(2, &mut store, &mut out);
        assert_eq!(
            acks_of(&decode_all(&out)),
            vec![
                CommandAck { seq: 1, result: Ok(()) },
                CommandAck { seq: 1, result: Ok(()) },
                CommandAck { seq: 2, result: Ok(()) },
                CommandAck { seq: 3, result: Ok(()) },
            ],
            "a duplicate gets the first one's ack again; a queued one its single ack"
        );
        // Replayed later (an old frame again): acknowledged with the first result, not applied:
        // the configuration changed since stays.
        let mut out = Vec::new();
        app.on_downlink_bytes(3, &cmd(4, Command::SetConfig(ConfigItem::NavRateHz(20))), &mut out);
        app.on_downlink_bytes(3, &rate, &mut out);
        app.on_downlink_bytes(3, &save, &mut out);
        assert_eq!(app.config.nav_rate_hz, 20, "the replayed SetConfig(5) was not applied");
        assert_eq!(
            acks_of(&decode_all(&out)),
            vec![CommandAck { seq: 4, result: Ok(()) }, CommandAck { seq: 2, result: Ok(()) }, CommandAck { seq: 3, result: Ok(()) }]
        );
        // The same number with another command (another sender) is a new command; a refused
        // one is refused again; seq 0 is never filtered.
        let mut out = Vec::new();
        app.on_downlink_bytes(4, &cmd(2, Command::SetConfig(ConfigItem::NavRateHz(7))), &mut out);
        assert_eq!(app.config.nav_rate_hz, 7);
        let bad = cmd(5, Command::SetConfig(ConfigItem::NavRateHz(0)));
        app.on_downlink_bytes(4, &bad, &mut out);
        app.on_downlink_bytes(4, &bad, &mut out);
        let zero = cmd(0, Command::SetConfig(ConfigItem::NavRateHz(9)));
        app.on_downlink_bytes(4, &zero, &mut out);
        app.on_downlink_bytes(4, &cmd(6, Command::SetConfig(ConfigItem::NavRateHz(8))), &mut out);
        app.on_downlink_bytes(4, &zero, &mut out);
        assert_eq!(app.config.nav_rate_hz, 9, "seq 0 applied both times");
        assert_eq!(
            acks_of(&decode_all(&out)),
            vec![
                CommandAck { seq: 2, result: Ok(()) },
                CommandAck { seq: 5, result: Err(Refusal::OutOfRange) },
                CommandAck { seq: 5, result: Err(Refusal::OutOfRange) },
                CommandAck { seq: 0, result: Ok(()) },
                CommandAck { seq: 6, result: Ok(()) },
                CommandAck { seq: 0, result: Ok(()) },
            ]
        );
        // Outside the window (RECENT_COMMANDS newer commands since): applied again.
        for k in 0..RECENT_COMMANDS as u16 {
            app.on_downlink_bytes(5, &cmd(100 + k, Command::SetConfig(ConfigItem::StreamRaw(true))), &mut Vec::new());
        }
        app.on_downlink_bytes(5, &rate, &mut Vec::new());
        assert_eq!(app.config.nav_rate_hz, 5);
    }

    #[test]
    fn set_config_is_stored_and_survives_a_reboot() {
        let mut store = MemStore::default();
        let mut app = App::new(Board::QemuMps2An386);
        let mut out = Vec::new();
        app.boot_with_store(0, &mut store, &mut out);
        app.on_downlink_bytes(5, &cmd(1, Command::SetConfig(ConfigItem::NavRateHz(5))), &mut out);
        app.service_store(6, &mut store, &mut out);
        let mut again = App::new(Board::QemuMps2An386);
        let mut out = Vec::new();
        again.boot_with_store(0, &mut store, &mut out);
        assert_eq!(again.config.nav_rate_hz, 5);
        assert!(boot_of(&decode_all(&out)).calibration.config_stored);
    }

    #[test]
    fn damaged_failed_and_absent_stores_give_defaults_and_say_so() {
        // Damaged beyond repair: erased, defaults, a BadCrc store fault.
        let mut store = MemStore { corrupted: true, ..Default::default() };
        let mut app = App::new(Board::QemuMps2An386);
        let mut out = Vec::new();
        app.boot_with_store(0, &mut store, &mut out);
        let msgs = decode_all(&out);
        assert_eq!(boot_of(&msgs).calibration.store, StoreStatus::Reformatted);
        assert_eq!(store.formats, 1);
        assert!(msgs.iter().any(|m| matches!(m, Uplink::Fault(Fault { source: FaultSource::Store, kind: FaultKind::BadCrc, .. }))));
        assert_eq!(app.config, AppConfig::default());
        // One damaged record: that record's defaults, the others in use.
        let mut store = MemStore { bad_key: Some(RecordKey::Imu.id()), ..Default::default() };
        store.save(&polarization(0, 1.1)).unwrap();
        let mut app = App::new(Board::QemuMps2An386);
        let mut out = Vec::new();
        app.boot_with_store(0, &mut store, &mut out);
        let msgs = decode_all(&out);
        assert_eq!(boot_of(&msgs).calibration.polarization_units_stored, 1);
        assert!(msgs.iter().any(|m| matches!(m, Uplink::Fault(Fault { source: FaultSource::Store, kind: FaultKind::BadCrc, .. }))));
        // A flash that does not answer: defaults, Failed, commands refused with StoreFailed.
        let mut failed = crate::store::FailedStore(FaultKind::BusNack);
        let mut app = App::new(Board::QemuMps2An386);
        let mut out = Vec::new();
        app.boot_with_store(0, &mut failed, &mut out);
        app.on_downlink_bytes(1, &cmd(3, Command::ReadRecord(RecordKey::Imu)), &mut out);
        let msgs = decode_all(&out);
        assert_eq!(boot_of(&msgs).calibration.store, StoreStatus::Failed);
        assert_eq!(acks_of(&msgs), vec![CommandAck { seq: 3, result: Err(Refusal::StoreFailed) }]);
        // A write that fails: refused, the old value stays in use.
        let mut store = MemStore::default();
        let mut app = App::new(Board::QemuMps2An386);
        let mut out = Vec::new();
        app.boot_with_store(0, &mut store, &mut out);
        store.fail_writes = true;
        app.on_downlink_bytes(1, &cmd(4, Command::SetRecord(polarization(0, 1.2))), &mut out);
        app.service_store(2, &mut store, &mut out);
        let msgs = decode_all(&out);
        assert_eq!(acks_of(&msgs), vec![CommandAck { seq: 4, result: Err(Refusal::StoreFailed) }]);
        assert_eq!(app.estimator.units_model(0).map(|m| m.channels[0].gain), Some(head::POLARIZATION_GAIN_COUNTS));
        // No store at all: store commands are not supported.
        let mut app = App::new(Board::QemuMps2An386);
        let mut out = Vec::new();
        app.boot(0, &mut out);
        app.on_downlink_bytes(1, &cmd(5, Command::EraseRecord(RecordKey::Imu)), &mut out);
        let msgs = decode_all(&out);
        assert_eq!(boot_of(&msgs).calibration, CalibrationInUse::NO_STORE);
        assert_eq!(acks_of(&msgs), vec![CommandAck { seq: 5, result: Err(Refusal::NotSupported) }]);
    }

    #[test]
    fn a_full_store_queue_refuses_with_busy() {
        let mut store = MemStore::default();
        let mut app = App::new(Board::QemuMps2An386);
        let mut out = Vec::new();
        app.boot_with_store(0, &mut store, &mut out);
        let mut bytes = Vec::new();
        for seq in 0..(STORE_QUEUE as u16 + 1) {
            bytes.extend(cmd(seq, Command::ReadRecord(RecordKey::Imu)));
        }
        let mut out = Vec::new();
        app.on_downlink_bytes(1, &bytes, &mut out);
        assert_eq!(acks_of(&decode_all(&out)), vec![CommandAck { seq: STORE_QUEUE as u16, result: Err(Refusal::Busy) }]);
        // One save at a time between two services.
        let mut bytes = cmd(20, Command::SetRecord(polarization(0, 1.0)));
        bytes.extend(cmd(21, Command::SetRecord(polarization(1, 1.0))));
        let mut out = Vec::new();
        app.on_downlink_bytes(2, &bytes, &mut out);
        assert_eq!(acks_of(&decode_all(&out)), vec![CommandAck { seq: 21, result: Err(Refusal::Busy) }]);
    }

    #[test]
    fn sylvester() {
        assert!(covariance_is_pd(&[1.0, 0.0, 0.0, 1.0, 0.0, 1.0]));
        assert!(!covariance_is_pd(&[1.0, 0.0, 0.0, 1.0, 0.0, 0.0]));
        assert!(!covariance_is_pd(&[-1.0, 0.0, 0.0, 1.0, 0.0, 1.0]));
    }
}
