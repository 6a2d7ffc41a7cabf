//! TE Connectivity MS5837-30BA pressure sensor (Blue Robotics Bar30) on I2C address 0x76.
//!
//! Datasheet procedure, all of it here:
//! - `RESET` (0x1E), then `PROM READ` 0xA0 + 2k for the 7 words k = 0..6: word 0 holds the CRC-4
//!   in bits 15:12 and factory data, words 1..6 the coefficients C1..C6. The CRC-4 is checked
//!   with the datasheet's algorithm ([`crc4`]): a mismatch is [`Error::BadCrc`].
//! - `CONVERT D1` (0x40 + 2 * osr) / `CONVERT D2` (0x50 + 2 * osr), wait the datasheet's maximum
//!   conversion time for the OSR ([`Osr::conversion_time_us`]), then `ADC READ` (0x00) and read
//!   24 bits. The chip answers 0 when no conversion has completed (read too early, or read twice):
//!   the driver reports [`Error::NotReady`] instead of a bogus pressure.
//! - First-order compensation (dT, TEMP, OFF, SENS, P) and the datasheet's second-order
//!   correction (Ti, OFFi, SENSi for TEMP < 20 C, < -15 C and >= 20 C), in 64-bit integers
//!   ([`compensate`]). Divisions by powers of two are arithmetic shifts (floor), which reproduces
//!   the datasheet's worked example (TEMP = 1981, SENS = 1145816755, P = 39998); C's truncating
//!   `/` would give TEMP = 1982.
//! - Depth from pressure: `(P - P_surface) / (rho * g)` with the water density a parameter
//!   ([`DepthParams`]).
//!
//! Written here rather than taken from a crate: the published MS5837 crates are Linux-only or
//! embedded-hal 0.2, or skip the CRC-4 check or the second-order compensation.
//!
//! Two ways to measure:
//! ```ignore
//! let mut depth = Ms5837::new(i2c, DepthParams { water_density_kgm3: 1025.0, ..Default::default() });
//! depth.init(&mut delay)?;                         // reset, PROM, CRC-4
//! let r = depth.measure(Osr::R4096, &mut delay)?;  // blocking: D1, D2, compensation (~18 ms)
//! // or, from a scheduler, without blocking (each call does at most one conversion step):
//! if let Some(r) = depth.poll(now_us)? { /* r.pressure_pa, r.temp_c, r.depth_m */ }
//! ```

use embedded_hal::delay::DelayNs;
use embedded_hal::i2c::I2c;

use super::Error;

/// 7-bit I2C address of the MS5837-30BA.
pub const ADDRESS: u8 = 0x76;

/// Command bytes.
pub mod cmd {
    pub const RESET: u8 = 0x1E;
    pub const CONVERT_D1: u8 = 0x40;
    pub const CONVERT_D2: u8 = 0x50;
    pub const ADC_READ: u8 = 0x00;
    pub const PROM_READ: u8 = 0xA0;
}

/// Time to wait after `RESET` before reading the PROM (datasheet: reload takes 2.8 ms max).
pub const RESET_TIME_US: u32 = 3_000;
/// Number of PROM words of the MS5837-30BA (CRC/factory word + C1..C6).
pub const PROM_WORDS: usize = 7;

/// Oversampling ratio of a conversion (resolution vs. conversion time).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Osr {
    R256 = 0,
    R512 = 1,
    R1024 = 2,
    R2048 = 3,
    R4096 = 4,
    R8192 = 5,
}

impl Osr {
    /// Offset added to `CONVERT_D1` / `CONVERT_D2`.
    pub const fn command_offset(self) -> u8 {
        2 * self as u8
    }
    /// From a command offset (0, 2, .., 10).
    pub const fn from_command_offset(off: u8) -> Option<Self> {
        Some(match off {
            0 => Self::R256,
            2 => Self::R512,
            4 => Self::R1024,
            6 => Self::R2048,
            8 => Self::R4096,
            10 => Self::R8192,
            _ => return None,
        })
    }
    /// Maximum conversion time from the datasheet, microseconds.
    pub const fn conversion_time_us(self) -> u32 {
        match self {
            Self::R256 => 600,
            Self::R512 => 1_170,
            Self::R1024 => 2_280,
            Self::R2048 => 4_540,
            Self::R4096 => 9_040,
            Self::R8192 => 18_080,
        }
    }
}

/// Which quantity a conversion measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Conversion {
    /// D1, digital pressure.
    Pressure,
    /// D2, digital temperature.
    Temperature,
}

/// The datasheet's CRC-4 over the PROM: word 0's CRC nibble (bits 15:12) and an eighth word are
/// taken as 0, the 16 bytes are shifted through polynomial 0x3 (x^4 + x + 1) MSB first.
pub fn crc4(prom: &[u16; PROM_WORDS]) -> u8 {
    let mut rem: u16 = 0;
    for cnt in 0..16usize {
        let word = if cnt / 2 == 0 { prom[0] & 0x0FFF } else { prom.get(cnt / 2).copied().unwrap_or(0) };
        rem ^= if cnt % 2 == 1 { word & 0x00FF } else { word >> 8 };
        for _ in 0..8 {
            rem = if rem & 0x8000 != 0 { (rem << 1) ^ 0x3000 } else { rem << 1 };
        }
    }
    ((rem >> 12) & 0x000F) as u8
}

/// Calibration PROM contents: `c[0]` = CRC (bits 15:12) + factory data, `c[1..=6]` = C1..C6.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Calibration {
    pub c: [u16; PROM_WORDS],
}

impl Calibration {
    /// Check the CRC-4 of PROM words.
    pub fn from_prom<E>(c: [u16; PROM_WORDS]) -> Result<Self, Error<E>> {
        let expected = (c[0] >> 12) as u8;
        let computed = crc4(&c);
        if expected != computed {
            return Err(Error::BadCrc { expected, computed });
        }
        Ok(Self { c })
    }
}

/// Intermediate and final values of the first-order compensation (datasheet names).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FirstOrder {
    pub dt: i64,
    /// 0.01 deg C.
    pub temp: i64,
    pub off: i64,
    pub sens: i64,
    /// 0.1 mbar (= 10 Pa).
    pub p: i64,
}

/// First-order compensation of raw D1 / D2.
pub fn first_order(cal: &Calibration, d1: u32, d2: u32) -> FirstOrder {
    let c = cal.c.map(i64::from);
    let (d1, d2) = (i64::from(d1), i64::from(d2));
    let dt = d2 - (c[5] << 8);
    let temp = 2000 + ((dt * c[6]) >> 23);
    let off = (c[2] << 16) + ((c[4] * dt) >> 7);
    let sens = (c[1] << 15) + ((c[3] * dt) >> 8);
    let p = (((d1 * sens) >> 21) - off) >> 13;
    FirstOrder { dt, temp, off, sens, p }
}

/// Compensated result: temperature in 0.01 deg C and pressure in 0.1 mbar (10 Pa), the chip's
/// native output resolutions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Compensated {
    pub temp_centi_c: i32,
    pub pressure_decimbar: i32,
}

impl Compensated {
    pub fn pressure_pa(&self) -> f32 {
        self.pressure_decimbar as f32 * 10.0
    }
    pub fn temp_c(&self) -> f32 {
        self.temp_centi_c as f32 / 100.0
    }
}

/// First- and second-order compensation, exactly as the MS5837-30BA datasheet.
pub fn compensate(cal: &Calibration, d1: u32, d2: u32) -> Compensated {
    let f = first_order(cal, d1, d2);
    let dt2 = f.dt * f.dt;
    let t = f.temp - 2000;
    let (ti, mut offi, mut sensi);
    if f.temp < 2000 {
        // Low temperature.
        ti = (3 * dt2) >> 33;
        offi = (3 * t * t) >> 1;
        sensi = (5 * t * t) >> 3;
        if f.temp < -1500 {
            // Very low temperature.
            let v = f.temp + 1500;
            offi += 7 * v * v;
            sensi += 4 * v * v;
        }
    } else {
        // High temperature.
        ti = (2 * dt2) >> 37;
        offi = (t * t) >> 4;
        sensi = 0;
    }
    let off2 = f.off - offi;
    let sens2 = f.sens - sensi;
    let p2 = (((i64::from(d1) * sens2) >> 21) - off2) >> 13;
    let temp2 = f.temp - ti;
    Compensated {
        temp_centi_c: temp2.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32,
        pressure_decimbar: p2.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32,
    }
}

/// Water column parameters for depth.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DepthParams {
    pub water_density_kgm3: f32,
    /// Absolute pressure at the surface (atmosphere), Pa.
    pub surface_pressure_pa: f32,
    pub g_mps2: f32,
}

impl Default for DepthParams {
    /// Sea water, standard atmosphere, standard gravity.
    fn default() -> Self {
        Self { water_density_kgm3: 1025.0, surface_pressure_pa: 101_325.0, g_mps2: 9.80665 }
    }
}

impl DepthParams {
    /// Depth (m, positive down) of an absolute pressure, hydrostatic with constant density.
    pub fn depth_m(&self, pressure_pa: f32) -> f32 {
        (pressure_pa - self.surface_pressure_pa) / (self.water_density_kgm3 * self.g_mps2)
    }
}

/// One depth measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DepthReading {
    pub pressure_pa: f32,
    pub temp_c: f32,
    pub depth_m: f32,
    pub d1: u32,
    pub d2: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    D1 { due_us: u64 },
    D2 { d1: u32, due_us: u64 },
}

/// The MS5837-30BA driver. Owns its I2C handle.
pub struct Ms5837<I2C> {
    i2c: I2C,
    address: u8,
    cal: Option<Calibration>,
    state: State,
    /// OSR used by [`Self::poll`].
    pub osr: Osr,
    pub params: DepthParams,
}

impl<I2C: I2c> Ms5837<I2C> {
    /// Driver at the chip's fixed address 0x76; OSR 4096 for [`Self::poll`] (9 ms per conversion).
    pub fn new(i2c: I2C, params: DepthParams) -> Self {
        Self { i2c, address: ADDRESS, cal: None, state: State::Idle, osr: Osr::R4096, params }
    }

    pub fn destroy(self) -> I2C {
        self.i2c
    }

    /// The calibration read by [`Self::init`], if any.
    pub fn calibration(&self) -> Option<Calibration> {
        self.cal
    }

    /// Reset, read the PROM and check its CRC-4.
    pub fn init(&mut self, delay: &mut impl DelayNs) -> Result<Calibration, Error<I2C::Error>> {
        self.cal = None;
        self.state = State::Idle;
        self.reset()?;
        delay.delay_us(RESET_TIME_US);
        let cal = Calibration::from_prom(self.read_prom()?)?;
        self.cal = Some(cal);
        Ok(cal)
    }

    pub fn reset(&mut self) -> Result<(), Error<I2C::Error>> {
        self.i2c.write(self.address, &[cmd::RESET]).map_err(Error::Bus)
    }

    /// Read the 7 PROM words (no CRC check).
    pub fn read_prom(&mut self) -> Result<[u16; PROM_WORDS], Error<I2C::Error>> {
        let mut words = [0u16; PROM_WORDS];
        for (k, w) in words.iter_mut().enumerate() {
            let mut b = [0u8; 2];
            self.i2c.write_read(self.address, &[cmd::PROM_READ + 2 * k as u8], &mut b).map_err(Error::Bus)?;
            *w = u16::from_be_bytes(b);
        }
        Ok(words)
    }

    /// Start a conversion; returns the time to wait before [`Self::read_adc`], in microseconds.
    pub fn start(&mut self, what: Conversion, osr: Osr) -> Result<u32, Error<I2C::Error>> {
        let base = match what {
            Conversion::Pressure => cmd::CONVERT_D1,
            Conversion::Temperature => cmd::CONVERT_D2,
        };
        self.i2c.write(self.address, &[base + osr.command_offset()]).map_err(Error::Bus)?;
        Ok(osr.conversion_time_us())
    }

    /// Read the 24-bit result of the last conversion. 0 (conversion not finished, or already
    /// read) is [`Error::NotReady`].
    pub fn read_adc(&mut self) -> Result<u32, Error<I2C::Error>> {
        let mut b = [0u8; 3];
        self.i2c.write_read(self.address, &[cmd::ADC_READ], &mut b).map_err(Error::Bus)?;
        let v = u32::from_be_bytes([0, b[0], b[1], b[2]]);
        if v == 0 { Err(Error::NotReady) } else { Ok(v) }
    }

    /// Compensate raw values with the calibration (after [`Self::init`]).
    pub fn convert(&self, d1: u32, d2: u32) -> Result<DepthReading, Error<I2C::Error>> {
        let cal = self.cal.ok_or(Error::NotReady)?;
        let c = compensate(&cal, d1, d2);
        let pressure_pa = c.pressure_pa();
        Ok(DepthReading { pressure_pa, temp_c: c.temp_c(), depth_m: self.params.depth_m(pressure_pa), d1, d2 })
    }

    /// Blocking measurement: D1 and D2 at `osr`, then compensation.
    pub fn measure(&mut self, osr: Osr, delay: &mut impl DelayNs) -> Result<DepthReading, Error<I2C::Error>> {
        if self.cal.is_none() {
            return Err(Error::NotReady);
        }
        self.state = State::Idle;
        let wait = self.start(Conversion::Pressure, osr)?;
        delay.delay_us(wait);
        let d1 = self.read_adc()?;
        let wait = self.start(Conversion::Temperature, osr)?;
        delay.delay_us(wait);
        let d2 = self.read_adc()?;
        self.convert(d1, d2)
    }

    /// Non-blocking measurement driven by the caller's clock. Each call does at most one step:
    /// start D1 (when idle), read D1 and start D2 (when D1's time is up), read D2 and return the
    /// reading (when D2's time is up). A full reading takes three calls and at least twice
    /// [`Osr::conversion_time_us`]. Any error puts the sequence back to idle.
    pub fn poll(&mut self, now_us: u64) -> Result<Option<DepthReading>, Error<I2C::Error>> {
        if self.cal.is_none() {
            return Err(Error::NotReady);
        }
        let r = self.step(now_us);
        if r.is_err() {
            self.state = State::Idle;
        }
        r
    }

    fn step(&mut self, now_us: u64) -> Result<Option<DepthReading>, Error<I2C::Error>> {
        match self.state {
            State::Idle => {
                let wait = self.start(Conversion::Pressure, self.osr)?;
                self.state = State::D1 { due_us: now_us + u64::from(wait) };
                Ok(None)
            }
            State::D1 { due_us } if now_us >= due_us => {
                let d1 = self.read_adc()?;
                let wait = self.start(Conversion::Temperature, self.osr)?;
                self.state = State::D2 { d1, due_us: now_us + u64::from(wait) };
                Ok(None)
            }
            State::D2 { d1, due_us } if now_us >= due_us => {
                let d2 = self.read_adc()?;
                self.state = State::Idle;
                self.convert(d1, d2).map(Some)
            }
            _ => Ok(None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal::i2c::{ErrorKind, NoAcknowledgeSource};
    use embedded_hal_mock::eh1::delay::NoopDelay;
    use embedded_hal_mock::eh1::i2c::{Mock, Transaction as T};

    /// The MS5837-30BA datasheet's worked example ("Pressure and temperature calculation",
    /// typical values column): C1..C6, D1, D2.
    const EXAMPLE_C: [u16; 6] = [34982, 36352, 20328, 22354, 26646, 26146];
    const EXAMPLE_D1: u32 = 4958179;
    const EXAMPLE_D2: u32 = 6815414;

    /// PROM with a valid CRC: factory bits 0x340 (version 0x1A, as on 30BA parts) and the
    /// example coefficients; crc4 of these words is 9 (computed independently with a Python
    /// transcription of the datasheet's C routine while writing this test).
    fn example_prom() -> [u16; 7] {
        let mut w = [0x0340, 0, 0, 0, 0, 0, 0];
        w[1..].copy_from_slice(&EXAMPLE_C);
        w[0] |= u16::from(crc4(&w)) << 12;
        w
    }

    #[test]
    fn datasheet_worked_example_first_order() {
        let cal = Calibration { c: example_prom() };
        let f = first_order(&cal, EXAMPLE_D1, EXAMPLE_D2);
        // Datasheet: dT = -5962, TEMP = 1981 (19.81 C), SENS = 1145816755, P = 39998 (3999.8 mbar).
        assert_eq!(f.dt, -5962);
        assert_eq!(f.temp, 1981);
        assert_eq!(f.sens, 1145816755);
        assert_eq!(f.p, 39998);
        // The datasheet prints OFF = 2381326464, which its own formula does not give:
        // C2*2^16 + C4*dT/2^7 = 2382364672 - 1041207.40625 = 2381323464.59 (a misprinted digit in
        // the datasheet). We assert the formula's value.
        assert_eq!(f.off, 2381323464);
    }

    #[test]
    fn datasheet_worked_example_second_order() {
        // TEMP = 1981 < 2000: Ti = 3*dT^2/2^33 = 0, OFFi = 3*19^2/2 = 541, SENSi = 5*19^2/8 = 225,
        // so P2 = ((D1*(SENS-225))/2^21 - (OFF-541))/2^13 = 39998 and TEMP2 = 1981 (hand-computed).
        let cal = Calibration { c: example_prom() };
        let c = compensate(&cal, EXAMPLE_D1, EXAMPLE_D2);
        assert_eq!(c, Compensated { temp_centi_c: 1981, pressure_decimbar: 39998 });
        assert!((c.pressure_pa() - 399_980.0).abs() < 1e-3);
        assert!((c.temp_c() - 19.81).abs() < 1e-5);
    }

    #[test]
    fn second_order_branches() {
        let cal = Calibration { c: example_prom() };
        // High temperature: D2 giving dT = +300000 -> TEMP = 2000 + 300000*26146/2^23 = 2935.
        let d2 = 26646 * 256 + 300_000;
        let f = first_order(&cal, EXAMPLE_D1, d2);
        assert_eq!(f.temp, 2935);
        let c = compensate(&cal, EXAMPLE_D1, d2);
        // Ti = 2*dT^2/2^37 = 1 (1.31); OFFi = 935^2/16 = 54639; SENSi = 0.
        assert_eq!(c.temp_centi_c, 2934);
        let p2 = (((i64::from(EXAMPLE_D1) * f.sens) >> 21) - (f.off - 54639)) >> 13;
        assert_eq!(i64::from(c.pressure_decimbar), p2);
        // Very low temperature: dT = -1_300_000 -> TEMP = 2000 - 4052 = -2052 (< -1500).
        let d2 = 26646 * 256 - 1_300_000;
        let f = first_order(&cal, EXAMPLE_D1, d2);
        assert_eq!(f.temp, -2052);
        let c = compensate(&cal, EXAMPLE_D1, d2);
        let t = f.temp - 2000;
        let v = f.temp + 1500;
        let offi = (3 * t * t) / 2 + 7 * v * v;
        let sensi = (5 * t * t) / 8 + 4 * v * v;
        let ti = 3 * f.dt * f.dt / (1i64 << 33);
        assert_eq!(i64::from(c.temp_centi_c), f.temp - ti);
        let p2 = (((i64::from(EXAMPLE_D1) * (f.sens - sensi)) >> 21) - (f.off - offi)) >> 13;
        assert_eq!(i64::from(c.pressure_decimbar), p2);
    }

    fn prom_transactions(words: &[u16; 7]) -> Vec<T> {
        words.iter().enumerate().map(|(k, w)| T::write_read(0x76, vec![0xA0 + 2 * k as u8], w.to_be_bytes().to_vec())).collect()
    }

    #[test]
    fn init_resets_reads_prom_and_checks_crc() {
        let prom = example_prom();
        assert_eq!(prom[0] >> 12, 9);
        let mut t = vec![T::write(0x76, vec![0x1E])];
        t.extend(prom_transactions(&prom));
        let mut i2c = Mock::new(&t);
        let mut dev = Ms5837::new(i2c.clone(), DepthParams::default());
        assert_eq!(dev.init(&mut NoopDelay::new()).unwrap().c, prom);
        i2c.done();
    }

    #[test]
    fn bad_crc_is_reported() {
        let mut prom = example_prom();
        prom[3] ^= 0x0100; // one flipped bit in C3
        let mut t = vec![T::write(0x76, vec![0x1E])];
        t.extend(prom_transactions(&prom));
        let mut i2c = Mock::new(&t);
        let mut dev = Ms5837::new(i2c.clone(), DepthParams::default());
        assert!(matches!(dev.init(&mut NoopDelay::new()), Err(Error::BadCrc { expected: 9, computed }) if computed != 9));
        assert_eq!(dev.calibration(), None);
        assert_eq!(dev.measure(Osr::R256, &mut NoopDelay::new()), Err(Error::NotReady));
        i2c.done();
    }

    #[test]
    fn nack_is_a_bus_error() {
        let nack = ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address);
        let t = vec![T::write(0x76, vec![0x1E]).with_error(nack)];
        let mut i2c = Mock::new(&t);
        let mut dev = Ms5837::new(i2c.clone(), DepthParams::default());
        assert_eq!(dev.init(&mut NoopDelay::new()), Err(Error::Bus(nack)));
        i2c.done();
    }

    fn adc(v: u32) -> T {
        T::write_read(0x76, vec![0x00], v.to_be_bytes()[1..].to_vec())
    }

    #[test]
    fn measure_converts_d1_then_d2_and_computes_depth() {
        let mut t = vec![T::write(0x76, vec![0x1E])];
        t.extend(prom_transactions(&example_prom()));
        t.extend([T::write(0x76, vec![0x4A]), adc(EXAMPLE_D1), T::write(0x76, vec![0x5A]), adc(EXAMPLE_D2)]);
        let mut i2c = Mock::new(&t);
        let params = DepthParams { water_density_kgm3: 1000.0, surface_pressure_pa: 100_000.0, g_mps2: 10.0 };
        let mut dev = Ms5837::new(i2c.clone(), params);
        dev.init(&mut NoopDelay::new()).unwrap();
        let r = dev.measure(Osr::R8192, &mut NoopDelay::new()).unwrap();
        i2c.done();
        assert_eq!((r.d1, r.d2), (EXAMPLE_D1, EXAMPLE_D2));
        assert!((r.pressure_pa - 399_980.0).abs() < 1e-2);
        // (399980 - 100000) / (1000 * 10) = 29.998 m.
        assert!((r.depth_m - 29.998).abs() < 1e-4);
    }

    #[test]
    fn adc_zero_is_not_ready_and_poll_steps_with_time() {
        let mut t = vec![T::write(0x76, vec![0x1E])];
        t.extend(prom_transactions(&example_prom()));
        // poll at t=0: start D1 (OSR 4096 -> 0x48); t=5000: too early, no traffic; t=9040: read D1
        // (0 = not ready -> error, back to idle); t=10000: start D1 again; t=19040: read D1,
        // start D2; t=28080: read D2 -> reading.
        t.extend([T::write(0x76, vec![0x48]), adc(0)]);
        t.extend([T::write(0x76, vec![0x48]), adc(EXAMPLE_D1), T::write(0x76, vec![0x58]), adc(EXAMPLE_D2)]);
        let mut i2c = Mock::new(&t);
        let mut dev = Ms5837::new(i2c.clone(), DepthParams::default());
        dev.init(&mut NoopDelay::new()).unwrap();
        assert_eq!(dev.poll(0), Ok(None));
        assert_eq!(dev.poll(5_000), Ok(None));
        assert_eq!(dev.poll(9_040), Err(Error::NotReady));
        assert_eq!(dev.poll(10_000), Ok(None));
        assert_eq!(dev.poll(19_040), Ok(None));
        assert_eq!(dev.poll(20_000), Ok(None));
        let r = dev.poll(28_080).unwrap().unwrap();
        assert!((r.pressure_pa - 399_980.0).abs() < 1e-2);
        i2c.done();
    }

    #[test]
    fn osr_commands_and_times() {
        assert_eq!(cmd::CONVERT_D1 + Osr::R256.command_offset(), 0x40);
        assert_eq!(cmd::CONVERT_D2 + Osr::R8192.command_offset(), 0x5A);
        for o in [Osr::R256, Osr::R512, Osr::R1024, Osr::R2048, Osr::R4096, Osr::R8192] {
            assert_eq!(Osr::from_command_offset(o.command_offset()), Some(o));
        }
        assert_eq!(Osr::from_command_offset(12), None);
    }
}
