//! ADS1115 model on I2C (one per polarization unit, addresses 0x48..0x4B).
//!
//! - Pointer register: the first byte written in a transaction selects the register
//!   (0 conversion, 1 config, 2 Lo_thresh, 3 Hi_thresh); two more bytes write it (MSB first).
//!   Reads return the selected register, MSB first.
//! - Config (reset value 0x8583): MUX (bits 14:12: AIN0-AIN1, AIN0-AIN3, AIN1-AIN3, AIN2-AIN3,
//!   AIN0..AIN3 to GND), PGA (11:9: +-6.144, 4.096, 2.048, 1.024, 0.512, 0.256 V), MODE (8:
//!   1 = single-shot), DR (7:5: 8..860 SPS). Writing OS = 1 in single-shot mode when idle starts
//!   one conversion lasting `1 / DR` (rounded up to a microsecond); while it runs, OS reads 0.
//!   In continuous mode the conversion register follows the input at the data rate.
//! - Conversion: the input (volts on AIN0..AIN3 from the caller's source) at the start of the
//!   conversion, differenced by MUX, quantized as `round(V * 32768 / FS)` and clipped to
//!   -32768..32767. The comparator / ALERT pin is not modelled (thresholds are stored only).
//! - Faults: [`Ads1115Model::faults`] (NACK / timeout per transaction), [`Ads1115Model::hang`]
//!   (a conversion never completes: OS stays 0), [`Ads1115Model::stuck`] (a single-ended channel's
//!   result frozen at a code).

use super::{BusFault, BusFaults, I2cChip, quantize};

mod reg {
    pub const CONVERSION: u8 = 0;
    pub const CONFIG: u8 = 1;
    pub const LO_THRESH: u8 = 2;
    pub const HI_THRESH: u8 = 3;
}
const OS: u16 = 1 << 15;
const MODE_SINGLE: u16 = 1 << 8;
const CONFIG_RESET: u16 = 0x8583;

/// Full-scale voltage of a PGA code (bits 11:9).
pub fn pga_full_scale_v(code: u16) -> f64 {
    match code & 0x7 {
        0 => 6.144,
        1 => 4.096,
        2 => 2.048,
        3 => 1.024,
        4 => 0.512,
        _ => 0.256,
    }
}

/// Samples per second of a DR code (bits 7:5).
pub fn data_rate_sps(code: u16) -> u32 {
    [8, 16, 32, 64, 128, 250, 475, 860][usize::from(code & 0x7)]
}

/// Conversion time (µs) of a DR code: 1 / DR rounded up.
pub fn conversion_time_us(code: u16) -> u64 {
    1_000_000u64.div_ceil(u64::from(data_rate_sps(code)))
}

pub struct Ads1115Model {
    address: u8,
    source: Box<dyn FnMut(u64) -> [f64; 4] + Send>,
    pointer: u8,
    config: u16,
    lo_thresh: u16,
    hi_thresh: u16,
    conversion: i16,
    /// Running single-shot conversion: (start, end, config at start).
    running: Option<(u64, u64, u16)>,
    /// Continuous mode: when it started.
    continuous_since: Option<u64>,
    wbuf: Vec<u8>,
    /// Transaction-level fault injection.
    pub faults: BusFaults,
    /// Conversions never complete (OS stays 0).
    pub hang: bool,
    /// Per single-ended channel AIN0..AIN3: the conversion result is frozen at this code.
    pub stuck: [Option<i16>; 4],
    /// Conversions completed.
    pub conversions: u64,
}

impl Ads1115Model {
    /// `source(t_us)` = volts on AIN0..AIN3 (to GND) at `t_us`.
    pub fn new(address: u8, source: impl FnMut(u64) -> [f64; 4] + Send + 'static) -> Self {
        Self {
            address,
            source: Box::new(source),
            pointer: 0,
            config: CONFIG_RESET,
            lo_thresh: 0x8000,
            hi_thresh: 0x7FFF,
            conversion: 0,
            running: None,
            continuous_since: None,
            wbuf: Vec::new(),
            faults: BusFaults::default(),
            hang: false,
            stuck: [None; 4],
            conversions: 0,
        }
    }

    /// The config register as last written (OS bit as written).
    pub fn config(&self) -> u16 {
        self.config
    }

    /// Quantized result for `config` of the input at `t_us`.
    fn convert(&mut self, t_us: u64, config: u16) -> i16 {
        let v = (self.source)(t_us);
        let mux = (config >> 12) & 0x7;
        let (p, n, single) = match mux {
            0 => (v[0], v[1], None),
            1 => (v[0], v[3], None),
            2 => (v[1], v[3], None),
            3 => (v[2], v[3], None),
            m => (v[usize::from(m - 4)], 0.0, Some(usize::from(m - 4))),
        };
        if let Some(code) = single.and_then(|ch| self.stuck[ch]) {
            return code;
        }
        let fs = pga_full_scale_v(config >> 9);
        quantize((p - n) * 32768.0 / fs, -32768, 32767, 0) as i16
    }

    /// Bring conversions up to `t_us`.
    fn update(&mut self, t_us: u64) {
        if let Some((start, end, cfg)) = self.running {
            if t_us >= end && !self.hang {
                self.conversion = self.convert(start, cfg);
                self.conversions += 1;
                self.running = None;
            }
        }
        if let Some(since) = self.continuous_since {
            let period = conversion_time_us(self.config >> 5);
            let n = t_us.saturating_sub(since) / period;
            if n >= 1 {
                let cfg = self.config;
                self.conversion = self.convert(since + (n - 1) * period, cfg);
            }
        }
    }

    fn write_config(&mut self, t_us: u64, v: u16) {
        let single = v & MODE_SINGLE != 0;
        self.config = v;
        if single {
            self.continuous_since = None;
            if v & OS != 0 && self.running.is_none() {
                self.running = Some((t_us, t_us + conversion_time_us(v >> 5), v));
            }
        } else if self.continuous_since.is_none() {
            self.running = None;
            self.continuous_since = Some(t_us);
        }
    }

    fn register(&self, r: u8) -> u16 {
        match r & 0x3 {
            reg::CONVERSION => self.conversion as u16,
            reg::CONFIG => {
                let busy = self.running.is_some();
                (self.config & !OS) | if busy { 0 } else { OS }
            }
            reg::LO_THRESH => self.lo_thresh,
            _ => self.hi_thresh,
        }
    }
}

impl I2cChip for Ads1115Model {
    fn address(&self) -> u8 {
        self.address
    }

    fn begin(&mut self, t_us: u64) -> Result<(), BusFault> {
        self.faults.check(t_us)?;
        self.wbuf.clear();
        self.update(t_us);
        Ok(())
    }

    fn write(&mut self, t_us: u64, bytes: &[u8]) -> Result<(), BusFault> {
        self.update(t_us);
        for &b in bytes {
            self.wbuf.push(b);
            match self.wbuf.as_slice() {
                [p] => self.pointer = p & 0x3,
                [p, hi, lo] => {
                    let v = u16::from_be_bytes([*hi, *lo]);
                    match p & 0x3 {
                        reg::CONFIG => self.write_config(t_us, v),
                        reg::LO_THRESH => self.lo_thresh = v,
                        reg::HI_THRESH => self.hi_thresh = v,
                        _ => {} // conversion register is read-only
                    }
                }
                _ => {}
            }
        }
        Ok(())
    }

    fn read(&mut self, t_us: u64, buf: &mut [u8]) -> Result<(), BusFault> {
        self.update(t_us);
        let v = self.register(self.pointer).to_be_bytes();
        for (i, b) in buf.iter_mut().enumerate() {
            *b = v[i % 2];
        }
        Ok(())
    }

    fn end(&mut self, _t_us: u64) {
        self.wbuf.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(m: &mut Ads1115Model, t: u64, bytes: &[u8]) {
        m.begin(t).unwrap();
        m.write(t, bytes).unwrap();
        m.end(t);
    }
    fn read(m: &mut Ads1115Model, t: u64, reg: u8) -> u16 {
        m.begin(t).unwrap();
        m.write(t, &[reg]).unwrap();
        let mut b = [0u8; 2];
        m.read(t, &mut b).unwrap();
        m.end(t);
        u16::from_be_bytes(b)
    }

    #[test]
    fn single_shot_conversion_with_timing_pga_and_mux() {
        let mut m = Ads1115Model::new(0x48, |t| [1.0, 2.0 + t as f64 * 1e-6, -0.1, 5.0]);
        assert_eq!(read(&mut m, 0, 1), 0x8583, "reset config, idle");
        // AIN1 single-ended, +-4.096 V, single-shot, 860 SPS, start.
        let cfg: u16 = 0x8000 | (0b101 << 12) | (0b001 << 9) | 0x0100 | (0b111 << 5) | 0b11;
        write(&mut m, 1000, &[1, (cfg >> 8) as u8, cfg as u8]);
        assert_eq!(read(&mut m, 1500, 1) & 0x8000, 0, "converting");
        assert_eq!(read(&mut m, 1000 + 1163, 1) & 0x8000, 0x8000, "done after 1/860 s");
        // Input at the start instant: 2.001 V at 4.096 V full scale.
        assert_eq!(read(&mut m, 3000, 0) as i16, (2.001f64 * 32768.0 / 4.096).round() as i16);
        // AIN3 = 5 V is beyond +-4.096 V: clipped. AIN2 = -0.1 V at +-0.256 V: negative code.
        let cfg3: u16 = 0x8000 | (0b111 << 12) | (0b001 << 9) | 0x0100 | (0b111 << 5);
        write(&mut m, 4000, &[1, (cfg3 >> 8) as u8, cfg3 as u8]);
        assert_eq!(read(&mut m, 6000, 0) as i16, 32767);
        let cfg2: u16 = 0x8000 | (0b110 << 12) | (0b101 << 9) | 0x0100 | (0b111 << 5);
        write(&mut m, 7000, &[1, (cfg2 >> 8) as u8, cfg2 as u8]);
        assert_eq!(read(&mut m, 9000, 0) as i16, -12800);
        // Differential AIN0 - AIN1 at 128 SPS: 7.813 ms.
        let cfgd: u16 = 0x8000 | (0b001 << 9) | 0x0100 | (0b100 << 5);
        write(&mut m, 10_000, &[1, (cfgd >> 8) as u8, cfgd as u8]);
        assert_eq!(read(&mut m, 17_812, 1) & 0x8000, 0);
        assert_eq!(read(&mut m, 17_813, 0) as i16, (-1.01f64 * 32768.0 / 4.096).round() as i16);
        assert_eq!(m.conversions, 4);
    }

    #[test]
    fn fault_knobs() {
        let mut m = Ads1115Model::new(0x49, |_| [1.0; 4]);
        let cfg: u16 = 0x8000 | (0b100 << 12) | (0b001 << 9) | 0x0100 | (0b111 << 5);
        m.hang = true;
        write(&mut m, 0, &[1, (cfg >> 8) as u8, cfg as u8]);
        assert_eq!(read(&mut m, 1_000_000, 1) & 0x8000, 0, "hung conversion never completes");
        m.hang = false;
        m.stuck[0] = Some(1234);
        assert_eq!(read(&mut m, 1_000_001, 0), 1234);
        m.faults.timeout_next = 1;
        assert_eq!(m.begin(0), Err(BusFault::Timeout));
        assert_eq!(m.address(), 0x49);
    }
}
