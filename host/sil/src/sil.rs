//! Native software-in-the-loop: the firmware's application core (`subnav_firmware::App`, its
//! drivers and `HeadSuite`), compiled for the host, scheduled on the same 1 ms logical tick as
//! the QEMU board, with its buses carried by the same bridge protocol to the same chip models
//! ([`SimHead`]). Only the CPU differs (f32 maths on x86 instead of the M4F's FPU), so a native
//! dive follows the QEMU dive closely but not bit for bit.
//!
//! Why: a 5-minute dive takes minutes under QEMU; natively it takes seconds, which makes seed
//! sweeps and filter tuning practical. The QEMU run stays the reference (`crate::dive`). Both are
//! run through [`crate::run::HeadRun`].

use std::cell::RefCell;
use std::collections::VecDeque;

use std::sync::{Arc, Mutex};

use embedded_io::Read as _;
use subnav_firmware::App;
use subnav_firmware::TelemetrySink;
use subnav_firmware::app::SERIAL_POLL_US;
use subnav_firmware::board_loop::{BoardIo, BoardLoop, BoardParts, CatchUp};
use subnav_firmware::bus_bridge::{BridgeClient, BridgeDelay, BridgeI2c, BridgePin, BridgeSpi, BridgeUart, ByteLink};
use subnav_firmware::drivers::w25q::W25q;
use subnav_firmware::head_suite::HeadSuite;
use subnav_firmware::sensors::SensorSuite;
use subnav_firmware::store::{FailedStore, FlashStore, RecordStore};
use subnav_wire::bridge::{BusRequest, BusResponse, MAX_REQUEST_FRAME, MAX_RESPONSE_FRAME, bus_map};
use subnav_wire::{self as wire, Board, Decoded, Downlink, FrameDecoder, MAX_UPLINK_FRAME, Uplink};

use super::dive::LiveStatus;
use super::head::{Scenario, SimHead};
use super::map_loop::MapLoop;
use super::replay::boot_commands;
use super::run::{Observer, RunOutput};
use subnav_link::qemu::BusHandler;

/// The bridge's byte link, answered in process by the chip models.
struct InProcessLink {
    head: SimHead,
    rx: VecDeque<u8>,
    dec: FrameDecoder<MAX_REQUEST_FRAME>,
    transactions: u64,
}

impl ByteLink for InProcessLink {
    fn write_all(&mut self, bytes: &[u8]) {
        for &b in bytes {
            if let Decoded::Message(req) = self.dec.push::<BusRequest>(b) {
                let resp: BusResponse = self.head.handle(&req);
                self.transactions += 1;
                let mut buf = [0u8; MAX_RESPONSE_FRAME];
                // A response always fits its maximum frame; an encoding failure would be a bug
                // in `shared` and shows up as a bus timeout in the firmware.
                if let Ok(frame) = wire::encode(&resp, &mut buf) {
                    self.rx.extend(frame.iter());
                }
            }
        }
    }
    fn read_byte(&mut self) -> Option<u8> {
        self.rx.pop_front()
    }
}

/// Telemetry decoded as it is written (and kept as frames, stamped with firmware time).
struct Collect<'a> {
    observer: Option<Observer<'a>>,
    /// Keep every frame and message (for a recording or a replay); otherwise only the messages
    /// the scoring reads ([`crate::dive::scored`]), so a day-long dive fits in memory.
    keep_all: bool,
    map: Option<MapLoop>,
    last_nav: Option<subnav_wire::NavSolution>,
    dec: FrameDecoder<MAX_UPLINK_FRAME>,
    msgs: Vec<Uplink>,
    corrupt: u64,
    now_us: u64,
    frames: Vec<(u64, Vec<u8>)>,
    /// What the host process receives (nothing while it is down).
    host: crate::dive::HostView,
}

impl TelemetrySink for Collect<'_> {
    fn write_frame(&mut self, frame: &[u8]) -> bool {
        if self.keep_all && !self.host.down_at(self.now_us) {
            self.frames.push((self.now_us, frame.to_vec()));
        }
        for &b in frame {
            match self.dec.push::<Uplink>(b) {
                Decoded::Message(m) => {
                    if !self.host.receives(&m) {
                        continue;
                    }
                    if let Uplink::Nav(n) = &m {
                        self.last_nav = Some(*n);
                    }
                    if let Some(map) = &self.map {
                        map.on_uplink(&m);
                    }
                    if let Some(obs) = self.observer {
                        obs(self.now_us, &m, self.map.as_ref());
                    }
                    if self.keep_all || crate::dive::scored(&m) {
                        self.msgs.push(m)
                    }
                }
                Decoded::Corrupt(_) => self.corrupt += 1,
                Decoded::Pending => {}
            }
        }
        true
    }
}

/// The native head as the board loop sees it: the bridge's clock, the modem (bridge UART 1, read
/// on the serial-poll grid as on the QEMU board), the suite, the store, the collecting sink.
struct SilBoard<'b, 'o, S> {
    t_us: u64,
    bridge: &'b RefCell<BridgeClient<InProcessLink>>,
    modem: BridgeUart<'b, InProcessLink>,
    modem_reads: u8,
    suite: S,
    store: &'b mut dyn RecordStore,
    sink: Collect<'o>,
}

/// Modem reads per serial poll (of 64 bytes each), as on the QEMU board.
const MODEM_READS_PER_POLL: u8 = 4;

impl<'o, S: SensorSuite> BoardIo for SilBoard<'_, 'o, S> {
    type Sensors = S;
    type Sink = Collect<'o>;
    fn now_us(&mut self) -> u64 {
        self.t_us
    }
    fn begin_tick(&mut self, t_us: u64) {
        self.bridge.borrow_mut().set_time(t_us);
        self.modem_reads = 0;
    }
    fn read_downlink(&mut self, t_us: u64, buf: &mut [u8]) -> usize {
        if t_us % SERIAL_POLL_US != 0 || self.modem_reads >= MODEM_READS_PER_POLL {
            return 0;
        }
        self.modem_reads += 1;
        self.modem.read(buf).unwrap_or(0)
    }
    fn parts(&mut self) -> BoardParts<'_, S, Collect<'o>> {
        BoardParts { sensors: Some(&mut self.suite), store: &mut *self.store, warm: None, sink: &mut self.sink }
    }
    fn reboot(&mut self) {}
}

/// Run `sc` natively to its end, on `head` (no map in the loop, deliveries not reported) or the
/// scenario's own head (its map in the loop, fixes and `downlink`'s frames over the modem).
/// [`crate::run::HeadRun`] is the public way in.
pub(crate) fn run(
    sc: &Scenario,
    head: Option<SimHead>,
    keep_all: bool,
    progress: Option<&dyn Fn(&LiveStatus)>,
    observer: Option<Observer<'_>>,
    downlink: Option<crate::chips::modem::LiveSource>,
) -> RunOutput {
    let delivered: Arc<Mutex<Vec<(u64, Vec<u8>)>>> = Arc::default();
    let (head, map) = match head {
        Some(h) => (h, None),
        None => {
            let map = sc.map_loop();
            // Fixes come over the modem (bridge UART 1) at their arrival time, as under QEMU.
            let tap = {
                let d = delivered.clone();
                Box::new(move |t: u64, f: &[u8]| d.lock().unwrap_or_else(|e| e.into_inner()).push((t, f.to_vec())))
            };
            (SimHead::build_live(sc, Some(tap), map.clone(), Vec::new(), downlink), map)
        }
    };
    run_native_on(sc, head, map, delivered, progress, keep_all, observer)
}

fn run_native_on(
    sc: &Scenario,
    head: SimHead,
    map: Option<MapLoop>,
    delivered: Arc<Mutex<Vec<(u64, Vec<u8>)>>>,
    progress: Option<&dyn Fn(&LiveStatus)>,
    keep_all: bool,
    observer: Option<Observer<'_>>,
) -> RunOutput {
    let mut sink = Collect {
        observer,
        keep_all,
        map: map.clone(),
        last_nav: None,
        dec: FrameDecoder::new(),
        msgs: Vec::new(),
        corrupt: 0,
        now_us: 0,
        frames: Vec::new(),
        host: crate::dive::HostView::new(sc),
    };
    let mut downlink = Vec::new();
    let mut app = App::new(Board::QemuMps2An386);
    // Evaluation switch: SUBNAV_COMPASS_WAVE_SIGMA=1 gives the filter the compass's wave part
    // (the comparison in docs/PERFORMANCE.md; off by default, as on the boards).
    if std::env::var_os("SUBNAV_COMPASS_WAVE_SIGMA").is_some_and(|v| v == "1") {
        app.estimator_mut().set_wave_sigma(true);
    }
    // Evaluation switches (the wind-step comparison in docs/PERFORMANCE.md): SUBNAV_NAV_FILTER=aukf
    // runs the seed's adaptive UKF (Sage-Husa R on the heading, depth and DVL updates, fading with
    // the persistence test) instead of the head's UKF with its adaptive heading R.
    if std::env::var_os("SUBNAV_NAV_FILTER").is_some_and(|v| v == "aukf") {
        app.estimator_mut().set_nav_config(subnav_core::head::nav_config().adaptive());
    }
    // SUBNAV_NAV_FILTER=fixed-r: the heading R does not adapt (the head's filter with a fixed R).
    if std::env::var_os("SUBNAV_NAV_FILTER").is_some_and(|v| v == "fixed-r") {
        app.estimator_mut().set_adaptive_heading_r(false);
    }
    let link = InProcessLink { head, rx: VecDeque::new(), dec: FrameDecoder::new(), transactions: 0 };
    let bridge = RefCell::new(BridgeClient::new(link));
    bridge.borrow_mut().max_polls = 4;
    // The store on SPI 0 / CS 1, loaded before the boot message, as on the QEMU board.
    let mut store = W25q::new(BridgeSpi::new(&bridge, bus_map::FLASH_SPI.0, bus_map::FLASH_SPI.1))
        .map(FlashStore::new)
        .map_err(|e| FailedStore(e.fault_kind()));
    let store: &mut dyn RecordStore = match &mut store {
        Ok(s) => s,
        Err(f) => f,
    };
    app.boot_with_store(0, store, &mut sink);
    // The configured start, as the QEMU board applies it from the same start arguments.
    for command in boot_commands(&sc.board_args()) {
        app.handle_command(0, Downlink { seq: 0, command }, &mut sink);
    }
    let mut delay = BridgeDelay::new(&bridge);
    let suite = HeadSuite::new(
        BridgeSpi::new(&bridge, bus_map::IMU_SPI.0, bus_map::IMU_SPI.1),
        core::array::from_fn(|u| BridgeI2c::new(&bridge, bus_map::POLARIZATION_ADC_I2C[u].0)),
        BridgeI2c::new(&bridge, bus_map::DEPTH_I2C.0),
        Some(BridgeUart::new(&bridge, bus_map::DVL_UART)),
        &mut delay,
    )
    .with_camera_trigger(BridgePin::new(&bridge, bus_map::CAMERA_TRIGGER_GPIO));
    let mut board =
        SilBoard { t_us: 0, bridge: &bridge, modem: BridgeUart::new(&bridge, bus_map::MODEM_UART), modem_reads: 0, suite, store, sink };
    // The board loop of the boards, on the run's logical time: one tick per pass.
    let mut board_loop = BoardLoop::new(CatchUp::EveryTick);
    let end_ms = (sc.duration_s * 1000.0).round() as u64;
    for ms in 0..=end_ms {
        board.t_us = ms * 1000;
        board.sink.now_us = board.t_us;
        if let (Some(p), Some(n)) = (progress.filter(|_| ms % 1000 == 0), board.sink.last_nav.as_ref()) {
            p(&LiveStatus::new(n, map.as_ref()));
        }
        // A reboot request is not acted on: the native run has no reset (as before the loop was shared).
        let _ = board_loop.pass(&mut app, &mut board);
    }
    let SilBoard { sink, .. } = board;
    let transactions = bridge.into_inner().link_mut().transactions;
    downlink.extend(delivered.lock().unwrap_or_else(|e| e.into_inner()).drain(..));
    let map = map.map(|m| {
        m.close();
        m.report()
    });
    RunOutput {
        messages: sink.msgs,
        frames: sink.frames,
        downlink,
        exit_code: Some(0),
        corrupt_frames: sink.corrupt,
        bus_transactions: transactions,
        map,
        recordings: Vec::new(),
    }
}

impl RunOutput {
    /// Write the run as its host recorded it (uplink and downlink frames; the "host time" of
    /// each chunk is the firmware time it was written at, plus the scenario's start). A host
    /// killed and restarted mid-dive (`FaultPlan::host_outage_s`) writes two recordings: `path`
    /// up to the kill and the series' next (`dive.2.snrec`) from the restart. Returns them.
    pub fn write_recording(&self, path: &std::path::Path, sc: &Scenario) -> anyhow::Result<Vec<std::path::PathBuf>> {
        use subnav_link::record::tap::HostRecorder;
        use subnav_link::record::{Meta, Stream};
        let mut meta = Meta::new(format!("native software-in-the-loop, scenario seed {}", sc.seed));
        meta.board_args = sc.board_args();
        let outage_head_us = sc.faults.host_outage_s.map(|(a, b)| ((a * 1e6) as u64, (b * 1e6) as u64));
        let mut w = HostRecorder::create(path, meta, outage_head_us)?;
        let t0 = u64::try_from(sc.start_utc_unix_us).unwrap_or(0);
        let mut down = self.downlink.iter().peekable();
        for (t, f) in &self.frames {
            while let Some((td, d)) = down.next_if(|(td, _)| td <= t) {
                w.chunk(Stream::Downlink, t0 + td, d)?;
            }
            w.chunk(Stream::Uplink, t0 + t, f)?;
        }
        for (td, d) in down {
            w.chunk(Stream::Downlink, t0 + td, d)?;
        }
        w.finish()
    }
}
