//! Run the firmware ELF in QEMU (`mps2-an386`) and stream its telemetry and logs to the host.
//!
//! - UART0 (telemetry + commands) is connected to a TCP socket this process listens on.
//! - The sensor-bus bridge (`subnav_wire::bridge`) runs over two named pipes the firmware opens
//!   through semihosting (synchronous: no virtual time passes while the host answers). Each
//!   I2C/SPI transaction is answered by a [`BusHandler`] (the chip models); with
//!   [`NothingAttached`], every transaction gets a NACK, as on a bus with nothing attached.
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
use subnav_wire::bridge::{BusFault, BusRequest, BusResponse, MAX_REQUEST_FRAME, MAX_RESPONSE_FRAME};
use subnav_wire::{self as wire, Decoded, Downlink, FrameDecoder, MAX_DOWNLINK_FRAME};

/// Answers the firmware's bus transactions (the simulated chips behind the QEMU board's buses).
pub trait BusHandler: Send {
    fn handle(&mut self, req: &BusRequest) -> BusResponse;
}

/// No device on any bus.
pub struct NothingAttached;

impl BusHandler for NothingAttached {
    fn handle(&mut self, req: &BusRequest) -> BusResponse {
        BusResponse { seq: req.seq, result: Err(BusFault::Nack) }
    }
}

/// Serve bridge requests from the request pipe until it closes. Returns the handler and the
/// number of transactions served (and corrupt request frames seen).
fn serve_bridge(req: PathBuf, resp: PathBuf, mut handler: Box<dyn BusHandler>) -> (Box<dyn BusHandler>, u64, u64) {
    let (mut served, mut corrupt) = (0u64, 0u64);
    // Same order as the firmware: request pipe first, then the response pipe.
    let Ok(mut rx) = std::fs::File::open(&req) else { return (handler, served, corrupt) };
    let Ok(mut tx) = std::fs::OpenOptions::new().write(true).open(&resp) else { return (handler, served, corrupt) };
    let mut dec = FrameDecoder::<MAX_REQUEST_FRAME>::new();
    let mut buf = [0u8; 4096];
    let mut out = [0u8; MAX_RESPONSE_FRAME];
    loop {
        let n = match rx.read(&mut buf) {
            Ok(0) | Err(_) => return (handler, served, corrupt),
            Ok(n) => n,
        };
        for &b in &buf[..n] {
            match dec.push::<BusRequest>(b) {
                Decoded::Pending => {}
                Decoded::Corrupt(_) => corrupt += 1,
                Decoded::Message(req) => {
                    let resp = handler.handle(&req);
                    served += 1;
                    let Ok(frame) = wire::encode(&resp, &mut out) else { continue };
                    if tx.write_all(frame).is_err() {
                        return (handler, served, corrupt);
                    }
                }
            }
        }
    }
}

/// Release a bridge thread still blocked opening the pipes (the firmware never opened them).
fn unblock_pipes(req: &std::path::Path, resp: &std::path::Path) {
    use std::os::unix::fs::OpenOptionsExt;
    const O_NONBLOCK: i32 = 0o4000; // Linux
    let _ = std::fs::OpenOptions::new().write(true).custom_flags(O_NONBLOCK).open(req);
    let _ = std::fs::OpenOptions::new().read(true).custom_flags(O_NONBLOCK).open(resp);
}

/// Waits for the emulator to connect its `what` until `deadline` (the run's wall-clock limit,
/// `--timeout-s`: connecting is part of it); `timeout` is that limit, for the message.
fn accept_from(listener: &TcpListener, child: &mut Child, what: &str, deadline: Instant, timeout: Duration) -> Result<TcpStream> {
    loop {
        match listener.accept() {
            Ok((s, _)) => {
                s.set_nonblocking(false)?;
                s.set_nodelay(true)?;
                return Ok(s);
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                if let Some(status) = child.try_wait()? {
                    let mut err = String::new();
                    if let Some(mut e) = child.stderr.take() {
                        let _ = e.read_to_string(&mut err);
                    }
                    bail!("QEMU exited before connecting its {what} ({status}): {}", err.trim());
                }
                if Instant::now() >= deadline {
                    bail!("QEMU did not connect its {what} within the run's time limit of {} s (--timeout-s)", timeout.as_secs_f64());
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(e) => return Err(e).with_context(|| format!("accepting the emulator's {what} connection")),
        }
    }
}

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
    /// Also send every byte chunk, as received or sent and before decoding, here (lossless
    /// recordings: `subnav qemu --record`).
    pub raw_tap: Option<mpsc::Sender<RawBytes>>,
    /// Extra board options (`key=value`, no commas), e.g. `utc_unix_us=...`, `lat_e7=...`.
    pub board_args: Vec<String>,
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
            raw_tap: None,
            board_args: Vec::new(),
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
    /// Bus transactions answered through the bridge, and corrupt request frames.
    pub bus_transactions: u64,
    pub bus_corrupt_requests: u64,
    /// Whatever QEMU printed on stderr.
    pub stderr: String,
}

impl QemuOutcome {
    pub fn success(&self) -> bool {
        self.exit_code == Some(0) && !self.timed_out
    }
}

/// A chunk of bytes that crossed the emulator's boundary (see [`QemuConfig::raw_tap`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RawBytes {
    Telemetry(Vec<u8>),
    Defmt(Vec<u8>),
    Downlink(Vec<u8>),
}

/// Lets the event callback send commands to the firmware.
pub struct Downlinker {
    tap: Option<mpsc::Sender<RawBytes>>,
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
        if let Some(t) = &self.tap {
            let _ = t.send(RawBytes::Downlink(frame.to_vec()));
        }
        Ok(seq)
    }

    /// Send raw bytes (tests use this to inject corrupt frames).
    pub fn send_raw(&mut self, bytes: &[u8]) -> Result<()> {
        if let Some(t) = &self.tap {
            let _ = t.send(RawBytes::Downlink(bytes.to_vec()));
        }
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
pub fn run(cfg: &QemuConfig, on_event: impl FnMut(QemuEvent, &mut Downlinker)) -> Result<QemuOutcome> {
    run_with_bus(cfg, Box::new(NothingAttached), on_event).map(|(o, _)| o)
}

/// [`run`] with the firmware's sensor buses answered by `bus`; returns the handler afterwards
/// (e.g. to read the simulator's truth log out of it).
pub fn run_with_bus(
    cfg: &QemuConfig,
    bus: Box<dyn BusHandler>,
    mut on_event: impl FnMut(QemuEvent, &mut Downlinker),
) -> Result<(QemuOutcome, Box<dyn BusHandler>)> {
    let table = DefmtTable::from_elf_path(&cfg.elf)?;
    // The wall-clock limit covers connecting too.
    let deadline = Instant::now().checked_add(cfg.timeout).with_context(|| format!("a time limit of {:?} is too long", cfg.timeout))?;
    let listener = TcpListener::bind("127.0.0.1:0").context("binding a local port for the emulated UART")?;
    let port = listener.local_addr()?.port();
    let mut args = vec!["arg=subnav".to_string()];
    if let Some(ms) = cfg.run_ms {
        args.push(format!("arg=run_ms={ms}"));
    }
    if let Some(ms) = cfg.panic_at_ms {
        args.push(format!("arg=panic_at_ms={ms}"));
    }
    for a in &cfg.board_args {
        if a.contains(',') || a.contains(' ') {
            bail!("board option {a:?} must not contain commas or spaces");
        }
        args.push(format!("arg={a}"));
    }
    let pipe_dir = std::env::temp_dir().join(format!("subnav-bridge-{}-{port}", std::process::id()));
    std::fs::create_dir_all(&pipe_dir).with_context(|| format!("creating {}", pipe_dir.display()))?;
    let (req_pipe, resp_pipe) = (pipe_dir.join("req"), pipe_dir.join("resp"));
    for p in [&req_pipe, &resp_pipe] {
        let st = Command::new("mkfifo").arg(p).status().context("running mkfifo")?;
        if !st.success() {
            bail!("mkfifo {} failed", p.display());
        }
    }
    args.push(format!("arg=bus_req={}", req_pipe.display()));
    args.push(format!("arg=bus_resp={}", resp_pipe.display()));

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
    let child = cmd.spawn().with_context(|| format!("starting {} (install it: apt-get install qemu-system-arm)", cfg.qemu.display()))?;
    let mut child = KillOnDrop(child);

    // QEMU connects to us as soon as it has parsed its options.
    listener.set_nonblocking(true)?;
    let (rq, rs) = (req_pipe.clone(), resp_pipe.clone());
    let bridge = std::thread::spawn(move || serve_bridge(rq, rs, bus));
    let stream = accept_from(&listener, &mut child.0, "UART", deadline, cfg.timeout)?;
    let mut downlink = Downlinker { tap: cfg.raw_tap.clone(), stream: stream.try_clone()?, next_seq: 1 };

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
    let rx: Receiver<Chunk> = rx;
    while tel_open || log_open {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            timed_out = true;
            break;
        }
        match rx.recv_timeout(left) {
            Ok(Chunk::Telemetry(bytes)) => {
                if let Some(t) = &cfg.raw_tap {
                    let _ = t.send(RawBytes::Telemetry(bytes.clone()));
                }
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
                if let Some(t) = &cfg.raw_tap {
                    let _ = t.send(RawBytes::Defmt(bytes.clone()));
                }
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
    drop(child);
    if !bridge.is_finished() {
        unblock_pipes(&req_pipe, &resp_pipe);
    }
    let stderr = stderr_handle.and_then(|h| h.join().ok()).unwrap_or_default();
    let (handler, bus_transactions, bus_corrupt_requests) =
        bridge.join().map_err(|_| anyhow::anyhow!("the sensor-bus bridge thread panicked"))?;
    let _ = std::fs::remove_dir_all(&pipe_dir);
    let outcome = QemuOutcome {
        exit_code,
        timed_out,
        link: uplink.stats(),
        log_lines,
        log_malformed: logs.malformed,
        bus_transactions,
        bus_corrupt_requests,
        stderr,
    };
    Ok((outcome, handler))
}

#[cfg(test)]
mod connect_tests {
    use super::*;

    /// `qemu --timeout-s 1` waited a fixed 20 s for an emulator that never connects.
    #[test]
    fn the_time_limit_covers_connecting() {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        listener.set_nonblocking(true).unwrap();
        let child = Command::new("sleep").arg("30").spawn().unwrap();
        let mut child = KillOnDrop(child);
        let t0 = Instant::now();
        let limit = Duration::from_millis(300);
        let e = accept_from(&listener, &mut child.0, "UART", t0 + limit, limit).unwrap_err().to_string();
        let took = t0.elapsed();
        assert!(took >= limit && took < Duration::from_secs(5), "took {took:?}");
        assert!(e.contains("UART") && e.contains("--timeout-s") && e.contains("0.3 s"), "{e}");
    }
}
