//! Board: STM32F405/F407 sensor head (stm32f4xx-hal). Thin glue around [`subnav_firmware::App`]:
//! - 168 MHz from an 8 MHz HSE crystal (change `HSE_HZ` for other boards);
//! - telemetry and commands on USART2 (PA2 TX, PA3 RX) at 460800 baud; received bytes go from
//!   the RXNE interrupt into a 1-KiB queue (`subnav_firmware::uart_queue`: 22 ms of a
//!   back-to-back downlink), drained by the board loop; losses (queue full, UART overrun,
//!   framing) are reported as `Fault(Link, Overrun | Malformed)`. Telemetry goes into a 2-KiB
//!   transmit queue sent by the TXE interrupt (`uart_queue::TxProducer`): the loop never waits
//!   for the wire; a frame that does not fit is refused whole and reported
//!   (`Fault(Link, TelemetryDropped)`);
//! - defmt logs over RTT (probe-rs), panics through panic-probe;
//! - time from SysTick at 1 kHz plus the sub-tick counter;
//! - sensors (the same drivers and `HeadSuite` as the QEMU board, only the buses differ): the
//!   ICM-42688-P on SPI1 (PA5 SCK, PA6 MISO, PA7 MOSI, PA4 chip select, 8 MHz, mode 0), the
//!   ADS1115 of polarization units 0-3 (0x48-0x4B) and the MS5837-30BA (0x76) sharing I2C1
//!   (PB6 SCL, PB7 SDA, 400 kHz), the ADS1115 of units 4-7 (0x48-0x4B) on I2C3 (PA8 SCL, PC9
//!   SDA, 400 kHz; the bus map's I2C 1), through embedded-hal-bus's `RefCellDevice`, each bus
//!   wrapped in `hal_bus` so its errors map to telemetry fault kinds;
//! - the DVL (Water Linked DVL-A50) on USART3 (PB10 TX, PB11 RX) at 115200 baud, received
//!   through its own interrupt-fed queue (losses: `Fault(Dvl, Overrun | Malformed)`);
//! - the store (calibrations, settings): the W25Q16JV on SPI2 (PB13 SCK, PB14 MISO, PB15 MOSI,
//!   PB12 chip select, 8 MHz, mode 0) through `FlashStore`; a chip that does not answer boots
//!   on defaults with a `Store` fault (`FailedStore`);
//! - the camera trigger line: PB0, push-pull, pulsed high for each frame;
//! - stack painting (cortex-m-stack): the peak is logged over defmt every 60 s;
//! - the independent watchdog (IWDG, on the LSI: it runs even if the main clock fails), fed once
//!   per pass of the board loop and started after the store's boot (reformatting a damaged store
//!   erases sector after sector, longer than its period); the reset cause from `RCC_CSR` (read,
//!   then cleared) goes in `Boot`;
//! - the warm-start record (`subnav_firmware::estimator::warm`) in the 4 KiB backup SRAM
//!   (0x4002_4000), which keeps its contents through every reset while VDD is up (no backup
//!   regulator needed for that): after a watchdog, brown-out or software reset the head starts
//!   from it. Built, not yet run on a board (the warm restart is tested on the QEMU board).
//!
//! Why stm32f4xx-hal rather than embassy-stm32: the application core is synchronous and
//! scheduled by the tick, a blocking HAL keeps the board file small, and it builds in a fraction
//! of embassy-stm32's time (matters for CI on two cores). Built in CI; not run there (no board,
//! and no emulator in reach runs it: docs/RELIABILITY.md, "The STM32 board under an emulator").
#![no_std]
#![no_main]

use core::sync::atomic::{AtomicU32, Ordering};

use core::cell::RefCell;
use cortex_m::interrupt::Mutex;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::{entry, exception};
use defmt_rtt as _;
use embedded_hal_bus::i2c::RefCellDevice;
use embedded_hal_bus::spi::ExclusiveDevice;
use heapless::spsc::Queue;
use panic_probe as _;
use stm32f4xx_hal::{
    pac::{self, interrupt},
    prelude::*,
    rcc::Config,
    serial::{self, RxListen, Serial},
    spi::{Mode, Phase, Polarity},
    watchdog::IndependentWatchdog,
};
use subnav_firmware::board_loop::{BoardIo, BoardLoop, BoardParts, CatchUp};
use subnav_firmware::drivers::w25q::W25q;
use subnav_firmware::estimator::warm::WARM_RECORD_BYTES;
use subnav_firmware::hal_bus::{HalBusError, HalI2c, HalI2cEither, HalSpi};
use subnav_firmware::head_suite::HeadSuite;
use subnav_firmware::sensors::SensorSuite;
use subnav_firmware::store::{FailedStore, FlashStore, RecordStore};
use subnav_firmware::time::TickClock;
use subnav_firmware::uart_queue::{RxConsumer, RxError, RxProducer, RxStats, TxConsumer, TxProducer, TxStats};
use subnav_firmware::{App, TelemetrySink};
use subnav_wire::bridge::bus_map;
use subnav_wire::{Board, FaultKind, FaultSource, ResetCause};

const HSE_HZ: u32 = 8_000_000;
const CORE_HZ: u32 = 168_000_000;
const TICK_HZ: u32 = 1_000;
const RELOAD: u32 = CORE_HZ / TICK_HZ - 1;

static MILLIS: AtomicU32 = AtomicU32::new(0);

/// The IWDG resets the chip after this long without a feed (a board-loop pass takes a few ms).
const WATCHDOG_PERIOD_MS: u32 = 500;

/// Why the chip reset, from `RCC_CSR` (`WDGRSTF` is the IWDG's flag; then cleared, so the next reset reports its own cause).
/// A power-on also sets the pin and brown-out flags, so the order matters.
fn take_reset_cause(rcc: &pac::RCC) -> ResetCause {
    let csr = rcc.csr().read();
    let cause = if csr.wdgrstf().bit_is_set() || csr.wwdgrstf().bit_is_set() {
        ResetCause::Watchdog
    } else if csr.sftrstf().bit_is_set() {
        ResetCause::Software
    } else if csr.porrstf().bit_is_set() {
        ResetCause::PowerOn
    } else if csr.borrstf().bit_is_set() {
        ResetCause::Brownout
    } else if csr.padrstf().bit_is_set() {
        ResetCause::Pin
    } else {
        ResetCause::PowerOn
    };
    rcc.csr().modify(|_, w| w.rmvf().set_bit());
    cause
}

/// Receive queues: 1 KiB for the downlink (22 ms at 460,800 baud), 512 B for the DVL (44 ms
/// at 115,200 baud); the board loop drains them every millisecond.
const DOWNLINK_QUEUE: usize = 1024;
const DVL_QUEUE: usize = 512;
static DOWNLINK_STATS: RxStats = RxStats::new();
static DVL_STATS: RxStats = RxStats::new();
static DOWNLINK_RX: Mutex<RefCell<Option<RxProducer<'static>>>> = Mutex::new(RefCell::new(None));
static DVL_RX: Mutex<RefCell<Option<RxProducer<'static>>>> = Mutex::new(RefCell::new(None));

/// Transmit queue of the telemetry: 2 KiB (44 ms of USART2 at 460,800 baud, several ticks'
/// worth of the largest bursts); the TXE interrupt sends it.
const TELEMETRY_QUEUE: usize = 2048;
static TELEMETRY_STATS: TxStats = TxStats::new();
static TELEMETRY_TX: Mutex<RefCell<Option<TxConsumer<'static>>>> = Mutex::new(RefCell::new(None));

/// Send the next queued telemetry byte when the data register is empty; with nothing queued,
/// stop the transmit interrupt (the loop enables it again when it queues a frame).
fn service_tx(usart: &pac::usart1::RegisterBlock, tx: &Mutex<RefCell<Option<TxConsumer<'static>>>>) {
    cortex_m::interrupt::free(|cs| {
        if usart.cr1().read().txeie().bit_is_clear() || usart.sr().read().txe().bit_is_clear() {
            return;
        }
        match tx.borrow(cs).borrow_mut().as_mut().and_then(TxConsumer::next_byte) {
            Some(b) => {
                usart.dr().write(|w| unsafe { w.dr().bits(u16::from(b)) });
            }
            None => {
                usart.cr1().modify(|_, w| w.txeie().clear_bit());
            }
        }
    });
}

/// Move every received byte (and error flag) of a USART into its queue.
fn service_rx(usart: &pac::usart1::RegisterBlock, rx: &Mutex<RefCell<Option<RxProducer<'static>>>>) {
    cortex_m::interrupt::free(|cs| {
        let mut slot = rx.borrow(cs).borrow_mut();
        // Bounded: the data register holds one byte, so this runs once or twice per interrupt.
        for _ in 0..4 {
            let sr = usart.sr().read();
            if sr.rxne().bit_is_clear() {
                break;
            }
            let framing = sr.fe().bit_is_set() || sr.nf().bit_is_set() || sr.pe().bit_is_set();
            let overrun = sr.ore().bit_is_set();
            // Reading DR after SR clears RXNE and the error flags.
            let byte = usart.dr().read().dr().bits() as u8;
            if let Some(p) = slot.as_mut() {
                if overrun {
                    p.on_error(RxError::Overrun);
                }
                if framing {
                    p.on_error(RxError::Framing);
                } else {
                    p.on_byte(byte);
                }
            }
        }
    });
}

#[interrupt]
fn USART2() {
    // SAFETY: read-only access to the status and data registers; the loop never reads them
    // (its `Rx` half is unused once the interrupt is enabled).
    service_rx(unsafe { &*pac::USART2::ptr() }, &DOWNLINK_RX);
    // SAFETY: the data register's write and CR1's TXEIE bit; the loop only sets TXEIE, inside a
    // critical section (`QueuedSink`).
    service_tx(unsafe { &*pac::USART2::ptr() }, &TELEMETRY_TX);
}

#[interrupt]
fn USART3() {
    // SAFETY: as for USART2; the DVL's `Tx` half only writes DR/reads TXE.
    service_rx(unsafe { &*pac::USART3::ptr() }, &DVL_RX);
}

/// The DVL's UART for its driver: reads from the interrupt-fed queue, writes (its few commands)
/// straight to USART3.
struct DvlUart {
    rx: RxConsumer<'static>,
    tx: serial::Tx<pac::USART3>,
}

impl embedded_io::ErrorType for DvlUart {
    type Error = HalBusError;
}

impl embedded_io::Read for DvlUart {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        Ok(self.rx.drain(buf))
    }
}

impl embedded_io::ReadReady for DvlUart {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(embedded_io::ReadReady::read_ready(&mut self.rx).unwrap_or(false))
    }
}

impl embedded_io::Write for DvlUart {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        embedded_io::Write::write(&mut self.tx, buf).map_err(|_| HalBusError(FaultKind::BusOther))
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        embedded_io::Write::flush(&mut self.tx).map_err(|_| HalBusError(FaultKind::BusOther))
    }
}

#[exception]
fn SysTick() {
    MILLIS.fetch_add(1, Ordering::Relaxed);
}

defmt::timestamp!("{=u64:us}", u64::from(MILLIS.load(Ordering::Relaxed)) * 1000);

/// Reads the tick count and SysTick consistently (the tick may fire between the two reads).
struct Clock(TickClock);

impl Clock {
    fn now_us(&mut self) -> u64 {
        loop {
            let a = MILLIS.load(Ordering::Relaxed);
            let cvr = cortex_m::peripheral::SYST::get_current();
            if MILLIS.load(Ordering::Relaxed) == a {
                return self.0.now_us(a, cvr);
            }
        }
    }
}

/// Busy-wait delay on the DWT cycle counter (the SysTick is the scheduler's clock).
#[derive(Clone, Copy)]
struct CycleDelay;

impl embedded_hal::delay::DelayNs for CycleDelay {
    fn delay_ns(&mut self, ns: u32) {
        let cycles = (u64::from(ns) * u64::from(CORE_HZ / 1_000_000)).div_ceil(1000);
        let start = cortex_m::peripheral::DWT::cycle_count();
        while u64::from(cortex_m::peripheral::DWT::cycle_count().wrapping_sub(start)) < cycles {}
    }
}

/// Telemetry into the transmit queue (whole frames or refused: counted by the application and
/// reported as `Fault(Link, TelemetryDropped)`), sent by USART2's TXE interrupt.
struct QueuedSink(TxProducer<'static>);

impl TelemetrySink for QueuedSink {
    fn write_frame(&mut self, frame: &[u8]) -> bool {
        let queued = self.0.write_frame(frame);
        if queued {
            cortex_m::interrupt::free(|_| {
                // SAFETY: sets TXEIE only (read-modify-write inside a critical section, so the
                // interrupt's own clearing of it cannot interleave).
                unsafe { &*pac::USART2::ptr() }.cr1().modify(|_, w| w.txeie().set_bit());
            });
        }
        queued
    }
}

/// The backup SRAM (clock on, write protection of the backup domain off), as the warm-start
/// record's memory. Taken once, at boot.
fn backup_sram(rcc: &pac::RCC, pwr: &pac::PWR) -> &'static mut [u8; WARM_RECORD_BYTES] {
    rcc.apb1enr().modify(|_, w| w.pwren().set_bit());
    pwr.cr().modify(|_, w| w.dbp().set_bit());
    rcc.ahb1enr().modify(|_, w| w.bkpsramen().set_bit());
    // SAFETY: the backup SRAM (RM0090 2.3: 0x4002_4000, 4 KiB), clocked and writable above,
    // used by nothing else; taken once at boot, so this is the only reference.
    unsafe { &mut *(0x4002_4000 as *mut [u8; WARM_RECORD_BYTES]) }
}

#[entry]
fn main() -> ! {
    let (Some(dp), Some(mut core)) = (pac::Peripherals::take(), cortex_m::Peripherals::take()) else {
        defmt::panic!("peripherals taken twice");
    };
    let reset_cause = take_reset_cause(&dp.RCC);
    let warm = backup_sram(&dp.RCC, &dp.PWR);
    let mut rcc = dp.RCC.freeze(Config::hse(HSE_HZ.Hz()).sysclk(CORE_HZ.Hz()));

    core.SYST.set_clock_source(SystClkSource::Core);
    core.SYST.set_reload(RELOAD);
    core.SYST.clear_current();
    core.SYST.enable_interrupt();
    core.SYST.enable_counter();

    core.DCB.enable_trace();
    core.DWT.enable_cycle_counter();
    cortex_m_stack::repaint_stack();

    let gpioa = dp.GPIOA.split(&mut rcc);
    let gpiob = dp.GPIOB.split(&mut rcc);
    let gpioc = dp.GPIOC.split(&mut rcc);
    let serial: Serial<pac::USART2> =
        match dp.USART2.serial((gpioa.pa2, gpioa.pa3), serial::Config::default().baudrate(460_800.bps()), &mut rcc) {
            Ok(s) => s,
            Err(_) => defmt::panic!("USART2 configuration rejected"),
        };
    // The `Tx` half stays unused: the TXE interrupt writes the data register.
    let (_tx, mut rx) = serial.split();
    let Some(telemetry_queue) = cortex_m::singleton!(: Queue<u8, TELEMETRY_QUEUE> = Queue::new()) else {
        defmt::panic!("telemetry queue taken twice");
    };
    let (telemetry_producer, telemetry_consumer) = telemetry_queue.split();
    cortex_m::interrupt::free(|cs| TELEMETRY_TX.borrow(cs).replace(Some(TxConsumer::new(telemetry_consumer))));
    let mut sink = QueuedSink(TxProducer::new(telemetry_producer, &TELEMETRY_STATS));
    let Some(downlink_queue) = cortex_m::singleton!(: Queue<u8, DOWNLINK_QUEUE> = Queue::new()) else {
        defmt::panic!("downlink queue taken twice");
    };
    let (producer, downlink_consumer) = downlink_queue.split();
    let downlink = RxConsumer::new(downlink_consumer);
    cortex_m::interrupt::free(|cs| DOWNLINK_RX.borrow(cs).replace(Some(RxProducer::new(producer, &DOWNLINK_STATS))));
    rx.listen();

    // The DVL on USART3.
    let dvl_serial: Serial<pac::USART3> =
        match dp.USART3.serial((gpiob.pb10, gpiob.pb11), serial::Config::default().baudrate(115_200.bps()), &mut rcc) {
            Ok(s) => s,
            Err(_) => defmt::panic!("USART3 configuration rejected"),
        };
    let (dvl_tx, mut dvl_rx) = dvl_serial.split();
    let Some(dvl_queue) = cortex_m::singleton!(: Queue<u8, DVL_QUEUE> = Queue::new()) else {
        defmt::panic!("DVL queue taken twice");
    };
    let (producer, dvl_consumer) = dvl_queue.split();
    cortex_m::interrupt::free(|cs| DVL_RX.borrow(cs).replace(Some(RxProducer::new(producer, &DVL_STATS))));
    dvl_rx.listen();
    // SAFETY: the handlers only touch their own USART's status/data registers and queue.
    unsafe {
        cortex_m::peripheral::NVIC::unmask(pac::Interrupt::USART2);
        cortex_m::peripheral::NVIC::unmask(pac::Interrupt::USART3);
    }

    let mut clock = Clock(TickClock::new(CORE_HZ));
    let mut app = App::new(Board::Stm32F405);
    app.set_reset_cause(reset_cause);
    defmt::info!("board stm32f405, reset cause {=?}", reset_cause);

    // The store: the W25Q16JV on SPI2.
    let spi2 = dp.SPI2.spi(
        (Some(gpiob.pb13), Some(gpiob.pb14), Some(gpiob.pb15)),
        Mode { polarity: Polarity::IdleLow, phase: Phase::CaptureOnFirstTransition },
        8.MHz(),
        &mut rcc,
    );
    let Ok(flash_dev) = ExclusiveDevice::new(spi2, gpiob.pb12.into_push_pull_output(), CycleDelay);
    let (mut flash_store, mut failed_store) = (None, None);
    let store: &mut dyn RecordStore = match W25q::new(HalSpi(flash_dev)) {
        Ok(flash) => flash_store.insert(FlashStore::new(flash)),
        Err(e) => failed_store.insert(FailedStore(e.fault_kind())),
    };
    app.boot_with_store(clock.now_us(), store, &mut sink);
    // Started after the store's boot (a reformat takes longer than its period).
    let mut watchdog = IndependentWatchdog::new(dp.IWDG);
    watchdog.start(WATCHDOG_PERIOD_MS.millis());
    // The IWDG resets at most a period after the last feed; the reset and this boot add little.
    let reset_gap_max_s = 2.0 * WATCHDOG_PERIOD_MS as f32 * 1e-3;
    if let Err(e) = app.warm_start_at_boot(warm.as_slice(), reset_gap_max_s) {
        defmt::info!("no warm start ({=?}): aligning", e);
    }

    // Sensors.
    let spi = dp.SPI1.spi(
        (Some(gpioa.pa5), Some(gpioa.pa6), Some(gpioa.pa7)),
        Mode { polarity: Polarity::IdleLow, phase: Phase::CaptureOnFirstTransition },
        8.MHz(),
        &mut rcc,
    );
    let cs = gpioa.pa4.into_push_pull_output();
    let Ok(imu_dev) = ExclusiveDevice::new(spi, cs, CycleDelay);
    // The bus map's I2C 0 is I2C1, its I2C 1 is I2C3 (subnav_wire::bridge::bus_map).
    let i2c1 = RefCell::new(dp.I2C1.i2c((gpiob.pb6, gpiob.pb7), 400.kHz(), &mut rcc));
    let i2c3 = RefCell::new(dp.I2C3.i2c((gpioa.pa8, gpioc.pc9), 400.kHz(), &mut rcc));
    let i2c_on = |bus: u8| match bus {
        0 => HalI2cEither::First(HalI2c(RefCellDevice::new(&i2c1))),
        _ => HalI2cEither::Second(HalI2c(RefCellDevice::new(&i2c3))),
    };
    let mut delay = CycleDelay;
    let suite = HeadSuite::new(
        HalSpi(imu_dev),
        core::array::from_fn(|u| i2c_on(bus_map::POLARIZATION_ADC_I2C[u].0)),
        i2c_on(bus_map::DEPTH_I2C.0),
        Some(DvlUart { rx: RxConsumer::new(dvl_consumer), tx: dvl_tx }),
        &mut delay,
    )
    .with_camera_trigger(gpiob.pb0.into_push_pull_output());
    defmt::info!(
        "sensor init: imu ok {=bool}, polarization ok {=?}, depth ok {=bool}",
        suite.init.imu.is_none(),
        suite.init.polarization.map(|p| p.is_none()),
        suite.init.depth.is_none()
    );
    let mut board = Stm32Board {
        clock,
        downlink,
        suite,
        store,
        warm: warm.as_mut_slice(),
        watchdog,
        sink,
        losses: 0,
        next_stack_report_us: 60_000_000,
    };
    // Real time: after a stall the loop goes on at the current tick (no burst of late ticks).
    let mut board_loop = BoardLoop::new(CatchUp::SkipAhead);
    loop {
        board_loop.pass(&mut app, &mut board);
        // Wake on the 1 kHz tick (or a received byte; the queues hold them until the next pass).
        cortex_m::asm::wfi();
    }
}

/// The board as the board loop sees it.
struct Stm32Board<'a, S> {
    clock: Clock,
    downlink: RxConsumer<'static>,
    suite: S,
    store: &'a mut dyn RecordStore,
    warm: &'a mut [u8],
    watchdog: IndependentWatchdog,
    sink: QueuedSink,
    /// Losses of the receive queues taken at the start of the tick, one bit per (queue, kind):
    /// see [`LOSSES`].
    losses: u8,
    next_stack_report_us: u64,
}

/// The receive queues' losses as faults, in the order of the `losses` bits: queue full or UART
/// overrun is `Overrun`; framing, noise, parity is `Malformed`.
const LOSSES: [(FaultSource, FaultKind); 4] = [
    (FaultSource::Link, FaultKind::Overrun),
    (FaultSource::Link, FaultKind::Malformed),
    (FaultSource::Dvl, FaultKind::Overrun),
    (FaultSource::Dvl, FaultKind::Malformed),
];

impl<S: SensorSuite> BoardIo for Stm32Board<'_, S> {
    type Sensors = S;
    type Sink = QueuedSink;

    fn now_us(&mut self) -> u64 {
        self.clock.now_us()
    }

    fn begin_tick(&mut self, _t_us: u64) {
        let (link, dvl) = (DOWNLINK_STATS.take_new(), DVL_STATS.take_new());
        let new = [link.overrun > 0, link.framing > 0, dvl.overrun > 0, dvl.framing > 0];
        self.losses = new.iter().enumerate().fold(0, |m, (k, &on)| if on { m | (1 << k) } else { m });
    }

    fn read_downlink(&mut self, _t_us: u64, buf: &mut [u8]) -> usize {
        self.downlink.drain(buf)
    }

    fn take_fault(&mut self) -> Option<(FaultSource, FaultKind)> {
        let k = self.losses.trailing_zeros() as usize;
        let loss = LOSSES.get(k).copied()?;
        self.losses &= !(1 << k);
        Some(loss)
    }

    fn parts(&mut self) -> BoardParts<'_, S, QueuedSink> {
        BoardParts { sensors: Some(&mut self.suite), store: &mut *self.store, warm: Some(&mut *self.warm), sink: &mut self.sink }
    }

    /// The stack's peak over defmt, every 60 s.
    fn end_tick(&mut self, t_us: u64, _app: &App) {
        if t_us >= self.next_stack_report_us {
            let size = cortex_m_stack::stack_size();
            defmt::info!("stack peak {=u32} bytes of {=u32} (painted)", size.saturating_sub(cortex_m_stack::stack_painted()), size);
            self.next_stack_report_us += 60_000_000;
        }
    }

    fn feed_watchdog(&mut self) {
        self.watchdog.feed();
    }

    /// After the queued telemetry (the reboot's `Ack` among it) is sent, at most 100 ms.
    fn reboot(&mut self) {
        let deadline_us = self.clock.now_us() + 100_000;
        while self.sink.0.pending() && self.clock.now_us() < deadline_us {}
        // The last byte leaves the shift register (22 µs at 460,800 baud).
        let end_us = self.clock.now_us() + 100;
        while self.clock.now_us() < end_us {}
        cortex_m::peripheral::SCB::sys_reset();
    }
}
