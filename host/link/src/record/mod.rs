//! Lossless recordings of a sensor-head session (`.snrec`).
//!
//! Every byte that crossed the link is kept exactly as received, with the host time it arrived,
//! per stream: uplink telemetry, defmt log bytes, downlink commands the host sent, and optional
//! truth rows from a simulator. Corrupt frames are recorded too (decoding happens on reading), so
//! a recording can be decoded again by a later host with better tools.
//!
//! Layout (all integers little endian):
//! ```text
//! header: MAGIC (8 bytes) | version u16 | meta_len u32 | meta (JSON, meta_len bytes) | crc32 u32
//! chunk:  SYNC (2 bytes)  | stream u8  | t_host_us u64 | len u32 | data (len bytes) | crc32 u32
//! ```
//! The header CRC covers version..meta; a chunk's CRC covers stream..data. CRC-32 is the same
//! ISO-HDLC CRC as the wire frames. A chunk is written with one `write` call and the file is not
//! buffered, so a crash loses at most the chunk being written; the reader reports a truncated or
//! damaged chunk, skips to the next valid `SYNC` and goes on.
//!
//! Why not MCAP for recording too: MCAP is the export format (`subnav export`), but its readers
//! stop at the first damaged record and it wants decoded messages on channels; a recording must
//! keep undecodable bytes and survive a crash or a damaged disk block mid-file.

pub mod reader;
pub mod session;
pub mod tap;
pub mod writer;

pub use reader::{Damage, Item, Loaded, ReadStats, Reader, RecordError, read_bytes, read_file};
pub use writer::Writer;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// First 8 bytes of a recording. The `\r\n` and `\x1a` catch text-mode mangling, like PNG's.
pub const MAGIC: [u8; 8] = *b"\x89SNREC\r\n";
/// Marks the start of each chunk (lets the reader resynchronise after damage).
pub const SYNC: [u8; 2] = [0xA5, 0x5A];
/// Format version this code writes and reads.
pub const VERSION: u16 = 1;
/// Largest chunk payload accepted (a larger length field is damage, not an allocation).
pub const MAX_CHUNK: usize = 1 << 20;
/// Largest header metadata accepted.
pub const MAX_META: usize = 1 << 16;
/// Bytes of a chunk around its data: sync, stream, time, length, CRC.
pub const CHUNK_OVERHEAD: usize = 2 + 1 + 8 + 4 + 4;

/// Which stream a chunk belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Stream {
    /// Uplink telemetry bytes (COBS frames), as received.
    Uplink,
    /// defmt log bytes (QEMU semihosting stdout or RTT channel 0), as received.
    Defmt,
    /// Downlink bytes the host sent to the sensor head.
    Downlink,
    /// Truth rows from a simulator: CSV lines `t_s,n_m,e_m,d_m,yaw_rad` (header line allowed).
    Truth,
}

impl Stream {
    pub const ALL: [Stream; 4] = [Stream::Uplink, Stream::Defmt, Stream::Downlink, Stream::Truth];

    pub fn code(self) -> u8 {
        match self {
            Stream::Uplink => 0,
            Stream::Defmt => 1,
            Stream::Downlink => 2,
            Stream::Truth => 3,
        }
    }

    pub fn from_code(c: u8) -> Option<Stream> {
        Stream::ALL.into_iter().find(|s| s.code() == c)
    }

    pub fn name(self) -> &'static str {
        match self {
            Stream::Uplink => "uplink",
            Stream::Defmt => "defmt",
            Stream::Downlink => "downlink",
            Stream::Truth => "truth",
        }
    }
}

/// Header metadata (JSON in the file, so fields can be added without a version bump).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Meta {
    /// Where the bytes came from, e.g. `qemu target/firmware/subnav-qemu.elf` or `serial /dev/ttyUSB0 at 460800 baud`.
    #[serde(default)]
    pub source: String,
    /// Host wall-clock time at the start of the recording, microseconds since the Unix epoch.
    #[serde(default)]
    pub start_unix_us: u64,
    /// The host tool that wrote it.
    #[serde(default)]
    pub writer: String,
    /// The firmware ELF, if known (needed to decode the defmt stream).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elf: Option<String>,
    /// The board's start arguments (`utc_unix_us=`, `lat_e7=`, `lon_e7=`, as on the QEMU
    /// semihosting command line): the configured start the board applies at boot as seq-0
    /// commands, which never cross the downlink (`subnav replay` needs them).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub board_args: Vec<String>,
    /// The file name of the recording this one continues (a host restarted mid-dive records
    /// the next of the series: `dive.2.snrec` continues `dive.snrec`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub continues: Option<String>,
}

impl Meta {
    pub fn new(source: impl Into<String>) -> Self {
        Self {
            source: source.into(),
            start_unix_us: now_unix_us(),
            writer: format!("subnav {}", env!("CARGO_PKG_VERSION")),
            elf: None,
            board_args: Vec::new(),
            continues: None,
        }
    }
}

/// One chunk of a stream.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Chunk {
    pub stream: Stream,
    /// Host receive time, microseconds since the Unix epoch.
    pub t_host_us: u64,
    pub data: Vec<u8>,
}

/// Host wall-clock time, microseconds since the Unix epoch (0 if the clock is before 1970).
pub fn now_unix_us() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_micros() as u64).unwrap_or(0)
}

/// Whether `bytes` start like a recording (as opposed to a raw uplink byte file).
pub fn is_recording(bytes: &[u8]) -> bool {
    bytes.starts_with(&MAGIC)
}

/// Whether the first bytes of a file (up to 8) are, or were, a recording's magic: intact, cut
/// short, a bit or two flipped, or mangled by a text-mode copy (`\r\n` -> `\n`). Such a file
/// is read as a recording, whose reader recovers it or says what is wrong, never as raw bytes.
pub fn looks_like_recording(head: &[u8]) -> bool {
    let head = &head[..head.len().min(MAGIC.len())];
    if head.is_empty() {
        return false;
    }
    let flipped_bits: u32 = head.iter().zip(MAGIC).map(|(a, b)| (a ^ b).count_ones()).sum();
    MAGIC.starts_with(head) || head.starts_with(&MAGIC[..6]) || (head.len() == MAGIC.len() && flipped_bits <= 2)
}

/// The `k`-th recording of a series (from 1): `dive.snrec`, `dive.2.snrec`, `dive.3.snrec`, ...
pub fn series_member(first: &Path, k: usize) -> PathBuf {
    if k <= 1 {
        return first.to_path_buf();
    }
    let stem = first.file_stem().map_or_else(|| "recording".into(), |s| s.to_string_lossy().into_owned());
    let name = match first.extension() {
        Some(ext) => format!("{stem}.{k}.{}", ext.to_string_lossy()),
        None => format!("{stem}.{k}"),
    };
    first.with_file_name(name)
}

/// The recordings of the series that starts at `first` which exist, in order (stops at the
/// first missing member).
pub fn series(first: &Path) -> Vec<PathBuf> {
    (1..).map(|k| series_member(first, k)).take_while(|p| p.exists()).collect()
}

/// Where a new recording of the series goes: the first member that does not exist, so that a
/// recorder started again (a host restarted mid-dive) never replaces what was recorded.
pub fn next_in_series(first: &Path) -> PathBuf {
    series_member(first, series(first).len() + 1)
}

/// The uplink of a recording file, decoded only for its counts and its coverage of the head's
/// time.
pub fn uplink_stats(path: &Path) -> anyhow::Result<crate::uplink::LinkStats> {
    let loaded = read_file(path)?;
    let mut dec = crate::uplink::UplinkDecoder::new();
    for c in loaded.chunks.iter().filter(|c| c.stream == Stream::Uplink) {
        dec.feed(&c.data, |_| {});
    }
    Ok(dec.stats())
}

/// What of the head's time lies between the recording `previous` and a stream `next` that
/// continues it (a restarted host's), in words: where `previous` ends and how much is in
/// neither; or that `previous` is of an earlier boot (or overlaps), or is unreadable.
pub fn continuation_note(previous: &Path, next: &crate::uplink::LinkStats) -> String {
    let p = previous.display();
    match uplink_stats(previous) {
        Ok(before) => match before.gap_to(next) {
            Some((a, b)) => {
                format!("{p} ends at head time {:.1} s: {:.1} s of telemetry are in neither", a as f64 * 1e-6, (b - a) as f64 * 1e-6)
            }
            None => format!("{p} is of an earlier boot or overlaps this one"),
        },
        Err(e) => format!("{p} is unreadable: {e:#}"),
    }
}

#[cfg(test)]
mod series_tests {
    use super::*;

    #[test]
    fn a_series_never_reuses_a_name() {
        let d = tempfile::tempdir().unwrap();
        let first = d.path().join("dive.snrec");
        assert_eq!(next_in_series(&first), first);
        std::fs::write(&first, b"x").unwrap();
        assert_eq!(next_in_series(&first), d.path().join("dive.2.snrec"));
        std::fs::write(d.path().join("dive.2.snrec"), b"x").unwrap();
        assert_eq!(next_in_series(&first), d.path().join("dive.3.snrec"));
        assert_eq!(series(&first), [first.clone(), d.path().join("dive.2.snrec")]);
        assert_eq!(series_member(&d.path().join("log"), 2), d.path().join("log.2"));
    }
}
