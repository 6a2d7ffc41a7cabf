//! ICM-42688-P model on SPI: register bank 0 as the firmware driver
//! (`subnav_firmware::drivers::icm42688`) and the datasheet see it.
//!
//! - SPI framing: the first byte of a transaction is `R/W | address` (bit 7 = read); the
//!   following bytes read or write consecutive registers (auto-increment), across ops.
//! - Registers: `WHO_AM_I` (0x75) = 0x47 (or [`Icm42688Model::who_am_i`] to inject a mismatch),
//!   `DEVICE_CONFIG` soft reset (all registers back to reset values, `INT_STATUS.RESET_DONE`),
//!   `PWR_MGMT0`, `GYRO_CONFIG0` / `ACCEL_CONFIG0` (range bits 7:5, ODR bits 3:0; reset value
//!   0x06 = +-2000 deg/s / +-16 g at 1 kHz), `REG_BANK_SEL` (other banks read as 0),
//!   `INT_STATUS` (0x2D; `DATA_RDY` set by each new sample, cleared on read).
//! - Data: sample-and-hold at the ODR: the registers hold the input at the latest instant
//!   `k * period <= t`, quantized with the datasheet's nominal sensitivity (round to nearest)
//!   and clipped to +-32767. A burst read is one consistent sample. A sensor that is off, or has
//!   not produced a sample since power-on, reads 0x8000 on every axis (the registers' reset
//!   value), which the driver treats as invalid. Temperature: `round((T - 25) * 132.48)`. The
//!   chip's internal filters and start-up times are not modelled.
//! - Axes: the input is in body FRD; the chip axes equal the body axes unless
//!   [`Icm42688Model::chip_from_body`] gives the mounting rotation.
//! - Faults: [`Icm42688Model::faults`] (NACK/timeout on whole transactions; on SPI a "NACK" is
//!   a transaction the bridge reports as failed), [`Icm42688Model::stuck`] (an axis frozen at a
//!   raw value, or at the next sample's value), [`Icm42688Model::saturate`] (axes forced to full
//!   scale), [`Icm42688Model::who_am_i`].

// Register map and constants, written here from the datasheet independently of the firmware
// driver, so that the driver-vs-chip cross-check compares two readings of the datasheet.
mod reg {
    pub const DEVICE_CONFIG: u8 = 0x11;
    pub const TEMP_DATA1: u8 = 0x1D;
    pub const GYRO_DATA_Z0: u8 = 0x2A;
    pub const INT_STATUS: u8 = 0x2D;
    pub const PWR_MGMT0: u8 = 0x4E;
    pub const GYRO_CONFIG0: u8 = 0x4F;
    pub const ACCEL_CONFIG0: u8 = 0x50;
    pub const WHO_AM_I: u8 = 0x75;
    pub const REG_BANK_SEL: u8 = 0x76;
}
const WHO_AM_I_VALUE: u8 = 0x47;
const SPI_READ: u8 = 0x80;
const SOFT_RESET: u8 = 0x01;
const INT_STATUS_DATA_RDY: u8 = 1 << 3;
const INT_STATUS_RESET_DONE: u8 = 1 << 4;
const TEMP_LSB_PER_C: f64 = 132.48;
const TEMP_OFFSET_C: f64 = 25.0;

/// Gyro sensitivity, LSB per deg/s, by `GYRO_FS_SEL` (+-2000 .. +-15.625 deg/s).
pub const GYRO_LSB_PER_DPS: [f64; 8] = [16.4, 32.8, 65.5, 131.0, 262.0, 524.3, 1048.6, 2097.2];
/// Accel sensitivity, LSB per g, by `ACCEL_FS_SEL` (+-16 .. +-2 g; codes 4..7 reserved, as +-2 g).
pub const ACCEL_LSB_PER_G: [f64; 8] = [2048.0, 4096.0, 8192.0, 16384.0, 16384.0, 16384.0, 16384.0, 16384.0];

/// Sample period (ns) of an ODR code (low-noise mode); reserved codes run at 1 kHz.
pub fn odr_period_ns(code: u8) -> u64 {
    match code & 0xF {
        1 => 31_250,
        2 => 62_500,
        3 => 125_000,
        4 => 250_000,
        5 => 500_000,
        7 => 5_000_000,
        8 => 10_000_000,
        9 => 20_000_000,
        10 => 40_000_000,
        11 => 80_000_000,
        15 => 2_000_000,
        _ => 1_000_000,
    }
}

use super::{BusFault, BusFaults, SpiChip, quantize};

/// Physical input of the IMU at one instant, body FRD axes (the simulator's truth plus its
/// sensor error models).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImuInput {
    pub gyro_radps: [f64; 3],
    /// Specific force (what an accelerometer measures: acceleration minus gravity), m/s^2.
    pub specific_force_mps2: [f64; 3],
    pub temp_c: f64,
}

/// A stuck axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Stuck {
    #[default]
    Free,
    /// Frozen at this raw value.
    At(i16),
    /// Freeze at the value of the next sample produced.
    AtNext,
}

/// Standard gravity used by the datasheet's LSB/g.
const G: f64 = 9.80665;

pub struct Icm42688Model {
    source: Box<dyn FnMut(u64) -> ImuInput + Send>,
    regs: [u8; 128],
    /// Transaction-level fault injection.
    pub faults: BusFaults,
    /// Value of `WHO_AM_I` (0x47 on a real part).
    pub who_am_i: u8,
    /// Per axis (accel x, y, z, gyro x, y, z): frozen raw output.
    pub stuck: [Stuck; 6],
    /// Axes forced to full scale (bits 0..2 accel x/y/z, 3..5 gyro x/y/z), sign of the input.
    pub saturate: u8,
    /// Mounting: `chip = chip_from_body * body` (row-major). Identity: chip axes = body FRD.
    pub chip_from_body: [[f64; 3]; 3],
    // Transaction state.
    in_transaction: bool,
    command: Option<(bool, u8)>,
    latched: Option<[u8; 14]>,
    // Sensor state.
    gyro_on_us: Option<u64>,
    accel_on_us: Option<u64>,
    status: u8,
    last_status_sample: Option<u64>,
    /// Transactions served (successful).
    pub transactions: u64,
}

impl Icm42688Model {
    pub fn new(source: impl FnMut(u64) -> ImuInput + Send + 'static) -> Self {
        let mut m = Self {
            source: Box::new(source),
            regs: [0; 128],
            faults: BusFaults::default(),
            who_am_i: WHO_AM_I_VALUE,
            stuck: [Stuck::Free; 6],
            saturate: 0,
            chip_from_body: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            in_transaction: false,
            command: None,
            latched: None,
            gyro_on_us: None,
            accel_on_us: None,
            status: 0,
            last_status_sample: None,
            transactions: 0,
        };
        m.reset();
        m
    }

    fn reset(&mut self) {
        self.regs = [0; 128];
        self.regs[usize::from(reg::GYRO_CONFIG0)] = 0x06;
        self.regs[usize::from(reg::ACCEL_CONFIG0)] = 0x06;
        self.gyro_on_us = None;
        self.accel_on_us = None;
        self.status = INT_STATUS_RESET_DONE;
        self.last_status_sample = None;
    }

    fn bank(&self) -> u8 {
        self.regs[usize::from(reg::REG_BANK_SEL)] & 0x7
    }

    /// Current gyro configuration as written by the firmware: (LSB per deg/s, sample period ns).
    pub fn gyro_config(&self) -> (f64, u64) {
        let v = self.regs[usize::from(reg::GYRO_CONFIG0)];
        (GYRO_LSB_PER_DPS[usize::from(v >> 5)], odr_period_ns(v))
    }

    /// Current accel configuration: (LSB per g, sample period ns).
    pub fn accel_config(&self) -> (f64, u64) {
        let v = self.regs[usize::from(reg::ACCEL_CONFIG0)];
        (ACCEL_LSB_PER_G[usize::from(v >> 5)], odr_period_ns(v))
    }

    /// Both sensors powered (in any mode other than off).
    pub fn powered(&self) -> bool {
        self.gyro_on_us.is_some() && self.accel_on_us.is_some()
    }

    /// Index of the latest sample at or before `t_us` of a sensor with period `period_ns` that
    /// was switched on at `on_us`; `None` before its first sample.
    fn sample_index(t_us: u64, on_us: Option<u64>, period_ns: u64) -> Option<u64> {
        let on_ns = on_us?.saturating_mul(1000);
        let t_ns = t_us.saturating_mul(1000);
        let k = t_ns / period_ns;
        // First sample strictly after switch-on.
        let first = on_ns / period_ns + 1;
        (k >= first).then_some(k)
    }

    /// The 14 data bytes (temperature, accel, gyro; big endian) at `t_us`.
    fn sample(&mut self, t_us: u64) -> [u8; 14] {
        let (g_lsb_per_dps, g_period_ns) = self.gyro_config();
        let (a_lsb_per_g, a_period_ns) = self.accel_config();
        let gk = Self::sample_index(t_us, self.gyro_on_us, g_period_ns);
        let ak = Self::sample_index(t_us, self.accel_on_us, a_period_ns);
        let mut raw = [i16::MIN; 7];
        let rot =
            |m: &[[f64; 3]; 3], v: [f64; 3]| -> [f64; 3] { core::array::from_fn(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2]) };
        // The input is read at the sample instant of each sensor.
        if let Some(k) = ak {
            let input = (self.source)(k * a_period_ns / 1000);
            let f = rot(&self.chip_from_body, input.specific_force_mps2);
            let s = a_lsb_per_g / G;
            for i in 0..3 {
                raw[1 + i] = quantize(f[i] * s, -32767, 32767, -32767) as i16;
            }
            raw[0] = quantize((input.temp_c - TEMP_OFFSET_C) * TEMP_LSB_PER_C, -32767, 32767, 0) as i16;
        }
        if let Some(k) = gk {
            let input = (self.source)(k * g_period_ns / 1000);
            let w = rot(&self.chip_from_body, input.gyro_radps);
            let s = g_lsb_per_dps * 180.0 / std::f64::consts::PI;
            for i in 0..3 {
                raw[4 + i] = quantize(w[i] * s, -32767, 32767, -32767) as i16;
            }
            if ak.is_none() {
                raw[0] = quantize((input.temp_c - TEMP_OFFSET_C) * TEMP_LSB_PER_C, -32767, 32767, 0) as i16;
            }
        }
        for axis in 0..6 {
            let valid = if axis < 3 { ak.is_some() } else { gk.is_some() };
            if !valid {
                continue;
            }
            let v = &mut raw[1 + axis];
            if self.saturate & (1 << axis) != 0 {
                *v = if *v < 0 { -32767 } else { 32767 };
            }
            match self.stuck[axis] {
                Stuck::Free => {}
                Stuck::At(x) => *v = x,
                Stuck::AtNext => self.stuck[axis] = Stuck::At(*v),
            }
        }
        let mut out = [0u8; 14];
        for (i, v) in raw.iter().enumerate() {
            out[2 * i..2 * i + 2].copy_from_slice(&v.to_be_bytes());
        }
        out
    }

    fn data_ready_index(&self, t_us: u64) -> Option<u64> {
        let (_, g_period_ns) = self.gyro_config();
        Self::sample_index(t_us, self.gyro_on_us, g_period_ns)
    }

    fn read_register(&mut self, t_us: u64, addr: u8) -> u8 {
        if self.bank() != 0 && addr != reg::REG_BANK_SEL {
            return 0;
        }
        match addr {
            reg::TEMP_DATA1..=reg::GYRO_DATA_Z0 => {
                let data = match self.latched {
                    Some(d) => d,
                    None => {
                        let d = self.sample(t_us);
                        self.latched = Some(d);
                        d
                    }
                };
                data[usize::from(addr - reg::TEMP_DATA1)]
            }
            reg::INT_STATUS => {
                let k = self.data_ready_index(t_us);
                let mut v = self.status;
                if k.is_some() && k != self.last_status_sample {
                    v |= INT_STATUS_DATA_RDY;
                }
                self.status = 0;
                self.last_status_sample = k;
                v
            }
            reg::WHO_AM_I => self.who_am_i,
            a => self.regs.get(usize::from(a)).copied().unwrap_or(0),
        }
    }

    fn write_register(&mut self, t_us: u64, addr: u8, v: u8) {
        if addr == reg::REG_BANK_SEL {
            self.regs[usize::from(addr)] = v & 0x7;
            return;
        }
        if self.bank() != 0 {
            return;
        }
        match addr {
            reg::DEVICE_CONFIG if v & SOFT_RESET != 0 => self.reset(),
            reg::PWR_MGMT0 => {
                self.regs[usize::from(addr)] = v;
                let gyro_on = (v >> 2) & 0x3 != 0;
                let accel_on = v & 0x3 != 0;
                self.gyro_on_us = if gyro_on { self.gyro_on_us.or(Some(t_us)) } else { None };
                self.accel_on_us = if accel_on { self.accel_on_us.or(Some(t_us)) } else { None };
            }
            // Read-only: data, status, identity.
            reg::TEMP_DATA1..=reg::INT_STATUS | reg::WHO_AM_I => {}
            a => {
                if let Some(r) = self.regs.get_mut(usize::from(a)) {
                    *r = v;
                }
            }
        }
    }

    fn clock_byte(&mut self, t_us: u64, mosi: u8) -> u8 {
        match self.command {
            None => {
                self.command = Some((mosi & SPI_READ != 0, mosi & 0x7F));
                0
            }
            Some((read, addr)) => {
                let out = if read {
                    self.read_register(t_us, addr)
                } else {
                    self.write_register(t_us, addr, mosi);
                    0
                };
                self.command = Some((read, (addr + 1) & 0x7F));
                out
            }
        }
    }
}

impl SpiChip for Icm42688Model {
    fn begin(&mut self, t_us: u64) -> Result<(), BusFault> {
        self.faults.check(t_us)?;
        self.in_transaction = true;
        self.command = None;
        self.latched = None;
        Ok(())
    }

    fn transfer(&mut self, t_us: u64, write: &[u8], read: &mut [u8]) -> Result<(), BusFault> {
        if !self.in_transaction {
            return Err(BusFault::Other);
        }
        let n = write.len().max(read.len());
        for i in 0..n {
            let out = self.clock_byte(t_us, write.get(i).copied().unwrap_or(0));
            if let Some(r) = read.get_mut(i) {
                *r = out;
            }
        }
        Ok(())
    }

    fn end(&mut self, _t_us: u64) {
        if self.in_transaction {
            self.transactions += 1;
        }
        self.in_transaction = false;
        self.command = None;
        self.latched = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(m: &mut Icm42688Model, t: u64, addr: u8, n: usize) -> Vec<u8> {
        m.begin(t).unwrap();
        m.transfer(t, &[addr | 0x80], &mut []).unwrap();
        let mut buf = vec![0u8; n];
        m.transfer(t, &[], &mut buf).unwrap();
        m.end(t);
        buf
    }
    fn write(m: &mut Icm42688Model, t: u64, addr: u8, v: u8) {
        m.begin(t).unwrap();
        m.transfer(t, &[addr, v], &mut []).unwrap();
        m.end(t);
    }

    #[test]
    fn identity_reset_power_and_data() {
        let mut m = Icm42688Model::new(|t| ImuInput {
            gyro_radps: [(10.0f64).to_radians(), 0.0, -1.0],
            specific_force_mps2: [0.0, 0.0, -G + t as f64 * 0.0],
            temp_c: 45.0,
        });
        assert_eq!(read(&mut m, 0, 0x75, 1), vec![0x47]);
        // Off: data registers read 0x8000.
        assert_eq!(read(&mut m, 0, 0x1F, 2), vec![0x80, 0x00]);
        write(&mut m, 0, 0x4E, 0x0F);
        // No sample yet at the switch-on instant; the first one 1 ms later (1 kHz default).
        assert_eq!(read(&mut m, 500, 0x25, 2), vec![0x80, 0x00]);
        let d = read(&mut m, 1000, 0x1D, 14);
        let w = |i: usize| i16::from_be_bytes([d[i], d[i + 1]]);
        assert_eq!(w(0), (20.0f64 * 132.48).round() as i16);
        assert_eq!(w(6), -2048); // -1 g at +-16 g
        assert_eq!(w(8), 164); // 10 deg/s at 16.4 LSB/(deg/s)
        assert_eq!(w(12), -940); // -1 rad/s = -57.3 deg/s = -939.7 LSB
    }

    #[test]
    fn data_ready_config_faults_and_reset() {
        let mut m =
            Icm42688Model::new(|t| ImuInput { gyro_radps: [t as f64 * 1e-6, 50.0, 0.0], specific_force_mps2: [0.0; 3], temp_c: 25.0 });
        write(&mut m, 0, 0x4F, (3 << 5) | 7); // +-250 deg/s, 200 Hz
        write(&mut m, 0, 0x4E, 0x0F);
        assert_eq!(read(&mut m, 4_999, 0x2D, 1)[0] & 0x08, 0, "no sample before 5 ms");
        assert_eq!(read(&mut m, 5_000, 0x2D, 1)[0] & 0x08, 0x08);
        assert_eq!(read(&mut m, 6_000, 0x2D, 1)[0] & 0x08, 0, "cleared by the read, same sample");
        assert_eq!(read(&mut m, 10_000, 0x2D, 1)[0] & 0x08, 0x08);
        // Sample-and-hold: at t = 12.3 ms the registers hold the 10 ms sample (x = 0.01 rad/s).
        let d = read(&mut m, 12_300, 0x25, 6);
        let x = i16::from_be_bytes([d[0], d[1]]);
        assert_eq!(x, (0.01f64.to_degrees() * 131.0).round() as i16);
        // y = 50 rad/s is far beyond +-250 deg/s: clipped to full scale.
        assert_eq!(i16::from_be_bytes([d[2], d[3]]), 32767);
        m.stuck[3] = Stuck::AtNext;
        let a = read(&mut m, 15_000, 0x25, 2);
        let b = read(&mut m, 40_000, 0x25, 2);
        assert_eq!(a, b, "stuck x axis");
        m.saturate = 1 << 5;
        let z = read(&mut m, 40_000, 0x29, 2);
        assert_eq!(i16::from_be_bytes([z[0], z[1]]), 32767);
        m.who_am_i = 0x00;
        assert_eq!(read(&mut m, 0, 0x75, 1), vec![0x00]);
        m.faults.nack_next = 1;
        assert_eq!(m.begin(0), Err(BusFault::Nack));
        // Other banks read as zero; back to bank 0.
        write(&mut m, 0, 0x76, 1);
        assert_eq!(read(&mut m, 0, 0x4F, 1), vec![0]);
        write(&mut m, 0, 0x76, 0);
        assert_eq!(read(&mut m, 0, 0x4F, 1), vec![(3 << 5) | 7]);
        // Soft reset: defaults, sensors off, RESET_DONE.
        write(&mut m, 50_000, 0x11, 0x01);
        assert_eq!(read(&mut m, 50_000, 0x4F, 1), vec![0x06]);
        assert_eq!(read(&mut m, 60_000, 0x2D, 1), vec![0x10]);
        assert!(!m.powered());
    }
}
