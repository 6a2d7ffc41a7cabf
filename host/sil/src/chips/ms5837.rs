//! MS5837-30BA model on I2C (address 0x76).
//!
//! - Commands: `RESET` 0x1E, `CONVERT D1` 0x40 + 2*osr, `CONVERT D2` 0x50 + 2*osr,
//!   `ADC READ` 0x00 (then 3 bytes), `PROM READ` 0xA0 + 2k (then 2 bytes; k = 7 reads 0).
//! - Conversion time by OSR (datasheet maximum: 0.60, 1.17, 2.28, 4.54, 9.04, 18.08 ms for OSR
//!   256 .. 8192). As on the chip, an `ADC READ` gives 0 if no conversion has completed since the
//!   last read, and an `ADC READ` during a conversion gives 0 and loses that conversion. A new
//!   conversion command during a conversion restarts it (the datasheet leaves this undefined).
//!   OSR sets the time only: resolution noise is the simulator's pressure noise.
//! - PROM: word 0 = CRC-4 (bits 15:12) | factory bits 0x0340, words 1..6 = C1..C6 (default: the
//!   datasheet's typical values). The CRC is computed here with the datasheet's algorithm.
//! - Inverse model: the conversion result is the D1 / D2 that the datasheet's first- and
//!   second-order compensation maps closest to the input pressure / temperature at the start
//!   of the conversion (exact integer search: the compensation is monotone in D2, and in D1
//!   for fixed D2), so a correct driver reads the input back within half an output LSB
//!   (5 Pa, 0.005 C) as long as D1 / D2 stay within 24 bits.
//! - Faults: [`Ms5837Model::faults`], [`Ms5837Model::corrupt_crc`] (PROM word 0's CRC nibble
//!   flipped), [`Ms5837Model::stuck_d1`] (pressure conversion frozen at a raw value).

use super::{BusFault, BusFaults, I2cChip};

/// 7-bit address.
pub const ADDRESS: u8 = 0x76;
/// The datasheet's typical coefficients C1..C6 (its worked example).
pub const DATASHEET_C: [u16; 6] = [34982, 36352, 20328, 22354, 26646, 26146];
/// Factory bits of PROM word 0 (product version 0x1A in bits 11:5).
pub const FACTORY_BITS: u16 = 0x0340;

/// Physical input at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PressureInput {
    /// Absolute pressure at the sensor, Pa.
    pub pressure_pa: f64,
    pub temp_c: f64,
}

/// Maximum conversion time (µs) by OSR index 0..5 (256 .. 8192).
pub const CONVERSION_TIME_US: [u64; 6] = [600, 1_170, 2_280, 4_540, 9_040, 18_080];

/// CRC-4 of the PROM per the datasheet (word 0's top nibble and an 8th word taken as 0).
pub fn prom_crc4(words: &[u16; 7]) -> u8 {
    let mut w = [0u16; 8];
    w[..7].copy_from_slice(words);
    w[0] &= 0x0FFF;
    let mut rem: u32 = 0;
    for cnt in 0..16 {
        let byte = if cnt % 2 == 1 { w[cnt >> 1] & 0xFF } else { w[cnt >> 1] >> 8 };
        rem ^= u32::from(byte);
        for _ in 0..8 {
            rem = if rem & 0x8000 != 0 { (rem << 1) ^ 0x3000 } else { rem << 1 };
        }
    }
    ((rem >> 12) & 0xF) as u8
}

/// The datasheet's compensation (first and second order) in integers: (TEMP2 in 0.01 C, P2 in
/// 0.1 mbar). Used by the inverse model; written from the datasheet independently of the driver.
pub fn forward(c: &[u16; 6], d1: i64, d2: i64) -> (i64, i64) {
    let [c1, c2, c3, c4, c5, c6] = c.map(i64::from);
    let dt = d2 - c5 * 256;
    let temp = 2000 + (dt * c6).div_euclid(1 << 23);
    let off = c2 * 65536 + (c4 * dt).div_euclid(128);
    let sens = c1 * 32768 + (c3 * dt).div_euclid(256);
    let (ti, offi, sensi) = if temp < 2000 {
        let t2 = (temp - 2000) * (temp - 2000);
        let (mut o, mut s) = (3 * t2 / 2, 5 * t2 / 8);
        if temp < -1500 {
            let v = (temp + 1500) * (temp + 1500);
            o += 7 * v;
            s += 4 * v;
        }
        (3 * dt * dt / (1 << 33), o, s)
    } else {
        (2 * dt * dt / (1 << 37), (temp - 2000) * (temp - 2000) / 16, 0)
    };
    let p = ((d1 * (sens - sensi)).div_euclid(1 << 21) - (off - offi)).div_euclid(1 << 13);
    (temp - ti, p)
}

/// Smallest `x` in `[lo, hi]` with `f(x) >= target` (f non-decreasing), or `hi`.
fn lower_bound(lo: i64, hi: i64, target: f64, f: impl Fn(i64) -> f64) -> i64 {
    let (mut lo, mut hi) = (lo, hi);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        if f(mid) >= target { hi = mid } else { lo = mid + 1 }
    }
    lo
}

/// Of `x` and `x - 1`, the one whose `f` is closer to `target`.
fn closest(x: i64, lo: i64, target: f64, f: impl Fn(i64) -> f64) -> i64 {
    if x > lo && (f(x - 1) - target).abs() <= (f(x) - target).abs() { x - 1 } else { x }
}

const MAX_24: i64 = (1 << 24) - 1;

/// Inverse model: the raw (D1, D2) whose compensated output is closest to `input`.
pub fn inverse(c: &[u16; 6], input: PressureInput) -> (u32, u32) {
    let t_target = input.temp_c * 100.0;
    let temp_of = |d2: i64| forward(c, 0, d2).0 as f64;
    let d2 = closest(lower_bound(0, MAX_24, t_target, temp_of), 0, t_target, temp_of);
    let p_target = input.pressure_pa / 10.0;
    let p_of = |d1: i64| forward(c, d1, d2).1 as f64;
    let d1 = closest(lower_bound(0, MAX_24, p_target, p_of), 0, p_target, p_of);
    (d1 as u32, d2 as u32)
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Pending {
    None,
    Adc,
    Prom(u8),
}

#[derive(Debug, Clone, Copy)]
struct Conversion {
    pressure: bool,
    start_us: u64,
    end_us: u64,
}

pub struct Ms5837Model {
    source: Box<dyn FnMut(u64) -> PressureInput + Send>,
    coefficients: [u16; 6],
    prom: [u16; 7],
    pending: Pending,
    running: Option<Conversion>,
    result: Option<u32>,
    /// Transaction-level fault injection.
    pub faults: BusFaults,
    /// PROM word 0 is read with its CRC nibble flipped.
    pub corrupt_crc: bool,
    /// Pressure conversions return this raw D1.
    pub stuck_d1: Option<u32>,
    /// Conversions completed and read.
    pub conversions: u64,
}

impl Ms5837Model {
    /// With the datasheet's typical coefficients.
    pub fn new(source: impl FnMut(u64) -> PressureInput + Send + 'static) -> Self {
        Self::with_coefficients(DATASHEET_C, source)
    }

    /// With calibration coefficients C1..C6 (the PROM's CRC is computed from them).
    pub fn with_coefficients(c: [u16; 6], source: impl FnMut(u64) -> PressureInput + Send + 'static) -> Self {
        let mut prom = [FACTORY_BITS, c[0], c[1], c[2], c[3], c[4], c[5]];
        prom[0] |= u16::from(prom_crc4(&prom)) << 12;
        Self {
            source: Box::new(source),
            coefficients: c,
            prom,
            pending: Pending::None,
            running: None,
            result: None,
            faults: BusFaults::default(),
            corrupt_crc: false,
            stuck_d1: None,
            conversions: 0,
        }
    }

    /// PROM words as stored (valid CRC).
    pub fn prom(&self) -> [u16; 7] {
        self.prom
    }

    pub fn coefficients(&self) -> [u16; 6] {
        self.coefficients
    }

    fn finish(&mut self, t_us: u64) {
        if let Some(c) = self.running {
            if t_us >= c.end_us {
                let input = (self.source)(c.start_us);
                let (d1, d2) = inverse(&self.coefficients, input);
                self.result = Some(if c.pressure { self.stuck_d1.unwrap_or(d1) } else { d2 });
                self.running = None;
            }
        }
    }

    fn command(&mut self, t_us: u64, cmd: u8) {
        self.pending = Pending::None;
        match cmd {
            0x1E => {
                self.running = None;
                self.result = None;
            }
            0x00 => self.pending = Pending::Adc,
            0x40..=0x4A | 0x50..=0x5A if cmd % 2 == 0 => {
                let osr = usize::from((cmd & 0x0F) / 2);
                self.result = None;
                self.running = Some(Conversion { pressure: cmd < 0x50, start_us: t_us, end_us: t_us + CONVERSION_TIME_US[osr] });
            }
            0xA0..=0xAE if cmd % 2 == 0 => self.pending = Pending::Prom((cmd - 0xA0) / 2),
            _ => {}
        }
    }
}

impl I2cChip for Ms5837Model {
    fn address(&self) -> u8 {
        ADDRESS
    }

    fn begin(&mut self, t_us: u64) -> Result<(), BusFault> {
        self.faults.check(t_us)
    }

    fn write(&mut self, t_us: u64, bytes: &[u8]) -> Result<(), BusFault> {
        for &b in bytes {
            self.finish(t_us);
            if b == 0x00 && self.running.is_some() {
                // ADC read during a conversion: 0, and that conversion is lost.
                self.running = None;
                self.result = None;
            }
            self.command(t_us, b);
        }
        Ok(())
    }

    fn read(&mut self, t_us: u64, buf: &mut [u8]) -> Result<(), BusFault> {
        self.finish(t_us);
        buf.fill(0);
        match self.pending {
            Pending::Adc => {
                let v = self.result.take().unwrap_or(0);
                if v != 0 {
                    self.conversions += 1;
                }
                for (b, s) in buf.iter_mut().zip(v.to_be_bytes()[1..].iter()) {
                    *b = *s;
                }
            }
            Pending::Prom(k) => {
                let mut w = self.prom.get(usize::from(k)).copied().unwrap_or(0);
                if k == 0 && self.corrupt_crc {
                    w ^= 0x1000;
                }
                for (b, s) in buf.iter_mut().zip(w.to_be_bytes().iter()) {
                    *b = *s;
                }
            }
            Pending::None => {}
        }
        self.pending = Pending::None;
        Ok(())
    }

    fn end(&mut self, _t_us: u64) {}
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forward_reproduces_the_datasheet_example() {
        // Datasheet typical values: D1 = 4958179, D2 = 6815414 -> TEMP = 1981, P = 39998 (first
        // order); second order changes neither here (Ti = 0, P2 = 39998, hand-computed).
        assert_eq!(forward(&DATASHEET_C, 4958179, 6815414), (1981, 39998));
    }

    #[test]
    fn prom_crc_matches_an_independent_computation() {
        // crc4 of [0x0340, C1..C6] = 9, computed with a Python transcription of the datasheet's
        // C routine while writing this test.
        let m = Ms5837Model::new(|_| PressureInput { pressure_pa: 1e5, temp_c: 20.0 });
        assert_eq!(m.prom()[0], 0x9340);
        assert_eq!(prom_crc4(&m.prom()), 9);
    }

    #[test]
    fn inverse_hits_the_target_within_half_an_lsb() {
        for (p, t) in [(101_325.0, 20.0), (400_000.0, 4.5), (2_900_000.0, -18.0), (150_000.0, 35.2), (99_999.0, -16.3)] {
            let (d1, d2) = inverse(&DATASHEET_C, PressureInput { pressure_pa: p, temp_c: t });
            let (t2, p2) = forward(&DATASHEET_C, i64::from(d1), i64::from(d2));
            assert!((t2 as f64 - t * 100.0).abs() <= 0.5 + 1e-9, "T {t}: {t2}");
            assert!((p2 as f64 * 10.0 - p).abs() <= 5.0 + 1e-9, "P {p}: {p2}");
        }
    }

    fn cmd(m: &mut Ms5837Model, t: u64, c: u8) {
        m.begin(t).unwrap();
        m.write(t, &[c]).unwrap();
        m.end(t);
    }
    fn read(m: &mut Ms5837Model, t: u64, c: u8, n: usize) -> Vec<u8> {
        m.begin(t).unwrap();
        m.write(t, &[c]).unwrap();
        let mut b = vec![0; n];
        m.read(t, &mut b).unwrap();
        m.end(t);
        b
    }

    #[test]
    fn conversion_timing_and_zero_reads() {
        let mut m = Ms5837Model::new(|_| PressureInput { pressure_pa: 200_000.0, temp_c: 10.0 });
        cmd(&mut m, 0, 0x48); // D1, OSR 4096: 9.04 ms
        assert_eq!(read(&mut m, 9_039, 0x00, 3), vec![0, 0, 0], "too early: 0, conversion lost");
        assert_eq!(read(&mut m, 20_000, 0x00, 3), vec![0, 0, 0], "lost");
        cmd(&mut m, 30_000, 0x48);
        let d1 = read(&mut m, 39_040, 0x00, 3);
        assert_ne!(d1, vec![0, 0, 0]);
        assert_eq!(read(&mut m, 40_000, 0x00, 3), vec![0, 0, 0], "read twice: 0");
        assert_eq!(m.conversions, 1);
        m.corrupt_crc = true;
        assert_eq!(read(&mut m, 0, 0xA0, 2), (0x9340u16 ^ 0x1000).to_be_bytes().to_vec());
        assert_eq!(read(&mut m, 0, 0xA2, 2), 34982u16.to_be_bytes().to_vec());
        assert_eq!(read(&mut m, 0, 0xAE, 2), vec![0, 0]);
    }
}
