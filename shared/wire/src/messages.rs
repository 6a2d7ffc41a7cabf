//! Message types on the link between the sensor head (firmware) and the host.
//!
//! Conventions (stated once for the whole project, see `docs/ARCHITECTURE.md`):
//! - Navigation frame: local NED (x north, y east, z down) in metres relative to the origin set
//!   by [`ConfigItem::Origin`]; depth is `z`, positive down.
//! - Body frame: FRD (x forward, y right, z down). Attitude quaternions rotate body -> NED and are
//!   stored `[w, x, y, z]`.
//! - Time: `t_us` is the sensor head's monotonic clock in microseconds since boot. UTC, once the
//!   host has set it, is `utc_offset_us + t_us` (see [`Downlink::SetTime`]).
//! - Units are in the field names (`_m`, `_mps`, `_rad`, `_radps`, `_mps2`, `_pa`, `_c`).
//!
//! Everything here is fixed size: the largest encoded frame is known at compile time
//! ([`super::MAX_UPLINK_FRAME`], [`super::MAX_DOWNLINK_FRAME`]).

use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

use crate::records::{CalibrationInUse, Record, RecordKey, RecordReport};

/// Which board produced the telemetry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Board {
    /// QEMU `mps2-an386` (Cortex-M4F), sensors simulated by the host.
    QemuMps2An386,
    /// STM32F405/F407-class sensor head.
    Stm32F405,
}

/// First message after every reset. A host refuses to interpret the rest of a stream whose
/// `protocol_version` or `schema_fingerprint` differs from its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Boot {
    pub protocol_version: u16,
    pub schema_fingerprint: u64,
    /// Firmware semantic version (major, minor, patch).
    pub firmware_version: [u8; 3],
    pub board: Board,
    /// Sensor-head clock at which this message was sent.
    pub t_us: u64,
    /// Which configuration and calibrations the head booted with, and the state of its store.
    pub calibration: CalibrationInUse,
    /// Why the head (re)started.
    pub reset_cause: ResetCause,
}

/// Why the sensor head started: read by the board at reset (STM32: `RCC_CSR`; QEMU: a word in
/// RAM the watchdog's NMI and the reboot command leave for the next boot).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetCause {
    /// Power applied (or the board cannot tell).
    PowerOn,
    /// The reset pin.
    Pin,
    /// Supply below the brown-out threshold.
    Brownout,
    /// A software reset: the `Reboot` command.
    Software,
    /// The watchdog was not fed in time: the firmware hung.
    Watchdog,
}

/// What the estimator is currently doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NavMode {
    /// No estimator output yet (not initialised, or no estimator on this build).
    Uninitialised,
    /// Aligning (static initialisation).
    Aligning,
    /// Inertial only: no aiding measurement accepted recently.
    Inertial,
    /// Aided navigation (compass / depth / velocity / position fixes).
    Aided,
}

/// Navigation solution in the local NED frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NavSolution {
    pub t_us: u64,
    pub mode: NavMode,
    pub pos_ned_m: [f32; 3],
    pub vel_ned_mps: [f32; 3],
    /// Body (FRD) -> NED rotation, `[w, x, y, z]`.
    pub att_nb_wxyz: [f32; 4],
    /// 1-sigma standard deviations of the position, velocity and attitude (roll, pitch, yaw) errors.
    pub sigma_pos_m: [f32; 3],
    pub sigma_vel_mps: [f32; 3],
    pub sigma_att_rad: [f32; 3],
    /// North-east covariance of the position error, m^2 (with `sigma_pos_m` the whole
    /// horizontal covariance, which a map built from this solution needs).
    pub cov_ne_m2: f32,
}

/// One IMU sample in the body frame, after scaling to SI units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImuSample {
    pub t_us: u64,
    pub gyro_radps: [f32; 3],
    pub accel_mps2: [f32; 3],
    pub temp_c: f32,
}

/// Raw photodiode readings of one polarization unit (ADC counts behind 0/45/90/135 deg polarizers).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PolarizationSample {
    pub t_us: u64,
    pub unit: u8,
    pub counts: [i16; 4],
}

/// Pressure sensor reading and the depth derived from it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DepthSample {
    pub t_us: u64,
    pub pressure_pa: f32,
    pub temp_c: f32,
    pub depth_m: f32,
}

/// What a DVL velocity is referenced to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DvlTracking {
    /// Velocity over the bottom (bottom lock): what the navigation filter fuses.
    Bottom,
    /// Velocity relative to the water column (no bottom lock): recorded, never fused.
    Water,
}

/// One DVL velocity report as the sensor head received it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DvlSample {
    /// Time of validity (centre of the ping), sensor-head clock.
    pub t_us: u64,
    /// When the report's last byte arrived, sensor-head clock (`>= t_us`).
    pub rx_us: u64,
    pub tracking: DvlTracking,
    /// The DVL's own validity flag (`false`: no lock; velocity not usable).
    pub valid: bool,
    /// Velocity in the DVL's axes, m/s.
    pub vel_dvl_mps: [f32; 3],
    /// Figure of merit (the DVL's 1-sigma estimate per axis), m/s.
    pub fom_mps: f32,
    /// Distance to the bottom, m (negative: unknown).
    pub altitude_m: f32,
    /// The DVL's own velocity covariance, DVL axes, row-major, (m/s)^2, when it sends one.
    pub covariance_m2ps2: Option<[f32; 9]>,
}

/// Raw sensor samples, for recording, replay and offline tuning.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RawSample {
    Imu(ImuSample),
    Polarization(PolarizationSample),
    Depth(DepthSample),
    Dvl(DvlSample),
}

/// Compass output: the heading the polarization compass measured, or why it could not.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CompassReport {
    pub t_us: u64,
    /// Heading (rad, from north, clockwise) and its 1-sigma, when a fix was made and UTC is known.
    pub heading_rad: Option<f32>,
    pub sigma_heading_rad: f32,
    /// Sun azimuth relative to the body x axis (rad) and refracted sun elevation (rad), in body level frame.
    pub sun_rel_azimuth_rad: f32,
    pub sun_elevation_rad: f32,
    /// Why there is no fix (0 = fix). Codes are defined by the compass module.
    pub no_fix_reason: u8,
    pub units_used: u8,
}

/// What one aid source did with its latest measurement, and since boot (PX4 EKF2's
/// `estimator_aid_source` status): one per source in [`AidStatuses`], by name.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AidStatus {
    /// Time of validity of the latest measurement offered to the filter (head clock; 0: none).
    pub t_us: u64,
    /// Its normalised innovation squared against the filter's full innovation covariance.
    pub nis: f32,
    /// Its test ratio: the gate's NIS over the gate's threshold (> 1: refused by the gate).
    pub test_ratio: f32,
    /// The measurement noise in use, as a variance (mean of the diagonal; the source's unit
    /// squared: rad^2, m^2, (m/s)^2, m^2).
    pub noise_var: f32,
    /// Whether the latest measurement was fused.
    pub fused: bool,
    /// Since boot: measurements fused, refused by the gate, and resets of the state this source
    /// measures after its timeout or a run of refusals (heading, velocity, position).
    pub fused_count: u32,
    pub refused_count: u32,
    pub resets: u32,
    /// Time of validity of the last fused measurement (0: never).
    pub last_fused_us: u64,
}

/// The aid sources of the head's estimator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AidSource {
    Heading,
    Depth,
    Dvl,
    Position,
}

impl AidSource {
    /// Every source, in the order the telemetry lists them.
    pub const ALL: [AidSource; 4] = [AidSource::Heading, AidSource::Depth, AidSource::Dvl, AidSource::Position];

    pub fn name(self) -> &'static str {
        match self {
            AidSource::Heading => "heading",
            AidSource::Depth => "depth",
            AidSource::Dvl => "dvl",
            AidSource::Position => "position",
        }
    }
}

/// Every aid source's status, by name. [`AidStatuses::get`] matches every [`AidSource`]: a new
/// source does not compile until it has its field here.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AidStatuses {
    /// The polarization compass's heading fixes.
    pub heading: AidStatus,
    /// The depth sensor.
    pub depth: AidStatus,
    /// The DVL's bottom-track velocity.
    pub dvl: AidStatus,
    /// Position fixes from the host (USBL, map).
    pub position: AidStatus,
}

impl AidStatuses {
    pub fn get(&self, s: AidSource) -> &AidStatus {
        match s {
            AidSource::Heading => &self.heading,
            AidSource::Depth => &self.depth,
            AidSource::Dvl => &self.dvl,
            AidSource::Position => &self.position,
        }
    }

    pub fn get_mut(&mut self, s: AidSource) -> &mut AidStatus {
        match s {
            AidSource::Heading => &mut self.heading,
            AidSource::Depth => &mut self.depth,
            AidSource::Dvl => &mut self.dvl,
            AidSource::Position => &mut self.position,
        }
    }
}

/// Estimator health, for tuning and for noticing trouble.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FilterHealth {
    pub t_us: u64,
    /// Each aid source's status, by name.
    pub aid: AidStatuses,
    /// The IMU's process-noise scale in use (variance ratio against the head's tuning; it grows
    /// when the innovations say the IMU is noisier than configured).
    pub imu_q_scale: f32,
    /// Fading factor applied at the latest update (1.0 = no fading).
    pub lambda: f32,
    /// Diagonal of the (adapted) process noise, per state group: attitude, velocity, position,
    /// gyro bias, accel bias (mean of each group's diagonal).
    pub q_diag: [f32; 5],
    /// Covariance repairs (symmetrise / eigenvalue floor) since boot.
    pub pd_repairs: u32,
    /// Filter steps refused since boot because the state covariance could not be made
    /// positive definite even by the eigenvalue repair (the step was not applied).
    pub cov_unrepairable: u32,
    /// Measurements rejected by the innovation gate since boot.
    pub gate_rejects: u32,
    /// Samples rejected as non-finite since boot.
    pub nonfinite_rejects: u32,
    /// Measurements fused at their own (past) time of validity since boot.
    pub late_fused: u32,
    /// Measurements refused for their time since boot: older than the filter's history, or
    /// stamped in the future beyond the accepted bound.
    pub late_refused: u32,
    /// Re-acquisitions since boot: heading and position resets after a run of mutually
    /// consistent fixes the gate refused (the estimate was wrong, not the fixes).
    pub heading_resets: u32,
    pub position_resets: u32,
    /// CPU load over the last reporting period, per mille.
    pub cpu_load_permille: u16,
}

/// Where a fault happened.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FaultSource {
    Imu,
    Polarization {
        unit: u8,
    },
    Depth,
    Dvl,
    /// The camera trigger line.
    Camera,
    Link,
    Filter,
    Scheduler,
    /// The persistent store (configuration and calibration flash).
    Store,
}

/// What went wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FaultKind {
    BusNack,
    BusTimeout,
    BusOther,
    BadCrc,
    IdentityMismatch,
    Stuck,
    Saturated,
    NonFinite,
    /// A downlink frame was corrupt (bad COBS / CRC / postcard).
    CorruptFrame,
    /// A task overran its period.
    Overrun,
    /// Telemetry could not be sent (output full); `count` messages were dropped.
    TelemetryDropped,
    /// A polarization unit reads no light while the others do (covered, fouled): left out of
    /// the compass solution.
    Occluded,
    /// A sentence or frame from a sensor that does not parse (bad framing, fields, numbers,
    /// overlong).
    Malformed,
    /// The sensor flagged its reading invalid (a DVL without bottom lock): never fused.
    Invalid,
    /// A measurement older than the filter's history: refused.
    TooOld,
    /// A measurement stamped in the future beyond the accepted bound: refused.
    FromFuture,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Fault {
    pub t_us: u64,
    pub source: FaultSource,
    pub kind: FaultKind,
    /// Occurrences since boot of this source/kind pair.
    pub count: u32,
}

impl core::fmt::Display for FaultSource {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            FaultSource::Imu => f.write_str("IMU"),
            FaultSource::Polarization { unit } => write!(f, "polarization unit {unit}"),
            FaultSource::Depth => f.write_str("depth sensor"),
            FaultSource::Dvl => f.write_str("DVL"),
            FaultSource::Camera => f.write_str("camera trigger"),
            FaultSource::Link => f.write_str("host link"),
            FaultSource::Filter => f.write_str("navigation filter"),
            FaultSource::Scheduler => f.write_str("scheduler"),
            FaultSource::Store => f.write_str("persistent store"),
        }
    }
}

impl core::fmt::Display for FaultKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            FaultKind::BusNack => "bus NACK: the device did not acknowledge",
            FaultKind::BusTimeout => "bus timeout or no data ready",
            FaultKind::BusOther => "bus error (arbitration loss, overrun or other)",
            FaultKind::BadCrc => "a CRC or checksum did not match (calibration data or a sentence)",
            FaultKind::IdentityMismatch => "identity register does not match the expected chip",
            FaultKind::Stuck => "readings stuck at the same value",
            FaultKind::Saturated => "readings saturated (at full scale)",
            FaultKind::NonFinite => "non-finite (NaN or infinite) value",
            FaultKind::CorruptFrame => "corrupt downlink frame (bad COBS, CRC or payload)",
            FaultKind::Overrun => "task overran its period",
            FaultKind::TelemetryDropped => "telemetry dropped: output buffer full",
            FaultKind::Occluded => "no light while the other units see it (covered or fouled)",
            FaultKind::Malformed => "malformed sentence (framing, fields or numbers), or longer than the line buffer",
            FaultKind::Invalid => "the sensor flagged its reading invalid (e.g. DVL without bottom lock): not fused",
            FaultKind::TooOld => "measurement older than the filter's history: not fused",
            FaultKind::FromFuture => "measurement stamped in the future beyond the accepted bound: not fused",
        })
    }
}

impl core::error::Error for FaultKind {}

impl core::fmt::Display for Fault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{}: {} (at t = {} us, {} times since boot)", self.source, self.kind, self.t_us, self.count)
    }
}

/// Why a downlink command was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Refusal {
    OutOfRange,
    NotFinite,
    NotSupported,
    NotPositiveDefinite,
    Busy,
    /// The command's time of validity is older than the filter's history.
    TooOld,
    /// The command's time of validity is in the future beyond the accepted bound.
    FromFuture,
    /// The persistent store could not write or read the record (nothing changed).
    StoreFailed,
}

impl core::fmt::Display for Refusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Refusal::OutOfRange => "a command value is outside its accepted range",
            Refusal::NotFinite => "a command value is NaN or infinite",
            Refusal::NotSupported => "command not supported by this firmware",
            Refusal::NotPositiveDefinite => "the command's covariance is not positive definite",
            Refusal::Busy => "sensor head busy (queue full, or the filter is not running yet): command not applied, retry",
            Refusal::TooOld => "the command's time is older than the filter's history: not applied",
            Refusal::FromFuture => "the command's time is further in the future than the head accepts: not applied",
            Refusal::StoreFailed => "the persistent store could not save or read the record: nothing changed",
        })
    }
}

impl core::error::Error for Refusal {}

/// The sensor head's answer to every downlink command.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CommandAck {
    pub seq: u16,
    pub result: Result<(), Refusal>,
}

/// The head fired its camera trigger line: frame `frame` (counting from 0 since boot) is
/// exposed at sensor-head time `t_us`. A camera on the host side stamps its images with this.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CameraTrigger {
    pub t_us: u64,
    pub frame: u32,
}

/// Firmware -> host.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Uplink {
    Boot(Boot),
    Nav(NavSolution),
    Raw(RawSample),
    Compass(CompassReport),
    Health(FilterHealth),
    Fault(Fault),
    Ack(CommandAck),
    Trigger(CameraTrigger),
    /// A stored record, answering `ReadRecord` (and one per key after `Boot`).
    Record(RecordReport),
}

impl Uplink {
    /// Sensor-head time stamp of the message.
    pub fn t_us(&self) -> Option<u64> {
        Some(match self {
            Uplink::Boot(m) => m.t_us,
            Uplink::Nav(m) => m.t_us,
            Uplink::Raw(RawSample::Imu(m)) => m.t_us,
            Uplink::Raw(RawSample::Polarization(m)) => m.t_us,
            Uplink::Raw(RawSample::Depth(m)) => m.t_us,
            Uplink::Raw(RawSample::Dvl(m)) => m.t_us,
            Uplink::Compass(m) => m.t_us,
            Uplink::Health(m) => m.t_us,
            Uplink::Fault(m) => m.t_us,
            Uplink::Trigger(m) => m.t_us,
            Uplink::Record(m) => m.t_us,
            Uplink::Ack(_) => return None,
        })
    }

    /// Short name of the message kind (used for channel names and counts).
    pub fn kind(&self) -> &'static str {
        match self {
            Uplink::Boot(_) => "boot",
            Uplink::Nav(_) => "nav",
            Uplink::Raw(RawSample::Imu(_)) => "raw.imu",
            Uplink::Raw(RawSample::Polarization(_)) => "raw.polarization",
            Uplink::Raw(RawSample::Depth(_)) => "raw.depth",
            Uplink::Raw(RawSample::Dvl(_)) => "raw.dvl",
            Uplink::Compass(_) => "compass",
            Uplink::Health(_) => "health",
            Uplink::Fault(_) => "fault",
            Uplink::Ack(_) => "ack",
            Uplink::Trigger(_) => "camera.trigger",
            Uplink::Record(_) => "record",
        }
    }
}

/// A configuration value. Each is range-checked by the firmware; a bad value is refused with a
/// [`Refusal`] in the [`CommandAck`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ConfigItem {
    /// Telemetry rate of navigation solutions, Hz (1..=50).
    NavRateHz(u8),
    /// Whether raw samples are streamed.
    StreamRaw(bool),
    /// Origin of the local NED frame (geodetic, rad and metres).
    Origin { lat_rad: f64, lon_rad: f64, alt_m: f32 },
    /// Water density for pressure -> depth, kg/m^3 (990..=1050).
    WaterDensityKgm3(f32),
}

/// Host -> firmware command body.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    SetConfig(ConfigItem),
    /// UTC microseconds since the Unix epoch at sensor-head time `t_us`.
    SetTime {
        t_us: u64,
        utc_unix_us: i64,
    },
    /// A position fix (e.g. a USBL fix or a recognised topological node) with its covariance
    /// (upper triangle, row-major: xx, xy, xz, yy, yz, zz), valid at sensor-head time `t_us`
    /// (usually in the past: the head fuses it at that time; refused with
    /// [`Refusal::TooOld`] / [`Refusal::FromFuture`] outside its history and future bound).
    PositionFix {
        t_us: u64,
        pos_ned_m: [f32; 3],
        cov_ned_m2: [f32; 6],
    },
    /// Re-initialise the estimator (not a reboot).
    ResetFilter,
    /// Reboot the sensor head.
    Reboot,
    /// Store a configuration or calibration record (range-checked; in use at once, and after
    /// every reboot).
    SetRecord(Record),
    /// Report the stored record (`Uplink::Record`).
    ReadRecord(RecordKey),
    /// Erase the stored record: its defaults are in use at once and after a reboot.
    EraseRecord(RecordKey),
}

/// Host -> firmware, with a sequence number echoed in the [`CommandAck`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Downlink {
    pub seq: u16,
    pub command: Command,
}
