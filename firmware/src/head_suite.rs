//! The sensor head's [`SensorSuite`] on top of the three drivers, for any buses: the STM32
//! board's SPI/I2C peripherals or the QEMU board's host bridge. The ADC scan and the depth
//! conversions are non-blocking state machines advanced by [`SensorSuite::service`] every tick;
//! the read calls return the latest completed results.
//!
//! The polarization scan (16 conversions, ~8 ms at 860 SPS polled every 1 ms tick) starts
//! `SCAN_LEAD_US` before each point of the polarization grid (multiples of the polarization
//! period from boot, where the application reads it), so the counts the compass gets are a few
//! ms old. Scanning back to back instead costs ~8,000 bus transactions a second for a 10 Hz
//! output (measured under QEMU), which is what made the QEMU board run at 100 % CPU.
//!
//! The DVL (optional: `None` on a board without one) is polled every tick: the driver assembles
//! its sentences from whatever bytes the UART has and stamps each report's time of validity
//! from the tick that completed it (`drivers::dvl_a50`, "Time").
//!
//! Axes: the IMU chip axes are the body FRD axes (mounting documented in `host/src/chips`);
//! the DVL reports in its own axes (its mounting is applied by the navigation filter).

use embedded_hal::delay::DelayNs;
use embedded_hal::digital::OutputPin;
use embedded_hal::i2c::I2c;
use embedded_hal::spi::SpiDevice;
use embedded_io::{Read, ReadReady, Write};
use subnav_wire::{DepthSample, DvlSample, DvlTracking, FaultKind, FaultSource, ImuSample};

use crate::drivers::ads1115::{AdcConfig, PolarizationAdcs, UNITS};
use crate::drivers::dvl_a50::{self, DvlA50, Sentence, Tracking};
use crate::drivers::icm42688::{self, Icm42688};
use crate::drivers::ms5837::{DepthParams, Ms5837};
use crate::drivers::{BusErrorKind, Error, StuckDetector};
use crate::sensors::{SensorFault, SensorSuite};

/// Polarization grid period (µs) and how long before each grid point a scan starts.
const SCAN_PERIOD_US: u64 = 1_000_000 / subnav_core::head::POLARIZATION_RATE_HZ as u64;
const SCAN_LEAD_US: u64 = 15_000;
/// A polarization scan older than this is not used (µs).
const SCAN_MAX_AGE_US: u64 = 300_000;
/// A depth reading older than this is not used (µs).
const DEPTH_MAX_AGE_US: u64 = 300_000;
/// Identical raw IMU samples in a row that mean a stuck axis.
const STUCK_LIMIT: u16 = 50;
/// Sentences looked at per `poll_dvl` call at most (replies and other sentences are skipped).
const DVL_SENTENCES_PER_POLL: usize = 4;

/// The UART of a board without a DVL: never has bytes, swallows writes.
pub struct NoDvl;

impl embedded_io::ErrorType for NoDvl {
    type Error = core::convert::Infallible;
}

impl Read for NoDvl {
    fn read(&mut self, _buf: &mut [u8]) -> Result<usize, Self::Error> {
        Ok(0)
    }
}

impl ReadReady for NoDvl {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(false)
    }
}

impl Write for NoDvl {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// The trigger line of a board without a camera: pulses go nowhere and
/// [`SensorSuite::trigger_camera`] says there is no camera.
pub struct NoCamera;

impl embedded_hal::digital::ErrorType for NoCamera {
    type Error = core::convert::Infallible;
}

impl OutputPin for NoCamera {
    fn set_low(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
    fn set_high(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// Results of bringing the sensors up: `None` = ok, else the fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InitReport {
    pub imu: Option<FaultKind>,
    pub polarization: [Option<FaultKind>; UNITS],
    pub depth: Option<FaultKind>,
}

pub struct HeadSuite<SPI: SpiDevice, I2C: I2c, U: embedded_io::ErrorType = NoDvl, P: OutputPin = NoCamera> {
    imu: Icm42688<SPI>,
    imu_ready: bool,
    imu_stuck: StuckDetector<6>,
    /// The last sample with only gyro axes stuck, and those axes (see `take_degraded_imu`).
    degraded_imu: Option<(ImuSample, u8)>,
    adcs: PolarizationAdcs<I2C>,
    scan: Option<(u64, [[i16; 4]; UNITS], [Option<FaultKind>; UNITS])>,
    /// A scan is in progress; the grid point the latest scan was started for.
    scanning: bool,
    scan_grid_us: Option<u64>,
    depth: Ms5837<I2C>,
    depth_ready: bool,
    last_depth: Option<(u64, DepthSample)>,
    depth_error: Option<FaultKind>,
    dvl: Option<DvlA50<U>>,
    /// The camera's trigger line (`None`: no camera).
    camera_trigger: Option<P>,
    pub init: InitReport,
}

fn kind<E: BusErrorKind>(e: &Error<E>) -> FaultKind {
    e.fault_kind()
}

impl<SPI, I2C, U> HeadSuite<SPI, I2C, U, NoCamera>
where
    SPI: SpiDevice,
    SPI::Error: BusErrorKind,
    I2C: I2c,
    I2C::Error: BusErrorKind,
    U: Read + ReadReady + Write,
    U::Error: BusErrorKind,
{
    /// Bring up all sensors; a sensor that fails stays in the suite and is retried on use.
    /// `dvl_uart`: the DVL's UART at [`dvl_a50::DEFAULT_BAUD`], or `None` without a DVL (the
    /// DVL streams its reports by itself: nothing is sent to it at start).
    pub fn new(spi: SPI, adc_buses: [I2C; UNITS], depth_bus: I2C, dvl_uart: Option<U>, delay: &mut impl DelayNs) -> Self {
        let mut imu = Icm42688::new(spi, icm42688::Config::default());
        let imu_init = imu.init(delay);
        let mut adcs = PolarizationAdcs::new(adc_buses, AdcConfig::default());
        let adc_init = adcs.init();
        let mut depth = Ms5837::new(depth_bus, DepthParams::default());
        let depth_init = depth.init(delay);
        let init = InitReport {
            imu: imu_init.as_ref().err().map(kind),
            polarization: core::array::from_fn(|u| adc_init.get(u).and_then(|r| r.as_ref().err()).map(kind)),
            depth: depth_init.as_ref().err().map(kind),
        };
        Self {
            imu,
            imu_ready: imu_init.is_ok(),
            imu_stuck: StuckDetector::new(STUCK_LIMIT),
            degraded_imu: None,
            adcs,
            scan: None,
            scanning: false,
            scan_grid_us: None,
            depth,
            depth_ready: depth_init.is_ok(),
            last_depth: None,
            depth_error: None,
            dvl: dvl_uart.map(|u| DvlA50::new(u, dvl_a50::DEFAULT_BAUD)),
            camera_trigger: None,
            init,
        }
    }

    /// The same suite with a camera on trigger line `pin` (driven low here, pulsed high per frame).
    pub fn with_camera_trigger<P: OutputPin>(self, mut pin: P) -> HeadSuite<SPI, I2C, U, P> {
        let _ = pin.set_low();
        let HeadSuite {
            imu,
            imu_ready,
            imu_stuck,
            degraded_imu,
            adcs,
            scan,
            scanning,
            scan_grid_us,
            depth,
            depth_ready,
            last_depth,
            depth_error,
            dvl,
            init,
            ..
        } = self;
        HeadSuite {
            imu,
            imu_ready,
            imu_stuck,
            degraded_imu,
            adcs,
            scan,
            scanning,
            scan_grid_us,
            depth,
            depth_ready,
            last_depth,
            depth_error,
            dvl,
            camera_trigger: Some(pin),
            init,
        }
    }
}

impl<SPI, I2C, U, P> HeadSuite<SPI, I2C, U, P>
where
    SPI: SpiDevice,
    SPI::Error: BusErrorKind,
    I2C: I2c,
    I2C::Error: BusErrorKind,
    U: Read + ReadReady + Write,
    U::Error: BusErrorKind,
    P: OutputPin,
{
    /// The DVL driver's counters (`None` without a DVL).
    pub fn dvl_counters(&self) -> Option<dvl_a50::DvlCounters> {
        self.dvl.as_ref().map(|d| *d.counters())
    }

    fn service_depth(&mut self, t_us: u64) {
        if self.depth_ready {
            match self.depth.poll(t_us) {
                Ok(Some(r)) => {
                    self.depth_error = None;
                    self.last_depth = Some((t_us, DepthSample { t_us, pressure_pa: r.pressure_pa, temp_c: r.temp_c, depth_m: r.depth_m }));
                }
                Ok(None) => {}
                Err(e) => self.depth_error = Some(kind(&e)),
            }
        }
    }
}

impl<SPI, I2C, U, P> SensorSuite for HeadSuite<SPI, I2C, U, P>
where
    SPI: SpiDevice,
    SPI::Error: BusErrorKind,
    I2C: I2c,
    I2C::Error: BusErrorKind,
    U: Read + ReadReady + Write,
    U::Error: BusErrorKind,
    P: OutputPin,
    P::Error: BusErrorKind,
{
    fn trigger_camera(&mut self, _t_us: u64) -> Result<bool, SensorFault> {
        let Some(pin) = self.camera_trigger.as_mut() else { return Ok(false) };
        // A pulse: the camera exposes on the rising edge.
        let pulse = pin.set_high().and_then(|()| pin.set_low());
        pulse.map(|()| true).map_err(|e| SensorFault { source: FaultSource::Camera, kind: e.fault_kind() })
    }

    fn poll_dvl(&mut self, t_us: u64) -> Result<Option<DvlSample>, SensorFault> {
        let Some(dvl) = self.dvl.as_mut() else { return Ok(None) };
        for _ in 0..DVL_SENTENCES_PER_POLL {
            let rx = match dvl.poll(t_us) {
                Ok(Some(rx)) => rx,
                Ok(None) => return Ok(None),
                Err(e) => return Err(SensorFault { source: FaultSource::Dvl, kind: e.fault_kind() }),
            };
            if let (Sentence::Velocity(v), Some(t_valid)) = (rx.sentence, rx.t_valid_us) {
                return Ok(Some(DvlSample {
                    t_us: t_valid,
                    rx_us: rx.rx_us,
                    tracking: match v.tracking {
                        Tracking::Bottom => DvlTracking::Bottom,
                        Tracking::Water => DvlTracking::Water,
                    },
                    valid: v.valid,
                    vel_dvl_mps: v.vel_dvl_mps,
                    fom_mps: v.fom_mps,
                    altitude_m: v.altitude_m.unwrap_or(-1.0),
                    covariance_m2ps2: v.covariance_m2ps2,
                }));
            }
        }
        Ok(None)
    }

    fn service(&mut self, t_us: u64) {
        if !self.scanning {
            // The next grid point at or after t_us, and whether we are inside its lead window.
            let grid = t_us.div_ceil(SCAN_PERIOD_US.max(1)) * SCAN_PERIOD_US;
            if grid.saturating_sub(t_us) <= SCAN_LEAD_US && self.scan_grid_us.is_none_or(|g| g < grid) {
                self.scanning = true;
                self.scan_grid_us = Some(grid);
            }
        }
        if !self.scanning {
            return self.service_depth(t_us);
        }
        if let Some(scan) = self.adcs.poll() {
            self.scanning = false;
            let errors = core::array::from_fn(|u| {
                let e = scan.errors.get(u).and_then(|e| e.as_ref()).map(kind);
                e.or_else(|| (scan.saturated.get(u).copied().unwrap_or(0) != 0).then_some(FaultKind::Saturated))
            });
            self.scan = Some((t_us, scan.counts, errors));
        }
        self.service_depth(t_us);
    }

    fn read_imu(&mut self, t_us: u64) -> Result<ImuSample, SensorFault> {
        let fault = |kind| SensorFault { source: FaultSource::Imu, kind };
        if !self.imu_ready {
            // Retry the bring-up (e.g. after a bus glitch at boot).
            self.imu_ready = self.imu.configure(self.imu.config()).is_ok() && matches!(self.imu.who_am_i(), Ok(0x47));
            if !self.imu_ready {
                return Err(fault(FaultKind::IdentityMismatch));
            }
        }
        let r = self.imu.read().map_err(|e| fault(kind(&e)))?;
        if r.any_saturated() {
            return Err(fault(FaultKind::Saturated));
        }
        let raw = [r.raw.accel[0], r.raw.accel[1], r.raw.accel[2], r.raw.gyro[0], r.raw.gyro[1], r.raw.gyro[2]].map(i32::from);
        let sample = ImuSample { t_us, gyro_radps: r.gyro_radps, accel_mps2: r.accel_mps2, temp_c: r.temp_c };
        let stuck = self.imu_stuck.update(raw);
        if stuck != 0 {
            // Channels 0-2 accelerometer, 3-5 gyro: with only gyro axes stuck the sample is kept
            // for the degraded mode (`take_degraded_imu`).
            self.degraded_imu = (stuck & 0b111 == 0).then_some((sample, ((stuck >> 3) & 0b111) as u8));
            return Err(fault(FaultKind::Stuck));
        }
        Ok(sample)
    }

    fn take_degraded_imu(&mut self) -> Option<(ImuSample, u8)> {
        self.degraded_imu.take()
    }

    fn read_polarization(&mut self, t_us: u64, unit: u8) -> Result<[i16; 4], SensorFault> {
        let fault = |kind| SensorFault { source: FaultSource::Polarization { unit }, kind };
        let Some((t_scan, counts, errors)) = &self.scan else { return Err(fault(FaultKind::BusTimeout)) };
        if t_us.saturating_sub(*t_scan) > SCAN_MAX_AGE_US {
            return Err(fault(FaultKind::BusTimeout));
        }
        if let Some(Some(k)) = errors.get(usize::from(unit)) {
            return Err(fault(*k));
        }
        counts.get(usize::from(unit)).copied().ok_or(fault(FaultKind::BusOther))
    }

    fn read_depth(&mut self, t_us: u64, water_density_kgm3: f32) -> Result<DepthSample, SensorFault> {
        let fault = |kind| SensorFault { source: FaultSource::Depth, kind };
        self.depth.params.water_density_kgm3 = water_density_kgm3;
        if !self.depth_ready {
            return Err(fault(self.init.depth.unwrap_or(FaultKind::BusOther)));
        }
        if let Some(k) = self.depth_error {
            return Err(fault(k));
        }
        match self.last_depth {
            Some((t, mut s)) if t_us.saturating_sub(t) <= DEPTH_MAX_AGE_US => {
                s.depth_m = self.depth.params.depth_m(s.pressure_pa);
                Ok(s)
            }
            _ => Err(fault(FaultKind::BusTimeout)),
        }
    }
}
