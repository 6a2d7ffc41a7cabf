//! The firmware's sensor drivers (compiled for the host) against the host's register-level chip
//! models: the driver's SI output must equal the chip's physical input within the quantization
//! the datasheet implies, over many random inputs, and the models' fault knobs must surface as
//! the right driver errors.
//!
//! Both sides were written from the datasheets independently (the chip models do not import the
//! driver's register constants or formulas), so agreement checks the register map, scaling,
//! timing and compensation of each.
//!
//! Bounds (why):
//! - ICM-42688-P: the chip rounds `value * sensitivity` to the nearest LSB, the driver divides by
//!   the same datasheet sensitivity in f32: |error| <= 0.5 LSB + f32 rounding
//!   (0.5 / 16.4 deg/s at +-2000 deg/s; 0.5 / 2048 g at +-16 g; 0.5 / 132.48 C).
//! - ADS1115: the chip rounds `V * 32768 / FS`: |error| <= 0.5 LSB = FS / 65536 (31 uV at
//!   +-2.048 V) + f32 rounding.
//! - MS5837-30BA: the chip's inverse model picks the D1/D2 whose compensated output is nearest
//!   the input, and the output resolution is 10 Pa / 0.01 C: |error| <= 5 Pa and 0.005 C, plus
//!   the f32 ulp of the output (0.25 Pa at 3 MPa).
//!
//! Transactions reach the models two ways: through small embedded-hal adapters (most tests),
//! and through the real QEMU bridge protocol (`BridgeClient` frames answered by a `ChipSet`).

use std::cell::{Cell, RefCell};
use std::collections::VecDeque;
use std::rc::Rc;
use std::sync::{Arc, Mutex};

use embedded_hal::delay::DelayNs;
use embedded_hal::{i2c, spi};
use subnav_firmware::bus_bridge::{BridgeClient, BridgeError, BridgeI2c, BridgeSpi, ByteLink};
use subnav_firmware::drivers::ads1115::{self as adc, AdcConfig, PgaRange, PolarizationAdcs};
use subnav_firmware::drivers::icm42688::{self as imu, AccelRange, Config as ImuConfig, GyroRange, Icm42688, Odr};
use subnav_firmware::drivers::ms5837::{DepthParams, Ms5837, Osr};
use subnav_firmware::drivers::{Error, StuckDetector};
use subnav_sil::chips::icm42688::Stuck;
use subnav_sil::chips::{Ads1115Model, BusFault, ChipSet, I2cChip, Icm42688Model, ImuInput, Ms5837Model, PressureInput, SpiChip};
use subnav_wire::bridge::{BusRequest, MAX_REQUEST_FRAME, bus_map};
use subnav_wire::{self as wire, Decoded, FaultKind, FrameDecoder};

// ---------------------------------------------------------------------------------------------
// Simulated time and embedded-hal adapters over the chip traits.

/// Firmware time shared by the buses and the delay.
#[derive(Clone, Default)]
struct Clock(Rc<Cell<u64>>);

impl Clock {
    fn now(&self) -> u64 {
        self.0.get()
    }
    fn advance_us(&self, us: u64) {
        self.0.set(self.0.get() + us);
    }
}

/// A delay that advances simulated time (the chips see the wait).
struct SimDelay(Clock);

impl DelayNs for SimDelay {
    fn delay_ns(&mut self, ns: u32) {
        self.0.advance_us(u64::from(ns).div_ceil(1000));
    }
}

/// An I2C bus with the chips attached to it.
#[derive(Clone)]
struct SimI2c {
    chips: Vec<Rc<RefCell<dyn I2cChip>>>,
    clock: Clock,
}

impl i2c::ErrorType for SimI2c {
    type Error = BridgeError;
}

impl i2c::I2c for SimI2c {
    fn transaction(&mut self, address: u8, ops: &mut [i2c::Operation<'_>]) -> Result<(), BridgeError> {
        let t = self.clock.now();
        let chip = self.chips.iter().find(|c| c.borrow().address() == address).ok_or(BridgeError(BusFault::Nack))?;
        let mut chip = chip.borrow_mut();
        chip.begin(t).map_err(BridgeError)?;
        let r = ops.iter_mut().try_for_each(|op| match op {
            i2c::Operation::Write(b) => chip.write(t, b),
            i2c::Operation::Read(b) => chip.read(t, b),
        });
        chip.end(t);
        r.map_err(BridgeError)
    }
}

/// One SPI device (chip select) with its chip.
struct SimSpi {
    chip: Rc<RefCell<dyn SpiChip>>,
    clock: Clock,
}

impl spi::ErrorType for SimSpi {
    type Error = BridgeError;
}

impl spi::SpiDevice for SimSpi {
    fn transaction(&mut self, ops: &mut [spi::Operation<'_, u8>]) -> Result<(), BridgeError> {
        let t = self.clock.now();
        let mut chip = self.chip.borrow_mut();
        chip.begin(t).map_err(BridgeError)?;
        let r = ops.iter_mut().try_for_each(|op| match op {
            spi::Operation::Write(w) => chip.transfer(t, w, &mut []),
            spi::Operation::Read(r) => chip.transfer(t, &[], r),
            spi::Operation::Transfer(r, w) => chip.transfer(t, w, r),
            spi::Operation::TransferInPlace(b) => {
                let w = b.to_vec();
                chip.transfer(t, &w, b)
            }
            spi::Operation::DelayNs(ns) => {
                self.clock.advance_us(u64::from(*ns).div_ceil(1000));
                Ok(())
            }
        });
        chip.end(t);
        r.map_err(BridgeError)
    }
}

/// Deterministic pseudo-random numbers (SplitMix64), no dependency.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [lo, hi).
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

// ---------------------------------------------------------------------------------------------
// ICM-42688-P

type ImuRig = (Icm42688<SimSpi>, Rc<RefCell<Icm42688Model>>, Arc<Mutex<ImuInput>>, Clock);

fn imu_rig(cfg: ImuConfig) -> ImuRig {
    let input = Arc::new(Mutex::new(ImuInput::default()));
    let src = input.clone();
    let model = Rc::new(RefCell::new(Icm42688Model::new(move |_t| *src.lock().unwrap())));
    let clock = Clock::default();
    let dev = Icm42688::new(SimSpi { chip: model.clone(), clock: clock.clone() }, cfg);
    (dev, model, input, clock)
}

#[test]
fn icm42688_reads_back_random_inputs_within_half_an_lsb() {
    let configs = [
        ImuConfig { gyro_range: GyroRange::Dps2000, accel_range: AccelRange::G16, odr: Odr::Hz1000 },
        ImuConfig { gyro_range: GyroRange::Dps500, accel_range: AccelRange::G4, odr: Odr::Hz200 },
        ImuConfig { gyro_range: GyroRange::Dps15_625, accel_range: AccelRange::G2, odr: Odr::Hz8000 },
    ];
    let mut rng = Rng(42);
    let mut worst = [0.0f64; 3];
    for cfg in configs {
        let (mut dev, model, input, clock) = imu_rig(cfg);
        dev.init(&mut SimDelay(clock.clone())).unwrap();
        assert!(model.borrow().powered());
        let period_us = (cfg.odr.period_ns() / 1000).max(1);
        let g_fs = 32767.0 / f64::from(cfg.gyro_range.lsb_per_radps());
        let a_fs = 32767.0 / f64::from(cfg.accel_range.lsb_per_mps2());
        let g_lsb = 1.0 / f64::from(cfg.gyro_range.lsb_per_radps());
        let a_lsb = 1.0 / f64::from(cfg.accel_range.lsb_per_mps2());
        for _ in 0..2000 {
            let x = ImuInput {
                gyro_radps: [0; 3].map(|_| rng.uniform(-0.99, 0.99) * g_fs),
                specific_force_mps2: [0; 3].map(|_| rng.uniform(-0.99, 0.99) * a_fs),
                temp_c: rng.uniform(-20.0, 60.0),
            };
            *input.lock().unwrap() = x;
            clock.advance_us(period_us);
            assert!(dev.data_ready().unwrap(), "a new sample every ODR period");
            let r = dev.read().unwrap();
            assert_eq!(r.saturated, 0);
            for i in 0..3 {
                let eg = (f64::from(r.gyro_radps[i]) - x.gyro_radps[i]).abs();
                let ea = (f64::from(r.accel_mps2[i]) - x.specific_force_mps2[i]).abs();
                assert!(eg <= 0.5 * g_lsb + 1e-6 * x.gyro_radps[i].abs(), "gyro {i}: {eg} > half LSB {}", 0.5 * g_lsb);
                assert!(ea <= 0.5 * a_lsb + 1e-6 * x.specific_force_mps2[i].abs(), "accel {i}: {ea} > half LSB {}", 0.5 * a_lsb);
                worst[0] = worst[0].max(eg / g_lsb);
                worst[1] = worst[1].max(ea / a_lsb);
            }
            let et = (f64::from(r.temp_c) - x.temp_c).abs();
            assert!(et <= 0.5 / 132.48 + 1e-5, "temperature {et}");
            worst[2] = worst[2].max(et * 132.48);
        }
    }
    println!("worst errors in LSB: gyro {:.3}, accel {:.3}, temperature {:.3}", worst[0], worst[1], worst[2]);
    // The quantization is really exercised (not trivially exact).
    assert!(worst.iter().all(|w| *w > 0.4));
}

#[test]
fn icm42688_saturation_stuck_axis_identity_and_nack() {
    let cfg = ImuConfig { gyro_range: GyroRange::Dps250, accel_range: AccelRange::G2, odr: Odr::Hz1000 };
    let (mut dev, model, input, clock) = imu_rig(cfg);
    dev.init(&mut SimDelay(clock.clone())).unwrap();
    // Beyond full scale: clipped and flagged.
    *input.lock().unwrap() = ImuInput { gyro_radps: [10.0, 0.0, -10.0], specific_force_mps2: [0.0, 30.0, 0.0], temp_c: 20.0 };
    clock.advance_us(1000);
    let r = dev.read().unwrap();
    assert_eq!(r.saturated, 0b101_010);
    assert_eq!(r.raw.gyro[0], 32767);
    assert_eq!(r.raw.gyro[2], -32767);
    // Saturation knob on an in-range input.
    *input.lock().unwrap() = ImuInput { gyro_radps: [0.1, 0.1, 0.1], specific_force_mps2: [1.0, 1.0, 1.0], temp_c: 20.0 };
    model.borrow_mut().saturate = 1 << 4;
    clock.advance_us(1000);
    assert_eq!(dev.read().unwrap().saturated, 1 << 4);
    model.borrow_mut().saturate = 0;
    // A stuck gyro x axis under a varying input is caught by the stuck detector.
    model.borrow_mut().stuck[3] = Stuck::AtNext;
    let mut det = StuckDetector::<6>::new(20);
    let mut rng = Rng(3);
    let mut mask = 0;
    for _ in 0..25 {
        *input.lock().unwrap() = ImuInput {
            gyro_radps: [0; 3].map(|_| rng.uniform(-1.0, 1.0)),
            specific_force_mps2: [0; 3].map(|_| rng.uniform(-9.0, 9.0)),
            temp_c: 20.0,
        };
        clock.advance_us(1000);
        let r = dev.read().unwrap();
        mask = det.update([r.raw.accel[0], r.raw.accel[1], r.raw.accel[2], r.raw.gyro[0], r.raw.gyro[1], r.raw.gyro[2]].map(i32::from));
    }
    assert_eq!(mask, 1 << 3, "only gyro x is stuck");
    // NACK on the next transaction -> Error::Bus, telemetry kind BusNack; then it recovers.
    model.borrow_mut().faults.nack_next = 1;
    let e = dev.read().unwrap_err();
    assert_eq!(e, Error::Bus(BridgeError(BusFault::Nack)));
    assert_eq!(e.fault_kind(), FaultKind::BusNack);
    model.borrow_mut().faults.timeout_next = 1;
    assert_eq!(dev.read().unwrap_err().fault_kind(), FaultKind::BusTimeout);
    assert!(dev.read().is_ok());
    // Wrong WHO_AM_I -> IdentityMismatch at init.
    model.borrow_mut().who_am_i = 0x6A;
    let e = dev.init(&mut SimDelay(clock.clone())).unwrap_err();
    assert_eq!(e, Error::IdentityMismatch { expected: 0x47, found: 0x6A });
    assert_eq!(e.fault_kind(), FaultKind::IdentityMismatch);
}

#[test]
fn icm42688_reports_not_ready_before_the_first_sample() {
    let (mut dev, model, _input, clock) = imu_rig(ImuConfig::default());
    // Before init the sensors are off: data registers read 0x8000.
    assert_eq!(dev.read(), Err(Error::NotReady));
    dev.init(&mut SimDelay(clock.clone())).unwrap();
    assert!(model.borrow().powered());
    // Powered at t = 1 ms (after the reset wait); the first 1 kHz sample is at t = 2 ms.
    assert_eq!(clock.now(), 1_200);
    assert_eq!(dev.read(), Err(Error::NotReady));
    assert!(!dev.data_ready().unwrap());
    clock.advance_us(800);
    assert!(dev.data_ready().unwrap());
    assert!(dev.read().is_ok());
}

// ---------------------------------------------------------------------------------------------
// 8 x ADS1115 on two buses

const UNITS: usize = bus_map::POLARIZATION_ADC_I2C.len();
type Volts = Arc<Mutex<[[f64; 4]; UNITS]>>;

fn adc_rig(config: AdcConfig) -> (PolarizationAdcs<SimI2c>, Vec<Rc<RefCell<Ads1115Model>>>, Volts, Clock) {
    let volts: Volts = Arc::new(Mutex::new([[0.0; 4]; UNITS]));
    let clock = Clock::default();
    let models: Vec<Rc<RefCell<Ads1115Model>>> = (0..UNITS)
        .map(|u| {
            let v = volts.clone();
            Rc::new(RefCell::new(Ads1115Model::new(bus_map::POLARIZATION_ADC_I2C[u].1, move |_t| v.lock().unwrap()[u])))
        })
        .collect();
    // One simulated bus per bus of the map, each with its own four chips.
    let bus = |n: u8| SimI2c {
        chips: (0..UNITS)
            .filter(|&u| bus_map::POLARIZATION_ADC_I2C[u].0 == n)
            .map(|u| models[u].clone() as Rc<RefCell<dyn I2cChip>>)
            .collect(),
        clock: clock.clone(),
    };
    let adcs = PolarizationAdcs::new(core::array::from_fn(|u| bus(bus_map::POLARIZATION_ADC_I2C[u].0)), config);
    (adcs, models, volts, clock)
}

#[test]
fn ads1115_reads_back_random_volts_within_half_an_lsb() {
    let mut rng = Rng(7);
    let mut worst = 0.0f64;
    for (fsr, rate) in [(PgaRange::Within4_096V, adc::DataRate::Sps860), (PgaRange::Within2_048V, adc::DataRate::Sps128)] {
        let (mut adcs, models, volts, clock) = adc_rig(AdcConfig { fsr, rate, max_polls: 50 });
        assert!(adcs.init().iter().all(|r| r.is_ok()));
        let fs = f64::from(adc::full_scale_v(fsr));
        let lsb = fs / 32768.0;
        for _ in 0..200 {
            let v: [[f64; 4]; UNITS] = [[0.0; 4]; UNITS].map(|row| row.map(|_| rng.uniform(0.0, 0.999 * fs)));
            *volts.lock().unwrap() = v;
            let scan = adcs.scan(&mut SimDelay(clock.clone()));
            assert!(scan.errors.iter().all(|e| e.is_none()), "{:?}", scan.errors);
            assert_eq!(scan.saturated, [0; UNITS]);
            for (u, (counts, volts_in)) in scan.counts.iter().zip(v.iter()).enumerate() {
                for (ch, (c, want)) in counts.iter().zip(volts_in.iter()).enumerate() {
                    let got = f64::from(adc::volts(*c, fsr));
                    let err = (got - want).abs();
                    assert!(err <= 0.5 * lsb + 1e-6 * fs, "unit {u} ch {ch}: {err} V > half LSB {}", 0.5 * lsb);
                    worst = worst.max(err / lsb);
                }
            }
        }
        // Each scan made 32 conversions, in the configured data rate's time.
        assert!(models.iter().all(|m| m.borrow().conversions >= 800));
        // The chips run with the PGA and data rate the driver configured (datasheet codes).
        let (pga, dr) = match (fsr, rate) {
            (PgaRange::Within4_096V, adc::DataRate::Sps860) => (0b001, 0b111),
            _ => (0b010, 0b100),
        };
        for m in &models {
            assert_eq!(((m.borrow().config() >> 9) & 7, (m.borrow().config() >> 5) & 7), (pga, dr));
        }
        // Beyond the PGA range: full-scale code, flagged.
        *volts.lock().unwrap() = [[0.0, 1.2 * fs, 0.0, 0.0]; UNITS];
        let scan = adcs.scan(&mut SimDelay(clock.clone()));
        assert_eq!(scan.saturated, [0b0010; UNITS]);
        assert_eq!(scan.counts[0][1], i16::MAX);
    }
    println!("worst ADC error: {worst:.3} LSB");
    assert!(worst > 0.4);
}

#[test]
fn ads1115_faults_fail_only_the_affected_unit() {
    let (mut adcs, models, volts, clock) = adc_rig(AdcConfig::default());
    assert!(adcs.init().iter().all(|r| r.is_ok()));
    *volts.lock().unwrap() = [[1.0, 1.5, 2.0, 2.5]; UNITS];
    // Unit 2 NACKs for a while (bus NACK), unit 1's conversions hang (no OS).
    models[2].borrow_mut().faults.nack_window_us = Some((0, 1_000_000));
    models[1].borrow_mut().hang = true;
    let scan = adcs.scan(&mut SimDelay(clock.clone()));
    assert_eq!(scan.errors[2], Some(Error::Bus(BridgeError(BusFault::Nack))));
    assert_eq!(scan.errors[2].as_ref().map(|e| e.fault_kind()), Some(FaultKind::BusNack));
    assert_eq!(scan.errors[1], Some(Error::NotReady));
    assert_eq!(scan.ok_units().collect::<Vec<_>>(), vec![0, 3, 4, 5, 6, 7]);
    for u in [0, 3, 4, 7] {
        for (ch, v) in [1.0, 1.5, 2.0, 2.5].iter().enumerate() {
            assert!((f64::from(adc::volts(scan.counts[u][ch], PgaRange::Within4_096V)) - v).abs() < 1.25e-4);
        }
    }
    // Faults cleared: the next scan has every unit again.
    models[1].borrow_mut().hang = false;
    clock.advance_us(1_000_000);
    let scan = adcs.scan(&mut SimDelay(clock.clone()));
    assert!(scan.errors.iter().all(|e| e.is_none()), "{:?}", scan.errors);
    // A stuck channel reads its frozen code.
    models[3].borrow_mut().stuck[2] = Some(1234);
    let scan = adcs.scan(&mut SimDelay(clock.clone()));
    assert_eq!(scan.counts[3][2], 1234);
}

// ---------------------------------------------------------------------------------------------
// MS5837-30BA

type DepthRig = (Ms5837<SimI2c>, Rc<RefCell<Ms5837Model>>, Arc<Mutex<PressureInput>>, Clock);

fn depth_rig() -> DepthRig {
    let input = Arc::new(Mutex::new(PressureInput { pressure_pa: 101_325.0, temp_c: 15.0 }));
    let src = input.clone();
    let model = Rc::new(RefCell::new(Ms5837Model::new(move |_t| *src.lock().unwrap())));
    let clock = Clock::default();
    let bus = SimI2c { chips: vec![model.clone() as Rc<RefCell<dyn I2cChip>>], clock: clock.clone() };
    let params = DepthParams { water_density_kgm3: 1025.0, surface_pressure_pa: 101_325.0, g_mps2: 9.80665 };
    (Ms5837::new(bus, params), model, input, clock)
}

#[test]
fn ms5837_reads_back_random_pressures_and_temperatures() {
    let (mut dev, model, input, clock) = depth_rig();
    let cal = dev.init(&mut SimDelay(clock.clone())).unwrap();
    assert_eq!(cal.c, model.borrow().prom());
    let mut rng = Rng(11);
    let (mut worst_p, mut worst_t) = (0.0f64, 0.0f64);
    let osrs = [Osr::R256, Osr::R512, Osr::R1024, Osr::R2048, Osr::R4096, Osr::R8192];
    for i in 0..1000 {
        let x = PressureInput { pressure_pa: rng.uniform(50_000.0, 3_000_000.0), temp_c: rng.uniform(-20.0, 60.0) };
        *input.lock().unwrap() = x;
        let r = dev.measure(osrs[i % 6], &mut SimDelay(clock.clone())).unwrap();
        let ep = (f64::from(r.pressure_pa) - x.pressure_pa).abs();
        let et = (f64::from(r.temp_c) - x.temp_c).abs();
        // Half the output LSB (10 Pa, 0.01 C) plus the f32 ulp of the output.
        assert!(ep <= 5.0 + x.pressure_pa * 1.2e-7, "P {} -> {}: {ep} Pa", x.pressure_pa, r.pressure_pa);
        assert!(et <= 0.005 + 1e-5, "T {} -> {}: {et} C", x.temp_c, r.temp_c);
        let depth_true = (x.pressure_pa - 101_325.0) / (1025.0 * 9.80665);
        assert!((f64::from(r.depth_m) - depth_true).abs() <= 5.5 / (1025.0 * 9.80665) + 1e-5);
        worst_p = worst_p.max(ep);
        worst_t = worst_t.max(et);
    }
    println!("worst MS5837 errors: {worst_p:.2} Pa, {worst_t:.4} C");
    assert!(worst_p > 3.0 && worst_t > 0.003, "quantization exercised");
    assert_eq!(model.borrow().conversions, 2000);
}

#[test]
fn ms5837_poll_timing_bad_crc_early_read_and_nack() {
    let (mut dev, model, input, clock) = depth_rig();
    dev.init(&mut SimDelay(clock.clone())).unwrap();
    *input.lock().unwrap() = PressureInput { pressure_pa: 201_325.0, temp_c: 8.0 };
    // Non-blocking: polled every 1 ms, a reading needs 2 x 9.04 ms at OSR 4096.
    let mut got = None;
    let start = clock.now();
    for _ in 0..40 {
        if let Some(r) = dev.poll(clock.now()).unwrap() {
            got = Some((r, clock.now() - start));
            break;
        }
        clock.advance_us(1000);
    }
    let (r, took_us) = got.expect("a reading");
    assert!((18_000..=21_000).contains(&took_us), "{took_us} us");
    assert!((r.depth_m - 100_000.0 / (1025.0 * 9.80665)).abs() < 1e-3);
    // Reading the ADC before the conversion has finished: the chip answers 0 -> NotReady.
    dev.start(subnav_firmware::drivers::ms5837::Conversion::Pressure, Osr::R8192).unwrap();
    clock.advance_us(10_000);
    assert_eq!(dev.read_adc(), Err(Error::NotReady));
    // Stuck pressure conversion: the reading no longer follows the input.
    model.borrow_mut().stuck_d1 = Some(5_000_000);
    let a = dev.measure(Osr::R256, &mut SimDelay(clock.clone())).unwrap();
    input.lock().unwrap().pressure_pa = 900_000.0;
    let b = dev.measure(Osr::R256, &mut SimDelay(clock.clone())).unwrap();
    assert_eq!((a.d1, b.d1), (5_000_000, 5_000_000));
    model.borrow_mut().stuck_d1 = None;
    // NACK -> Bus error.
    model.borrow_mut().faults.nack_next = 1;
    let e = dev.measure(Osr::R256, &mut SimDelay(clock.clone())).unwrap_err();
    assert_eq!(e.fault_kind(), FaultKind::BusNack);
    // Corrupted PROM CRC -> BadCrc at init, and no readings until a good init.
    model.borrow_mut().corrupt_crc = true;
    let e = dev.init(&mut SimDelay(clock.clone())).unwrap_err();
    assert!(matches!(e, Error::BadCrc { expected, computed } if expected != computed));
    assert_eq!(e.fault_kind(), FaultKind::BadCrc);
    assert_eq!(dev.poll(clock.now()), Err(Error::NotReady));
    model.borrow_mut().corrupt_crc = false;
    assert!(dev.init(&mut SimDelay(clock.clone())).is_ok());
}

// ---------------------------------------------------------------------------------------------
// Through the QEMU bridge protocol: drivers -> BridgeI2c/BridgeSpi -> frames -> ChipSet -> frames.

/// The host end of the bridge in-process: decodes request frames, answers them with the chip
/// set, queues the response frames.
struct Loopback {
    chips: ChipSet,
    dec: FrameDecoder<MAX_REQUEST_FRAME>,
    rx: VecDeque<u8>,
}

impl ByteLink for Loopback {
    fn write_all(&mut self, bytes: &[u8]) {
        for &b in bytes {
            if let Decoded::Message(req) = self.dec.push::<BusRequest>(b) {
                let resp = self.chips.handle(&req);
                let mut buf = [0u8; subnav_wire::bridge::MAX_RESPONSE_FRAME];
                let frame = wire::encode(&resp, &mut buf).expect("response fits");
                self.rx.extend(frame.iter().copied());
            }
        }
    }
    fn read_byte(&mut self) -> Option<u8> {
        self.rx.pop_front()
    }
}

/// A delay that moves the bridge's timestamp (what the QEMU board's scheduler does).
struct BridgeDelay<'a>(&'a RefCell<BridgeClient<Loopback>>, Cell<u64>);

impl DelayNs for BridgeDelay<'_> {
    fn delay_ns(&mut self, ns: u32) {
        self.1.set(self.1.get() + u64::from(ns).div_ceil(1000));
        self.0.borrow_mut().set_time(self.1.get());
    }
}

#[test]
fn drivers_work_through_the_bridge_protocol_and_chipset() {
    let mut chips = ChipSet::new();
    chips.attach_spi(
        0,
        0,
        Icm42688Model::new(|_| ImuInput { gyro_radps: [0.1, -0.2, 0.3], specific_force_mps2: [0.0, 0.0, -9.80665], temp_c: 21.0 }),
    );
    // Unit u's inputs: 0.25 (ch + 1) + 0.4 u volts; unit 3's AIN2 and AIN3 beyond the range.
    let volts_in =
        |u: usize, ch: usize| if u == 3 && ch >= 2 { 4.5 + 0.5 * (ch - 2) as f64 } else { 0.25 * (ch as f64 + 1.0) + 0.4 * u as f64 };
    for (u, (bus, address)) in bus_map::POLARIZATION_ADC_I2C.into_iter().enumerate() {
        chips.attach_i2c(bus, Ads1115Model::new(address, move |_| core::array::from_fn(|ch| volts_in(u, ch))));
    }
    chips.attach_i2c(bus_map::DEPTH_I2C.0, Ms5837Model::new(|_| PressureInput { pressure_pa: 150_000.0, temp_c: 12.0 }));
    let client = RefCell::new(BridgeClient::new(Loopback { chips, dec: FrameDecoder::new(), rx: VecDeque::new() }));
    let mut delay = BridgeDelay(&client, Cell::new(0));

    let mut imu_dev = Icm42688::new(BridgeSpi::new(&client, 0, 0), ImuConfig::default());
    imu_dev.init(&mut delay).unwrap();
    delay.delay_us(1000);
    let r = imu_dev.read().unwrap();
    assert!((r.gyro_radps[2] - 0.3).abs() < 1e-3 && (r.accel_mps2[2] + 9.80665).abs() < 1e-2 && (r.temp_c - 21.0).abs() < 0.01);
    assert_eq!(imu::WHO_AM_I_VALUE, imu_dev.who_am_i().unwrap());

    let mut adcs =
        PolarizationAdcs::new(core::array::from_fn(|u| BridgeI2c::new(&client, bus_map::POLARIZATION_ADC_I2C[u].0)), AdcConfig::default());
    assert!(adcs.init().iter().all(|r| r.is_ok()));
    let scan = adcs.scan(&mut delay);
    for u in 0..bus_map::POLARIZATION_ADC_I2C.len() {
        for ch in 0..4 {
            let v = f64::from(adc::volts(scan.counts[u][ch], PgaRange::Within4_096V));
            let want = volts_in(u, ch).min(4.096 - 4.096 / 32768.0);
            assert!((v - want).abs() < 1.25e-4, "unit {u} ch {ch}: {v} vs {want}");
        }
    }
    assert_eq!(scan.saturated, [0, 0, 0, 0b1100, 0, 0, 0, 0], "unit 3: AIN2 = 4.5 V and AIN3 = 5 V are beyond 4.096 V");

    let mut depth = Ms5837::new(BridgeI2c::new(&client, bus_map::DEPTH_I2C.0), DepthParams::default());
    depth.init(&mut delay).unwrap();
    let r = depth.measure(Osr::R2048, &mut delay).unwrap();
    assert!((r.pressure_pa - 150_000.0).abs() <= 5.0 && (r.temp_c - 12.0).abs() <= 0.005);
    // An absent device NACKs through the whole stack.
    let mut ghost = Ms5837::new(BridgeI2c::new(&client, 2), DepthParams::default());
    assert_eq!(ghost.init(&mut delay).unwrap_err().fault_kind(), FaultKind::BusNack);
}
