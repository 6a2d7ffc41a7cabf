//! Register-level models of the sensor head's chips, answering the firmware's bus transactions
//! (under QEMU through `subnav_wire::bridge`, in tests through embedded-hal adapters).
//!
//! Each model does what the silicon does and nothing more: register map, configuration effects
//! (range, ODR, PGA, data rate, OSR), quantization and clipping, conversion timing, identity and
//! PROM contents. The physical input at each instant comes from a caller-supplied source
//! (closure `FnMut(t_us) -> input`); sensor error models (bias, noise, random walk) belong to the
//! simulator and are applied before the values reach the chip.
//!
//! | model | chip | bus | input |
//! |---|---|---|---|
//! | [`icm42688::Icm42688Model`] | ICM-42688-P IMU | SPI | [`icm42688::ImuInput`] (body FRD rates / specific force, temperature) |
//! | [`ads1115::Ads1115Model`] | ADS1115 ADC | I2C 0x48..0x4B (two buses: `bus_map`) | volts on AIN0..AIN3 |
//! | [`ms5837::Ms5837Model`] | MS5837-30BA | I2C 0x76 | [`ms5837::PressureInput`] (absolute Pa, deg C) |
//! | [`dvl_a50::DvlA50Model`] | Water Linked DVL-A50 | UART 0 | [`dvl_a50::DvlInput`] (body velocity and rate, altitude, current) |
//! | [`camera::CameraModel`] | downward polarization camera (IMX250MZR-class) | trigger on GPIO 0 | the rendered seafloor at the truth pose of each trigger |
//! | [`w25q::W25qModel`] | Winbond W25Q16JV 2 MiB NOR flash (the store) | SPI 0, CS 1 | its contents (memory or a file), power cuts |
//! | [`modem::ModemModel`] | acoustic modem / USBL link delivering downlink frames | UART 1 | frames with their arrival times |
//!
//! Time: every call carries `t_us`, the firmware's timestamp of the transaction (the bridge's
//! `BusRequest::t_us`), so a run is deterministic whatever the host's speed.
//!
//! Transactions: a transaction is `begin` .. ops .. `end` (SPI: chip select low .. high;
//! I2C: START + address .. STOP). Reads after a write in the same transaction continue it
//! (SPI: the register address is the first byte of the first op; I2C: a repeated START).
//!
//! Faults: every model has a [`BusFaults`] (`.faults`) that fails whole transactions: NACK or
//! timeout on the next N, inside a time window, or with a seeded probability. Chip-specific
//! knobs (stuck axis, saturation, wrong `WHO_AM_I`, corrupted PROM CRC, hung conversion) are
//! fields of each model.
//!
//! [`ChipSet`] routes bridge requests to the attached models and implements
//! [`subnav_link::qemu::BusHandler`]:
//! ```ignore
//! let mut chips = ChipSet::new();
//! chips.attach_spi(0, 0, Icm42688Model::new(move |t_us| imu_truth(t_us)));
//! for (u, (bus, addr)) in bus_map::POLARIZATION_ADC_I2C.into_iter().enumerate() {
//!     chips.attach_i2c(bus, Ads1115Model::new(addr, move |t_us| photodiode_volts(u, t_us)));
//! }
//! chips.attach_i2c(0, Ms5837Model::new(move |t_us| PressureInput { pressure_pa: p(t_us), temp_c: 12.0 }));
//! let response = chips.handle(&request);             // or give `Box::new(chips)` to the QEMU runner
//! ```

pub mod ads1115;
pub mod camera;
pub mod dvl_a50;
pub mod icm42688;
pub mod modem;
pub mod ms5837;
pub mod w25q;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use subnav_wire::bridge::{Bus, BusRequest, BusResponse, Op, ReadData};

pub use subnav_wire::bridge::BusFault;

pub use ads1115::Ads1115Model;
pub use icm42688::{Icm42688Model, ImuInput};
pub use ms5837::{Ms5837Model, PressureInput};

/// A serial instrument on a UART: bytes fully received by `t_us` come out, commands go in.
pub trait UartChip: Send {
    /// Copy up to `buf.len()` bytes received by `t_us`; returns how many.
    fn read(&mut self, t_us: u64, buf: &mut [u8]) -> usize;
    /// Bytes the firmware sent at `t_us`.
    fn write(&mut self, t_us: u64, bytes: &[u8]);
}

/// A chip on an I2C bus.
/// A device on a digital line the firmware drives (e.g. a camera's trigger input).
pub trait GpioChip: Send {
    /// The line went to `high` at `t_us`.
    fn set(&mut self, t_us: u64, high: bool);
}

pub trait I2cChip: Send {
    /// 7-bit address.
    fn address(&self) -> u8;
    /// START + address at `t_us`. An error here is the address phase failing (NACK / stretch).
    fn begin(&mut self, t_us: u64) -> Result<(), BusFault>;
    /// Bytes written by the controller.
    fn write(&mut self, t_us: u64, bytes: &[u8]) -> Result<(), BusFault>;
    /// Bytes read by the controller (after a repeated START if the transaction wrote first).
    fn read(&mut self, t_us: u64, buf: &mut [u8]) -> Result<(), BusFault>;
    /// STOP.
    fn end(&mut self, t_us: u64);
}

/// A chip on an SPI bus (one chip select).
pub trait SpiChip: Send {
    /// Chip select asserted at `t_us`. An error fails the whole transaction.
    fn begin(&mut self, t_us: u64) -> Result<(), BusFault>;
    /// One full-duplex operation inside the transaction: `write.len().max(read.len())` bytes are
    /// clocked; missing write bytes are sent as 0x00, extra read bytes are discarded.
    fn transfer(&mut self, t_us: u64, write: &[u8], read: &mut [u8]) -> Result<(), BusFault>;
    /// Chip select released.
    fn end(&mut self, t_us: u64);
}

/// Bus-level fault injection, checked once per transaction (at `begin`).
#[derive(Debug, Clone)]
pub struct BusFaults {
    /// NACK the next N transactions.
    pub nack_next: u32,
    /// Time out the next N transactions.
    pub timeout_next: u32,
    /// NACK every transaction with `start_us <= t_us < end_us`.
    pub nack_window_us: Option<(u64, u64)>,
    /// Time out (never answer) every transaction with `start_us <= t_us < end_us`.
    pub timeout_window_us: Option<(u64, u64)>,
    /// NACK each transaction with this probability (seeded, reproducible).
    pub nack_probability: f64,
    rng: ChaCha8Rng,
    /// Transactions failed so far.
    pub injected: u64,
}

impl Default for BusFaults {
    fn default() -> Self {
        Self::seeded(0)
    }
}

impl BusFaults {
    pub fn seeded(seed: u64) -> Self {
        Self {
            nack_next: 0,
            timeout_next: 0,
            nack_window_us: None,
            timeout_window_us: None,
            nack_probability: 0.0,
            rng: ChaCha8Rng::seed_from_u64(seed),
            injected: 0,
        }
    }

    /// NACK with probability `p`, drawn from a generator seeded with `seed`.
    pub fn with_nack_probability(mut self, p: f64, seed: u64) -> Self {
        self.nack_probability = p;
        self.rng = ChaCha8Rng::seed_from_u64(seed);
        self
    }

    /// Decide the fate of a transaction starting at `t_us`.
    pub fn check(&mut self, t_us: u64) -> Result<(), BusFault> {
        let fault = if self.nack_next > 0 {
            self.nack_next -= 1;
            Some(BusFault::Nack)
        } else if self.timeout_next > 0 {
            self.timeout_next -= 1;
            Some(BusFault::Timeout)
        } else if self.timeout_window_us.is_some_and(|(a, b)| (a..b).contains(&t_us)) {
            Some(BusFault::Timeout)
        } else if self.nack_window_us.is_some_and(|(a, b)| (a..b).contains(&t_us))
            // The generator is drawn only outside windows, so a window does not shift the draws.
            || (self.nack_probability > 0.0 && self.rng.random::<f64>() < self.nack_probability)
        {
            Some(BusFault::Nack)
        } else {
            None
        };
        match fault {
            Some(f) => {
                self.injected += 1;
                Err(f)
            }
            None => Ok(()),
        }
    }
}

/// The chips behind the bridge: routes each [`BusRequest`] to the model at its bus and address
/// (I2C) or chip select (SPI). A request to nothing is NACKed, as on a real bus.
#[derive(Default)]
pub struct ChipSet {
    i2c: Vec<(u8, Box<dyn I2cChip>)>,
    spi: Vec<(u8, u8, Box<dyn SpiChip>)>,
    uart: Vec<(u8, Box<dyn UartChip>)>,
    gpio: Vec<(u8, Box<dyn GpioChip>)>,
    /// Transactions served per kind: ok, failed.
    pub served: [u64; 2],
}

impl ChipSet {
    pub fn new() -> Self {
        Self::default()
    }

    /// Attach an I2C chip to bus `bus` (at its own address).
    pub fn attach_i2c(&mut self, bus: u8, chip: impl I2cChip + 'static) -> &mut Self {
        self.i2c.push((bus, Box::new(chip)));
        self
    }

    /// Attach an SPI chip to bus `bus`, chip select `cs`.
    pub fn attach_spi(&mut self, bus: u8, cs: u8, chip: impl SpiChip + 'static) -> &mut Self {
        self.spi.push((bus, cs, Box::new(chip)));
        self
    }

    /// Remove the SPI chip at `bus` / `cs` (to attach another one there).
    pub fn detach_spi(&mut self, bus: u8, cs: u8) -> &mut Self {
        self.spi.retain(|(b, c, _)| (*b, *c) != (bus, cs));
        self
    }

    /// Attach a serial instrument to UART `port`.
    pub fn attach_uart(&mut self, port: u8, chip: impl UartChip + 'static) -> &mut Self {
        self.uart.push((port, Box::new(chip)));
        self
    }

    /// Attach a device to digital output `pin`.
    pub fn attach_gpio(&mut self, pin: u8, chip: impl GpioChip + 'static) -> &mut Self {
        self.gpio.push((pin, Box::new(chip)));
        self
    }

    /// Answer one bridge request.
    pub fn handle(&mut self, req: &BusRequest) -> BusResponse {
        let result = self.run(req);
        self.served[usize::from(result.is_err())] += 1;
        BusResponse { seq: req.seq, result }
    }

    fn run(&mut self, req: &BusRequest) -> Result<ReadData, BusFault> {
        let n = usize::from(req.n_ops).min(req.ops.len());
        let ops = &req.ops[..n];
        let t = req.t_us;
        let mut data = ReadData::EMPTY;
        let mut buf = [0u8; subnav_wire::bridge::MAX_OP_BYTES];
        match req.bus {
            Bus::I2c { bus, address } => {
                let chip = self.i2c.iter_mut().find(|(b, c)| *b == bus && c.address() == address).map(|(_, c)| c).ok_or(BusFault::Nack)?;
                chip.begin(t)?;
                let r = (|| {
                    for op in ops {
                        match op {
                            Op::Write(bytes) => chip.write(t, bytes.as_slice())?,
                            Op::Read { len } => {
                                let out = buf.get_mut(..usize::from(*len)).ok_or(BusFault::Other)?;
                                chip.read(t, out)?;
                                if !data.push(out) {
                                    return Err(BusFault::Other);
                                }
                            }
                            Op::Transfer(_) => return Err(BusFault::Other),
                        }
                    }
                    Ok(())
                })();
                chip.end(t);
                r.map(|()| data)
            }
            Bus::Uart { port } => {
                // Nothing attached: a silent line (a UART has no acknowledge), not a fault.
                let Some(chip) = self.uart.iter_mut().find(|(p, _)| *p == port).map(|(_, c)| c) else { return Ok(data) };
                for op in ops {
                    match op {
                        Op::Write(bytes) => chip.write(t, bytes.as_slice()),
                        Op::Read { len } => {
                            let out = buf.get_mut(..usize::from(*len)).ok_or(BusFault::Other)?;
                            let n = chip.read(t, out).min(out.len());
                            if !data.push(&out[..n]) {
                                return Err(BusFault::Other);
                            }
                        }
                        Op::Transfer(_) => return Err(BusFault::Other),
                    }
                }
                Ok(data)
            }
            Bus::Gpio { pin } => {
                // Nothing attached: a line to nowhere, not a fault.
                for op in ops {
                    let Op::Write(level) = op else { return Err(BusFault::Other) };
                    let high = level.as_slice().first().is_some_and(|&l| l != 0);
                    for (_, chip) in self.gpio.iter_mut().filter(|(p, _)| *p == pin) {
                        chip.set(t, high);
                    }
                }
                Ok(data)
            }
            Bus::Spi { bus, cs } => {
                let chip = self.spi.iter_mut().find(|(b, c, _)| *b == bus && *c == cs).map(|(_, _, c)| c).ok_or(BusFault::Nack)?;
                chip.begin(t)?;
                let r = (|| {
                    for op in ops {
                        let (w, len): (&[u8], usize) = match op {
                            Op::Write(bytes) => (bytes.as_slice(), 0),
                            Op::Read { len } => (&[], usize::from(*len)),
                            Op::Transfer(bytes) => (bytes.as_slice(), bytes.as_slice().len()),
                        };
                        let out = buf.get_mut(..len).ok_or(BusFault::Other)?;
                        chip.transfer(t, w, out)?;
                        if !data.push(out) {
                            return Err(BusFault::Other);
                        }
                    }
                    Ok(())
                })();
                chip.end(t);
                r.map(|()| data)
            }
        }
    }
}

impl subnav_link::qemu::BusHandler for ChipSet {
    fn handle(&mut self, req: &BusRequest) -> BusResponse {
        ChipSet::handle(self, req)
    }
}

/// Round to the nearest integer and clip to `[lo, hi]`; NaN gives `nan_value`.
pub(crate) fn quantize(x: f64, lo: i32, hi: i32, nan_value: i32) -> i32 {
    if x.is_nan() {
        return nan_value;
    }
    let r = x.round();
    if r <= f64::from(lo) {
        lo
    } else if r >= f64::from(hi) {
        hi
    } else {
        r as i32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use subnav_wire::bridge::{Bytes, MAX_OPS};

    #[test]
    fn faults_fire_in_order_and_reproducibly() {
        let mut f = BusFaults { nack_next: 1, timeout_next: 1, nack_window_us: Some((100, 200)), ..Default::default() };
        assert_eq!(f.check(0), Err(BusFault::Nack));
        assert_eq!(f.check(0), Err(BusFault::Timeout));
        assert_eq!(f.check(0), Ok(()));
        assert_eq!(f.check(150), Err(BusFault::Nack));
        assert_eq!(f.check(200), Ok(()));
        assert_eq!(f.injected, 3);
        let draw = |seed| {
            let mut f = BusFaults::default().with_nack_probability(0.3, seed);
            (0..1000).map(|_| f.check(0).is_err()).collect::<Vec<_>>()
        };
        let a = draw(7);
        assert_eq!(a, draw(7));
        let n = a.iter().filter(|x| **x).count();
        assert!((240..360).contains(&n), "{n} NACKs of 1000 at p = 0.3");
    }

    #[test]
    fn chipset_routes_and_nacks_absent_devices() {
        let mut set = ChipSet::new();
        set.attach_i2c(0, Ms5837Model::new(|_| PressureInput { pressure_pa: 101_325.0, temp_c: 20.0 }));
        let mut ops = [Op::Read { len: 0 }; MAX_OPS];
        ops[0] = Op::Write(Bytes::from_slice(&[0xA2]).unwrap());
        ops[1] = Op::Read { len: 2 };
        let req = BusRequest { seq: 3, t_us: 0, bus: Bus::I2c { bus: 0, address: 0x76 }, n_ops: 2, ops };
        let resp = set.handle(&req);
        assert_eq!(resp.seq, 3);
        assert_eq!(resp.result.unwrap().as_slice().len(), 2);
        let absent = BusRequest { bus: Bus::I2c { bus: 0, address: 0x48 }, ..req };
        assert_eq!(set.handle(&absent).result, Err(BusFault::Nack));
        let wrong_bus = BusRequest { bus: Bus::I2c { bus: 1, address: 0x76 }, ..req };
        assert_eq!(set.handle(&wrong_bus).result, Err(BusFault::Nack));
        assert_eq!(set.served, [1, 2]);
    }

    #[test]
    fn quantize_rounds_and_clips() {
        assert_eq!(quantize(1.49, -10, 10, 0), 1);
        assert_eq!(quantize(-1.5, -10, 10, 0), -2);
        assert_eq!(quantize(1e9, -10, 10, 0), 10);
        assert_eq!(quantize(f64::NEG_INFINITY, -10, 10, 0), -10);
        assert_eq!(quantize(f64::NAN, -10, 10, 7), 7);
    }
}
