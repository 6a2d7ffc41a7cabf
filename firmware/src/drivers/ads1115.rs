//! Polarization photodiodes: eight TI ADS1115 16-bit ADCs on two I2C buses (0x48, 0x49, 0x4A,
//! 0x4B on each: the chip has only four addresses).
//!
//! Wiring (`subnav_wire::bridge::bus_map::POLARIZATION_ADC_I2C`): ADC `u` serves polarization
//! unit `u`, units 0-3 on the first bus, 4-7 on the second; its single-ended inputs AIN0..AIN3
//! carry the photodiodes behind the 0, 45, 90 and 135 deg polarizers, the order of
//! `subnav_wire::PolarizationSample::counts`. 8 units x 4 channels = 32 channels.
//!
//! The chip itself is driven by the maintained `ads1x1x` crate (eldruin, embedded-hal 1.0,
//! no_std): one-shot conversions with the chosen PGA range and data rate, polled through its
//! `nb` interface (the config register's OS bit). This module only schedules the 32 conversions:
//! the eight ADCs convert in parallel, channel by channel, and a unit whose ADC fails (NACK,
//! conversion that never completes) is reported on its own while the others still deliver.
//!
//! Counts are the raw signed 16-bit conversion results; [`volts`] converts with the PGA range.
//! A count at either end of the range (32767 or -32768) means the input is outside the PGA
//! range: it is flagged in [`Scan::saturated`].
//!
//! ```ignore
//! // one handle per ADC, on the bus the bus map gives (e.g. embedded-hal-bus devices)
//! let mut adcs = PolarizationAdcs::new(core::array::from_fn(|u| bus_for(u)), AdcConfig::default());
//! let init = adcs.init();                          // per unit: Ok, or the error of that ADC
//! // from the scheduler, every tick (non-blocking; about 5 calls per scan):
//! if let Some(scan) = adcs.poll() { /* scan.counts[unit][0..4], scan.errors[unit] */ }
//! // or blocking: let scan = adcs.scan(&mut delay);
//! ```

use ads1x1x::{Ads1x1x, DataRate16Bit, FullScaleRange, TargetAddr, channel, ic, mode};
use embedded_hal::delay::DelayNs;
use embedded_hal::i2c::I2c;

use super::Error;

/// Number of ADCs (= the head's polarization units) and channels per ADC.
pub const UNITS: usize = subnav_core::head::POLARIZATION_UNITS;
pub const CHANNELS: usize = 4;
/// (I2C bus, address) of unit 0..7: the bus map (its length must be the head's unit count).
pub const BUS_ADDRESSES: [(u8, u8); UNITS] = subnav_wire::bridge::bus_map::POLARIZATION_ADC_I2C;

/// The ADDR pin strapping that gives an address (0x48 GND, 0x49 VDD, 0x4A SDA, 0x4B SCL).
const fn target(address: u8) -> TargetAddr {
    match address {
        0x49 => TargetAddr::Vdd,
        0x4A => TargetAddr::Sda,
        0x4B => TargetAddr::Scl,
        _ => TargetAddr::Gnd,
    }
}

/// One ADS1115 in one-shot mode (the `ads1x1x` driver).
pub type Adc<I2C> = Ads1x1x<I2C, ic::Ads1115, ic::Resolution16Bit, mode::OneShot>;

pub use ads1x1x::{DataRate16Bit as DataRate, FullScaleRange as PgaRange};

/// Full-scale voltage of a PGA setting.
pub const fn full_scale_v(fsr: FullScaleRange) -> f32 {
    match fsr {
        FullScaleRange::Within6_144V => 6.144,
        FullScaleRange::Within4_096V => 4.096,
        FullScaleRange::Within2_048V => 2.048,
        FullScaleRange::Within1_024V => 1.024,
        FullScaleRange::Within0_512V => 0.512,
        FullScaleRange::Within0_256V => 0.256,
    }
}

/// Conversion time of a data rate, microseconds (1 / rate, rounded up).
pub const fn conversion_time_us(rate: DataRate16Bit) -> u32 {
    match rate {
        DataRate16Bit::Sps8 => 125_000,
        DataRate16Bit::Sps16 => 62_500,
        DataRate16Bit::Sps32 => 31_250,
        DataRate16Bit::Sps64 => 15_625,
        DataRate16Bit::Sps128 => 7_813,
        DataRate16Bit::Sps250 => 4_000,
        DataRate16Bit::Sps475 => 2_106,
        DataRate16Bit::Sps860 => 1_163,
    }
}

/// Volts of a count at a PGA range (1 LSB = FS / 32768).
pub fn volts(counts: i16, fsr: FullScaleRange) -> f32 {
    f32::from(counts) * full_scale_v(fsr) / 32768.0
}

/// ADC configuration, the same for every chip.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AdcConfig {
    pub fsr: FullScaleRange,
    pub rate: DataRate16Bit,
    /// Polls of one conversion that find it still running before the unit is given up for this
    /// scan ([`Error::NotReady`]). Size it to the conversion time over the polling period.
    pub max_polls: u16,
}

impl Default for AdcConfig {
    /// +-4.096 V (photodiode amplifiers swing 0..3.3 V), 860 SPS, 50 polls.
    fn default() -> Self {
        Self { fsr: FullScaleRange::Within4_096V, rate: DataRate16Bit::Sps860, max_polls: 50 }
    }
}

/// The result of one scan of the 32 channels.
#[derive(Debug)]
pub struct Scan<E> {
    /// `counts[unit][channel]`, channels in polarizer order 0, 45, 90, 135 deg. Zero for a failed unit.
    pub counts: [[i16; CHANNELS]; UNITS],
    /// Per unit: bit `k` set = channel `k` at full scale.
    pub saturated: [u8; UNITS],
    /// Per unit: `None`, or why that unit has no data in this scan.
    pub errors: [Option<Error<E>>; UNITS],
}

impl<E> Scan<E> {
    /// Units with a complete set of counts.
    pub fn ok_units(&self) -> impl Iterator<Item = usize> + '_ {
        self.errors.iter().enumerate().filter(|(_, e)| e.is_none()).map(|(u, _)| u)
    }
}

enum Slot<E> {
    Pending(u16),
    Done,
    Failed(Error<E>),
}

/// The eight ADCs of the polarization units.
pub struct PolarizationAdcs<I2C: I2c> {
    adcs: [Adc<I2C>; UNITS],
    config: AdcConfig,
    channel: usize,
    slots: [Slot<I2C::Error>; UNITS],
    counts: [[i16; CHANNELS]; UNITS],
    saturated: [u8; UNITS],
}

impl<I2C: I2c> PolarizationAdcs<I2C> {
    /// One bus handle per ADC (handles on one bus shared, e.g. with `embedded-hal-bus` or the
    /// QEMU bridge), unit `u`'s on the bus [`BUS_ADDRESSES`] names, at its address there. No
    /// bus traffic until [`Self::init`].
    pub fn new(buses: [I2C; UNITS], config: AdcConfig) -> Self {
        let mut i = 0;
        let adcs = buses.map(|bus| {
            let target = target(BUS_ADDRESSES.get(i).map_or(0x48, |b| b.1));
            i += 1;
            Ads1x1x::new_ads1115(bus, target)
        });
        Self {
            adcs,
            config,
            channel: 0,
            slots: core::array::from_fn(|_| Slot::Pending(0)),
            counts: [[0; CHANNELS]; UNITS],
            saturated: [0; UNITS],
        }
    }

    /// Give the bus handles back.
    pub fn destroy(self) -> [I2C; UNITS] {
        self.adcs.map(|a| a.destroy_ads1115())
    }

    pub fn config(&self) -> AdcConfig {
        self.config
    }

    /// Set PGA range and data rate on every ADC. The result per unit; a unit that failed here
    /// can be retried with another `init` (its scans will report the bus error meanwhile).
    pub fn init(&mut self) -> [Result<(), Error<I2C::Error>>; UNITS] {
        let cfg = self.config;
        self.channel = 0;
        self.slots = core::array::from_fn(|_| Slot::Pending(0));
        let mut out: [Result<(), Error<I2C::Error>>; UNITS] = core::array::from_fn(|_| Ok(()));
        for (adc, r) in self.adcs.iter_mut().zip(out.iter_mut()) {
            *r = adc.set_full_scale_range(cfg.fsr).and_then(|()| adc.set_data_rate(cfg.rate)).map_err(map_err);
        }
        out
    }

    /// Advance the scan without blocking. Returns the scan when all 32 channels are done (or
    /// their unit failed); the next call starts a new scan.
    pub fn poll(&mut self) -> Option<Scan<I2C::Error>> {
        // At most one pass per channel: when a channel completes on every ADC the next one is
        // started in the same call.
        for _ in 0..=CHANNELS {
            let ch = self.channel;
            let max_polls = self.config.max_polls;
            for (u, (adc, slot)) in self.adcs.iter_mut().zip(self.slots.iter_mut()).enumerate() {
                let Slot::Pending(polls) = slot else { continue };
                match read_channel(adc, ch) {
                    Ok(v) => {
                        if let Some(c) = self.counts.get_mut(u).and_then(|row| row.get_mut(ch)) {
                            *c = v;
                        }
                        if v == i16::MAX || v == i16::MIN {
                            if let Some(s) = self.saturated.get_mut(u) {
                                *s |= 1 << ch;
                            }
                        }
                        *slot = Slot::Done;
                    }
                    Err(nb::Error::WouldBlock) => {
                        *polls = polls.saturating_add(1);
                        if *polls > max_polls {
                            *slot = Slot::Failed(Error::NotReady);
                        }
                    }
                    Err(nb::Error::Other(e)) => *slot = Slot::Failed(map_err(e)),
                }
            }
            if self.slots.iter().any(|s| matches!(s, Slot::Pending(_))) {
                return None;
            }
            // Channel complete on every ADC: next channel (failed units stay failed).
            for s in self.slots.iter_mut() {
                if matches!(s, Slot::Done) {
                    *s = Slot::Pending(0);
                }
            }
            self.channel += 1;
            if self.channel >= CHANNELS {
                return Some(self.finish());
            }
        }
        None
    }

    /// Blocking scan: polls every quarter conversion time until the scan completes.
    pub fn scan(&mut self, delay: &mut impl DelayNs) -> Scan<I2C::Error> {
        let step = (conversion_time_us(self.config.rate) / 4).max(50);
        loop {
            if let Some(s) = self.poll() {
                return s;
            }
            delay.delay_us(step);
        }
    }

    fn finish(&mut self) -> Scan<I2C::Error> {
        self.channel = 0;
        let slots = core::mem::replace(&mut self.slots, core::array::from_fn(|_| Slot::Pending(0)));
        let errors = slots.map(|s| match s {
            Slot::Failed(e) => Some(e),
            _ => None,
        });
        let mut counts = core::mem::replace(&mut self.counts, [[0; CHANNELS]; UNITS]);
        let mut saturated = core::mem::replace(&mut self.saturated, [0; UNITS]);
        for ((row, sat), e) in counts.iter_mut().zip(saturated.iter_mut()).zip(errors.iter()) {
            if e.is_some() {
                *row = [0; CHANNELS];
                *sat = 0;
            }
        }
        Scan { counts, saturated, errors }
    }
}

fn map_err<E>(e: ads1x1x::Error<E>) -> Error<E> {
    match e {
        ads1x1x::Error::I2C(e) => Error::Bus(e),
        ads1x1x::Error::InvalidInputData => Error::InvalidInput,
    }
}

fn read_channel<I2C: I2c>(adc: &mut Adc<I2C>, ch: usize) -> nb::Result<i16, ads1x1x::Error<I2C::Error>> {
    match ch {
        0 => adc.read(channel::SingleA0),
        1 => adc.read(channel::SingleA1),
        2 => adc.read(channel::SingleA2),
        _ => adc.read(channel::SingleA3),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal::i2c::{ErrorKind, NoAcknowledgeSource};
    use embedded_hal_mock::eh1::i2c::{Mock, Transaction as T};

    // Config register bits (datasheet table "Config Register Field Descriptions").
    const OS: u16 = 1 << 15;
    const MODE_SINGLE: u16 = 1 << 8;
    const COMP_QUE_DISABLE: u16 = 0b11;
    const PGA_4V096: u16 = 0b001 << 9;
    const DR_860: u16 = 0b111 << 5;

    fn cfg(mux: u16) -> u16 {
        OS | (mux << 12) | PGA_4V096 | MODE_SINGLE | DR_860 | COMP_QUE_DISABLE
    }
    fn write_cfg(addr: u8, v: u16) -> T {
        T::write(addr, vec![0x01, (v >> 8) as u8, v as u8])
    }
    fn read_reg(addr: u8, reg: u8, v: u16) -> T {
        T::write_read(addr, vec![reg], v.to_be_bytes().to_vec())
    }

    #[test]
    fn init_writes_pga_and_data_rate() {
        // ads1x1x starts from the reset config 0x8583; PGA 001 (+-4.096 V) gives 0x8383, then
        // DR 111 (860 SPS) gives 0x83E3. One mock per unit, each expecting only its own address.
        let buses: [Mock; UNITS] = core::array::from_fn(|u| Mock::new(&init_transactions(BUS_ADDRESSES[u].1)));
        let mut adcs = PolarizationAdcs::new(buses, AdcConfig::default());
        assert!(adcs.init().iter().all(|r| r.is_ok()));
        assert_eq!(cfg(0b100), 0xC3E3);
        for mut b in adcs.destroy() {
            b.done();
        }
    }

    /// Transactions of one unit for a whole scan: per channel, is-busy check (config read, OS=1
    /// = idle), trigger (config write with the channel's MUX), one busy poll (OS=0), one idle
    /// poll (OS=1), conversion read.
    fn scan_transactions(addr: u8, counts: [i16; 4]) -> Vec<T> {
        let mut t = Vec::new();
        for (ch, c) in counts.iter().enumerate() {
            let mux = 0b100 | ch as u16;
            let c_cfg = cfg(mux);
            t.push(read_reg(addr, 0x01, c_cfg));
            t.push(write_cfg(addr, c_cfg));
            t.push(read_reg(addr, 0x01, c_cfg & !OS));
            t.push(read_reg(addr, 0x01, c_cfg));
            t.push(read_reg(addr, 0x00, *c as u16));
        }
        t
    }

    fn init_transactions(addr: u8) -> Vec<T> {
        vec![write_cfg(addr, 0x8383), write_cfg(addr, 0x83E3)]
    }

    #[test]
    fn scan_reads_32_channels_and_flags_saturation() {
        let counts = [
            [100, 200, 300, 400],
            [-5, 0, 5, 10],
            [32767, 1, 2, -32768],
            [7, 7, 7, 7],
            [1, 2, 3, 4],
            [5, 6, 7, 8],
            [9, 10, 11, 32767],
            [12, 13, 14, 15],
        ];
        let buses: [Mock; UNITS] = core::array::from_fn(|u| {
            let mut t = init_transactions(BUS_ADDRESSES[u].1);
            t.extend(scan_transactions(BUS_ADDRESSES[u].1, counts[u]));
            Mock::new(&t)
        });
        let mut adcs = PolarizationAdcs::new(buses, AdcConfig::default());
        assert!(adcs.init().iter().all(|r| r.is_ok()));
        let mut scan = None;
        for _ in 0..20 {
            if let Some(s) = adcs.poll() {
                scan = Some(s);
                break;
            }
        }
        let scan = scan.expect("scan completes");
        assert_eq!(scan.counts, counts);
        assert_eq!(scan.saturated, [0, 0, 0b1001, 0, 0, 0, 0b1000, 0]);
        assert!(scan.errors.iter().all(|e| e.is_none()));
        assert_eq!(scan.ok_units().count(), UNITS);
        for mut b in adcs.destroy() {
            b.done();
        }
    }

    #[test]
    fn a_nacking_adc_fails_only_its_unit() {
        let counts: [[i16; 4]; UNITS] = core::array::from_fn(|u| if u == 1 { [0; 4] } else { [1, 2, 3, 4].map(|c| c + 4 * u as i16) });
        let nack = ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address);
        let buses: [Mock; UNITS] = core::array::from_fn(|u| {
            let mut t = init_transactions(BUS_ADDRESSES[u].1);
            if u == 1 {
                t.push(T::write_read(BUS_ADDRESSES[u].1, vec![0x01], vec![0, 0]).with_error(nack));
            } else {
                t.extend(scan_transactions(BUS_ADDRESSES[u].1, counts[u]));
            }
            Mock::new(&t)
        });
        let mut adcs = PolarizationAdcs::new(buses, AdcConfig::default());
        assert!(adcs.init().iter().all(|r| r.is_ok()));
        let scan = (0..20).find_map(|_| adcs.poll()).expect("scan completes");
        assert_eq!(scan.errors[1], Some(Error::Bus(nack)));
        assert_eq!(scan.counts[0], counts[0]);
        assert_eq!(scan.counts[2], counts[2]);
        assert_eq!(scan.counts[7], counts[7]);
        assert_eq!(scan.ok_units().collect::<Vec<_>>(), vec![0, 2, 3, 4, 5, 6, 7]);
        for mut b in adcs.destroy() {
            b.done();
        }
    }

    #[test]
    fn a_conversion_that_never_completes_is_not_ready() {
        let addr = BUS_ADDRESSES[0].1;
        let c0 = cfg(0b100);
        let mut t = init_transactions(addr);
        t.push(read_reg(addr, 0x01, c0));
        t.push(write_cfg(addr, c0));
        // The trigger's WouldBlock counts as poll 1, the busy read as poll 2, the next busy read
        // exceeds max_polls = 2.
        for _ in 0..2 {
            t.push(read_reg(addr, 0x01, c0 & !OS));
        }
        let mut bus0 = Mock::new(&t);
        let others: Vec<Mock> = (1..UNITS)
            .map(|u| {
                let mut t = init_transactions(BUS_ADDRESSES[u].1);
                t.extend(scan_transactions(BUS_ADDRESSES[u].1, [1, 2, 3, 4]));
                Mock::new(&t)
            })
            .collect();
        let buses: [Mock; UNITS] = core::array::from_fn(|u| if u == 0 { bus0.clone() } else { others[u - 1].clone() });
        let mut adcs = PolarizationAdcs::new(buses, AdcConfig { max_polls: 2, ..AdcConfig::default() });
        assert!(adcs.init().iter().all(|r| r.is_ok()));
        let scan = (0..20).find_map(|_| adcs.poll()).expect("scan completes");
        assert_eq!(scan.errors[0], Some(Error::NotReady));
        assert_eq!(scan.counts[3], [1, 2, 3, 4]);
        bus0.done();
        for mut b in others {
            b.done();
        }
    }

    #[test]
    fn volts_use_the_pga_range() {
        assert!((volts(16384, FullScaleRange::Within4_096V) - 2.048).abs() < 1e-6);
        assert!((volts(-32768, FullScaleRange::Within0_256V) + 0.256).abs() < 1e-6);
    }
}
