//! Downlink command handling: the duplicate filter ([`RecentCommands`]), applying a command
//! (configuration, time, position fixes, filter reset, reboot) with its `Ack`, and the store
//! commands ([`StoreCommand`]), which are checked and queued here and run by
//! [`App::service_store`] from the board loop (flash writes take milliseconds; they never run
//! inside a command's decoding).
//!
//! A child module of `app`: it works on the `App`'s own state, as the rest of the application.

use subnav_core::head;
use subnav_core::nav::NavError;
use subnav_wire::{Command, CommandAck, ConfigItem, Downlink, FaultKind, Record, RecordKey, RecordReport, Refusal, Uplink};

use super::{App, BoardRequest, StoreState};
use crate::calibration;
use crate::store::{RecordStore, StoreError};
use crate::telemetry::TelemetrySink;
use crate::{info, warn};

/// A command on the store: save a record (checked first), read one back, erase one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StoreCommand {
    Save(Record),
    Read(RecordKey),
    Erase(RecordKey),
}

impl StoreCommand {
    /// The store command a downlink command is, if it is one.
    pub fn of(command: &Command) -> Option<Self> {
        match *command {
            Command::SetRecord(r) => Some(Self::Save(r)),
            Command::ReadRecord(k) => Some(Self::Read(k)),
            Command::EraseRecord(k) => Some(Self::Erase(k)),
            _ => None,
        }
    }
}

/// Sequenced commands remembered for duplicate detection.
pub const RECENT_COMMANDS: usize = 8;

/// The duplicate filter of the downlink. A command with `seq != 0` whose `(seq, digest of the
/// command)` matches one of the last [`RECENT_COMMANDS`] received is a retransmission or a
/// replay: it is not applied again; it is acknowledged again with the first one's result (a
/// sender whose ack was lost gets it), or, while that one is still queued for the store, by
/// the one ack it will get. A command refused `Busy` is not remembered: its retry is a new try.
/// `seq == 0` (the board's configured start) is never filtered. A
/// different command under a recent number is a new command (senders share the number
/// space: operator from 1, USBL fixes from 1, the map from 0x8000). An exact replay older than
/// the window is applied again: a fix is then refused for its time of validity (`TooOld`),
/// configuration is idempotent; `Reboot` and `ResetFilter` would run again (the wire carries
/// no session, so nothing older can be told from a new command).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct RecentCommands {
    /// Per slot: sequence number, command digest, and the ack it got ([`ACK_EMPTY`] for an
    /// unused slot, [`ACK_QUEUED`] while queued for the store; plain integers, so an `App` is
    /// built in place: with `Option`s in it, LLVM kept an 8 KB temporary in the board loop's
    /// frame).
    pub(super) seq: [u16; RECENT_COMMANDS],
    pub(super) digest: [u32; RECENT_COMMANDS],
    pub(super) ack: [u8; RECENT_COMMANDS],
    pub(super) next: usize,
    /// Duplicates seen since boot.
    pub(super) duplicates: u32,
}

pub(super) const ACK_EMPTY: u8 = 0;
const ACK_QUEUED: u8 = 1;
const ACK_OK: u8 = 2;

const REFUSALS: [Refusal; 8] = [
    Refusal::OutOfRange,
    Refusal::NotFinite,
    Refusal::NotSupported,
    Refusal::NotPositiveDefinite,
    Refusal::Busy,
    Refusal::TooOld,
    Refusal::FromFuture,
    Refusal::StoreFailed,
];

fn ack_code(result: Option<Result<(), Refusal>>) -> u8 {
    match result {
        None => ACK_QUEUED,
        Some(Ok(())) => ACK_OK,
        Some(Err(e)) => REFUSALS.iter().position(|r| *r == e).map_or(ACK_OK + 1, |k| ACK_OK + 1 + k as u8),
    }
}

fn ack_of(code: u8) -> Option<Result<(), Refusal>> {
    match code {
        ACK_EMPTY | ACK_QUEUED => None,
        ACK_OK => Some(Ok(())),
        k => Some(Err(REFUSALS.get(usize::from(k - ACK_OK - 1)).copied().unwrap_or(Refusal::Busy))),
    }
}

impl RecentCommands {
    /// The slot of an earlier `(seq, digest)`, if remembered.
    fn find(&self, seq: u16, digest: u32) -> Option<usize> {
        (0..RECENT_COMMANDS).find(|&k| {
            self.ack.get(k).is_some_and(|a| *a != ACK_EMPTY) && self.seq.get(k) == Some(&seq) && self.digest.get(k) == Some(&digest)
        })
    }

    /// The ack the command in slot `k` got (`None`: still queued).
    fn result(&self, k: usize) -> Option<Result<(), Refusal>> {
        self.ack.get(k).copied().and_then(ack_of)
    }

    fn remember(&mut self, seq: u16, digest: u32, result: Option<Result<(), Refusal>>) {
        let k = self.next;
        if let (Some(s), Some(d), Some(a)) = (self.seq.get_mut(k), self.digest.get_mut(k), self.ack.get_mut(k)) {
            (*s, *d, *a) = (seq, digest, ack_code(result));
        }
        self.next = (self.next + 1) % RECENT_COMMANDS;
    }

    /// Record the ack of a queued command.
    fn acked(&mut self, seq: u16, result: Result<(), Refusal>) {
        if let Some(k) = (0..RECENT_COMMANDS).find(|&k| self.ack.get(k) == Some(&ACK_QUEUED) && self.seq.get(k) == Some(&seq)) {
            if let Some(a) = self.ack.get_mut(k) {
                *a = ack_code(Some(result));
            }
        }
    }
}

/// A queued read or erase (a save waits in its own slot: a record is the large item, and the
/// `App` sits in the board loop's frame at the stack peak).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum StoreOp {
    Read(RecordKey),
    Erase(RecordKey),
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct StoreJob {
    seq: u16,
    op: StoreOp,
}

/// Reads and erases accepted between two services of the store (and one save).
pub const STORE_QUEUE: usize = 4;

fn key_is_known(key: RecordKey) -> bool {
    match key {
        RecordKey::Polarization { unit } => usize::from(unit) < head::POLARIZATION_UNITS,
        _ => true,
    }
}

/// Why the filter refused a measurement, as the reason a command's `Ack` gives.
fn refusal(e: NavError) -> Refusal {
    match e {
        NavError::TooOld => Refusal::TooOld,
        NavError::FromFuture => Refusal::FromFuture,
        NavError::NonFinite => Refusal::NotFinite,
        NavError::BadConfig | NavError::BadTime | NavError::Filter(_) => Refusal::Busy,
    }
}

/// Positive definiteness of a symmetric 3x3 given as its upper triangle (xx, xy, xz, yy, yz, zz),
/// by Sylvester's criterion (leading principal minors > 0).
pub(super) fn covariance_is_pd(c: &[f32; 6]) -> bool {
    let [xx, xy, xz, yy, yz, zz] = c.map(f64::from);
    let m1 = xx;
    let m2 = xx * yy - xy * xy;
    let m3 = xx * (yy * zz - yz * yz) - xy * (xy * zz - yz * xz) + xz * (xy * yz - yy * xz);
    m1 > 0.0 && m2 > 0.0 && m3 > 0.0
}

impl App {
    /// Run the store commands received since the last call (and store a changed configuration),
    /// acknowledging each. Boards call this from their main loop: flash writes and erases take
    /// milliseconds, so they never run inside a command's decoding.
    #[inline(never)] // keeps its temporaries out of the board loop's stack frame
    pub fn service_store(&mut self, now_us: u64, store: &mut dyn RecordStore, sink: &mut impl TelemetrySink) {
        if self.config_dirty && self.store == StoreState::Working {
            self.config_dirty = false;
            if let Err(e) = store.save(&Record::RunConfig(calibration::run_config_record(&self.config))) {
                self.store_fault(now_us, e.fault_kind(), sink);
            }
        }
        if let Some((seq, r)) = self.pending_save.take() {
            let result = match store.save(&r) {
                Ok(()) => self.use_record(&r),
                Err(e) => {
                    self.store_fault(now_us, e.fault_kind(), sink);
                    Err(Refusal::StoreFailed)
                }
            };
            self.recent.acked(seq, result);
            self.telemetry.send(&Uplink::Ack(CommandAck { seq, result }), sink);
        }
        while let Some(job) = self.store_jobs.pop_front() {
            let result = match job.op {
                StoreOp::Read(key) => match store.load(key) {
                    Ok(stored) => {
                        self.telemetry.send(&Uplink::Record(RecordReport { t_us: now_us, key, stored }), sink);
                        Ok(())
                    }
                    Err(StoreError::BadRecord(_)) => {
                        self.store_fault(now_us, FaultKind::BadCrc, sink);
                        self.telemetry.send(&Uplink::Record(RecordReport { t_us: now_us, key, stored: None }), sink);
                        Ok(())
                    }
                    Err(e) => {
                        self.store_fault(now_us, e.fault_kind(), sink);
                        Err(Refusal::StoreFailed)
                    }
                },
                StoreOp::Erase(key) => match store.erase(key) {
                    Ok(()) => {
                        self.use_default(key);
                        Ok(())
                    }
                    Err(e) => {
                        self.store_fault(now_us, e.fault_kind(), sink);
                        Err(Refusal::StoreFailed)
                    }
                },
            };
            self.recent.acked(job.seq, result);
            self.telemetry.send(&Uplink::Ack(CommandAck { seq: job.seq, result }), sink);
        }
    }

    /// Check a store command and queue it for [`App::service_store`].
    fn queue_store(&mut self, seq: u16, command: StoreCommand) -> Result<(), Refusal> {
        match self.store {
            StoreState::Absent => return Err(Refusal::NotSupported),
            StoreState::Failed => return Err(Refusal::StoreFailed),
            StoreState::Working => {}
        }
        match command {
            StoreCommand::Save(r) => {
                calibration::check(&r)?;
                if self.pending_save.is_some() {
                    return Err(Refusal::Busy);
                }
                self.pending_save = Some((seq, r));
                Ok(())
            }
            StoreCommand::Read(k) | StoreCommand::Erase(k) if !key_is_known(k) => Err(Refusal::OutOfRange),
            StoreCommand::Read(k) => self.store_jobs.push_back(StoreJob { seq, op: StoreOp::Read(k) }).map_err(|_| Refusal::Busy),
            StoreCommand::Erase(k) => self.store_jobs.push_back(StoreJob { seq, op: StoreOp::Erase(k) }).map_err(|_| Refusal::Busy),
        }
    }

    /// Apply a command as if it came over the downlink (boards use this for a configured start:
    /// time and origin given at launch). It is acknowledged like any other. Commands carry their
    /// own times (a fix its time of validity), so the arrival tick `_now_us` changes nothing.
    #[inline(never)] // keeps its temporaries out of the board loop's stack frame (see PERFORMANCE.md, stack)
    pub fn handle_command(&mut self, _now_us: u64, cmd: Downlink, sink: &mut impl TelemetrySink) {
        let digest = cmd.command_digest();
        if cmd.seq != 0 {
            if let Some(k) = self.recent.find(cmd.seq, digest) {
                let again = self.recent.result(k);
                self.recent.duplicates = self.recent.duplicates.wrapping_add(1);
                warn!("command {=u16} is a duplicate, not applied again", cmd.seq);
                if let Some(result) = again {
                    self.telemetry.send(&Uplink::Ack(CommandAck { seq: cmd.seq, result }), sink);
                }
                return;
            }
        }
        if let Some(op) = StoreCommand::of(&cmd.command) {
            // Acknowledged by `service_store` once done, or now if refused.
            match self.queue_store(cmd.seq, op) {
                Ok(()) => self.remember(cmd.seq, digest, None),
                Err(e) => {
                    warn!("command {=u16} refused", cmd.seq);
                    self.remember(cmd.seq, digest, Some(Err(e)));
                    self.telemetry.send(&Uplink::Ack(CommandAck { seq: cmd.seq, result: Err(e) }), sink);
                }
            }
            return;
        }
        let result = self.apply(cmd.command);
        self.remember(cmd.seq, digest, Some(result));
        match result {
            Ok(()) => info!("command {=u16} accepted", cmd.seq),
            Err(_) => warn!("command {=u16} refused", cmd.seq),
        }
        self.telemetry.send(&Uplink::Ack(CommandAck { seq: cmd.seq, result }), sink);
    }

    /// Remember a command for the duplicate filter; one refused `Busy` is not remembered (a
    /// retry must be tried again).
    fn remember(&mut self, seq: u16, digest: u32, result: Option<Result<(), Refusal>>) {
        if seq != 0 && result != Some(Err(Refusal::Busy)) {
            self.recent.remember(seq, digest, result);
        }
    }

    fn apply(&mut self, command: Command) -> Result<(), Refusal> {
        let command = match command {
            Command::PositionFix { t_us, pos_ned_m, cov_ned_m2 } => {
                if !pos_ned_m.iter().chain(cov_ned_m2.iter()).all(|v| v.is_finite()) {
                    return Err(Refusal::NotFinite);
                }
                if !covariance_is_pd(&cov_ned_m2) {
                    return Err(Refusal::NotPositiveDefinite);
                }
                return self.estimator.on_position_fix(t_us, pos_ned_m, cov_ned_m2).map_err(refusal);
            }
            Command::ResetFilter => {
                self.estimator.reset();
                self.warm_armed_gap_s = -1.0;
                return Ok(());
            }
            other => other,
        };
        match command {
            Command::SetConfig(item) => {
                let before = self.config;
                self.apply_config(item)?;
                if self.config != before && self.store == StoreState::Working {
                    self.config_dirty = true;
                }
                Ok(())
            }
            Command::SetTime { t_us, utc_unix_us } => {
                let t = i64::try_from(t_us).map_err(|_| Refusal::OutOfRange)?;
                // 2000-01-01 .. 2200-01-01: anything else is a host bug.
                if !(946_684_800_000_000..=7_258_118_400_000_000).contains(&utc_unix_us) {
                    return Err(Refusal::OutOfRange);
                }
                self.utc_offset_us = Some(utc_unix_us - t);
                Ok(())
            }
            Command::PositionFix { .. } | Command::ResetFilter => Ok(()), // handled above
            Command::Reboot => {
                self.request = BoardRequest::Reboot;
                Ok(())
            }
            // Queued by `handle_command`, never applied here.
            Command::SetRecord(_) | Command::ReadRecord(_) | Command::EraseRecord(_) => Err(Refusal::NotSupported),
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
                if lat_rad.abs() > core::f64::consts::FRAC_PI_2
                    || lon_rad.abs() > core::f64::consts::PI
                    || !(-12_000.0..=10_000.0).contains(&alt_m)
                {
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
