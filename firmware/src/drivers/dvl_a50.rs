//! Water Linked DVL-A50 (and A125) Doppler velocity log on a UART, speaking Water Linked's own
//! serial protocol.
//!
//! Document: Water Linked, "DVL A50/A125 serial protocol", serial protocol versions 2.6.x and
//! 2.7.x, <https://docs.waterlinked.com/dvl/dvl-serial-protocol/> (source
//! `docs/dvl/dvl-serial-protocol.md` of github.com/waterlinked/docs). Implemented here:
//! - "Serial protocol / Overview": 115200 8-N-1 by default; a packet is `w`, direction (`r` from
//!   the DVL, `c` to it), command letter, `,option` fields, `*xx` checksum, and a line ending of
//!   LF, CR+LF or CR. Lines are assembled from bytes into a bounded buffer ([`MAX_LINE`]);
//!   longer lines are dropped and counted ([`DvlCounters::overlong`]).
//! - "Checksum": CRC-8, polynomial 0x07, init 0x00, no reflection, xor-out 0x00 (check value
//!   0xf4 over `123456789`), over every byte before the `*`, sent as two lower-case hex digits.
//!   The DVL always sends a checksum, so a response without one is malformed. [`crc8`] is tested
//!   on the document's check value and on its example sentences.
//! - "Velocity report (wrz)": `wrz,vx,vy,vz,valid,altitude,fom,covariance,time_of_validity,
//!   time_of_transmission,time,status` -> [`VelocityReport`] with [`Tracking::Bottom`].
//! - "Velocity report (wrs)" (water tracking, protocol 2.7.0; same fields without altitude) ->
//!   [`VelocityReport`] with [`Tracking::Water`]. The document's printed `wrs` example carries
//!   the checksum of its `wrz` example (`*50`; the CRC-8 of that line is 0x7b); the test
//!   `document_wrs_example_has_a_wrong_checksum` pins this.
//! - "Command overview": the replies `wra` (ack), `wrn` (nak), `wr?` (malformed request) and
//!   `wr!` (checksum mismatch) -> [`Sentence::Reply`]; other sentences (`wru`, `wrp`, `wrv`,
//!   `wrw`, `wrc`, the deprecated `wrx` / `wrt`) are checked and reported as
//!   [`Sentence::Other`] without parsing their fields. Commands are sent with a checksum by
//!   [`DvlA50::send_command`] (the DVL accepts them with or without).
//!
//! Axes and units as the DVL reports them: velocity in the DVL's body frame (or its vehicle
//! frame when a mounting rotation offset is configured in the DVL), m/s; altitude m; figure of
//! merit m/s; covariance (m/s)^2, row-major; times are the DVL's Unix microseconds. The
//! mounting rotation and lever arm to the sensor head's body frame are applied by the
//! navigation filter (`subnav_core::nav::dvl`), not here.
//!
//! Counting (never fused): malformed lines, bad checksums, overlong lines and reports the DVL
//! flags invalid (`valid = n`, no bottom lock) are counted separately in [`DvlCounters`]. A
//! malformed line or a bad checksum is returned as [`Error::Malformed`] / [`Error::BadCrc`];
//! an invalid report is returned (its altitude and status are useful) but
//! [`VelocityReport::bottom_velocity`] gives nothing to fuse from it.
//!
//! Tolerance: fields after the documented ones are ignored (the protocol's minor versions add
//! backwards-compatible functionality); a non-finite number (`nan`, `inf`) in any field, a
//! time of transmission before the time of validity, or a latency above [`MAX_LATENCY_US`] is
//! malformed.
//!
//! Time: [`Received::t_valid_us`] maps the DVL's time of validity to the caller's clock:
//! `t_rx - (bytes on the wire / baud) - (time_of_transmission - time_of_validity)`, with `t_rx`
//! the `now_us` of the [`DvlA50::poll`] call that completed the line (poll at least every
//! millisecond or so to keep this close).
//!
//! ```ignore
//! let mut dvl = DvlA50::new(uart, DEFAULT_BAUD);
//! match dvl.poll(now_us) {
//!     Ok(Some(rx)) => if let (Sentence::Velocity(v), Some(t)) = (rx.sentence, rx.t_valid_us) {
//!         if let Some(m) = v.bottom_velocity() { /* fuse m at t */ }
//!     },
//!     Ok(None) => {}                                  // no complete line yet
//!     Err(e) => faults.record(now_us, e.fault_kind()), // bus, malformed, bad checksum
//! }
//! ```

use embedded_io::{Read, ReadReady, Write};

use super::Error;

/// Default baud rate (8-N-1, no flow control).
pub const DEFAULT_BAUD: u32 = 115_200;
/// Longest accepted line, bytes without the line ending. A `wrz` with a full covariance in the
/// DVL's number format is about 120 bytes; lines above this are dropped and counted.
pub const MAX_LINE: usize = 200;
/// Largest accepted `time_of_transmission - time_of_validity`, µs (the acoustic round trip at
/// the A50's maximum range plus processing is well under this).
pub const MAX_LATENCY_US: u64 = 2_000_000;
/// Bytes processed per [`DvlA50::poll`] at most, so a UART that never stops delivering bytes
/// cannot hold the caller.
pub const MAX_BYTES_PER_POLL: usize = 2 * MAX_LINE;
/// Bits per byte on the wire at 8-N-1 (start + 8 data + stop).
pub const BITS_PER_BYTE: u64 = 10;

const RX_CHUNK: usize = 32;

/// Commands (bodies without checksum; [`DvlA50::send_command`] adds `*xx` and LF).
pub mod cmd {
    /// Get protocol version (`wrv,major.minor.patch`).
    pub const VERSION: &[u8] = b"wcv";
    /// Get product detail (`wrw,...`).
    pub const PRODUCT: &[u8] = b"wcw";
    /// Trigger one ping (when `acoustic_enabled = n`).
    pub const TRIGGER_PING: &[u8] = b"wcx";
    /// Serial output protocol 3: Water Linked serial V2 (`wrz`, `wru`, `wrp`, no deprecated sentences).
    pub const PROTOCOL_WL_V2: &[u8] = b"wcp,3";
    /// Enable acoustics (normal pinging), leave the other parameters.
    pub const ACOUSTICS_ON: &[u8] = b"wcs,,,y,,,";
    /// Bottom tracking with automatic range (`range_mode = auto`).
    pub const RANGE_AUTO: &[u8] = b"wcs,,,,,auto,";
    /// Water tracking (`range_mode = wt`, protocol >= 2.7.0): reports become `wrs`.
    pub const WATER_TRACK: &[u8] = b"wcs,,,,,wt,";
}

/// CRC-8 of the protocol: polynomial 0x07, init 0x00, MSB first, no final xor.
pub const fn crc8(data: &[u8]) -> u8 {
    let mut crc = 0u8;
    let mut rest = data;
    while let [byte, tail @ ..] = rest {
        crc ^= *byte;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x80 != 0 { (crc << 1) ^ 0x07 } else { crc << 1 };
            bit += 1;
        }
        rest = tail;
    }
    crc
}

/// What the velocity is relative to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Tracking {
    /// `wrz`: relative to the bottom (or another reflecting surface), with altitude.
    Bottom,
    /// `wrs`: relative to the water column 1.5..4.5 m below the DVL; no altitude.
    Water,
}

/// A velocity report (`wrz` or `wrs`), in the DVL's frame and units.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VelocityReport {
    pub tracking: Tracking,
    /// vx, vy, vz in the DVL frame, m/s.
    pub vel_dvl_mps: [f32; 3],
    /// `valid = y`: lock on the reflecting surface; velocities (and altitude) are valid.
    pub valid: bool,
    /// Altitude over the bottom, m (`wrz` only; the DVL sends a negative value without lock).
    pub altitude_m: Option<f32>,
    /// Figure of merit (accuracy of the velocities), m/s.
    pub fom_mps: f32,
    /// Velocity covariance, row-major, (m/s)^2 (`None` when the field is empty).
    pub covariance_m2ps2: Option<[f32; 9]>,
    /// Centre of ping, DVL Unix time, µs.
    pub time_of_validity_us: u64,
    /// Just before the report was sent, DVL Unix time, µs.
    pub time_of_transmission_us: u64,
    /// Time since the previous velocity report, ms.
    pub time_since_last_ms: f32,
    /// Status mask: bit 0 = high temperature (thermal shutdown soon).
    pub status: u8,
}

/// Status bit 0: high temperature, the DVL will soon shut down.
pub const STATUS_HIGH_TEMPERATURE: u8 = 0x01;

/// A bottom-referenced velocity fit for the navigation filter (only from valid `wrz`).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BottomVelocity {
    pub vel_dvl_mps: [f32; 3],
    pub fom_mps: f32,
    pub covariance_m2ps2: Option<[f32; 9]>,
    pub altitude_m: f32,
}

impl VelocityReport {
    /// The velocity to fuse: only a valid bottom-track report with a non-negative altitude
    /// (water-track velocity is relative to a moving water column; invalid reports carry
    /// placeholder values).
    pub fn bottom_velocity(&self) -> Option<BottomVelocity> {
        match (self.tracking, self.valid, self.altitude_m) {
            (Tracking::Bottom, true, Some(a)) if a >= 0.0 => Some(BottomVelocity {
                vel_dvl_mps: self.vel_dvl_mps,
                fom_mps: self.fom_mps,
                covariance_m2ps2: self.covariance_m2ps2,
                altitude_m: a,
            }),
            _ => None,
        }
    }

    /// `time_of_transmission - time_of_validity`, µs.
    pub fn latency_us(&self) -> u64 {
        self.time_of_transmission_us.saturating_sub(self.time_of_validity_us)
    }
}

/// Replies to a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Reply {
    /// `wra`
    Ack,
    /// `wrn`: the command was understood but failed.
    Nak,
    /// `wr?`: the DVL could not understand the command (or timed out between characters).
    MalformedRequest,
    /// `wr!`: the command's checksum did not match.
    ChecksumMismatch,
}

/// One checked sentence.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Sentence {
    Velocity(VelocityReport),
    Reply(Reply),
    /// A valid sentence this driver does not parse: direction and command letter (`b'r', b'u'`
    /// for `wru`).
    Other {
        direction: u8,
        command: u8,
    },
}

/// Why a line was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SentenceError {
    /// Not a sentence of the protocol (framing, missing checksum, field count or format).
    Malformed,
    /// The checksum did not match.
    BadChecksum { expected: u8, computed: u8 },
}

fn hex_digit(b: u8) -> Option<u8> {
    match b {
        b'0'..=b'9' => Some(b - b'0'),
        b'a'..=b'f' => Some(b - b'a' + 10),
        _ => None,
    }
}

fn field_str(f: &[u8]) -> Result<&str, SentenceError> {
    core::str::from_utf8(f).map_err(|_| SentenceError::Malformed)
}

/// Powers of ten exactly as f32 rounds them (`1e0 ..= 1e38`).
const POW10_F32: [f32; 39] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22, 1e23,
    1e24, 1e25, 1e26, 1e27, 1e28, 1e29, 1e30, 1e31, 1e32, 1e33, 1e34, 1e35, 1e36, 1e37, 1e38,
];

/// A decimal number as the DVL writes it: `[+-]digits[.digits][(e|E)[+-]digits]` (at least one
/// mantissa digit). Why not `str::parse::<f32>`: core's correctly rounded parser (Eisel-Lemire
/// with its 10 KB power-of-five table and the big-decimal fallback) is 15 KB of flash on the
/// M4F, an eighth of the firmware's budget. Here: the first 19 significant digits as an integer,
/// rounded once to f32, times or divided by a power of ten: within 2 ulp of the correctly
/// rounded value (tested against `str::parse`), far below the protocol's 1 mm/s resolution.
/// Anything else (`nan`, `inf`, hex, empty, overflow) is malformed.
pub fn parse_decimal_f32(f: &[u8]) -> Option<f32> {
    let (neg, rest) = match f.split_first() {
        Some((b'-', r)) => (true, r),
        Some((b'+', r)) => (false, r),
        _ => (false, f),
    };
    let mut mant: u64 = 0;
    let mut digits = 0u32; // significant digits kept in `mant`
    let mut exp10: i32 = 0;
    let mut seen_digit = false;
    let mut seen_point = false;
    let mut i = 0usize;
    while let Some(&c) = rest.get(i) {
        match c {
            b'0'..=b'9' => {
                seen_digit = true;
                if digits < 19 {
                    mant = mant * 10 + u64::from(c - b'0');
                    if mant != 0 {
                        digits += 1;
                    }
                    if seen_point {
                        exp10 -= 1;
                    }
                } else if !seen_point {
                    exp10 += 1; // a digit beyond the 19 kept ones, before the point
                }
            }
            b'.' if !seen_point => seen_point = true,
            _ => break,
        }
        i += 1;
    }
    if !seen_digit {
        return None;
    }
    if let Some(&c) = rest.get(i) {
        if c != b'e' && c != b'E' {
            return None;
        }
        let e = rest.get(i + 1..)?;
        let (eneg, edig) = match e.split_first() {
            Some((b'-', r)) => (true, r),
            Some((b'+', r)) => (false, r),
            _ => (false, e),
        };
        if edig.is_empty() || edig.len() > 4 || !edig.iter().all(u8::is_ascii_digit) {
            return None;
        }
        let ev = edig.iter().fold(0i32, |a, d| a * 10 + i32::from(d - b'0'));
        exp10 += if eneg { -ev } else { ev };
    }
    let m = mant as f32;
    let v = if mant == 0 {
        0.0
    } else if exp10 >= 0 {
        m * *POW10_F32.get(usize::try_from(exp10).ok()?)?
    } else {
        let k = usize::try_from(-exp10).ok()?;
        match POW10_F32.get(k) {
            Some(p) => m / p,
            // Below 1e-38: two steps (subnormal or zero results are fine here).
            None => (m / 1e38) / *POW10_F32.get(k.checked_sub(38)?)?,
        }
    };
    let v = if neg { -v } else { v };
    v.is_finite().then_some(v)
}

fn parse_f32(f: &[u8]) -> Result<f32, SentenceError> {
    parse_decimal_f32(f).ok_or(SentenceError::Malformed)
}

fn parse_u64(f: &[u8]) -> Result<u64, SentenceError> {
    // `u64::from_str` accepts a leading '+'; the protocol's integers are plain digits.
    if f.is_empty() || !f.iter().all(u8::is_ascii_digit) {
        return Err(SentenceError::Malformed);
    }
    field_str(f)?.parse().map_err(|_| SentenceError::Malformed)
}

fn parse_flag(f: &[u8]) -> Result<bool, SentenceError> {
    match f {
        b"y" => Ok(true),
        b"n" => Ok(false),
        _ => Err(SentenceError::Malformed),
    }
}

fn parse_covariance(f: &[u8]) -> Result<Option<[f32; 9]>, SentenceError> {
    if f.is_empty() {
        return Ok(None);
    }
    let mut c = [0.0f32; 9];
    let mut n = 0usize;
    for part in f.split(|b| *b == b';') {
        let slot = c.get_mut(n).ok_or(SentenceError::Malformed)?;
        *slot = parse_f32(part)?;
        n += 1;
    }
    if n == 9 { Ok(Some(c)) } else { Err(SentenceError::Malformed) }
}

/// Fields of a velocity report after `wrz,` / `wrs,`.
fn parse_velocity(tracking: Tracking, options: &[u8]) -> Result<VelocityReport, SentenceError> {
    let mut it = options.split(|b| *b == b',');
    let mut next = || it.next().ok_or(SentenceError::Malformed);
    let vx = parse_f32(next()?)?;
    let vy = parse_f32(next()?)?;
    let vz = parse_f32(next()?)?;
    let valid = parse_flag(next()?)?;
    let altitude_m = match tracking {
        Tracking::Bottom => Some(parse_f32(next()?)?),
        Tracking::Water => None,
    };
    let fom_mps = parse_f32(next()?)?;
    let covariance_m2ps2 = parse_covariance(next()?)?;
    let time_of_validity_us = parse_u64(next()?)?;
    let time_of_transmission_us = parse_u64(next()?)?;
    let time_since_last_ms = parse_f32(next()?)?;
    let status = u8::try_from(parse_u64(next()?)?).map_err(|_| SentenceError::Malformed)?;
    if fom_mps < 0.0
        || time_since_last_ms < 0.0
        || time_of_transmission_us < time_of_validity_us
        || time_of_transmission_us - time_of_validity_us > MAX_LATENCY_US
    {
        return Err(SentenceError::Malformed);
    }
    Ok(VelocityReport {
        tracking,
        vel_dvl_mps: [vx, vy, vz],
        valid,
        altitude_m,
        fom_mps,
        covariance_m2ps2,
        time_of_validity_us,
        time_of_transmission_us,
        time_since_last_ms,
        status,
    })
}

/// Check and parse one line (without its line ending).
pub fn parse_sentence(line: &[u8]) -> Result<Sentence, SentenceError> {
    if !line.iter().all(|b| (0x20..=0x7E).contains(b)) {
        return Err(SentenceError::Malformed);
    }
    let star = line.iter().rposition(|b| *b == b'*').ok_or(SentenceError::Malformed)?;
    let (body, tail) = line.split_at(star);
    let expected = match tail {
        [b'*', hi, lo] => match (hex_digit(*hi), hex_digit(*lo)) {
            (Some(h), Some(l)) => (h << 4) | l,
            _ => return Err(SentenceError::Malformed),
        },
        _ => return Err(SentenceError::Malformed),
    };
    let (direction, command, options) = match body {
        [b'w', d, c] => (*d, *c, None),
        [b'w', d, c, b',', rest @ ..] => (*d, *c, Some(rest)),
        _ => return Err(SentenceError::Malformed),
    };
    let computed = crc8(body);
    if computed != expected {
        return Err(SentenceError::BadChecksum { expected, computed });
    }
    if direction != b'r' {
        return if direction == b'c' { Ok(Sentence::Other { direction, command }) } else { Err(SentenceError::Malformed) };
    }
    let reply = |r| if options.is_none() { Ok(Sentence::Reply(r)) } else { Err(SentenceError::Malformed) };
    match command {
        b'z' => parse_velocity(Tracking::Bottom, options.ok_or(SentenceError::Malformed)?).map(Sentence::Velocity),
        b's' => parse_velocity(Tracking::Water, options.ok_or(SentenceError::Malformed)?).map(Sentence::Velocity),
        b'a' => reply(Reply::Ack),
        b'n' => reply(Reply::Nak),
        b'?' => reply(Reply::MalformedRequest),
        b'!' => reply(Reply::ChecksumMismatch),
        c if c.is_ascii_alphabetic() => Ok(Sentence::Other { direction, command: c }),
        _ => Err(SentenceError::Malformed),
    }
}

/// Result of feeding one byte to a [`LineAssembler`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineEvent {
    /// No complete line yet.
    Pending,
    /// A line is complete: read it with [`LineAssembler::line`], then [`LineAssembler::clear`].
    Complete,
    /// A line longer than the buffer ended; it was dropped.
    Overlong,
}

/// Assembles lines ended by LF, CR+LF or CR into a fixed buffer. Empty lines (the LF of a
/// CR+LF) are skipped.
#[derive(Debug, Clone)]
pub struct LineAssembler<const N: usize> {
    buf: [u8; N],
    len: usize,
    overlong: bool,
}

impl<const N: usize> Default for LineAssembler<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> LineAssembler<N> {
    pub const fn new() -> Self {
        Self { buf: [0; N], len: 0, overlong: false }
    }

    pub fn push(&mut self, b: u8) -> LineEvent {
        if b == b'\r' || b == b'\n' {
            if self.overlong {
                self.overlong = false;
                self.len = 0;
                return LineEvent::Overlong;
            }
            return if self.len == 0 { LineEvent::Pending } else { LineEvent::Complete };
        }
        if self.overlong {
            return LineEvent::Pending;
        }
        match self.buf.get_mut(self.len) {
            Some(slot) => {
                *slot = b;
                self.len += 1;
            }
            None => self.overlong = true,
        }
        LineEvent::Pending
    }

    /// The completed line (valid after [`LineEvent::Complete`]).
    pub fn line(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }

    pub fn clear(&mut self) {
        self.len = 0;
        self.overlong = false;
    }
}

/// Per-outcome counts since [`DvlA50::new`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DvlCounters {
    /// Velocity reports with `valid = y` (bottom or water track).
    pub valid_reports: u32,
    /// Velocity reports with `valid = n` (no lock): never fused.
    pub invalid_reports: u32,
    /// Replies (`wra`, `wrn`, `wr?`, `wr!`).
    pub replies: u32,
    /// Checked sentences not parsed here (`wru`, `wrp`, ...).
    pub other_sentences: u32,
    /// Lines that are not sentences of the protocol (bad framing, fields, numbers, times).
    pub malformed: u32,
    /// Lines whose checksum did not match.
    pub bad_checksum: u32,
    /// Lines longer than [`MAX_LINE`], dropped.
    pub overlong: u32,
    /// Bus (UART) errors.
    pub bus_errors: u32,
}

/// A sentence with its reception time.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Received {
    pub sentence: Sentence,
    /// `now_us` of the poll that completed the line.
    pub rx_us: u64,
    /// Line length in bytes (without the line ending).
    pub line_len: usize,
    /// For velocity reports: the time of validity in the caller's clock (see the module doc).
    pub t_valid_us: Option<u64>,
}

/// The DVL on a UART. The driver owns the UART (read and write halves as one
/// `embedded_io` port) and gives it back with [`DvlA50::destroy`].
pub struct DvlA50<U> {
    uart: U,
    baud: u32,
    line: LineAssembler<MAX_LINE>,
    rx: [u8; RX_CHUNK],
    rx_pos: usize,
    rx_len: usize,
    counters: DvlCounters,
}

impl<U: embedded_io::ErrorType> DvlA50<U> {
    /// `baud`: the configured rate (0 is taken as [`DEFAULT_BAUD`]); used for the time of
    /// validity only.
    pub fn new(uart: U, baud: u32) -> Self {
        Self {
            uart,
            baud: if baud == 0 { DEFAULT_BAUD } else { baud },
            line: LineAssembler::new(),
            rx: [0; RX_CHUNK],
            rx_pos: 0,
            rx_len: 0,
            counters: DvlCounters::default(),
        }
    }

    pub fn destroy(self) -> U {
        self.uart
    }

    pub fn counters(&self) -> &DvlCounters {
        &self.counters
    }

    /// Wire time of `bytes` bytes, µs.
    pub fn wire_time_us(&self, bytes: usize) -> u64 {
        (bytes as u64).saturating_mul(BITS_PER_BYTE).saturating_mul(1_000_000) / u64::from(self.baud)
    }

    /// Check and count one completed line.
    fn finish_line(&mut self, now_us: u64) -> Result<Received, Error<U::Error>> {
        let line_len = self.line.line().len();
        let parsed = parse_sentence(self.line.line());
        self.line.clear();
        let c = &mut self.counters;
        let sentence = match parsed {
            Ok(s) => s,
            Err(SentenceError::Malformed) => {
                c.malformed = c.malformed.saturating_add(1);
                return Err(Error::Malformed);
            }
            Err(SentenceError::BadChecksum { expected, computed }) => {
                c.bad_checksum = c.bad_checksum.saturating_add(1);
                return Err(Error::BadCrc { expected, computed });
            }
        };
        let mut t_valid_us = None;
        match &sentence {
            Sentence::Velocity(v) => {
                if v.valid {
                    c.valid_reports = c.valid_reports.saturating_add(1);
                } else {
                    c.invalid_reports = c.invalid_reports.saturating_add(1);
                }
                // The line ending (at least one byte) went over the wire after the line.
                let on_wire = self.wire_time_us(line_len + 1);
                t_valid_us = Some(now_us.saturating_sub(on_wire).saturating_sub(v.latency_us()));
            }
            Sentence::Reply(_) => c.replies = c.replies.saturating_add(1),
            Sentence::Other { .. } => c.other_sentences = c.other_sentences.saturating_add(1),
        }
        Ok(Received { sentence, rx_us: now_us, line_len, t_valid_us })
    }

    /// Feed buffered bytes; stops at the first completed (or refused) line.
    fn drain(&mut self, now_us: u64, budget: &mut usize) -> Option<Result<Received, Error<U::Error>>> {
        while self.rx_pos < self.rx_len && *budget > 0 {
            let b = self.rx.get(self.rx_pos).copied().unwrap_or(b'\n');
            self.rx_pos += 1;
            *budget -= 1;
            match self.line.push(b) {
                LineEvent::Pending => {}
                LineEvent::Complete => return Some(self.finish_line(now_us)),
                LineEvent::Overlong => {
                    self.counters.overlong = self.counters.overlong.saturating_add(1);
                    return Some(Err(Error::Malformed));
                }
            }
        }
        None
    }
}

impl<U: Read + ReadReady> DvlA50<U> {
    /// Read what the UART has (without blocking: only while `read_ready`) until one line
    /// completes, at most [`MAX_BYTES_PER_POLL`] bytes. `Ok(None)`: no complete line yet.
    /// Call again after `Ok(Some)` or an error: more lines may be waiting.
    pub fn poll(&mut self, now_us: u64) -> Result<Option<Received>, Error<U::Error>> {
        let mut budget = MAX_BYTES_PER_POLL;
        loop {
            if let Some(r) = self.drain(now_us, &mut budget) {
                return r.map(Some);
            }
            if budget == 0 {
                return Ok(None);
            }
            let ready = self.uart.read_ready().map_err(|e| self.bus_error(e))?;
            if !ready {
                return Ok(None);
            }
            let want = budget.min(RX_CHUNK);
            let n = match self.rx.get_mut(..want) {
                Some(buf) => self.uart.read(buf).map_err(|e| self.bus_error(e))?,
                None => 0,
            };
            if n == 0 {
                return Ok(None);
            }
            self.rx_pos = 0;
            self.rx_len = n.min(want);
        }
    }

    fn bus_error(&mut self, e: U::Error) -> Error<U::Error> {
        self.counters.bus_errors = self.counters.bus_errors.saturating_add(1);
        Error::Bus(e)
    }
}

impl<U: Read + ReadReady + Write> DvlA50<U> {
    /// Send a command body (e.g. [`cmd::PROTOCOL_WL_V2`]) with its checksum and LF. A body
    /// that is not `wc...` printable ASCII without `*`, or too long, is refused.
    pub fn send_command(&mut self, body: &[u8]) -> Result<(), Error<U::Error>> {
        let ok = body.len() >= 3
            && body.len() <= MAX_LINE - 3
            && body.starts_with(b"wc")
            && body.iter().all(|b| (0x20..=0x7E).contains(b) && *b != b'*');
        if !ok {
            return Err(Error::InvalidInput);
        }
        let crc = crc8(body);
        const HEX: &[u8; 16] = b"0123456789abcdef";
        let hex = |n: u8| HEX.get(usize::from(n & 0xF)).copied().unwrap_or(b'0');
        let tail = [b'*', hex(crc >> 4), hex(crc), b'\n'];
        self.uart.write_all(body).map_err(|e| self.bus_error(e))?;
        self.uart.write_all(&tail).map_err(|e| self.bus_error(e))?;
        self.uart.flush().map_err(|e| self.bus_error(e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimal_parser_is_within_two_ulp_of_the_correctly_rounded_value() {
        let mut cases: Vec<String> = [
            "0",
            "-0",
            "0.000",
            "1",
            "-1.30",
            "0.120",
            "-0.400",
            "2.000",
            "1.855",
            "1e-07",
            "1e+09",
            "9.00e-6",
            "1.4",
            "123.00",
            "2.707",
            "+3.5",
            "0.0000001234",
            "12345678901234567890123",
            "1.17549435e-38",
            "3.4e38",
            "7.",
            ".5",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        // Every value the DVL's 3-decimal format can give between -20 and 20 m/s, and a sweep of
        // mantissas and exponents.
        for k in (-20_000..=20_000).step_by(7) {
            cases.push(format!("{:.3}", k as f64 / 1000.0));
        }
        for e in -40..=38 {
            for m in [1.0f64, 1.5, 2.123456789, 9.99] {
                cases.push(format!("{m}e{e}"));
            }
        }
        for c in &cases {
            let exact: f32 = c.parse().unwrap();
            if exact.is_infinite() {
                assert_eq!(parse_decimal_f32(c.as_bytes()), None, "{c} overflows f32: malformed");
                continue;
            }
            let ours = parse_decimal_f32(c.as_bytes()).unwrap_or_else(|| panic!("{c} refused"));
            let ulp = (exact.abs().max(f32::MIN_POSITIVE)).to_bits().abs_diff(ours.abs().max(f32::MIN_POSITIVE).to_bits());
            assert!(ulp <= 2 && ours.is_sign_negative() == exact.is_sign_negative() || exact == 0.0, "{c}: {ours} vs {exact} ({ulp} ulp)");
        }
        for bad in ["", "-", ".", "nan", "inf", "-inf", "1e", "1e+", "1.2.3", "0x10", "1,5", "1e99", "1 ", "e5", "1e12345"] {
            assert_eq!(parse_decimal_f32(bad.as_bytes()), None, "{bad:?} accepted");
        }
    }
    use std::collections::VecDeque;
    use std::vec::Vec;

    /// The document's `wrz` example ("Velocity report (wrz)").
    const DOC_WRZ: &[u8] = b"wrz,0.120,-0.400,2.000,y,1.30,1.855,1e-07;0;1.4;0;1.2;0;0.2;0;1e+09,7,14,123.00,1*50";
    /// The document's `wrs` example ("Velocity report (wrs)"), printed with the `wrz` checksum.
    const DOC_WRS: &[u8] = b"wrs,0.120,-0.400,2.000,y,1.855,1e-07;0;1.4;0;1.2;0;0.2;0;1e+09,7,14,123.00,1*50";

    fn with_crc(body: &str) -> Vec<u8> {
        let mut v = body.as_bytes().to_vec();
        v.extend_from_slice(format!("*{:02x}", crc8(body.as_bytes())).as_bytes());
        v
    }

    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    struct UartError;
    impl embedded_io::Error for UartError {
        fn kind(&self) -> embedded_io::ErrorKind {
            embedded_io::ErrorKind::Other
        }
    }

    /// A UART: bytes in, bytes out, an optional error on the next read.
    #[derive(Default)]
    struct Uart {
        rx: VecDeque<u8>,
        tx: Vec<u8>,
        fail_next: bool,
        reads: usize,
    }
    impl embedded_io::ErrorType for Uart {
        type Error = UartError;
    }
    impl Read for Uart {
        fn read(&mut self, buf: &mut [u8]) -> Result<usize, UartError> {
            if std::mem::take(&mut self.fail_next) {
                return Err(UartError);
            }
            self.reads += 1;
            let n = buf.len().min(self.rx.len());
            for b in buf.iter_mut().take(n) {
                *b = self.rx.pop_front().unwrap();
            }
            Ok(n)
        }
    }
    impl ReadReady for Uart {
        fn read_ready(&mut self) -> Result<bool, UartError> {
            Ok(!self.rx.is_empty() || self.fail_next)
        }
    }
    impl Write for Uart {
        fn write(&mut self, buf: &[u8]) -> Result<usize, UartError> {
            self.tx.extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> Result<(), UartError> {
            Ok(())
        }
    }

    fn drain_all(dvl: &mut DvlA50<Uart>, now_us: u64) -> Vec<Result<Received, Error<UartError>>> {
        let mut out = Vec::new();
        for _ in 0..1000 {
            match dvl.poll(now_us) {
                Ok(None) => break,
                Ok(Some(r)) => out.push(Ok(r)),
                Err(e) => out.push(Err(e)),
            }
        }
        out
    }

    #[test]
    fn crc8_matches_the_document_check_value_and_examples() {
        assert_eq!(crc8(b"123456789"), 0xf4);
        // "Checksum" section's verification example, and the wrx / wru / wrp examples.
        assert_eq!(crc8(b"wrx,1164.94,0.000,0.000,0.000,2.707,-1.00,n,1"), 0x39);
        assert_eq!(crc8(b"wrx,112.83,0.007,0.017,0.006,0.000,0.93,y,0"), 0xd2);
        assert_eq!(crc8(b"wru,1,-0.500,1.25,-62,-104"), 0xf0);
        assert_eq!(crc8(b"wrp,49056.809,0.41,0.15,1.23,0.4,53.9,13.0,19.3,0"), 0xde);
        assert_eq!(crc8(&DOC_WRZ[..DOC_WRZ.len() - 3]), 0x50);
    }

    #[test]
    fn parses_the_document_wrz_example() {
        let Ok(Sentence::Velocity(v)) = parse_sentence(DOC_WRZ) else { panic!("{:?}", parse_sentence(DOC_WRZ)) };
        assert_eq!(v.tracking, Tracking::Bottom);
        assert_eq!(v.vel_dvl_mps, [0.120, -0.400, 2.000]);
        assert!(v.valid);
        assert_eq!(v.altitude_m, Some(1.30));
        assert_eq!(v.fom_mps, 1.855);
        assert_eq!(v.covariance_m2ps2, Some([1e-7, 0.0, 1.4, 0.0, 1.2, 0.0, 0.2, 0.0, 1e9]));
        assert_eq!((v.time_of_validity_us, v.time_of_transmission_us), (7, 14));
        assert_eq!(v.latency_us(), 7);
        assert_eq!(v.time_since_last_ms, 123.0);
        assert_eq!(v.status, STATUS_HIGH_TEMPERATURE);
        let b = v.bottom_velocity().unwrap();
        assert_eq!((b.vel_dvl_mps, b.altitude_m, b.fom_mps), ([0.120, -0.400, 2.000], 1.30, 1.855));
    }

    #[test]
    fn document_wrs_example_has_a_wrong_checksum() {
        assert_eq!(parse_sentence(DOC_WRS), Err(SentenceError::BadChecksum { expected: 0x50, computed: 0x7b }));
        // With its own checksum it is a water-track report: no altitude, not fusable.
        let fixed = with_crc(core::str::from_utf8(&DOC_WRS[..DOC_WRS.len() - 3]).unwrap());
        let Ok(Sentence::Velocity(v)) = parse_sentence(&fixed) else { panic!() };
        assert_eq!(v.tracking, Tracking::Water);
        assert_eq!(v.altitude_m, None);
        assert_eq!(v.fom_mps, 1.855);
        assert!(v.valid);
        assert_eq!(v.bottom_velocity(), None);
    }

    #[test]
    fn invalid_report_parses_but_is_not_fusable() {
        let s = with_crc("wrz,0.000,0.000,0.000,n,-1.00,2.707,,1700000000000000,1700000000050000,250.00,0");
        let Ok(Sentence::Velocity(v)) = parse_sentence(&s) else { panic!() };
        assert!(!v.valid);
        assert_eq!(v.covariance_m2ps2, None);
        assert_eq!(v.latency_us(), 50_000);
        assert_eq!(v.bottom_velocity(), None);
        // valid = y with a negative altitude is not fused either.
        let s = with_crc("wrz,0.1,0,0,y,-1.00,0.01,,1,2,100,0");
        let Ok(Sentence::Velocity(v)) = parse_sentence(&s) else { panic!() };
        assert_eq!(v.bottom_velocity(), None);
    }

    #[test]
    fn replies_and_other_sentences() {
        assert_eq!(parse_sentence(&with_crc("wra")), Ok(Sentence::Reply(Reply::Ack)));
        assert_eq!(parse_sentence(&with_crc("wrn")), Ok(Sentence::Reply(Reply::Nak)));
        assert_eq!(parse_sentence(&with_crc("wr?")), Ok(Sentence::Reply(Reply::MalformedRequest)));
        assert_eq!(parse_sentence(&with_crc("wr!")), Ok(Sentence::Reply(Reply::ChecksumMismatch)));
        assert_eq!(parse_sentence(&with_crc("wra,1")), Err(SentenceError::Malformed));
        assert_eq!(parse_sentence(b"wru,1,-0.500,1.25,-62,-104*f0"), Ok(Sentence::Other { direction: b'r', command: b'u' }));
        assert_eq!(parse_sentence(&with_crc("wrv,2.6.0")), Ok(Sentence::Other { direction: b'r', command: b'v' }));
        assert_eq!(parse_sentence(&with_crc("wcv")), Ok(Sentence::Other { direction: b'c', command: b'v' }));
    }

    #[test]
    fn malformed_lines_are_refused() {
        let bad = [
            "wrz,0.1,0.2,0.3,y,1.0,0.01,,1,2,100",                       // field missing
            "wrz,0.1,0.2,0.3,x,1.0,0.01,,1,2,100,0",                     // flag
            "wrz,0.1,abc,0.3,y,1.0,0.01,,1,2,100,0",                     // number
            "wrz,nan,0.2,0.3,y,1.0,0.01,,1,2,100,0",                     // non-finite
            "wrz,0.1,inf,0.3,y,1.0,0.01,,1,2,100,0",                     // non-finite
            "wrz,0.1,0.2,0.3,y,1.0,0.01,1;2;3,1,2,100,0",                // covariance with 3 entries
            "wrz,0.1,0.2,0.3,y,1.0,0.01,1;2;3;4;5;6;7;8;9;10,1,2,100,0", // 10 entries
            "wrz,0.1,0.2,0.3,y,1.0,-0.01,,1,2,100,0",                    // negative fom
            "wrz,0.1,0.2,0.3,y,1.0,0.01,,5,2,100,0",                     // transmitted before validity
            "wrz,0.1,0.2,0.3,y,1.0,0.01,,1,9000000,100,0",               // latency above the limit
            "wrz,0.1,0.2,0.3,y,1.0,0.01,,+1,2,100,0",                    // signed integer
            "wrz,0.1,0.2,0.3,y,1.0,0.01,,1,2,100,256",                   // status above 8 bits
            "wrz",                                                       // no fields
            "xrz,0.1",                                                   // not 'w'
            "wxz,0.1",                                                   // direction
            "wr",                                                        // too short
        ];
        for b in bad {
            assert_eq!(parse_sentence(&with_crc(b)), Err(SentenceError::Malformed), "{b}");
        }
        // Checksum framing: missing, upper case, one digit, non-hex, non-printable bytes.
        for b in [&b"wra"[..], b"wra*A0", b"wra*a", b"wra*g0", b"wra*a00", b"w\x01a*00"] {
            assert_eq!(parse_sentence(b), Err(SentenceError::Malformed), "{:?}", core::str::from_utf8(b));
        }
        // A trailing extra field is tolerated (minor protocol versions add fields).
        assert!(matches!(parse_sentence(&with_crc("wrz,0.1,0.2,0.3,y,1.0,0.01,,1,2,100,0,b")), Ok(Sentence::Velocity(_))));
    }

    #[test]
    fn bad_checksum_is_its_own_error() {
        let mut s = DOC_WRZ.to_vec();
        // Flip one digit of vx: "0.120" -> "0.130".
        s[7] = b'3';
        assert_eq!(parse_sentence(&s), Err(SentenceError::BadChecksum { expected: 0x50, computed: crc8(&s[..s.len() - 3]) }));
    }

    #[test]
    fn line_assembler_handles_all_endings_and_overlong_lines() {
        let mut a = LineAssembler::<8>::new();
        let mut lines = Vec::new();
        for b in b"wra\r\nwrn\rwr?\n\n\nabcdefghij\nwr!\n" {
            match a.push(*b) {
                LineEvent::Pending => {}
                LineEvent::Complete => {
                    lines.push(String::from_utf8(a.line().to_vec()).unwrap());
                    a.clear();
                }
                LineEvent::Overlong => lines.push("<overlong>".into()),
            }
        }
        assert_eq!(lines, ["wra", "wrn", "wr?", "<overlong>", "wr!"]);
        // Exactly N bytes fit.
        let mut a = LineAssembler::<3>::new();
        assert_eq!(a.push(b'w'), LineEvent::Pending);
        a.push(b'r');
        a.push(b'a');
        assert_eq!(a.push(b'\n'), LineEvent::Complete);
        assert_eq!(a.line(), b"wra");
    }

    #[test]
    fn driver_counts_every_outcome_separately() {
        let mut uart = Uart::default();
        let mut feed = |s: &[u8], end: &[u8]| {
            uart.rx.extend(s);
            uart.rx.extend(end);
        };
        feed(DOC_WRZ, b"\r\n");
        feed(&with_crc("wrz,0.000,0.000,0.000,n,-1.00,2.707,,100,200,250.00,0"), b"\n");
        feed(DOC_WRS, b"\r"); // bad checksum
        feed(b"wrz,0.1,garbage*00", b"\n"); // bad checksum (checked before fields)
        feed(&with_crc("wrz,0.1,garbage"), b"\n"); // malformed
        feed(&[b'x'; MAX_LINE + 10], b"\n"); // overlong
        feed(&with_crc("wra"), b"\n");
        feed(b"wru,1,-0.500,1.25,-62,-104*f0", b"\n");
        let mut dvl = DvlA50::new(uart, DEFAULT_BAUD);
        let out = drain_all(&mut dvl, 1_000_000);
        assert_eq!(out.len(), 8);
        assert!(matches!(out[0], Ok(Received { sentence: Sentence::Velocity(VelocityReport { valid: true, .. }), .. })));
        assert!(matches!(out[1], Ok(Received { sentence: Sentence::Velocity(VelocityReport { valid: false, .. }), .. })));
        assert_eq!(out[2], Err(Error::BadCrc { expected: 0x50, computed: 0x7b }));
        assert!(matches!(out[3], Err(Error::BadCrc { .. })));
        assert_eq!(out[4], Err(Error::Malformed));
        assert_eq!(out[5], Err(Error::Malformed));
        assert!(matches!(out[6], Ok(Received { sentence: Sentence::Reply(Reply::Ack), t_valid_us: None, .. })));
        assert!(matches!(out[7], Ok(Received { sentence: Sentence::Other { command: b'u', .. }, .. })));
        assert_eq!(
            *dvl.counters(),
            DvlCounters {
                valid_reports: 1,
                invalid_reports: 1,
                replies: 1,
                other_sentences: 1,
                malformed: 1,
                bad_checksum: 2,
                overlong: 1,
                bus_errors: 0
            }
        );
        // The overlong line did not leak into the next one.
        assert!(dvl.destroy().rx.is_empty());
    }

    #[test]
    fn time_of_validity_in_the_local_clock() {
        let mut uart = Uart::default();
        let s = with_crc("wrz,0.5,0.0,0.0,y,3.0,0.002,,1700000000000000,1700000000030000,100,0");
        uart.rx.extend(&s);
        uart.rx.extend(b"\n");
        let mut dvl = DvlA50::new(uart, DEFAULT_BAUD);
        let rx = dvl.poll(5_000_000).unwrap().unwrap();
        // (len + 1) bytes * 10 bits at 115200 baud, plus 30 ms latency.
        let wire = ((s.len() as u64 + 1) * 10 * 1_000_000) / 115_200;
        assert_eq!(rx.t_valid_us, Some(5_000_000 - wire - 30_000));
        assert_eq!(rx.line_len, s.len());
    }

    #[test]
    fn poll_without_data_or_a_partial_line_returns_none_and_keeps_the_bytes() {
        let mut dvl = DvlA50::new(Uart::default(), DEFAULT_BAUD);
        assert_eq!(dvl.poll(0), Ok(None));
        dvl.uart.rx.extend(&DOC_WRZ[..40]);
        assert_eq!(dvl.poll(0), Ok(None));
        assert!(dvl.uart.rx.is_empty(), "the partial line was consumed into the line buffer");
        dvl.uart.rx.extend(&DOC_WRZ[40..]);
        dvl.uart.rx.extend(b"\n");
        assert!(matches!(dvl.poll(1), Ok(Some(Received { sentence: Sentence::Velocity(_), rx_us: 1, .. }))));
    }

    #[test]
    fn poll_is_bounded_on_an_endless_stream() {
        let mut uart = Uart::default();
        uart.rx.extend(std::iter::repeat_n(b'w', 100_000));
        let mut dvl = DvlA50::new(uart, DEFAULT_BAUD);
        assert_eq!(dvl.poll(0), Ok(None));
        assert_eq!(dvl.uart.rx.len(), 100_000 - MAX_BYTES_PER_POLL);
    }

    #[test]
    fn several_lines_in_one_read_chunk_all_come_out() {
        let mut uart = Uart::default();
        for _ in 0..3 {
            uart.rx.extend(b"wra*");
            uart.rx.extend(format!("{:02x}\n", crc8(b"wra")).as_bytes());
        }
        let mut dvl = DvlA50::new(uart, DEFAULT_BAUD);
        let out = drain_all(&mut dvl, 0);
        assert_eq!(out.len(), 3);
        assert!(out.iter().all(|r| matches!(r, Ok(Received { sentence: Sentence::Reply(Reply::Ack), .. }))));
        assert_eq!(dvl.uart.reads, 1, "one 24-byte read carried all three lines");
    }

    #[test]
    fn bus_errors_are_wrapped_and_counted() {
        let uart = Uart { fail_next: true, ..Default::default() };
        let mut dvl = DvlA50::new(uart, DEFAULT_BAUD);
        assert_eq!(dvl.poll(0), Err(Error::Bus(UartError)));
        assert_eq!(dvl.counters().bus_errors, 1);
        assert_eq!(dvl.poll(0), Ok(None));
    }

    #[test]
    fn commands_go_out_with_their_checksum() {
        let mut dvl = DvlA50::new(Uart::default(), DEFAULT_BAUD);
        dvl.send_command(cmd::PROTOCOL_WL_V2).unwrap();
        dvl.send_command(cmd::VERSION).unwrap();
        let tx = dvl.destroy().tx;
        let expected = format!("wcp,3*{:02x}\nwcv*{:02x}\n", crc8(b"wcp,3"), crc8(b"wcv"));
        assert_eq!(String::from_utf8(tx).unwrap(), expected);
        let mut dvl = DvlA50::new(Uart::default(), DEFAULT_BAUD);
        for bad in [&b"wrz"[..], b"wc", b"wcs,*", b"wc\n"] {
            assert_eq!(dvl.send_command(bad), Err(Error::InvalidInput));
        }
        assert!(dvl.destroy().tx.is_empty());
    }
}
