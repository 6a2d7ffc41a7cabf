//! Recording a simulated run as its host would: a thread that writes the QEMU runner's raw byte
//! chunks ([`QemuConfig::raw_tap`](crate::qemu::QemuConfig::raw_tap)) into a recording as they
//! come, and [`HostRecorder`], which also plays a host process killed and started again
//! mid-dive (the dead host records nothing; the new one starts the next recording of the
//! series, which joins the running head).

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::thread::JoinHandle;

use anyhow::{Result, anyhow};

use super::{Meta, Stream, Writer, series_member};
use crate::output::AtomicFile;
use crate::qemu::{QemuConfig, RawBytes};
use crate::uplink::UplinkDecoder;

/// The recordings of a run's host: one per life of the host process.
pub struct HostRecorder {
    first: PathBuf,
    meta: Meta,
    /// The host is gone from head time `.0` to `.1`, µs.
    outage_head_us: Option<(u64, u64)>,
    life: Life,
    /// The world's view of the head's time (decoded from the uplink as it passes).
    world: UplinkDecoder,
    latest_head_us: u64,
    written: Vec<PathBuf>,
}

enum Life {
    Alive(Box<Writer<AtomicFile>>),
    /// Killed; the next life starts with the first uplink bytes at or after the outage's end.
    Dead,
}

impl HostRecorder {
    /// The first recording goes to `path`, under a temporary name until its first bytes (a run
    /// that fails before leaves an old file there untouched); after a restart, the next one goes
    /// to the series' next name (`dive.2.snrec`), its metadata naming the one it continues.
    pub fn create(path: &Path, meta: Meta, outage_head_us: Option<(u64, u64)>) -> Result<Self> {
        let w = Writer::create_atomic(path, &meta)?;
        Ok(Self {
            first: path.to_path_buf(),
            meta,
            outage_head_us,
            life: Life::Alive(Box::new(w)),
            world: UplinkDecoder::new(),
            latest_head_us: 0,
            written: Vec::new(),
        })
    }

    /// One chunk that crossed the link at host time `t_host_us`: recorded if the host is alive.
    pub fn chunk(&mut self, stream: Stream, t_host_us: u64, data: &[u8]) -> Result<()> {
        // A host that lives through the run records every byte; only an outage needs the time.
        let Some((killed_at, back_at)) = self.outage_head_us else { return self.write(stream, t_host_us, data) };
        if stream == Stream::Uplink {
            let latest = &mut self.latest_head_us;
            self.world.feed(data, |e| {
                if let crate::uplink::LinkEvent::Message(m) = e {
                    *latest = m.t_us().map_or(*latest, |t| t.max(*latest));
                }
            });
        }
        let t = self.latest_head_us;
        // Killed at `killed_at` (the first life only): what was written is on disk (each chunk is).
        if t >= killed_at
            && self.written.is_empty()
            && let Life::Alive(w) = std::mem::replace(&mut self.life, Life::Dead)
        {
            self.written.push(w.into_inner().commit()?);
        }
        if t >= back_at && matches!(self.life, Life::Dead) {
            // Started again: the next recording of the series, from these bytes on.
            let mut meta = self.meta.clone();
            meta.start_unix_us = t_host_us;
            meta.continues = self.written.last().and_then(|p| p.file_name()).map(|n| n.to_string_lossy().into_owned());
            let next = series_member(&self.first, self.written.len() + 1);
            self.life = Life::Alive(Box::new(Writer::create_atomic(&next, &meta)?));
        }
        self.write(stream, t_host_us, data)
    }

    fn write(&mut self, stream: Stream, t_host_us: u64, data: &[u8]) -> Result<()> {
        // Nothing to write leaves an old file at the path alone (the recording is published
        // under its name with its first bytes).
        let (Life::Alive(w), false) = (&mut self.life, data.is_empty()) else { return Ok(()) };
        w.chunk(stream, t_host_us, data)?;
        w.publish()
    }

    /// Close the recording in progress; returns every recording written, in order.
    pub fn finish(mut self) -> Result<Vec<PathBuf>> {
        if let Life::Alive(w) = self.life
            && w.chunks.iter().any(|&n| n > 0)
        {
            self.written.push(w.into_inner().commit()?);
        }
        Ok(self.written)
    }
}

/// A recording in progress; call [`QemuRecorder::finish`] after the run (and after dropping
/// every clone of the config's tap) to flush it and get the recordings written.
pub struct QemuRecorder {
    handle: JoinHandle<Result<Vec<PathBuf>>>,
}

impl QemuRecorder {
    /// Create the recording at `path` and point `cfg.raw_tap` at it. The file is written under a
    /// temporary name until the first bytes arrive: a run that fails before (QEMU missing, a bad
    /// ELF) leaves an old recording at `path` untouched.
    pub fn start(cfg: &mut QemuConfig, path: &Path) -> Result<Self> {
        Self::start_with_host_outage(cfg, path, None)
    }

    /// As [`start`](Self::start), for a host process that is gone from head time `.0` to `.1`
    /// (µs): see [`HostRecorder`].
    pub fn start_with_host_outage(cfg: &mut QemuConfig, path: &Path, outage_head_us: Option<(u64, u64)>) -> Result<Self> {
        let mut meta = Meta::new(format!("qemu {}", cfg.elf.display()));
        meta.elf = Some(cfg.elf.display().to_string());
        meta.board_args = cfg.board_args.clone();
        let mut w = HostRecorder::create(path, meta, outage_head_us)?;
        let (tx, rx) = mpsc::channel::<RawBytes>();
        cfg.raw_tap = Some(tx);
        let handle = std::thread::spawn(move || -> Result<Vec<PathBuf>> {
            for raw in rx {
                let now = super::now_unix_us();
                match raw {
                    RawBytes::Telemetry(b) => w.chunk(Stream::Uplink, now, &b)?,
                    RawBytes::Defmt(b) => w.chunk(Stream::Defmt, now, &b)?,
                    RawBytes::Downlink(b) => w.chunk(Stream::Downlink, now, &b)?,
                }
            }
            w.finish()
        });
        Ok(Self { handle })
    }

    /// Wait for the writer (the run must be over and `cfg.raw_tap` dropped or taken); returns
    /// the recordings written.
    pub fn finish(self) -> Result<Vec<PathBuf>> {
        self.handle.join().map_err(|_| anyhow!("the recording thread panicked"))?
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use subnav_wire::{self as wire, Board, CalibrationInUse, ResetCause, Uplink, boot_message};

    /// A host killed at 3 s and back at 6 s of head time, its bytes arriving in pieces that
    /// cut frames: the first recording ends before 3 s, the second starts at 6 s mid-frame,
    /// joins the running head and names the first.
    #[test]
    fn a_restarted_host_writes_the_next_recording_from_its_restart() {
        let mut bytes = vec![];
        let mut buf = [0u8; wire::MAX_UPLINK_FRAME];
        let boot = boot_message(Board::QemuMps2An386, [0, 1, 0], 0, CalibrationInUse::NO_STORE, ResetCause::PowerOn);
        bytes.extend_from_slice(wire::encode(&Uplink::Boot(boot), &mut buf).unwrap());
        for k in 0..100u64 {
            bytes.extend_from_slice(wire::encode(&crate::uplink::tests::nav(k * 100_000), &mut buf).unwrap());
        }
        let d = tempfile::tempdir().unwrap();
        let path = d.path().join("dive.snrec");
        let mut w = HostRecorder::create(&path, Meta::new("test"), Some((3_000_000, 6_000_000))).unwrap();
        for (i, piece) in bytes.chunks(37).enumerate() {
            w.chunk(Stream::Uplink, 1_000 + i as u64, piece).unwrap();
            w.chunk(Stream::Defmt, 1_000 + i as u64, b"log").unwrap();
        }
        let written = w.finish().unwrap();
        assert_eq!(written, [path.clone(), d.path().join("dive.2.snrec")]);
        let (a, b) = (super::super::uplink_stats(&written[0]).unwrap(), super::super::uplink_stats(&written[1]).unwrap());
        assert!(!a.joined_running_head && a.last_head_us.is_some_and(|t| t < 3_000_000), "{a:?}");
        assert!(b.joined_running_head && b.first_head_us.is_some_and(|t| (6_000_000..6_200_000).contains(&t)), "{b:?}");
        assert_eq!(b.frames_bad, 1, "the restarted host starts mid-frame");
        let (x, y) = a.gap_to(&b).unwrap();
        assert!((y - x) > 3_000_000 && (y - x) < 3_300_000, "gap {x}..{y}");
        let second = super::super::read_file(&written[1]).unwrap();
        assert_eq!(second.meta.continues.as_deref(), Some("dive.snrec"));
        // The dead host recorded no log either: about 3 s of the 10 s of logs are in neither.
        let first = super::super::read_file(&written[0]).unwrap();
        let logs = first.stream_bytes(Stream::Defmt).len() + second.stream_bytes(Stream::Defmt).len();
        let all = bytes.len().div_ceil(37) * 3;
        assert!(logs < all * 8 / 10 && logs > all * 6 / 10, "{logs} of {all} log bytes recorded");
    }
}
