//! Where telemetry bytes come from: a recorded file, a TCP socket (e.g. QEMU's
//! `-serial tcp::PORT,server=on`), or a serial port.

use std::io::Read;
use std::net::TcpStream;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result};

#[derive(Debug, Clone)]
pub enum Source {
    File(PathBuf),
    Tcp(String),
    Serial { path: String, baud: u32 },
}

impl std::fmt::Display for Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Source::File(p) => write!(f, "file {}", p.display()),
            Source::Tcp(a) => write!(f, "tcp {a}"),
            Source::Serial { path, baud } => write!(f, "serial {path} at {baud} baud"),
        }
    }
}

impl Source {
    /// Open the source for reading. Serial ports read with a timeout so that a quiet line does
    /// not look like an end of stream (`read` returning `TimedOut` is retried by the caller).
    pub fn open(&self) -> Result<Box<dyn Read + Send>> {
        Ok(match self {
            Source::File(p) => Box::new(std::fs::File::open(p).with_context(|| format!("opening {}", p.display()))?),
            Source::Tcp(addr) => {
                Box::new(TcpStream::connect(addr).with_context(|| format!("connecting to {addr} (is the emulator or bridge listening?)"))?)
            }
            Source::Serial { path, baud } => Box::new(
                serialport::new(path, *baud)
                    .timeout(Duration::from_millis(200))
                    .open()
                    .with_context(|| format!("opening serial port {path} (check the path and permissions, e.g. the dialout group)"))?,
            ),
        })
    }
}

/// Read everything from `reader`, calling `on_bytes` per chunk, until end of stream (or until
/// `on_bytes` returns false). Timeouts are retried; other errors end the stream with an error.
pub fn pump(reader: &mut dyn Read, mut on_bytes: impl FnMut(&[u8]) -> bool) -> Result<()> {
    let mut buf = [0u8; 4096];
    loop {
        match reader.read(&mut buf) {
            Ok(0) => return Ok(()),
            Ok(n) => {
                if !on_bytes(&buf[..n]) {
                    return Ok(());
                }
            }
            Err(e)
                if matches!(e.kind(), std::io::ErrorKind::TimedOut | std::io::ErrorKind::Interrupted | std::io::ErrorKind::WouldBlock) => {}
            Err(e) => return Err(e).context("reading telemetry"),
        }
    }
}
