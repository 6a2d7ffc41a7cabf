//! Run the firmware ELF in QEMU (`mps2-an386`) and stream its telemetry and logs to the host.
//!
//! - UART0 (telemetry + commands) is connected to a TCP socket this process listens on.
//! - Semihosting carries the defmt log stream (QEMU's stdout) and the exit status.
//! - `-icount shift=N,align=off,sleep=off` makes virtual time follow executed instructions:
//!   the same ELF and options give the same telemetry on any machine at any host speed.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use subnav_shared::wire::{self, Downlink, MAX_DOWNLINK_FRAME};

use super::defmt_log::{DefmtTable, LogLine};
use super::uplink::{LinkEvent, LinkStats, UplinkDecoder};

/// How to run the emulator.
#[derive(Debug, Clone)]
pub struct QemuConfig {
    pub elf: PathBuf,
    /// The `qemu-system-arm` executable.
    pub qemu: PathBuf,
    /// Firmware time after which the QEMU board exits successfully.
    pub run_ms: Option<u64>,
    /// Self-test: make the firmware panic at this firmware time.
    pub panic_at_ms: Option<u64>,
    /// QEMU `-icount shift`: each instruction takes 2^shift ns of virtual time.
    pub icount_shift: u8,
    /// Wall-clock limit; the emulator is killed after it.
    pub timeout: Duration,
    /// Also write the raw uplink bytes to this file (a recording `subnav decode --file` reads).
    pub record: Option<PathBuf>,
}

impl QemuConfig {
    pub fn new(elf: impl Into<PathBuf>) -> Self {
        Self {
            elf: elf.into(),
            qemu: PathBuf::from("qemu-system-arm"),
            run_ms: Some(5_000),
            panic_at_ms: None,
            icount_shift: 3,
            timeout: Duration::from_secs(120),
            record: None,
        }
    }
}

/// Something that came out of the emulator.
#[derive(Debug, Clone, PartialEq)]
pub enum QemuEvent {
    Link(LinkEvent),
    Log(LogLine),
}

/// How the run ended.
#[derive(Debug, Clone)]
pub struct QemuOutcome {
    /// QEMU's exit code (the firmware's semihosting exit status), None if killed.
    pub exit_code: Option<i32>,
    pub timed_out: bool,
    pub link: LinkStats,
    pub log_lines: u64,
    pub log_malformed: u64,
    /// Whatever QEMU printed on stderr.
    pub stderr: String,
}

impl QemuOutcome {
    pub fn success(&self) -> bool {
        self.exit_code == Some(0) && !self.timed_out
    }
}

/// Lets the event callback send commands to the firmware.
pub struct Downlinker {
    stream: TcpStream,
    next_seq: u16,
}

impl Downlinker {
    /// Send a command; returns its sequence number (echoed in the firmware's ack).
    pub fn send(&mut self, command: wire::Command) -> Result<u16> {
        let seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1);
        let mut buf = [0u8; MAX_DOWNLINK_FRAME];
        let frame = wire::encode(&Downlink { seq, command }, &mut buf).map_err(|e| anyhow::anyhow!("encoding command: {e}"))?;
        self.stream.write_all(frame).context("sending a command to the emulator")?;
        Ok(seq)
    }

    /// Send raw bytes (tests use this to inject corrupt frames).
    pub fn send_raw(&mut self, bytes: &[u8]) -> Result<()> {
        self.stream.write_all(bytes).context("sending bytes to the emulator")
    }
}

enum Chunk {
    Telemetry(Vec<u8>),
    Defmt(Vec<u8>),
    TelemetryEnd,
    DefmtEnd,
}

fn spawn_reader(mut r: impl Read + Send + 'static, tx: mpsc::Sender<Chunk>, wrap: fn(Vec<u8>) -> Chunk, end: Chunk) {
    std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        loop {
            match r.read(&mut buf) {
                Ok(0) | Err(_) => break,
                Ok(n) => {
                    if tx.send(wrap(buf[..n].to_vec())).is_err() {
                        return;
                    }
                }
            }
        }
        let _ = tx.send(end);
    });
}

struct KillOnDrop(Child);
impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Boot the ELF in QEMU and call `on_event` for every message and log line, live, until the
/// firmware exits (or the timeout). `on_event` may send commands through the [`Downlinker`].
pub fn run(cfg: &QemuConfig, mut on_event: impl FnMut(QemuEvent, &mut Downlinker)) -> Result<QemuOutcome> {
    let table = DefmtTable::from_elf_path(&cfg.elf)?;
    let listener = TcpListener::bind("127.0.0.1:0").context("binding a local port for the emulated UART")?;
    let port = listener.local_addr()?.port();

    let mut args = vec!["arg=subnav".to_string()];
    if let Some(ms) = cfg.run_ms {
        args.push(format!("arg=run_ms={ms}"));
    }
    if let Some(ms) = cfg.panic_at_ms {
        args.push(format!("arg=panic_at_ms={ms}"));
    }
    let mut cmd = Command::new(&cfg.qemu);
    cmd.args(["-machine", "mps2-an386", "-cpu", "cortex-m4", "-display", "none", "-monitor", "none"])
        .arg("-serial")
        .arg(format!("tcp:127.0.0.1:{port}"))
        .arg("-semihosting-config")
        .arg(format!("enable=on,target=native,{}", args.join(",")))
        .arg("-icount")
        .arg(format!("shift={},align=off,sleep=off", cfg.icount_shift))
        .arg("-kernel")
        .arg(&cfg.elf)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let child = cmd.spawn().with_context(|| {
        format!("starting {} (install it: apt-get install qemu-system-arm)", cfg.qemu.display())
    })?;
    let mut child = KillOnDrop(child);

    // QEMU connects to us as soon as it has parsed its options.
    listener.set_nonblocking(true)?;
    let started = Instant::now();
    let stream = loop {
        match listener.accept() {
            Ok((s, _)) => break s,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                if let Some(status) = child.0.try_wait()? {
                    let mut err = String::new();
                    if let Some(mut e) = child.0.stderr.take() {
                        let _ = e.read_to_string(&mut err);
                    }
                    bail!("QEMU exited before connecting its UART ({status}): {}", err.trim());
                }
                if started.elapsed() > Duration::from_secs(20) {
                    bail!("QEMU did not connect its UART within 20 s");
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(e) => return Err(e).context("accepting the emulator's UART connection"),
        }
    };
    stream.set_nonblocking(false)?;
    stream.set_nodelay(true)?;
    let mut downlink = Downlinker { stream: stream.try_clone()?, next_seq: 1 };

    let (tx, rx) = mpsc::channel();
    spawn_reader(stream, tx.clone(), Chunk::Telemetry, Chunk::TelemetryEnd);
    let stdout = child.0.stdout.take().context("QEMU stdout")?;
    spawn_reader(stdout, tx, Chunk::Defmt, Chunk::DefmtEnd);
    let stderr_handle = child.0.stderr.take().map(|mut e| {
        std::thread::spawn(move || {
            let mut s = String::new();
            let _ = e.read_to_string(&mut s);
            s
        })
    });

    let mut record = match &cfg.record {
        Some(p) => Some(std::fs::File::create(p).with_context(|| format!("creating {}", p.display()))?),
        None => None,
    };
    let mut uplink = UplinkDecoder::new();
    let mut logs = table.stream();
    let mut log_lines = 0u64;
    let (mut tel_open, mut log_open) = (true, true);
    let mut timed_out = false;
    let deadline = Instant::now() + cfg.timeout;
    let rx: Receiver<Chunk> = rx;
    while tel_open || log_open {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            timed_out = true;
            break;
        }
        match rx.recv_timeout(left) {
            Ok(Chunk::Telemetry(bytes)) => {
                if let Some(f) = record.as_mut() {
                    f.write_all(&bytes).context("writing the recording")?;
                }
                let mut events = vec![];
                uplink.feed(&bytes, |e| events.push(e));
                for e in events {
                    on_event(QemuEvent::Link(e), &mut downlink);
                }
            }
            Ok(Chunk::Defmt(bytes)) => {
                let mut lines = vec![];
                logs.feed(&bytes, |l| lines.push(l));
                for l in lines {
                    log_lines += 1;
                    on_event(QemuEvent::Log(l), &mut downlink);
                }
            }
            Ok(Chunk::TelemetryEnd) => tel_open = false,
            Ok(Chunk::DefmtEnd) => log_open = false,
            Err(RecvTimeoutError::Timeout) => {
                timed_out = true;
                break;
            }
            Err(RecvTimeoutError::Disconnected) => break,
        }
    }
    let exit_code = if timed_out {
        let _ = child.0.kill();
        let _ = child.0.wait();
        None
    } else {
        child.0.wait()?.code()
    };
    let stderr = stderr_handle.and_then(|h| h.join().ok()).unwrap_or_default();
    Ok(QemuOutcome { exit_code, timed_out, link: uplink.stats(), log_lines, log_malformed: logs.malformed, stderr })
}
