//! The board loop, written once: what a pass of every board does, in its order, behind a small
//! board trait ([`BoardIo`]: time, the downlink's bytes, the board's own losses, its sensors,
//! store, kept memory and telemetry sink, the watchdog, reboot), in the style of smoltcp's
//! `poll(now, device)`.
//!
//! A pass ([`BoardLoop::pass`]) runs every 1-ms tick due by the board's clock, each on the
//! *logical* time grid t = k ms, in this order: the downlink's bytes (and the losses the board
//! counted in its receive queues), the sensors (`App::sensor_tick`), the store's queued commands
//! (`App::service_store`), the warm-start record (`App::service_warm_record`), the periodic
//! telemetry (`App::poll`, which may ask for a reboot); after the ticks, the watchdog is fed and
//! the CPU-load window closed. Both board binaries are HAL setup plus `loop { pass; wfi }`; the
//! native software-in-the-loop run and the replay call the same pass with a board whose clock is
//! the run's logical time.
//!
//! Why one loop: the order decides what a tick sees (a command handled before or after the
//! sensors of its tick, the store served before `poll`), and four copies drifted apart (the
//! replay had no store service, the STM32 board ran its sensors off the grid).
//!
//! Missed ticks: a board whose time is logical (QEMU under `-icount`, the host runs) processes
//! every tick, so a run is repeatable whatever the host's speed ([`CatchUp::EveryTick`]); a real
//! board skips ahead to the current tick after a stall instead of bursting
//! ([`CatchUp::SkipAhead`]), and counts the ticks it skipped.

use core::sync::atomic::{Ordering, compiler_fence};

use subnav_wire::{FaultKind, FaultSource};

use crate::App;
use crate::app::BoardRequest;
use crate::sensors::SensorSuite;
use crate::store::RecordStore;
use crate::telemetry::TelemetrySink;

/// Downlink reads per tick at most (of up to [`DOWNLINK_CHUNK`] bytes each): bounds a tick's
/// work under a flood; 1 KiB per ms is over 20 times what 460,800 baud brings.
pub const DOWNLINK_READS_PER_TICK: usize = 16;
/// Bytes per downlink read.
pub const DOWNLINK_CHUNK: usize = 64;
/// Losses taken from the board per tick at most.
const BOARD_FAULTS_PER_TICK: usize = 4;
/// Length of the CPU-load window, µs.
pub const CPU_LOAD_WINDOW_US: u64 = 1_000_000;

/// What a board gives the loop for a tick, borrowed together (they are used together).
pub struct BoardParts<'a, S, T> {
    /// The sensor suite (`None`: a board without sensors).
    pub sensors: Option<&'a mut S>,
    /// The store of records (`NoStore` when there is none).
    pub store: &'a mut dyn RecordStore,
    /// Memory that survives a reset, for the warm-start record (`None`: not kept).
    pub warm: Option<&'a mut [u8]>,
    /// Where telemetry goes.
    pub sink: &'a mut T,
}

/// A board as the loop sees it.
pub trait BoardIo {
    type Sensors: SensorSuite;
    type Sink: TelemetrySink;

    /// The board's monotonic time, µs (hardware time; the tick grid is derived from it).
    fn now_us(&mut self) -> u64;

    /// A tick at logical time `t_us` begins (the simulated boards set their bridge's clock).
    fn begin_tick(&mut self, _t_us: u64) {}

    /// Received downlink bytes, into `buf`; 0 when there are no more this tick. Called until it
    /// returns 0, at most [`DOWNLINK_READS_PER_TICK`] times a tick.
    fn read_downlink(&mut self, t_us: u64, buf: &mut [u8]) -> usize;

    /// A loss the board counted since the last call (a receive queue that overflowed, a UART
    /// overrun or framing error), reported as a fault of `source`.
    fn take_fault(&mut self) -> Option<(FaultSource, FaultKind)> {
        None
    }

    /// The sensors, store, kept memory and sink.
    fn parts(&mut self) -> BoardParts<'_, Self::Sensors, Self::Sink>;

    /// The tick at `t_us` is done (board self-tests, the end of a run, a stack report).
    fn end_tick(&mut self, _t_us: u64, _app: &App) {}

    /// Whether the loop stops here (the replay, at the end of what it can reproduce). Asked
    /// after each downlink read and after each tick; boards never stop.
    fn halt(&mut self, _app: &App) -> bool {
        false
    }

    /// Feed the watchdog (after the ticks of a pass; the kept record is written by then).
    fn feed_watchdog(&mut self) {}

    /// The application asked for a reboot (its telemetry is written): hardware boards reset
    /// and do not return; a host run notes it.
    fn reboot(&mut self);
}

/// How a pass ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PassEnd {
    /// The due ticks ran; wait for the next.
    Idle,
    /// The application asked for a reboot and [`BoardIo::reboot`] returned.
    Reboot,
    /// [`BoardIo::halt`] said stop.
    Halted,
}

/// Whether missed ticks are run late or skipped (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CatchUp {
    EveryTick,
    SkipAhead,
}

/// The loop's state: the next tick, the CPU-load window.
#[derive(Debug, Clone)]
pub struct BoardLoop {
    catch_up: CatchUp,
    next_tick_ms: u64,
    window_start_us: Option<u64>,
    busy_us: u64,
    /// Ticks skipped since boot ([`CatchUp::SkipAhead`] only).
    pub skipped_ticks: u64,
}

impl BoardLoop {
    /// A loop whose first tick is t = 0.
    pub const fn new(catch_up: CatchUp) -> Self {
        Self { catch_up, next_tick_ms: 0, window_start_us: None, busy_us: 0, skipped_ticks: 0 }
    }

    /// The logical time of the next tick, µs.
    pub fn next_tick_us(&self) -> u64 {
        self.next_tick_ms.saturating_mul(1000)
    }

    /// One pass: every tick due by the board's clock, then the watchdog and the CPU load.
    #[inline(always)] // one frame with the board's `main` (the stack peak is under it)
    pub fn pass<B: BoardIo>(&mut self, app: &mut App, board: &mut B) -> PassEnd {
        let wake_us = board.now_us();
        let window_start_us = *self.window_start_us.get_or_insert(wake_us);
        let hw_ms = wake_us / 1000;
        if self.catch_up == CatchUp::SkipAhead && self.next_tick_ms < hw_ms {
            self.skipped_ticks = self.skipped_ticks.saturating_add(hw_ms - self.next_tick_ms);
            self.next_tick_ms = hw_ms;
        }
        while self.next_tick_ms <= hw_ms {
            let t_us = self.next_tick_ms * 1000;
            self.next_tick_ms += 1;
            let end = Self::tick(app, board, t_us);
            if end != PassEnd::Idle {
                return end;
            }
        }
        // The kept record's writes are done before the loop can stop (the next reset reads them).
        compiler_fence(Ordering::SeqCst);
        board.feed_watchdog();
        let done_us = board.now_us();
        self.busy_us = self.busy_us.saturating_add(done_us.saturating_sub(wake_us));
        let window = done_us.saturating_sub(window_start_us);
        if window >= CPU_LOAD_WINDOW_US {
            app.set_cpu_load(u16::try_from(self.busy_us * 1000 / window).unwrap_or(1000));
            self.window_start_us = Some(done_us);
            self.busy_us = 0;
        }
        PassEnd::Idle
    }

    /// One tick at logical time `t_us`, in the loop's order.
    #[inline(always)]
    fn tick<B: BoardIo>(app: &mut App, board: &mut B, t_us: u64) -> PassEnd {
        board.begin_tick(t_us);
        let mut buf = [0u8; DOWNLINK_CHUNK];
        for _ in 0..DOWNLINK_READS_PER_TICK {
            let n = board.read_downlink(t_us, &mut buf);
            let Some(bytes) = buf.get(..n).filter(|b| !b.is_empty()) else { break };
            app.on_downlink_bytes(t_us, bytes, board.parts().sink);
            if board.halt(app) {
                return PassEnd::Halted;
            }
        }
        for _ in 0..BOARD_FAULTS_PER_TICK {
            let Some((source, kind)) = board.take_fault() else { break };
            app.board_fault(t_us, source, kind, board.parts().sink);
        }
        let parts = board.parts();
        if let Some(sensors) = parts.sensors {
            app.sensor_tick(t_us, sensors, parts.sink);
        }
        app.service_store(t_us, parts.store, parts.sink);
        if let Some(kept) = parts.warm {
            app.service_warm_record(t_us, kept);
        }
        if app.poll(t_us, parts.sink) == BoardRequest::Reboot {
            board.reboot();
            return PassEnd::Reboot;
        }
        board.end_tick(t_us, app);
        if board.halt(app) {
            return PassEnd::Halted;
        }
        PassEnd::Idle
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::app::tests::decode_all;
    use crate::store::NoStore;
    use subnav_wire::{self as wire, Board, Command, CommandAck, ConfigItem, Downlink, Uplink};

    /// A board without sensors (never asked: `parts` gives none).
    struct NoSensors;

    impl SensorSuite for NoSensors {
        fn read_imu(&mut self, _t_us: u64) -> Result<subnav_wire::ImuSample, crate::sensors::SensorFault> {
            unreachable!()
        }
        fn read_polarization(&mut self, _t_us: u64, _unit: u8) -> Result<[i16; 4], crate::sensors::SensorFault> {
            unreachable!()
        }
        fn read_depth(&mut self, _t_us: u64, _rho: f32) -> Result<subnav_wire::DepthSample, crate::sensors::SensorFault> {
            unreachable!()
        }
    }

    /// A board on a settable clock, with scripted downlink bytes and losses.
    struct TestBoard {
        now_us: u64,
        /// Bytes and the tick (ms) from which they are readable.
        downlink: Vec<(u64, Vec<u8>)>,
        faults: Vec<(FaultSource, FaultKind)>,
        store: NoStore,
        out: Vec<u8>,
        ticks: Vec<u64>,
        reboots: u32,
        feeds: u32,
        /// Clock advance per `now_us` call (a pass that takes time).
        busy_per_read_us: u64,
    }

    impl TestBoard {
        fn new() -> Self {
            Self {
                now_us: 0,
                downlink: Vec::new(),
                faults: Vec::new(),
                store: NoStore,
                out: Vec::new(),
                ticks: Vec::new(),
                reboots: 0,
                feeds: 0,
                busy_per_read_us: 0,
            }
        }
    }

    impl BoardIo for TestBoard {
        type Sensors = NoSensors;
        type Sink = Vec<u8>;
        fn now_us(&mut self) -> u64 {
            let t = self.now_us;
            self.now_us += self.busy_per_read_us;
            t
        }
        fn begin_tick(&mut self, t_us: u64) {
            self.ticks.push(t_us);
        }
        fn read_downlink(&mut self, t_us: u64, buf: &mut [u8]) -> usize {
            let Some(k) = self.downlink.iter().position(|(ms, _)| *ms * 1000 <= t_us) else { return 0 };
            let bytes = &mut self.downlink[k].1;
            let n = bytes.len().min(buf.len());
            buf[..n].copy_from_slice(&bytes[..n]);
            bytes.drain(..n);
            if bytes.is_empty() {
                self.downlink.remove(k);
            }
            n
        }
        fn take_fault(&mut self) -> Option<(FaultSource, FaultKind)> {
            self.faults.pop()
        }
        fn parts(&mut self) -> BoardParts<'_, Self::Sensors, Self::Sink> {
            BoardParts { sensors: None, store: &mut self.store, warm: None, sink: &mut self.out }
        }
        fn feed_watchdog(&mut self) {
            self.feeds += 1;
        }
        fn reboot(&mut self) {
            self.reboots += 1;
        }
    }

    fn frame(seq: u16, command: Command) -> Vec<u8> {
        let mut buf = [0u8; wire::MAX_DOWNLINK_FRAME];
        wire::encode(&Downlink { seq, command }, &mut buf).unwrap().to_vec()
    }

    #[test]
    fn every_tick_on_the_grid_runs_once_in_order_and_a_reboot_ends_the_pass() {
        let mut app = App::new(Board::QemuMps2An386);
        let mut board = TestBoard::new();
        let mut lp = BoardLoop::new(CatchUp::EveryTick);
        app.boot(0, &mut board.out);
        // A stall: the first pass wakes at 3.7 ms and runs ticks 0..=3 on the grid.
        board.now_us = 3_700;
        board.downlink.push((2, frame(1, Command::SetConfig(ConfigItem::NavRateHz(20)))));
        board.faults.push((FaultSource::Link, FaultKind::Overrun));
        assert_eq!(lp.pass(&mut app, &mut board), PassEnd::Idle);
        assert_eq!(board.ticks, vec![0, 1000, 2000, 3000]);
        assert_eq!(board.feeds, 1);
        let msgs = decode_all(&board.out);
        assert!(msgs.iter().any(|m| matches!(m, Uplink::Ack(CommandAck { seq: 1, result: Ok(()) }))));
        assert!(msgs.iter().any(|m| matches!(m, Uplink::Fault(f) if f.source == FaultSource::Link && f.kind == FaultKind::Overrun)));
        assert_eq!(app.config.nav_rate_hz, 20);
        // Nothing due: no tick, the watchdog still fed.
        assert_eq!(lp.pass(&mut app, &mut board), PassEnd::Idle);
        assert_eq!(board.ticks.len(), 4);
        assert_eq!(board.feeds, 2);
        // A reboot command: acknowledged, then the board is asked, the pass ends.
        board.now_us = 5_000;
        board.downlink.push((4, frame(2, Command::Reboot)));
        assert_eq!(lp.pass(&mut app, &mut board), PassEnd::Reboot);
        assert_eq!(board.reboots, 1);
        assert_eq!(board.ticks, vec![0, 1000, 2000, 3000, 4000], "the pass ended at the rebooting tick");
        assert!(decode_all(&board.out).iter().any(|m| matches!(m, Uplink::Ack(CommandAck { seq: 2, result: Ok(()) }))));
    }

    #[test]
    fn a_real_board_skips_missed_ticks_and_counts_them() {
        let mut app = App::new(Board::Stm32F405);
        let mut board = TestBoard::new();
        let mut lp = BoardLoop::new(CatchUp::SkipAhead);
        board.now_us = 10_200;
        lp.pass(&mut app, &mut board);
        assert_eq!(board.ticks, vec![10_000]);
        assert_eq!(lp.skipped_ticks, 10);
        board.now_us = 11_000;
        lp.pass(&mut app, &mut board);
        assert_eq!(board.ticks, vec![10_000, 11_000]);
        assert_eq!(lp.skipped_ticks, 10);
    }

    #[test]
    fn a_flood_is_bounded_per_tick_and_nothing_is_lost() {
        let mut app = App::new(Board::QemuMps2An386);
        let mut board = TestBoard::new();
        let mut lp = BoardLoop::new(CatchUp::EveryTick);
        let mut flood = Vec::new();
        for seq in 1..=100u16 {
            let fix = Command::PositionFix { t_us: 0, pos_ned_m: [1.0; 3], cov_ned_m2: [1.0, 0.0, 0.0, 1.0, 0.0, 1.0] };
            flood.extend(frame(seq, fix));
        }
        let len = flood.len();
        board.downlink.push((0, flood));
        lp.pass(&mut app, &mut board);
        let acked = decode_all(&board.out).iter().filter(|m| matches!(m, Uplink::Ack(_))).count();
        assert!(acked < 100, "one tick takes {} of {len} bytes", DOWNLINK_READS_PER_TICK * DOWNLINK_CHUNK);
        for ms in 1..10 {
            board.now_us = ms * 1000;
            lp.pass(&mut app, &mut board);
        }
        let acks: Vec<u16> =
            decode_all(&board.out).iter().filter_map(|m| if let Uplink::Ack(a) = m { Some(a.seq) } else { None }).collect();
        assert_eq!(acks, (1..=100).collect::<Vec<_>>());
    }

    #[test]
    fn the_cpu_load_is_the_busy_share_of_a_one_second_window() {
        let mut app = App::new(Board::QemuMps2An386);
        let mut board = TestBoard::new();
        let mut lp = BoardLoop::new(CatchUp::EveryTick);
        // Each pass reads the clock twice, 100 µs apart: 100 µs busy per 1-ms pass, 10 %.
        board.busy_per_read_us = 100;
        // The window closes after the 1-s tick's health; the 2-s health reports it.
        for ms in 0..=2_000u64 {
            board.now_us = ms * 1000;
            lp.pass(&mut app, &mut board);
        }
        let health = decode_all(&board.out)
            .into_iter()
            .filter_map(|m| if let Uplink::Health(h) = m { Some(h) } else { None })
            .last()
            .expect("health at 2 s");
        assert!((95..=105).contains(&health.cpu_load_permille), "{}", health.cpu_load_permille);
    }
}
