//! Board: QEMU `mps2-an386` (Cortex-M4F). Thin glue around [`subnav_firmware::App`]:
//! - telemetry and commands on CMSDK UART0 (0x4000_4000), which QEMU connects to a socket/file;
//! - defmt logs and the exit status over semihosting;
//! - time from SysTick (25 MHz core clock, 1 kHz tick); with `-icount ... sleep=off` QEMU's
//!   virtual time follows executed instructions, so a run is repeatable bit for bit.
//!
//! Run options come from the semihosting command line (`-semihosting-config arg=...`):
//! `run_ms=N` exits successfully after N ms of firmware time; `panic_at_ms=N` panics on purpose
//! (self-test of the panic path: the run must fail).
#![no_std]
#![no_main]

use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::{entry, exception};
use cortex_m_semihosting::debug;
use defmt_semihosting as _;
use subnav_firmware::{App, TelemetrySink, app::BoardRequest};
use subnav_shared::wire::Board;

mod cmsdk_uart;
use cmsdk_uart::Uart;

const CORE_HZ: u32 = 25_000_000;
const TICK_HZ: u32 = 1_000;
const RELOAD: u32 = CORE_HZ / TICK_HZ - 1;

static MILLIS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    MILLIS.fetch_add(1, Ordering::Relaxed);
}

/// Monotonic microseconds since boot (wraps after 49 days of uptime in the ms counter; a
/// 64-bit extension is kept by the caller-visible `Clock`).
struct Clock {
    last_ms: u32,
    high: u64,
}

impl Clock {
    fn now_us(&mut self) -> u64 {
        let (ms, cvr) = loop {
            let a = MILLIS.load(Ordering::Relaxed);
            let cvr = cortex_m::peripheral::SYST::get_current();
            if MILLIS.load(Ordering::Relaxed) == a {
                break (a, cvr);
            }
        };
        if ms < self.last_ms {
            self.high += 1 << 32;
        }
        self.last_ms = ms;
        let sub_us = u64::from(RELOAD - cvr.min(RELOAD)) / u64::from(CORE_HZ / 1_000_000);
        (self.high + u64::from(ms)) * 1000 + sub_us
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
}

fn parse_u64(s: &[u8]) -> Option<u64> {
    if s.is_empty() {
        return None;
    }
    s.iter().try_fold(0u64, |acc, &c| {
        if c.is_ascii_digit() { acc.checked_mul(10)?.checked_add(u64::from(c - b'0')) } else { None }
    })
}

fn run_options() -> RunOptions {
    let mut opts = RunOptions { run_ms: None, panic_at_ms: None };
    let mut buf = [0u8; 256];
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
        }
    }
    opts
}

#[entry]
fn main() -> ! {
    let mut core = cortex_m::Peripherals::take().unwrap_or_else(|| fail("core peripherals taken twice"));
    core.SYST.set_clock_source(SystClkSource::Core);
    core.SYST.set_reload(RELOAD);
    core.SYST.clear_current();
    core.SYST.enable_interrupt();
    core.SYST.enable_counter();

    let mut uart = Uart::uart0();
    let opts = run_options();
    let mut clock = Clock { last_ms: 0, high: 0 };
    let mut app = App::new(Board::QemuMps2An386);

    defmt::info!("board qemu-mps2-an386, run_ms={=?}", opts.run_ms);
    app.boot(clock.now_us(), &mut uart);

    let mut rx = [0u8; 64];
    let mut window_start_us = clock.now_us();
    let mut busy_us: u64 = 0;
    loop {
        let wake_us = clock.now_us();
        let n = uart.read_available(&mut rx);
        if let Some(bytes) = rx.get(..n) {
            if !bytes.is_empty() {
                app.on_downlink_bytes(wake_us, bytes, &mut uart);
            }
        }
        if app.poll(wake_us, &mut uart) == BoardRequest::Reboot {
            defmt::info!("reboot requested");
            cortex_m::peripheral::SCB::sys_reset();
        }
        if let Some(t) = opts.panic_at_ms {
            if wake_us >= t * 1000 {
                panic!("injected panic at {} ms (panic_at_ms self-test)", t);
            }
        }
        if let Some(t) = opts.run_ms {
            if wake_us >= t * 1000 {
                defmt::info!("run_ms reached, exiting");
                debug::exit(debug::EXIT_SUCCESS);
            }
        }
        let done_us = clock.now_us();
        busy_us += done_us.saturating_sub(wake_us);
        let window = done_us.saturating_sub(window_start_us);
        if window >= 1_000_000 {
            app.set_cpu_load(u16::try_from(busy_us * 1000 / window).unwrap_or(1000));
            window_start_us = done_us;
            busy_us = 0;
        }
        cortex_m::asm::wfi();
    }
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

#[exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    defmt::error!("hard fault");
    debug::exit(debug::EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}
