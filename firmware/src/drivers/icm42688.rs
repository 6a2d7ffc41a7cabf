//! TDK InvenSense ICM-42688-P 6-axis IMU on SPI (register bank 0).
//!
//! What the driver does (datasheet DS-000347 register map, bank 0):
//! - identifies the chip (`WHO_AM_I` 0x75 = 0x47), soft-resets it (`DEVICE_CONFIG` 0x11 bit 0,
//!   then 1 ms), selects bank 0 (`REG_BANK_SEL` 0x76);
//! - sets gyro / accel full-scale range and output data rate (`GYRO_CONFIG0` 0x4F,
//!   `ACCEL_CONFIG0` 0x50: range in bits 7:5, ODR code in bits 3:0) and powers both sensors in
//!   low-noise mode with the temperature sensor on (`PWR_MGMT0` 0x4E = 0x0F);
//! - reads temperature, accel and gyro in one 14-byte burst from `TEMP_DATA1` 0x1D (big endian,
//!   the reset default of `INTF_CONFIG0`), scales them to SI with the datasheet's nominal
//!   sensitivities (gyro 16.4 LSB/(deg/s) at +-2000 deg/s ... 2097.2 at +-15.625; accel 2048 LSB/g at
//!   +-16 g ... 16384 at +-2 g; temperature `raw / 132.48 + 25` deg C);
//! - reports saturation: an axis at full scale (|raw| >= 32767) is flagged in
//!   [`ImuReading::saturated`], the value is still returned (clipped, as the chip outputs it);
//! - reports invalid data: the chip outputs -32768 on every axis of a sensor that is off or has
//!   no sample yet; the driver returns [`Error::NotReady`] for that;
//! - data-ready: `INT_STATUS` 0x2D bit 3 (`DATA_RDY_INT`, cleared by reading the register).
//!
//! Written here rather than taken from a crate: the published ICM-42688 crates are either
//! embedded-hal 0.2, async-only, or do not expose ranges/ODR together with data-ready and
//! saturation reporting.
//!
//! Output axes are the chip's axes (see [`super`] for the mounting convention); `g` is standard
//! gravity 9.80665 m/s^2, the unit the datasheet sensitivities are given in.
//!
//! ```ignore
//! let mut imu = Icm42688::new(spi_device, Config { gyro_range: GyroRange::Dps500, accel_range: AccelRange::G4, odr: Odr::Hz1000 });
//! imu.init(&mut delay)?;                     // WHO_AM_I, reset, ranges, ODR, power on
//! if imu.data_ready()? {                     // optional: INT_STATUS.DATA_RDY
//!     let r = imu.read()?;                   // r.gyro_radps, r.accel_mps2, r.temp_c, r.saturated
//! }
//! ```

use embedded_hal::delay::DelayNs;
use embedded_hal::spi::{Operation, SpiDevice};

use super::Error;

/// Bank 0 register addresses used by the driver (and by the host's chip model).
pub mod reg {
    pub const DEVICE_CONFIG: u8 = 0x11;
    pub const TEMP_DATA1: u8 = 0x1D;
    pub const ACCEL_DATA_X1: u8 = 0x1F;
    pub const GYRO_DATA_X1: u8 = 0x25;
    pub const INT_STATUS: u8 = 0x2D;
    pub const PWR_MGMT0: u8 = 0x4E;
    pub const GYRO_CONFIG0: u8 = 0x4F;
    pub const ACCEL_CONFIG0: u8 = 0x50;
    pub const WHO_AM_I: u8 = 0x75;
    pub const REG_BANK_SEL: u8 = 0x76;
}

/// `WHO_AM_I` value of the ICM-42688-P.
pub const WHO_AM_I_VALUE: u8 = 0x47;
/// SPI: bit 7 of the first byte set = read.
pub const SPI_READ: u8 = 0x80;
/// `DEVICE_CONFIG` bit 0: soft reset.
pub const SOFT_RESET: u8 = 0x01;
/// `INT_STATUS` bit 3: new data in the data registers.
pub const INT_STATUS_DATA_RDY: u8 = 1 << 3;
/// `INT_STATUS` bit 4: reset done.
pub const INT_STATUS_RESET_DONE: u8 = 1 << 4;
/// `PWR_MGMT0`: gyro low-noise (bits 3:2 = 11), accel low-noise (bits 1:0 = 11), temperature on.
pub const PWR_MGMT0_LOW_NOISE: u8 = 0x0F;
/// Temperature sensitivity, LSB per deg C, and its offset (deg C at raw 0).
pub const TEMP_LSB_PER_C: f32 = 132.48;
pub const TEMP_OFFSET_C: f32 = 25.0;
/// Standard gravity, m/s^2 per g.
pub const G_MPS2: f32 = 9.80665;
/// The value the chip reports for an invalid sample.
pub const INVALID: i16 = i16::MIN;
/// |raw| at or above this is full scale (saturated).
pub const FULL_SCALE: i16 = i16::MAX;

/// Gyro full-scale range (`GYRO_FS_SEL`, `GYRO_CONFIG0` bits 7:5).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum GyroRange {
    Dps2000 = 0,
    Dps1000 = 1,
    Dps500 = 2,
    Dps250 = 3,
    Dps125 = 4,
    Dps62_5 = 5,
    Dps31_25 = 6,
    Dps15_625 = 7,
}

impl GyroRange {
    /// Register field value.
    pub const fn fs_sel(self) -> u8 {
        self as u8
    }
    /// From the 3-bit register field.
    pub const fn from_fs_sel(bits: u8) -> Self {
        match bits & 0x7 {
            0 => Self::Dps2000,
            1 => Self::Dps1000,
            2 => Self::Dps500,
            3 => Self::Dps250,
            4 => Self::Dps125,
            5 => Self::Dps62_5,
            6 => Self::Dps31_25,
            _ => Self::Dps15_625,
        }
    }
    /// Nominal sensitivity from the datasheet, LSB per deg/s.
    pub const fn lsb_per_dps(self) -> f32 {
        match self {
            Self::Dps2000 => 16.4,
            Self::Dps1000 => 32.8,
            Self::Dps500 => 65.5,
            Self::Dps250 => 131.0,
            Self::Dps125 => 262.0,
            Self::Dps62_5 => 524.3,
            Self::Dps31_25 => 1048.6,
            Self::Dps15_625 => 2097.2,
        }
    }
    /// Nominal sensitivity, LSB per rad/s.
    pub fn lsb_per_radps(self) -> f32 {
        self.lsb_per_dps() * (180.0 / core::f32::consts::PI)
    }
}

/// Accelerometer full-scale range (`ACCEL_FS_SEL`, `ACCEL_CONFIG0` bits 7:5).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AccelRange {
    G16 = 0,
    G8 = 1,
    G4 = 2,
    G2 = 3,
}

impl AccelRange {
    pub const fn fs_sel(self) -> u8 {
        self as u8
    }
    /// From the 3-bit register field (values 4..7 are reserved; read as +-2 g).
    pub const fn from_fs_sel(bits: u8) -> Self {
        match bits & 0x7 {
            0 => Self::G16,
            1 => Self::G8,
            2 => Self::G4,
            _ => Self::G2,
        }
    }
    /// Nominal sensitivity, LSB per g.
    pub const fn lsb_per_g(self) -> f32 {
        match self {
            Self::G16 => 2048.0,
            Self::G8 => 4096.0,
            Self::G4 => 8192.0,
            Self::G2 => 16384.0,
        }
    }
    /// Nominal sensitivity, LSB per m/s^2.
    pub fn lsb_per_mps2(self) -> f32 {
        self.lsb_per_g() / G_MPS2
    }
}

/// Output data rate (`GYRO_ODR` / `ACCEL_ODR`, bits 3:0), low-noise mode codes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Odr {
    Hz32000 = 1,
    Hz16000 = 2,
    Hz8000 = 3,
    Hz4000 = 4,
    Hz2000 = 5,
    Hz1000 = 6,
    Hz200 = 7,
    Hz100 = 8,
    Hz50 = 9,
    Hz25 = 10,
    Hz12_5 = 11,
    Hz500 = 15,
}

impl Odr {
    pub const fn code(self) -> u8 {
        self as u8
    }
    /// From the 4-bit register field; `None` for reserved or low-power-only codes.
    pub const fn from_code(code: u8) -> Option<Self> {
        Some(match code & 0xF {
            1 => Self::Hz32000,
            2 => Self::Hz16000,
            3 => Self::Hz8000,
            4 => Self::Hz4000,
            5 => Self::Hz2000,
            6 => Self::Hz1000,
            7 => Self::Hz200,
            8 => Self::Hz100,
            9 => Self::Hz50,
            10 => Self::Hz25,
            11 => Self::Hz12_5,
            15 => Self::Hz500,
            _ => return None,
        })
    }
    /// Sample period in nanoseconds.
    pub const fn period_ns(self) -> u64 {
        match self {
            Self::Hz32000 => 31_250,
            Self::Hz16000 => 62_500,
            Self::Hz8000 => 125_000,
            Self::Hz4000 => 250_000,
            Self::Hz2000 => 500_000,
            Self::Hz1000 => 1_000_000,
            Self::Hz500 => 2_000_000,
            Self::Hz200 => 5_000_000,
            Self::Hz100 => 10_000_000,
            Self::Hz50 => 20_000_000,
            Self::Hz25 => 40_000_000,
            Self::Hz12_5 => 80_000_000,
        }
    }
}

/// Driver configuration (applied by [`Icm42688::init`] / [`Icm42688::configure`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    pub gyro_range: GyroRange,
    pub accel_range: AccelRange,
    /// Same ODR for gyro and accel.
    pub odr: Odr,
}

impl Default for Config {
    /// +-500 deg/s, +-4 g, 1 kHz: an AUV turns slowly, and 1 kHz leaves the 200 Hz task a fresh
    /// sample at every tick.
    fn default() -> Self {
        Self { gyro_range: GyroRange::Dps500, accel_range: AccelRange::G4, odr: Odr::Hz1000 }
    }
}

/// Raw register values of one burst read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RawImu {
    pub temp: i16,
    pub accel: [i16; 3],
    pub gyro: [i16; 3],
}

/// One IMU sample in SI units, chip axes.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImuReading {
    pub gyro_radps: [f32; 3],
    pub accel_mps2: [f32; 3],
    pub temp_c: f32,
    /// Saturated axes: bits 0..2 accel x/y/z, bits 3..5 gyro x/y/z.
    pub saturated: u8,
    pub raw: RawImu,
}

impl ImuReading {
    pub const fn any_saturated(&self) -> bool {
        self.saturated != 0
    }
}

/// The ICM-42688-P driver. Owns its `SpiDevice`.
pub struct Icm42688<SPI> {
    spi: SPI,
    config: Config,
}

impl<SPI: SpiDevice> Icm42688<SPI> {
    /// Wrap the device; no bus traffic until [`Self::init`].
    pub fn new(spi: SPI, config: Config) -> Self {
        Self { spi, config }
    }

    /// Give the bus back.
    pub fn destroy(self) -> SPI {
        self.spi
    }

    pub fn config(&self) -> Config {
        self.config
    }

    /// Identify, soft-reset, configure and power on the sensors.
    pub fn init(&mut self, delay: &mut impl DelayNs) -> Result<(), Error<SPI::Error>> {
        self.write_reg(reg::REG_BANK_SEL, 0)?;
        self.check_identity()?;
        self.write_reg(reg::DEVICE_CONFIG, SOFT_RESET)?;
        // Datasheet: wait 1 ms after a soft reset before any other register access.
        delay.delay_us(1_000);
        self.check_identity()?;
        self.configure(self.config)?;
        self.write_reg(reg::PWR_MGMT0, PWR_MGMT0_LOW_NOISE)?;
        // Datasheet: no register writes for 200 us after a PWR_MGMT0 change.
        delay.delay_us(200);
        Ok(())
    }

    /// Read `WHO_AM_I`.
    pub fn who_am_i(&mut self) -> Result<u8, Error<SPI::Error>> {
        self.read_reg(reg::WHO_AM_I)
    }

    fn check_identity(&mut self) -> Result<(), Error<SPI::Error>> {
        let found = self.who_am_i()?;
        if found != WHO_AM_I_VALUE {
            return Err(Error::IdentityMismatch { expected: WHO_AM_I_VALUE, found });
        }
        Ok(())
    }

    /// Write ranges and ODR (may be called again at run time; takes effect at the next sample).
    pub fn configure(&mut self, config: Config) -> Result<(), Error<SPI::Error>> {
        self.write_reg(reg::GYRO_CONFIG0, (config.gyro_range.fs_sel() << 5) | config.odr.code())?;
        self.write_reg(reg::ACCEL_CONFIG0, (config.accel_range.fs_sel() << 5) | config.odr.code())?;
        self.config = config;
        Ok(())
    }

    /// `INT_STATUS.DATA_RDY`: a new sample arrived since the last status read (reading clears it).
    pub fn data_ready(&mut self) -> Result<bool, Error<SPI::Error>> {
        Ok(self.read_reg(reg::INT_STATUS)? & INT_STATUS_DATA_RDY != 0)
    }

    /// Burst-read temperature, accel and gyro registers.
    pub fn read_raw(&mut self) -> Result<RawImu, Error<SPI::Error>> {
        let mut b = [0u8; 14];
        self.spi.transaction(&mut [Operation::Write(&[reg::TEMP_DATA1 | SPI_READ]), Operation::Read(&mut b)]).map_err(Error::Bus)?;
        let w = |i: usize| i16::from_be_bytes([b.get(i).copied().unwrap_or(0), b.get(i + 1).copied().unwrap_or(0)]);
        Ok(RawImu { temp: w(0), accel: [w(2), w(4), w(6)], gyro: [w(8), w(10), w(12)] })
    }

    /// Read one sample and scale it to SI units.
    pub fn read(&mut self) -> Result<ImuReading, Error<SPI::Error>> {
        let raw = self.read_raw()?;
        scale(&raw, self.config)
    }

    /// Read a sample only if `DATA_RDY` is set (two transactions when it is).
    pub fn read_if_ready(&mut self) -> Result<Option<ImuReading>, Error<SPI::Error>> {
        if self.data_ready()? { self.read().map(Some) } else { Ok(None) }
    }

    fn read_reg(&mut self, reg: u8) -> Result<u8, Error<SPI::Error>> {
        let mut v = [0u8; 1];
        self.spi.transaction(&mut [Operation::Write(&[reg | SPI_READ]), Operation::Read(&mut v)]).map_err(Error::Bus)?;
        Ok(v[0])
    }

    fn write_reg(&mut self, reg: u8, value: u8) -> Result<(), Error<SPI::Error>> {
        self.spi.write(&[reg & !SPI_READ, value]).map_err(Error::Bus)
    }
}

/// Scale raw registers to SI with the datasheet sensitivities for `config`.
pub fn scale<E>(raw: &RawImu, config: Config) -> Result<ImuReading, Error<E>> {
    if raw.accel.iter().all(|&v| v == INVALID) || raw.gyro.iter().all(|&v| v == INVALID) {
        return Err(Error::NotReady);
    }
    let mut saturated = 0u8;
    for (i, &v) in raw.accel.iter().chain(raw.gyro.iter()).enumerate() {
        if v.unsigned_abs() >= FULL_SCALE.unsigned_abs() {
            saturated |= 1 << i;
        }
    }
    let a = config.accel_range.lsb_per_mps2();
    let g = config.gyro_range.lsb_per_radps();
    Ok(ImuReading {
        gyro_radps: raw.gyro.map(|v| f32::from(v) / g),
        accel_mps2: raw.accel.map(|v| f32::from(v) / a),
        temp_c: f32::from(raw.temp) / TEMP_LSB_PER_C + TEMP_OFFSET_C,
        saturated,
        raw: *raw,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal::spi::ErrorKind;
    use embedded_hal_mock::eh1::delay::NoopDelay;
    use embedded_hal_mock::eh1::spi::{Mock, Transaction as T};

    fn read_reg(reg: u8, v: u8) -> Vec<T<u8>> {
        vec![T::transaction_start(), T::write_vec(vec![reg | 0x80]), T::read(v), T::transaction_end()]
    }
    fn write_reg(reg: u8, v: u8) -> Vec<T<u8>> {
        vec![T::transaction_start(), T::write_vec(vec![reg, v]), T::transaction_end()]
    }

    fn init_sequence(cfg: Config) -> Vec<T<u8>> {
        let mut t = Vec::new();
        t.extend(write_reg(0x76, 0));
        t.extend(read_reg(0x75, 0x47));
        t.extend(write_reg(0x11, 0x01));
        t.extend(read_reg(0x75, 0x47));
        t.extend(write_reg(0x4F, (cfg.gyro_range as u8) << 5 | cfg.odr as u8));
        t.extend(write_reg(0x50, (cfg.accel_range as u8) << 5 | cfg.odr as u8));
        t.extend(write_reg(0x4E, 0x0F));
        t
    }

    #[test]
    fn init_identifies_resets_configures_and_powers_on() {
        let cfg = Config { gyro_range: GyroRange::Dps250, accel_range: AccelRange::G8, odr: Odr::Hz200 };
        let expected = init_sequence(cfg);
        // Register values from the datasheet: GYRO_CONFIG0 = 011_0_0111, ACCEL_CONFIG0 = 001_0_0111.
        assert!(expected.contains(&T::write_vec(vec![0x4F, 0b0110_0111])));
        assert!(expected.contains(&T::write_vec(vec![0x50, 0b0010_0111])));
        let mut spi = Mock::new(&expected);
        let mut imu = Icm42688::new(spi.clone(), cfg);
        imu.init(&mut NoopDelay::new()).unwrap();
        spi.done();
    }

    #[test]
    fn who_am_i_mismatch_is_reported() {
        let mut t = write_reg(0x76, 0);
        t.extend(read_reg(0x75, 0x6F));
        let mut spi = Mock::new(&t);
        let mut imu = Icm42688::new(spi.clone(), Config::default());
        assert_eq!(imu.init(&mut NoopDelay::new()), Err(Error::IdentityMismatch { expected: 0x47, found: 0x6F }));
        spi.done();
    }

    /// embedded-hal-mock's SPI mock cannot inject errors: a device whose every transaction fails.
    struct FailingSpi;
    impl embedded_hal::spi::ErrorType for FailingSpi {
        type Error = ErrorKind;
    }
    impl SpiDevice for FailingSpi {
        fn transaction(&mut self, _: &mut [Operation<'_, u8>]) -> Result<(), ErrorKind> {
            Err(ErrorKind::Other)
        }
    }

    #[test]
    fn bus_error_is_wrapped() {
        let mut imu = Icm42688::new(FailingSpi, Config::default());
        assert_eq!(imu.init(&mut NoopDelay::new()), Err(Error::Bus(ErrorKind::Other)));
        assert_eq!(imu.read(), Err(Error::Bus(ErrorKind::Other)));
        let _spi: FailingSpi = imu.destroy();
    }

    fn burst(raw: &RawImu) -> Vec<T<u8>> {
        let mut b = Vec::new();
        for v in [raw.temp, raw.accel[0], raw.accel[1], raw.accel[2], raw.gyro[0], raw.gyro[1], raw.gyro[2]] {
            b.extend(v.to_be_bytes());
        }
        vec![T::transaction_start(), T::write_vec(vec![0x9D]), T::read_vec(b), T::transaction_end()]
    }

    #[test]
    fn read_scales_with_datasheet_sensitivities() {
        let cfg = Config { gyro_range: GyroRange::Dps2000, accel_range: AccelRange::G16, odr: Odr::Hz1000 };
        // 1 g on z = 2048 LSB at +-16 g; 164 LSB = 10 deg/s at 16.4 LSB/(deg/s); 2649.6 LSB = 20 C above 25 C.
        let raw = RawImu { temp: 2650, accel: [0, -1024, 2048], gyro: [164, -1640, 0] };
        let mut spi = Mock::new(&burst(&raw));
        let mut imu = Icm42688::new(spi.clone(), cfg);
        let r = imu.read().unwrap();
        spi.done();
        assert!((r.accel_mps2[2] - 9.80665).abs() < 1e-5);
        assert!((r.accel_mps2[1] + 9.80665 / 2.0).abs() < 1e-5);
        assert!((r.gyro_radps[0] - 10f32.to_radians()).abs() < 1e-6);
        assert!((r.gyro_radps[1] + 100f32.to_radians()).abs() < 1e-5);
        assert!((r.temp_c - (2650.0 / 132.48 + 25.0)).abs() < 1e-4);
        assert_eq!(r.saturated, 0);
        assert_eq!(r.raw, raw);
    }

    #[test]
    fn saturated_axes_are_flagged_and_invalid_data_is_not_ready() {
        let raw = RawImu { temp: 0, accel: [32767, 0, -32767], gyro: [0, 0, 32767] };
        let mut t = burst(&raw);
        t.extend(burst(&RawImu { temp: 0, accel: [INVALID; 3], gyro: [INVALID; 3] }));
        let mut spi = Mock::new(&t);
        let mut imu = Icm42688::new(spi.clone(), Config::default());
        let r = imu.read().unwrap();
        assert_eq!(r.saturated, 0b10_0101);
        assert!(r.any_saturated());
        assert_eq!(imu.read(), Err(Error::NotReady));
        spi.done();
    }

    #[test]
    fn data_ready_reads_int_status_bit3() {
        let mut t = read_reg(0x2D, 0x08);
        t.extend(read_reg(0x2D, 0x10));
        let mut spi = Mock::new(&t);
        let mut imu = Icm42688::new(spi.clone(), Config::default());
        assert!(imu.data_ready().unwrap());
        assert_eq!(imu.read_if_ready().unwrap(), None);
        spi.done();
    }

    #[test]
    fn register_field_roundtrips() {
        for bits in 0..8 {
            assert_eq!(GyroRange::from_fs_sel(bits).fs_sel(), bits);
        }
        for code in 0..16u8 {
            if let Some(o) = Odr::from_code(code) {
                assert_eq!(o.code(), code);
            }
        }
        assert_eq!(Odr::from_code(0), None);
    }
}
