//! The one way to run a simulated head: [`HeadRun`], a builder (target native or QEMU, the head,
//! what to keep, a recording, a progress display, an observer, a live downlink, a time limit)
//! whose [`HeadRun::run`] returns one output type, [`RunOutput`], scored by
//! [`RunOutput::score`] (`crate::dive::evaluate`, i.e. `subnav_link::score`).
//!
//! Why one: the CLI, the tests, the calibration sessions, the dives, the map loop and the seed
//! sweeps used to pick among nine entry points with positional flags, and repeated the scoring
//! call after each. The two targets differ only in where the firmware runs (`crate::sil` in
//! process, `crate::dive` under QEMU); what a caller asks for is the same.
//! (`subnav qemu`, the raw board with or without the simulated sensors, its link events and
//! statistics printed as they come, runs on `subnav_link::qemu` directly.)
//!
//! ```no_run
//! # fn main() -> anyhow::Result<()> {
//! use subnav_sil::{Scenario, run::HeadRun};
//! let sc = Scenario::default();
//! let out = HeadRun::native(&sc).run()?;
//! let result = out.score(&sc)?;
//! println!("heading RMSE {:.3} deg", result.score.heading_rmse_deg);
//! # Ok(()) }
//! ```

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use subnav_link::qemu::{Downlinker, QemuEvent};
use subnav_wire::Uplink;

use crate::chips::modem::LiveSource;
use crate::dive::{DiveResult, LiveStatus, evaluate};
use crate::head::{Scenario, SimHead};
use crate::map_loop::{MapLoop, MapLoopReport};

/// Where the firmware runs.
#[derive(Debug, Clone, PartialEq)]
pub enum Target {
    /// The firmware's application core compiled for the host (`crate::sil`): seconds per dive.
    Native,
    /// The QEMU board firmware `elf` (`crate::dive`): the reference, minutes per dive. The run is
    /// an error past `timeout` of wall time.
    Qemu { elf: PathBuf, timeout: Duration },
}

/// Called with every uplink message the host receives, as it is decoded: the head's time (µs;
/// under QEMU the message's own time, or the latest before it for messages without one), the
/// message and the map in the loop. It only watches: the run is the same with or without.
pub type Observer<'a> = &'a dyn Fn(u64, &Uplink, Option<&MapLoop>);

/// QEMU: called with every event of the board (decoded messages, defmt log lines, link events)
/// before the run handles it, with the board's command link to send commands on (e.g. after its
/// `Boot`). The board-level tests use it (the watchdog, the store, the stack report).
pub type QemuHook<'a> = &'a mut dyn FnMut(&QemuEvent, &mut Downlinker);

/// A run of a simulated head, to be configured then [`run`](HeadRun::run).
pub struct HeadRun<'a> {
    sc: &'a Scenario,
    target: Target,
    head: Option<SimHead>,
    keep_all: bool,
    record: Option<&'a Path>,
    progress: Option<&'a dyn Fn(&LiveStatus)>,
    observer: Option<Observer<'a>>,
    downlink: Option<LiveSource>,
    board_args: Vec<String>,
    run_ms: Option<u64>,
    qemu_hook: Option<QemuHook<'a>>,
}

/// What a run produced.
pub struct RunOutput {
    /// Every message the host received ([`HeadRun::keep_all`]) or only those the scoring reads
    /// ([`crate::dive::scored`]; bounded by the navigation rate: a day-long dive fits in memory).
    pub messages: Vec<Uplink>,
    /// Native runs that keep everything: the uplink frames as the firmware wrote them, with its
    /// time (µs) of writing (what a recording holds). Empty under QEMU (its recording is written
    /// as it runs).
    pub frames: Vec<(u64, Vec<u8>)>,
    /// Native runs: downlink frames delivered (position fixes, commands), with the firmware time
    /// they were delivered at (empty on a head given with [`HeadRun::on_head`]).
    pub downlink: Vec<(u64, Vec<u8>)>,
    /// The firmware's exit status (native: always `Some(0)`, there is no process to fail).
    pub exit_code: Option<i32>,
    pub corrupt_frames: u64,
    pub bus_transactions: u64,
    /// The map in the loop (scenarios with a camera, head not given).
    pub map: Option<MapLoopReport>,
    /// The recordings written ([`HeadRun::record`]; more than one when the scenario restarts the host).
    pub recordings: Vec<PathBuf>,
}

impl<'a> HeadRun<'a> {
    fn new(sc: &'a Scenario, target: Target) -> Self {
        Self {
            sc,
            target,
            head: None,
            keep_all: false,
            record: None,
            progress: None,
            observer: None,
            downlink: None,
            board_args: Vec::new(),
            run_ms: None,
            qemu_hook: None,
        }
    }

    /// Run `sc` natively (the application core in process).
    pub fn native(sc: &'a Scenario) -> Self {
        Self::new(sc, Target::Native)
    }

    /// Run `sc` on the QEMU board firmware `elf` (a wall-clock limit of 15 minutes unless
    /// [`HeadRun::timeout`] says otherwise).
    pub fn qemu(sc: &'a Scenario, elf: &Path) -> Self {
        Self::new(sc, Target::Qemu { elf: elf.to_path_buf(), timeout: Duration::from_secs(900) })
    }

    /// Run `sc` on `target`.
    pub fn on(sc: &'a Scenario, target: Target) -> Self {
        Self::new(sc, target)
    }

    /// Run on `head` (built for the scenario, e.g. with a flash that outlives the run) instead of
    /// the scenario's own head. Such a head has no map in the loop, and its deliveries are not
    /// reported in [`RunOutput::downlink`].
    pub fn on_head(mut self, head: SimHead) -> Self {
        self.head = Some(head);
        self
    }

    /// Keep every message (and, native, every frame), not only the scored ones.
    pub fn keep_all(mut self) -> Self {
        self.keep_all = true;
        self
    }

    /// Write the run's recording at `path` (the host's view: a restarted host writes a second
    /// recording beside it). Implies [`HeadRun::keep_all`] natively.
    pub fn record(mut self, path: &'a Path) -> Self {
        self.record = Some(path);
        self
    }

    /// QEMU: the wall-clock limit; the run is an error past it (nothing natively).
    pub fn timeout(mut self, t: Duration) -> Self {
        if let Target::Qemu { timeout, .. } = &mut self.target {
            *timeout = t;
        }
        self
    }

    /// Called with the latest navigation solution's status (native: every second of head time;
    /// QEMU: every solution).
    pub fn progress(mut self, p: &'a dyn Fn(&LiveStatus)) -> Self {
        self.progress = Some(p);
        self
    }

    /// Shown every message as it is received.
    pub fn observer(mut self, o: Observer<'a>) -> Self {
        self.observer = Some(o);
        self
    }

    /// Native: polled with the head's time for downlink frames to deliver over the modem as the
    /// run goes (e.g. an autopilot's GPS turned into fixes by `subnav mavlink`): the head then
    /// depends on them, unlike with an observer. Not available under QEMU (an error).
    pub fn downlink(mut self, source: LiveSource) -> Self {
        self.downlink = Some(source);
        self
    }

    /// QEMU: board options after the scenario's (e.g. `hang_at_ms=70000`, `warm=0`).
    pub fn board_args(mut self, args: impl IntoIterator<Item = String>) -> Self {
        self.board_args.extend(args);
        self
    }

    /// QEMU: the board's own run length per boot (it counts on each boot's clock, so a board
    /// that resets runs longer than the scenario); default the scenario's duration.
    pub fn run_ms(mut self, ms: u64) -> Self {
        self.run_ms = Some(ms);
        self
    }

    /// QEMU: see [`QemuHook`].
    pub fn qemu_events(mut self, hook: QemuHook<'a>) -> Self {
        self.qemu_hook = Some(hook);
        self
    }

    /// Run to the scenario's end.
    pub fn run(self) -> Result<RunOutput> {
        let HeadRun { sc, target, head, keep_all, record, progress, observer, downlink, board_args, run_ms, qemu_hook } = self;
        match target {
            Target::Native => {
                if !board_args.is_empty() || run_ms.is_some() || qemu_hook.is_some() {
                    bail!("board options, a board run length and a QEMU event hook are for QEMU runs");
                }
                let run = crate::sil::run(sc, head, keep_all || record.is_some(), progress, observer, downlink);
                let recordings = match record {
                    Some(p) => run.write_recording(p, sc).with_context(|| format!("writing the recording {}", p.display()))?,
                    None => Vec::new(),
                };
                Ok(RunOutput { recordings, ..run })
            }
            Target::Qemu { elf, timeout } => {
                if downlink.is_some() {
                    bail!("a live downlink is for native runs: under QEMU the head's modem carries the scenario's fixes");
                }
                if !elf.is_file() {
                    bail!("firmware ELF {}: no such file (`cargo xtask build --board qemu` builds it)", elf.display());
                }
                let opts = crate::dive::QemuRun { record, timeout, progress, observer, keep_all, board_args, run_ms, hook: qemu_hook };
                crate::dive::run_qemu(&elf, sc, head, opts).with_context(|| format!("running {} under QEMU", elf.display()))
            }
        }
    }
}

impl RunOutput {
    /// The run's figures against the scenario's truth (the one scoring, `subnav_link::score`),
    /// with the map's report and the recordings' spans.
    pub fn score(&self, sc: &Scenario) -> Result<DiveResult> {
        evaluate(sc, &self.messages, self.exit_code, self.corrupt_frames, self.bus_transactions)
            .with_map(self.map.clone(), sc)
            .with_recordings(&self.recordings)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn short() -> Scenario {
        Scenario { duration_s: 1.0, ..Scenario::default() }
    }

    /// What one target cannot do is refused with the reason, before anything runs.
    #[test]
    fn options_of_the_other_target_are_refused() {
        let sc = short();
        let err = HeadRun::native(&sc).board_args(["warm=0".to_string()]).run().err().expect("refused").to_string();
        assert!(err.contains("for QEMU runs"), "{err}");
        let err = HeadRun::native(&sc).run_ms(10).run().err().expect("refused").to_string();
        assert!(err.contains("for QEMU runs"), "{err}");
        let elf = Path::new("/nonexistent/subnav-qemu.elf");
        let err = HeadRun::qemu(&sc, elf).downlink(Box::new(|_| Vec::new())).run().err().expect("refused").to_string();
        assert!(err.contains("native runs"), "{err}");
        let err = HeadRun::qemu(&sc, elf).run().err().expect("refused").to_string();
        assert!(err.contains("/nonexistent/subnav-qemu.elf") && err.contains("no such file"), "{err}");
    }

    /// A native run keeps the scored messages only unless told, and a recording implies all.
    #[test]
    fn what_a_native_run_keeps() {
        let sc = short();
        let lean = HeadRun::native(&sc).run().unwrap();
        assert!(lean.frames.is_empty() && lean.messages.iter().all(crate::dive::scored));
        assert_eq!(lean.exit_code, Some(0));
        let dir = tempfile::tempdir().unwrap();
        let rec = dir.path().join("r.snrec");
        let full = HeadRun::native(&sc).record(&rec).run().unwrap();
        assert!(!full.frames.is_empty() && full.messages.len() > lean.messages.len());
        assert_eq!(full.recordings, vec![rec.clone()]);
        assert!(rec.is_file());
    }
}
