//! Where telemetry bytes come from: a recorded file, a TCP socket (e.g. QEMU's
//! `-serial tcp::PORT,server=on`), or a serial port.

use std::io::Read;
use std::net::{TcpStream, ToSocketAddrs};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

/// How long a live source's `read` waits before returning `TimedOut` (then [`pump`] lets its
/// caller check its own limits: `--duration-s`, `--idle-timeout-s`).
pub const READ_TIMEOUT: Duration = Duration::from_millis(200);
/// How long connecting to a TCP source may take.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

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
    /// Open the source for reading. Serial ports and TCP sockets read with a timeout
    /// ([`READ_TIMEOUT`]) so that a quiet line neither looks like an end of stream nor blocks
    /// forever (`read` returning `TimedOut` is retried by [`pump`]).
    pub fn open(&self) -> Result<Box<dyn Read + Send>> {
        Ok(match self {
            Source::File(p) => Box::new(std::fs::File::open(p).with_context(|| format!("opening {}", p.display()))?),
            Source::Tcp(addr) => {
                let sock = addr
                    .to_socket_addrs()
                    .with_context(|| format!("{addr} is not a TCP address (expected HOST:PORT)"))?
                    .next()
                    .with_context(|| format!("{addr} resolves to no address"))?;
                let s = TcpStream::connect_timeout(&sock, CONNECT_TIMEOUT)
                    .with_context(|| format!("connecting to {addr} (is the emulator or bridge listening?)"))?;
                s.set_read_timeout(Some(READ_TIMEOUT)).context("setting the socket's read timeout")?;
                Box::new(s)
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
/// `on_bytes` returns false). A read timeout calls `on_bytes(&[])` (so the caller can stop at
/// its deadline while the source is quiet) and is retried; with `idle_limit`, a source quiet
/// for that long ends with an error saying so. Other errors end the stream with an error.
pub fn pump(reader: &mut dyn Read, idle_limit: Option<Duration>, mut on_bytes: impl FnMut(&[u8]) -> bool) -> Result<()> {
    let mut buf = [0u8; 4096];
    let mut last_data = Instant::now();
    loop {
        match reader.read(&mut buf) {
            Ok(0) => return Ok(()),
            Ok(n) => {
                last_data = Instant::now();
                if !on_bytes(&buf[..n]) {
                    return Ok(());
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) if matches!(e.kind(), std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock) => {
                if !on_bytes(&[]) {
                    return Ok(());
                }
                if let Some(limit) = idle_limit {
                    if last_data.elapsed() >= limit {
                        bail!("no data from the source for {:.1} s (the idle timeout); is the sensor head running?", limit.as_secs_f64());
                    }
                }
            }
            Err(e) => return Err(e).context("reading telemetry"),
        }
    }
}
