//! Board: QEMU `mps2-an386` (Cortex-M4F). Thin glue around [`subnav_firmware::App`]:
//! - telemetry and commands on CMSDK UART0 (0x4000_4000), which QEMU connects to a socket/file;
//! - the sensors (ICM-42688-P on SPI, 4x ADS1115 and MS5837 on I2C, the DVL-A50 on UART 0)
//!   through the host bridge, and the modem that brings the host's position fixes (UART 1)
//!   (two named pipes opened over semihosting, see `semihost_pipe.rs`): the same drivers as on
//!   the STM32 board, only the bus implementation differs;
//! - defmt logs and the exit status over semihosting;
//! - time from SysTick (25 MHz core clock, 1 kHz tick); with `-icount ... sleep=off` QEMU's
//!   virtual time follows executed instructions, so a run is repeatable bit for bit.
//!
//! The scheduler runs on *logical* time: tick k is processed as t = k ms, after the hardware
//! tick k has happened. Time spent waiting for the host bridge therefore changes nothing in the
//! telemetry, and a run is repeatable (only the measured CPU load depends on the host).
//!
//! Run options come from the semihosting command line (`-semihosting-config arg=...`):
//! `run_ms=N` exits successfully after N ms of firmware time; `panic_at_ms=N` panics on purpose
//! (self-test of the panic path: the run must fail); `hang_at_ms=N` stops the board loop at N ms
//! after a power-on (self-test of the watchdog: the head must reset and boot again, reporting
//! `ResetCause::Watchdog`); `warm=0` ignores the warm-start record after a reset (the cold
//! restart, for comparison); `bus_req=PATH bus_resp=PATH` are the bridge's pipes (without them
//! the board runs without sensors).
//!
//! Watchdog (`cmsdk_watchdog.rs`): fed once per pass of the board loop; a loop stopped for
//! `WATCHDOG_PERIOD_MS` raises its NMI (the cause is marked for the next boot), twice that
//! resets the machine.
//!
//! Warm restart (`warm_ram.rs`): the running head keeps its warm-start record in RAM that
//! survives a reset; after a watchdog or software reset it starts from it, not from the origin.
#![no_std]
#![no_main]

use core::sync::atomic::{AtomicU32, Ordering};

use core::cell::RefCell;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::{entry, exception};
use cortex_m_semihosting::debug;
use defmt_semihosting as _;

/// The bridge link, or nothing (no sensors).
struct PipeLink(Option<SemihostPipe>);

impl ByteLink for PipeLink {
    fn write_all(&mut self, bytes: &[u8]) {
        if let Some(p) = self.0.as_mut() {
            p.write_all(bytes);
        }
    }
    fn read_byte(&mut self) -> Option<u8> {
        self.0.as_mut().and_then(|p| p.read_byte())
    }
}

use subnav_firmware::app::SERIAL_POLL_US;
use subnav_firmware::board_loop::{BoardIo, BoardLoop, BoardParts, CatchUp};
use subnav_firmware::bus_bridge::{BridgeClient, BridgeDelay, BridgeI2c, BridgePin, BridgeSpi, BridgeUart, ByteLink};
use subnav_firmware::drivers::w25q::W25q;
use subnav_firmware::head_suite::HeadSuite;
use subnav_firmware::sensors::SensorSuite;
use subnav_firmware::store::{FailedStore, FlashStore, NoStore, RecordStore};
use subnav_firmware::time::TickClock;
use subnav_firmware::{App, TelemetrySink};
use subnav_wire::bridge::bus_map;
use subnav_wire::{Board, Command, ConfigItem, Downlink, ResetCause};

mod cmsdk_uart;
mod cmsdk_watchdog;
mod semihost_pipe;
mod warm_ram;
use cmsdk_uart::Uart;
use cmsdk_watchdog::Watchdog;
use semihost_pipe::SemihostPipe;

const CORE_HZ: u32 = 25_000_000;
const TICK_HZ: u32 = 1_000;
const RELOAD: u32 = CORE_HZ / TICK_HZ - 1;

static MILLIS: AtomicU32 = AtomicU32::new(0);

/// The watchdog's NMI comes after this long without a feed, its reset after twice this (ms of
/// virtual time; a board-loop pass takes a few ms at most, the store's boot a few tens).
const WATCHDOG_PERIOD_MS: u32 = 500;

#[exception]
fn SysTick() {
    MILLIS.fetch_add(1, Ordering::Relaxed);
}

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

impl TelemetrySink for Uart {
    fn write_frame(&mut self, frame: &[u8]) -> bool {
        self.write_all(frame);
        true
    }
}

defmt::timestamp!("{=u64:us}", {
    let ms = MILLIS.load(Ordering::Relaxed);
    u64::from(ms) * 1000
});

/// Options from the semihosting command line.
struct RunOptions {
    run_ms: Option<u64>,
    panic_at_ms: Option<u64>,
    hang_at_ms: Option<u64>,
    /// `warm=0`: align cold after a reset (default: warm start from the kept record).
    warm: bool,
    /// Paths of the bridge pipes (NUL-terminated copies), if given.
    bus_req: Option<([u8; 200], usize)>,
    bus_resp: Option<([u8; 200], usize)>,
    /// Configured start: UTC at boot and the NED origin (1e-7 deg).
    utc_unix_us: Option<u64>,
    lat_e7: Option<i64>,
    lon_e7: Option<i64>,
}

fn parse_i64(s: &[u8]) -> Option<i64> {
    match s.split_first() {
        Some((b'-', rest)) => parse_u64(rest).and_then(|v| i64::try_from(v).ok()).map(|v| -v),
        _ => parse_u64(s).and_then(|v| i64::try_from(v).ok()),
    }
}

fn path_arg(v: &[u8]) -> Option<([u8; 200], usize)> {
    let mut p = [0u8; 200];
    // leave room for the terminating NUL
    p.get_mut(..v.len()).filter(|_| v.len() < 200)?.copy_from_slice(v);
    Some((p, v.len() + 1))
}

fn parse_u64(s: &[u8]) -> Option<u64> {
    if s.is_empty() {
        return None;
    }
    s.iter().try_fold(0u64, |acc, &c| if c.is_ascii_digit() { acc.checked_mul(10)?.checked_add(u64::from(c - b'0')) } else { None })
}

#[inline(never)] // its 640-byte command-line buffer stays out of the board loop's frame
fn run_options() -> RunOptions {
    let mut opts = RunOptions {
        run_ms: None,
        panic_at_ms: None,
        hang_at_ms: None,
        warm: true,
        bus_req: None,
        bus_resp: None,
        utc_unix_us: None,
        lat_e7: None,
        lon_e7: None,
    };
    let mut buf = [0u8; 640];
    // SYS_GET_CMDLINE (0x15): parameter block [buffer address, buffer length]; the host writes
    // a NUL-terminated command line and updates the length.
    let mut block = [buf.as_mut_ptr() as usize, buf.len()];
    // SAFETY: a semihosting call with a valid parameter block pointing at our own buffer.
    let ret = unsafe { cortex_m_semihosting::syscall1(0x15, block.as_mut_ptr() as usize) };
    if ret != 0 {
        return opts;
    }
    let len = block[1].min(buf.len());
    for word in buf[..len].split(|&c| c == b' ' || c == 0) {
        if let Some(v) = word.strip_prefix(b"run_ms=") {
            opts.run_ms = parse_u64(v);
        } else if let Some(v) = word.strip_prefix(b"panic_at_ms=") {
            opts.panic_at_ms = parse_u64(v);
        } else if let Some(v) = word.strip_prefix(b"hang_at_ms=") {
            opts.hang_at_ms = parse_u64(v);
        } else if let Some(v) = word.strip_prefix(b"warm=") {
            opts.warm = v != b"0";
        } else if let Some(v) = word.strip_prefix(b"bus_req=") {
            opts.bus_req = path_arg(v);
        } else if let Some(v) = word.strip_prefix(b"bus_resp=") {
            opts.bus_resp = path_arg(v);
        } else if let Some(v) = word.strip_prefix(b"utc_unix_us=") {
            opts.utc_unix_us = parse_u64(v);
        } else if let Some(v) = word.strip_prefix(b"lat_e7=") {
            opts.lat_e7 = parse_i64(v);
        } else if let Some(v) = word.strip_prefix(b"lon_e7=") {
            opts.lon_e7 = parse_i64(v);
        }
    }
    opts
}

#[entry]
fn main() -> ! {
    // Paint the free stack so the peak use can be measured at the end of the run.
    cortex_m_stack::repaint_stack();
    let mut core = cortex_m::Peripherals::take().unwrap_or_else(|| fail("core peripherals taken twice"));
    core.SYST.set_clock_source(SystClkSource::Core);
    core.SYST.set_reload(RELOAD);
    core.SYST.clear_current();
    core.SYST.enable_interrupt();
    core.SYST.enable_counter();
    let reset_cause = cmsdk_watchdog::take_reset_cause();

    let mut uart = Uart::uart0();
    let opts = run_options();
    let clock = Clock(TickClock::new(CORE_HZ));
    let mut app = App::new(Board::QemuMps2An386);
    app.set_reset_cause(reset_cause);

    let pipe = match (&opts.bus_req, &opts.bus_resp) {
        (Some((req, rl)), Some((resp, sl))) => SemihostPipe::open(req.get(..*rl).unwrap_or(&[]), resp.get(..*sl).unwrap_or(&[])),
        _ => None,
    };
    defmt::info!("board qemu-mps2-an386, run_ms={=?}, sensor bridge={=bool}, reset cause {=?}", opts.run_ms, pipe.is_some(), reset_cause);
    let has_bridge = pipe.is_some();
    let bridge = RefCell::new(BridgeClient::new(PipeLink(pipe)));
    // Reads block until the host answers; `None` means the pipe broke: fail fast (BusTimeout).
    bridge.borrow_mut().max_polls = 4;

    // The store: the W25Q on SPI 0 / CS 1 (through the bridge); none without a bridge.
    let (mut flash_store, mut failed_store, mut no_store) = (None, None, NoStore);
    let store: &mut dyn RecordStore = if has_bridge {
        match W25q::new(BridgeSpi::new(&bridge, bus_map::FLASH_SPI.0, bus_map::FLASH_SPI.1)) {
            Ok(flash) => flash_store.insert(FlashStore::new(flash)),
            Err(e) => failed_store.insert(FailedStore(e.fault_kind())),
        }
    } else {
        &mut no_store
    };
    app.boot_with_store(0, store, &mut uart);
    // After a watchdog reset the head stopped at most two watchdog periods before this boot.
    let warm = warm_ram::take();
    let reset_gap_max_s = 2.0 * WATCHDOG_PERIOD_MS as f32 * 1e-3;
    if !opts.warm {
        warm.fill(0);
    }
    if let Err(e) = app.warm_start_at_boot(warm.as_slice(), reset_gap_max_s) {
        defmt::info!("no warm start ({=?}): aligning", e);
    }
    // Started after the store's boot: reformatting a damaged store erases sector after sector
    // (seconds of flash time, bounded by the chip's size), longer than the watchdog's period.
    let watchdog = Watchdog::start(WATCHDOG_PERIOD_MS);
    if let Some(utc) = opts.utc_unix_us.and_then(|u| i64::try_from(u).ok()) {
        app.handle_command(0, Downlink { seq: 0, command: Command::SetTime { t_us: 0, utc_unix_us: utc } }, &mut uart);
    }
    if let (Some(lat), Some(lon)) = (opts.lat_e7, opts.lon_e7) {
        let deg = core::f64::consts::PI / 180.0 * 1e-7;
        let origin = ConfigItem::Origin { lat_rad: lat as f64 * deg, lon_rad: lon as f64 * deg, alt_m: 0.0 };
        app.handle_command(0, Downlink { seq: 0, command: Command::SetConfig(origin) }, &mut uart);
    }

    let mut suite = has_bridge.then(|| {
        let mut delay = BridgeDelay::new(&bridge);
        let suite = HeadSuite::new(
            BridgeSpi::new(&bridge, bus_map::IMU_SPI.0, bus_map::IMU_SPI.1),
            core::array::from_fn(|u| BridgeI2c::new(&bridge, bus_map::POLARIZATION_ADC_I2C[u].0)),
            BridgeI2c::new(&bridge, bus_map::DEPTH_I2C.0),
            Some(BridgeUart::new(&bridge, bus_map::DVL_UART)),
            &mut delay,
        )
        .with_camera_trigger(BridgePin::new(&bridge, bus_map::CAMERA_TRIGGER_GPIO));
        defmt::info!(
            "sensor init: imu {=?} polarization {=?} depth {=?}",
            suite.init.imu.is_none(),
            suite.init.polarization.map(|p| p.is_none()),
            suite.init.depth.is_none()
        );
        suite
    });

    // The modem that brings the host's position fixes in a simulated dive (bridge UART 1: read
    // on the firmware's logical time, so the run stays deterministic).
    let modem = has_bridge.then(|| BridgeUart::new(&bridge, bus_map::MODEM_UART));
    let mut board = QemuBoard {
        clock,
        uart,
        modem,
        bridge: &bridge,
        suite: suite.as_mut(),
        store,
        warm: warm.as_mut_slice(),
        watchdog,
        opts: &opts,
        reset_cause,
        uart_read: false,
        modem_reads: 0,
    };
    // Logical time: every tick runs, whatever the host's speed (see the module doc).
    let mut board_loop = BoardLoop::new(CatchUp::EveryTick);
    loop {
        board_loop.pass(&mut app, &mut board);
        cortex_m::asm::wfi();
    }
}

/// The board as the board loop sees it.
struct QemuBoard<'a, S> {
    clock: Clock,
    uart: Uart,
    modem: Option<BridgeUart<'a, PipeLink>>,
    bridge: &'a RefCell<BridgeClient<PipeLink>>,
    suite: Option<&'a mut S>,
    store: &'a mut dyn RecordStore,
    warm: &'a mut [u8],
    watchdog: Watchdog,
    opts: &'a RunOptions,
    reset_cause: ResetCause,
    /// This tick's UART 0 read is done; the modem's reads this tick.
    uart_read: bool,
    modem_reads: u8,
}

/// Modem reads per serial poll (of 64 bytes each).
const MODEM_READS_PER_POLL: u8 = 4;

impl<S: SensorSuite> BoardIo for QemuBoard<'_, S> {
    type Sensors = S;
    type Sink = Uart;

    fn now_us(&mut self) -> u64 {
        self.clock.now_us()
    }

    fn begin_tick(&mut self, t_us: u64) {
        self.bridge.borrow_mut().set_time(t_us);
        self.uart_read = false;
        self.modem_reads = 0;
    }

    /// UART 0 first (what it holds), then the modem on the serial-poll grid.
    fn read_downlink(&mut self, t_us: u64, buf: &mut [u8]) -> usize {
        if !self.uart_read {
            self.uart_read = true;
            let n = self.uart.read_available(buf);
            if n > 0 {
                return n;
            }
        }
        match self.modem.as_mut().filter(|_| t_us % SERIAL_POLL_US == 0 && self.modem_reads < MODEM_READS_PER_POLL) {
            Some(m) => {
                self.modem_reads += 1;
                embedded_io::Read::read(m, buf).unwrap_or(0)
            }
            None => 0,
        }
    }

    fn parts(&mut self) -> BoardParts<'_, S, Uart> {
        BoardParts { sensors: self.suite.as_deref_mut(), store: &mut *self.store, warm: Some(&mut *self.warm), sink: &mut self.uart }
    }

    /// The self-tests (`panic_at_ms`, `hang_at_ms`) and the end of the run (`run_ms`).
    fn end_tick(&mut self, t_us: u64, _app: &App) {
        if let Some(t) = self.opts.panic_at_ms {
            if t_us >= t * 1000 {
                panic!("injected panic at {} ms (panic_at_ms self-test)", t);
            }
        }
        if let Some(t) = self.opts.hang_at_ms.filter(|_| self.reset_cause == ResetCause::PowerOn) {
            if t_us >= t * 1000 {
                hang(t);
            }
        }
        if let Some(t) = self.opts.run_ms {
            if t_us >= t * 1000 {
                let size = cortex_m_stack::stack_size();
                let peak = size.saturating_sub(cortex_m_stack::stack_painted());
                defmt::info!("stack peak {=u32} bytes of {=u32} (painted)", peak, size);
                defmt::info!("run_ms reached, exiting");
                debug::exit(debug::EXIT_SUCCESS);
            }
        }
    }

    fn feed_watchdog(&mut self) {
        self.watchdog.feed();
    }

    fn reboot(&mut self) {
        defmt::info!("reboot requested");
        cmsdk_watchdog::mark_next_reset(ResetCause::Software);
        cortex_m::peripheral::SCB::sys_reset();
    }
}

/// The `hang_at_ms` self-test: the board loop stops here for good (out of line, so the board
/// loop's frame does not change with it).
#[inline(never)]
fn hang(t_ms: u64) -> ! {
    defmt::warn!("board loop stopped at {=u64} ms (hang_at_ms self-test)", t_ms);
    #[allow(clippy::empty_loop)]
    loop {}
}

fn fail(msg: &str) -> ! {
    defmt::error!("fatal: {=str}", msg);
    debug::exit(debug::EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}

/// panic-probe would `udf` into a HardFault and hang QEMU: exit with a failure status instead.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    defmt::error!("panic: {}", defmt::Display2Format(info));
    debug::exit(debug::EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}

/// The watchdog's first expiry (mps2-an386 wires it to the NMI): the board loop has stopped.
/// Mark the cause for the next boot and wait for the watchdog's reset.
#[exception]
unsafe fn NonMaskableInt() {
    cmsdk_watchdog::mark_next_reset(ResetCause::Watchdog);
    #[allow(clippy::empty_loop)]
    loop {}
}

#[exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    defmt::error!("hard fault");
    debug::exit(debug::EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}
