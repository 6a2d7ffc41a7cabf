//! Recording a QEMU run: a thread that writes the runner's raw byte chunks
//! ([`QemuConfig::raw_tap`](crate::qemu::QemuConfig::raw_tap)) into a recording as they come.

use std::path::Path;
use std::sync::mpsc;
use std::thread::JoinHandle;

use anyhow::{Result, anyhow};

use super::{Meta, Stream, Writer};
use crate::qemu::{QemuConfig, RawBytes};

/// A recording in progress; call [`QemuRecorder::finish`] after the run (and after dropping
/// every clone of the config's tap) to flush it and get its chunk counts.
pub struct QemuRecorder {
    handle: JoinHandle<Result<[u64; 4]>>,
}

impl QemuRecorder {
    /// Create the recording at `path` and point `cfg.raw_tap` at it. The file is written under a
    /// temporary name until the first bytes arrive: a run that fails before (QEMU missing, a bad
    /// ELF) leaves an old recording at `path` untouched.
    pub fn start(cfg: &mut QemuConfig, path: &Path) -> Result<Self> {
        let mut meta = Meta::new(format!("qemu {}", cfg.elf.display()));
        meta.elf = Some(cfg.elf.display().to_string());
        meta.board_args = cfg.board_args.clone();
        let mut w = Writer::create_atomic(path, &meta)?;
        let (tx, rx) = mpsc::channel::<RawBytes>();
        cfg.raw_tap = Some(tx);
        let handle = std::thread::spawn(move || -> Result<[u64; 4]> {
            for raw in rx {
                match raw {
                    RawBytes::Telemetry(b) => w.chunk_now(Stream::Uplink, &b)?,
                    RawBytes::Defmt(b) => w.chunk_now(Stream::Defmt, &b)?,
                    RawBytes::Downlink(b) => w.chunk_now(Stream::Downlink, &b)?,
                }
                if w.chunks.iter().any(|&n| n > 0) {
                    w.publish()?;
                }
            }
            let chunks = w.chunks;
            if chunks.iter().any(|&n| n > 0) {
                w.into_inner().commit()?;
            }
            Ok(chunks)
        });
        Ok(Self { handle })
    }

    /// Wait for the writer (the run must be over and `cfg.raw_tap` dropped or taken).
    pub fn finish(self) -> Result<[u64; 4]> {
        self.handle.join().map_err(|_| anyhow!("the recording thread panicked"))?
    }
}
