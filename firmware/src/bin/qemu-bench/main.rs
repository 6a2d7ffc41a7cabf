//! Target benchmarks: instruction counts of the shared core on the Cortex-M4F, under QEMU.
//!
//! Run with `cargo xtask bench-target`. QEMU runs with `-icount shift=0,align=off,sleep=off`, so
//! one instruction = 1 ns of virtual time; SysTick counts the 25 MHz core clock of mps2-an386,
//! i.e. one tick per 40 instructions. Each case runs `iterations` times between two SysTick
//! readings; the harness subtracts an empty-loop baseline and prints instructions per call.
//! QEMU is not cycle-accurate: these are instruction counts, not cycles (a real M4F needs
//! more cycles than instructions for loads, divisions and branches).
//!
//! Results go to UART0 as text lines `bench <name> <iterations> <instructions_per_call>`,
//! which xtask collects. Add cases in `cases.rs`.
#![no_std]
#![no_main]

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::entry;
use cortex_m_semihosting::debug;
use defmt_semihosting as _;

mod cases;
#[path = "../qemu/cmsdk_uart.rs"]
mod cmsdk_uart;

const RELOAD: u32 = 0x00FF_FFFF;
const INSTRUCTIONS_PER_TICK: u64 = 40;

/// The free-running 24-bit SysTick down-counter (no interrupt: a measurement must stay below
/// 2^24 ticks = 671 M instructions, which `run` checks).
fn ticks() -> u32 {
    cortex_m::peripheral::SYST::get_current()
}

fn elapsed(t0: u32, t1: u32) -> u64 {
    u64::from(t0.wrapping_sub(t1) & RELOAD)
}

/// Runs and reports benchmark cases.
pub struct Bench {
    uart: cmsdk_uart::Uart,
    baseline_ticks_per_iter_x1000: u64,
}

impl Bench {
    fn measure<R>(&mut self, iterations: u32, f: &mut impl FnMut() -> R) -> u64 {
        let t0 = ticks();
        for _ in 0..iterations {
            core::hint::black_box(f());
        }
        let t1 = ticks();
        elapsed(t0, t1) * 1000 / u64::from(iterations.max(1))
    }

    /// Measure `f` over `iterations` calls and print instructions per call.
    pub fn run<R>(&mut self, name: &str, iterations: u32, mut f: impl FnMut() -> R) {
        // One untimed call first, so one-time work (e.g. lazy tables) is not averaged in.
        core::hint::black_box(f());
        let x1000 = self.measure(iterations, &mut f).saturating_sub(self.baseline_ticks_per_iter_x1000);
        let total_ticks = x1000 * u64::from(iterations) / 1000;
        let mut line: heapless::String<160> = heapless::String::new();
        if total_ticks >= u64::from(RELOAD) / 2 {
            let _ = core::fmt::write(&mut line, format_args!("bench-error {name}: too many iterations for the 24-bit counter\n"));
        } else {
            let instr = x1000 * INSTRUCTIONS_PER_TICK / 1000;
            let _ = core::fmt::write(&mut line, format_args!("bench {name} {iterations} {instr}\n"));
        }
        self.uart.write_all(line.as_bytes());
    }
}

#[entry]
fn main() -> ! {
    let Some(mut core) = cortex_m::Peripherals::take() else { fail() };
    // The M4F FPU is enabled by cortex-m-rt for the hard-float target.
    core.SYST.set_clock_source(SystClkSource::Core);
    core.SYST.set_reload(RELOAD);
    core.SYST.clear_current();
    core.SYST.disable_interrupt();
    core.SYST.enable_counter();
    let mut bench = Bench { uart: cmsdk_uart::Uart::uart0(), baseline_ticks_per_iter_x1000: 0 };
    let mut nothing = || 0u32;
    bench.baseline_ticks_per_iter_x1000 = bench.measure(10_000, &mut nothing);
    // Calibration: 1000 iterations of a known instruction sequence (10 NOPs per call).
    bench.run("calibration.10_nops", 1000, || {
        for _ in 0..1 {
            cortex_m::asm::nop();
            cortex_m::asm::nop();
            cortex_m::asm::nop();
            cortex_m::asm::nop();
            cortex_m::asm::nop();
            cortex_m::asm::nop();
            cortex_m::asm::nop();
            cortex_m::asm::nop();
            cortex_m::asm::nop();
            cortex_m::asm::nop();
        }
    });
    cases::run_all(&mut bench);
    bench.uart.write_all(b"bench-done\n");
    debug::exit(debug::EXIT_SUCCESS);
    fail()
}

fn fail() -> ! {
    debug::exit(debug::EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    defmt::error!("panic: {}", defmt::Display2Format(info));
    fail()
}
