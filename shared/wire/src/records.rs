//! What the sensor head keeps across a reboot: the run-time configuration and its calibrations,
//! one record per key, each stored versioned and checked.
//!
//! The same types travel over the link (`Command::SetRecord`, `Uplink::Record`) and sit in the
//! head's flash ([`encode_stored`] / [`decode_stored`]: a format byte, the postcard payload and a
//! CRC-32 of both), so the host that computes a calibration writes exactly what the head
//! stores. A stored record whose format byte, CRC or payload does not check is never used: the
//! head falls back to its defaults and says so in [`CalibrationInUse`].
//!
//! Units and frames follow [`crate::messages`]. Calibration models (what each number means):
//! - Polarization channel `k` of a unit: `counts_k = offset_k + gain_k * 0.5 * (S0 + eta_k (S1
//!   cos 2 th_k + S2 sin 2 th_k))`, `eta_k = (ER_k - 1) / (ER_k + 1)`, `th_k = polarizer_rad[k]`
//!   from the unit's reference axis (`subnav_core::compass::unit`).
//! - IMU: `gyro_body = R_body_imu * M_g * (gyro_raw - b_g)` and the same for the accelerometer,
//!   with `M` the inverse of the scale-and-misalignment matrix, upper triangular (its rotation
//!   part is the mounting rotation `R`): `[m00, m01, m02, m11, m12, m22]`.
//! - DVL: the rotation of the DVL's axes into the body axes, the lever arm and a scale factor.

use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

/// The stored form's version: bumped when a record type changes incompatibly (a head then boots
/// on defaults for that record and reports it, instead of reading a wrong layout).
pub const STORED_FORMAT: u8 = 1;

/// Which record.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RecordKey {
    RunConfig,
    /// Calibration of polarization unit `unit` (0..4).
    Polarization {
        unit: u8,
    },
    Imu,
    DvlMounting,
}

impl RecordKey {
    /// The key's number in the store (one byte).
    pub const fn id(&self) -> u8 {
        match self {
            RecordKey::RunConfig => 1,
            RecordKey::Imu => 2,
            RecordKey::DvlMounting => 3,
            RecordKey::Polarization { unit } => 16u8.saturating_add(*unit),
        }
    }

    pub const fn from_id(id: u8) -> Option<Self> {
        match id {
            1 => Some(RecordKey::RunConfig),
            2 => Some(RecordKey::Imu),
            3 => Some(RecordKey::DvlMounting),
            16..=31 => Some(RecordKey::Polarization { unit: id - 16 }),
            _ => None,
        }
    }
}

impl core::fmt::Display for RecordKey {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RecordKey::RunConfig => f.write_str("run configuration"),
            RecordKey::Polarization { unit } => write!(f, "polarization unit {unit} calibration"),
            RecordKey::Imu => f.write_str("IMU calibration"),
            RecordKey::DvlMounting => f.write_str("DVL mounting"),
        }
    }
}

/// Geodetic origin of the local NED frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Origin {
    pub lat_rad: f64,
    pub lon_rad: f64,
    pub alt_m: f32,
}

/// The run-time configuration (what `SetConfig` changes); stored whenever it changes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RunConfigRecord {
    pub nav_rate_hz: u8,
    pub stream_raw: bool,
    pub water_density_kgm3: f32,
    pub origin: Option<Origin>,
}

/// Calibration of one polarization unit, per channel (0/45/90/135 deg nominal).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PolarizationCalibration {
    pub unit: u8,
    /// Counts per unit of intensity.
    pub gain: [f32; 4],
    /// Dark offset, counts.
    pub offset_counts: [f32; 4],
    /// Polarizer transmission axis from the unit's reference axis, rad.
    pub polarizer_rad: [f32; 4],
    /// T_max / T_min (> 1).
    pub extinction_ratio: [f32; 4],
}

/// IMU calibration: biases, scale-and-misalignment inverses and the mounting rotation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImuCalibration {
    pub gyro_bias_radps: [f32; 3],
    pub accel_bias_mps2: [f32; 3],
    /// Upper triangle `[m00, m01, m02, m11, m12, m22]` of the matrix applied after the bias:
    /// the inverse of the gyro's scale and non-orthogonality (triangular: any rotation is in
    /// `body_from_imu_wxyz`).
    pub gyro_correction: [f32; 6],
    pub accel_correction: [f32; 6],
    /// Rotation IMU axes -> body FRD, `[w, x, y, z]`.
    pub body_from_imu_wxyz: [f32; 4],
}

/// DVL mounting: rotation DVL axes -> body FRD, lever arm (body FRD, m) and scale factor.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DvlMountingRecord {
    pub body_from_dvl_wxyz: [f32; 4],
    pub lever_arm_body_m: [f32; 3],
    /// Velocity scale factor (true = measured / scale).
    pub scale: f32,
}

/// One record, as set over the downlink, reported back and stored.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Record {
    RunConfig(RunConfigRecord),
    Polarization(PolarizationCalibration),
    Imu(ImuCalibration),
    DvlMounting(DvlMountingRecord),
}

impl Record {
    pub const fn key(&self) -> RecordKey {
        match self {
            Record::RunConfig(_) => RecordKey::RunConfig,
            Record::Polarization(p) => RecordKey::Polarization { unit: p.unit },
            Record::Imu(_) => RecordKey::Imu,
            Record::DvlMounting(_) => RecordKey::DvlMounting,
        }
    }
}

/// The head's answer to `ReadRecord` (and its report of each record at boot).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RecordReport {
    pub t_us: u64,
    pub key: RecordKey,
    /// The stored record (`None`: nothing valid stored under the key; the head uses defaults).
    pub stored: Option<Record>,
}

/// State of the persistent store at boot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreStatus {
    /// This board has no store: everything is a default and nothing survives a reboot.
    Absent,
    /// Read; the records it holds are in use.
    Ok,
    /// Readable but holds no record (a new head): defaults in use.
    Empty,
    /// It was damaged beyond the store's own repair and has been erased: defaults in use.
    Reformatted,
    /// The flash does not answer (bus fault, wrong chip): defaults in use, nothing is saved.
    Failed,
}

/// Which configuration and calibration the head booted with (in the `Boot` message).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(test, derive(postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CalibrationInUse {
    pub store: StoreStatus,
    /// The run configuration came from the store (else the firmware's defaults).
    pub config_stored: bool,
    /// Bit `u`: polarization unit `u` uses its stored calibration (else the nominal model).
    pub polarization_units_stored: u8,
    pub imu_stored: bool,
    pub dvl_stored: bool,
}

impl CalibrationInUse {
    /// A head without a store.
    pub const NO_STORE: CalibrationInUse = CalibrationInUse {
        store: StoreStatus::Absent,
        config_stored: false,
        polarization_units_stored: 0,
        imu_stored: false,
        dvl_stored: false,
    };
}

/// Bytes of the largest stored record.
pub const MAX_STORED_RECORD: usize = 1 + Record::POSTCARD_MAX_SIZE + 4;

/// Why stored bytes are not a record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoredError {
    /// Too short to hold a format byte and a CRC.
    Truncated,
    /// Written by another version of the record layout.
    Format { found: u8 },
    /// The CRC-32 does not match: damaged.
    Crc,
    /// The CRC matches but the payload is not a record (a firmware bug, not damage).
    Payload,
    /// The output buffer is too small (encoding).
    Buffer,
}

impl core::fmt::Display for StoredError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            StoredError::Truncated => f.write_str("stored record truncated"),
            StoredError::Format { found } => write!(f, "stored record has format {found}, this firmware reads {STORED_FORMAT}"),
            StoredError::Crc => f.write_str("stored record fails its CRC-32 (damaged)"),
            StoredError::Payload => f.write_str("stored record's payload does not decode"),
            StoredError::Buffer => f.write_str("buffer too small for the record"),
        }
    }
}

impl core::error::Error for StoredError {}

const STORED_CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// The stored form of `record` in `buf`: `[STORED_FORMAT] ++ postcard(record) ++ crc32_le`.
pub fn encode_stored<'b>(record: &Record, buf: &'b mut [u8]) -> Result<&'b [u8], StoredError> {
    let (first, rest) = buf.split_first_mut().ok_or(StoredError::Buffer)?;
    *first = STORED_FORMAT;
    let n = postcard::to_slice(record, rest).map_err(|_| StoredError::Buffer)?.len();
    let body_len = 1 + n;
    let crc = STORED_CRC.checksum(buf.get(..body_len).ok_or(StoredError::Buffer)?);
    buf.get_mut(body_len..body_len + 4).ok_or(StoredError::Buffer)?.copy_from_slice(&crc.to_le_bytes());
    buf.get(..body_len + 4).ok_or(StoredError::Buffer)
}

/// The record in `bytes` (the stored form), checked.
pub fn decode_stored(bytes: &[u8]) -> Result<Record, StoredError> {
    if bytes.len() < 1 + 4 {
        return Err(StoredError::Truncated);
    }
    let (body, crc) = bytes.split_at(bytes.len() - 4);
    let mut crc_le = [0u8; 4];
    crc_le.copy_from_slice(crc);
    if STORED_CRC.checksum(body) != u32::from_le_bytes(crc_le) {
        return Err(StoredError::Crc);
    }
    match body.split_first() {
        Some((&STORED_FORMAT, payload)) => match postcard::take_from_bytes::<Record>(payload) {
            Ok((r, [])) => Ok(r),
            _ => Err(StoredError::Payload),
        },
        Some((&found, _)) => Err(StoredError::Format { found }),
        None => Err(StoredError::Truncated),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn imu() -> Record {
        let eye = [1.0, 0.0, 0.0, 1.0, 0.0, 1.0];
        Record::Imu(ImuCalibration {
            gyro_bias_radps: [1e-3, -2e-3, 3e-4],
            accel_bias_mps2: [0.05, -0.02, 0.1],
            gyro_correction: eye,
            accel_correction: eye,
            body_from_imu_wxyz: [1.0, 0.0, 0.0, 0.0],
        })
    }

    #[test]
    fn stored_form_round_trips_and_every_bit_flip_is_caught() {
        let mut buf = [0u8; MAX_STORED_RECORD];
        let stored = encode_stored(&imu(), &mut buf).unwrap().to_vec();
        assert_eq!(decode_stored(&stored), Ok(imu()));
        for bit in 0..stored.len() * 8 {
            let mut b = stored.clone();
            b[bit / 8] ^= 1 << (bit % 8);
            assert!(decode_stored(&b).is_err(), "flip of bit {bit} not caught");
        }
        assert_eq!(decode_stored(&stored[..3]), Err(StoredError::Truncated));
    }

    #[test]
    fn another_format_is_refused_by_its_number() {
        let mut buf = [0u8; MAX_STORED_RECORD];
        let mut stored = encode_stored(&imu(), &mut buf).unwrap().to_vec();
        stored[0] = STORED_FORMAT + 1;
        let n = stored.len();
        let crc = STORED_CRC.checksum(&stored[..n - 4]);
        stored[n - 4..].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(decode_stored(&stored), Err(StoredError::Format { found: STORED_FORMAT + 1 }));
    }

    #[test]
    fn key_ids_are_distinct_and_invert() {
        let keys = [RecordKey::RunConfig, RecordKey::Imu, RecordKey::DvlMounting]
            .into_iter()
            .chain((0..4).map(|unit| RecordKey::Polarization { unit }));
        let mut seen = std::collections::BTreeSet::new();
        for k in keys {
            assert!(seen.insert(k.id()));
            assert_eq!(RecordKey::from_id(k.id()), Some(k));
        }
        assert_eq!(RecordKey::from_id(0), None);
    }
}
