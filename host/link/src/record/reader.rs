//! Reading a recording: never panics, never allocates more than the input's size, reports every
//! damaged region (offset, length, why) and recovers every intact chunk after it.

use std::path::Path;

use anyhow::Context;
use serde::Serialize;
use subnav_wire::frame::FRAME_CRC;

use super::{CHUNK_OVERHEAD, Chunk, MAGIC, MAX_CHUNK, MAX_META, Meta, SYNC, Stream, VERSION};

/// Why a recording cannot be read at all (its header is unusable).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RecordError {
    /// The file does not start with the recording magic (it may be a raw uplink byte file).
    NotARecording,
    /// Written by a newer format version.
    UnsupportedVersion(u16),
    /// The header is cut short.
    TruncatedHeader,
    /// The header CRC does not match.
    HeaderCrc,
    /// The header metadata is not valid JSON.
    BadMeta(String),
}

impl std::fmt::Display for RecordError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RecordError::NotARecording => {
                write!(f, "not a subnav recording (no magic); raw uplink byte files are read by `subnav decode --file`")
            }
            RecordError::UnsupportedVersion(v) => {
                write!(f, "recording format version {v} is newer than this host reads ({VERSION}); update subnav")
            }
            RecordError::TruncatedHeader => write!(f, "the recording header is truncated (the file was cut before any data)"),
            RecordError::HeaderCrc => write!(f, "the recording header is damaged (CRC mismatch)"),
            RecordError::BadMeta(e) => write!(f, "the recording header metadata is not valid JSON: {e}"),
        }
    }
}

impl std::error::Error for RecordError {}

/// A damaged or unreadable region that was skipped.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Damage {
    /// Byte offset in the file where the damage starts.
    pub offset: usize,
    /// Bytes skipped.
    pub len: usize,
    pub reason: &'static str,
}

/// What the reader yields.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Item {
    Chunk(Chunk),
    Damage(Damage),
}

/// Counts over a whole read.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct ReadStats {
    pub chunks: u64,
    pub damaged_regions: u64,
    pub damaged_bytes: u64,
}

/// Iterates over the chunks (and damaged regions) of a recording held in memory.
pub struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    pub meta: Meta,
    pub version: u16,
    pub stats: ReadStats,
}

fn le_u16(b: &[u8], at: usize) -> Option<u16> {
    Some(u16::from_le_bytes(b.get(at..at + 2)?.try_into().ok()?))
}
fn le_u32(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}
fn le_u64(b: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(b.get(at..at + 8)?.try_into().ok()?))
}

/// Result of trying to parse one chunk at a position.
enum Attempt {
    Ok(Chunk, usize),
    /// Not enough bytes left for the chunk the length field announces.
    Truncated,
    Bad(&'static str),
}

impl<'a> Reader<'a> {
    /// Parse the header.
    pub fn new(bytes: &'a [u8]) -> Result<Self, RecordError> {
        if bytes.len() < MAGIC.len() {
            return Err(if MAGIC.starts_with(bytes) && !bytes.is_empty() {
                RecordError::TruncatedHeader
            } else {
                RecordError::NotARecording
            });
        }
        if !bytes.starts_with(&MAGIC) {
            return Err(RecordError::NotARecording);
        }
        let m = MAGIC.len();
        let version = le_u16(bytes, m).ok_or(RecordError::TruncatedHeader)?;
        let meta_len = le_u32(bytes, m + 2).ok_or(RecordError::TruncatedHeader)? as usize;
        if meta_len > MAX_META {
            return Err(RecordError::HeaderCrc);
        }
        let meta_end = m + 6 + meta_len;
        let meta_bytes = bytes.get(m + 6..meta_end).ok_or(RecordError::TruncatedHeader)?;
        let crc = le_u32(bytes, meta_end).ok_or(RecordError::TruncatedHeader)?;
        let covered = bytes.get(m..meta_end).ok_or(RecordError::TruncatedHeader)?;
        if FRAME_CRC.checksum(covered) != crc {
            return Err(RecordError::HeaderCrc);
        }
        if version > VERSION || version == 0 {
            return Err(RecordError::UnsupportedVersion(version));
        }
        let meta: Meta = serde_json::from_slice(meta_bytes).map_err(|e| RecordError::BadMeta(e.to_string()))?;
        Ok(Self { bytes, pos: meta_end + 4, meta, version, stats: ReadStats::default() })
    }

    /// Byte offset of the next chunk to read (right after the header when new).
    pub fn offset(&self) -> usize {
        self.pos
    }

    fn attempt(&self, at: usize) -> Attempt {
        let b = self.bytes;
        let Some(head) = b.get(at..at + CHUNK_OVERHEAD - 4) else { return Attempt::Truncated };
        if head.get(..2) != Some(&SYNC[..]) {
            return Attempt::Bad("no chunk sync marker");
        }
        let Some(stream) = head.get(2).copied().and_then(Stream::from_code) else { return Attempt::Bad("unknown stream code") };
        let (Some(t_host_us), Some(len)) = (le_u64(b, at + 3), le_u32(b, at + 11)) else { return Attempt::Truncated };
        let len = len as usize;
        if len == 0 || len > MAX_CHUNK {
            return Attempt::Bad("chunk length out of range");
        }
        let data_start = at + CHUNK_OVERHEAD - 4;
        let Some(data) = b.get(data_start..data_start + len) else { return Attempt::Truncated };
        let Some(crc) = le_u32(b, data_start + len) else { return Attempt::Truncated };
        let Some(covered) = b.get(at + 2..data_start + len) else { return Attempt::Truncated };
        if FRAME_CRC.checksum(covered) != crc {
            return Attempt::Bad("chunk CRC mismatch");
        }
        Attempt::Ok(Chunk { stream, t_host_us, data: data.to_vec() }, data_start + len + 4)
    }

    /// After damage at `from`, the offset of the next position where a valid chunk starts (or
    /// the end of the input).
    fn resync(&self, from: usize) -> usize {
        let mut i = from;
        while let Some(rest) = self.bytes.get(i..) {
            let Some(k) = rest.windows(2).position(|w| w == SYNC) else { break };
            let cand = i + k;
            if let Attempt::Ok(..) = self.attempt(cand) {
                return cand;
            }
            i = cand + 1;
        }
        self.bytes.len()
    }
}

impl Iterator for Reader<'_> {
    type Item = Item;

    fn next(&mut self) -> Option<Item> {
        if self.pos >= self.bytes.len() {
            return None;
        }
        let at = self.pos;
        let reason = match self.attempt(at) {
            Attempt::Ok(chunk, next) => {
                self.pos = next;
                self.stats.chunks += 1;
                return Some(Item::Chunk(chunk));
            }
            Attempt::Truncated => "truncated chunk",
            Attempt::Bad(r) => r,
        };
        let next = self.resync(at + 1);
        let reason =
            if next >= self.bytes.len() && reason == "truncated chunk" { "truncated final chunk (recording cut short)" } else { reason };
        self.pos = next;
        self.stats.damaged_regions += 1;
        self.stats.damaged_bytes += (next - at) as u64;
        Some(Item::Damage(Damage { offset: at, len: next - at, reason }))
    }
}

/// A recording read into memory: its metadata, its chunks in file order, and the damage seen.
#[derive(Debug, Clone, Default)]
pub struct Loaded {
    pub meta: Meta,
    pub chunks: Vec<Chunk>,
    pub damage: Vec<Damage>,
    pub stats: ReadStats,
}

impl Loaded {
    /// Chunks of one stream, in order.
    pub fn stream(&self, s: Stream) -> impl Iterator<Item = &Chunk> {
        self.chunks.iter().filter(move |c| c.stream == s)
    }

    /// All bytes of one stream, concatenated.
    pub fn stream_bytes(&self, s: Stream) -> Vec<u8> {
        self.stream(s).flat_map(|c| c.data.iter().copied()).collect()
    }
}

/// Read a whole recording from memory.
pub fn read_bytes(bytes: &[u8]) -> Result<Loaded, RecordError> {
    let mut r = Reader::new(bytes)?;
    let (mut chunks, mut damage) = (vec![], vec![]);
    for item in r.by_ref() {
        match item {
            Item::Chunk(c) => chunks.push(c),
            Item::Damage(d) => damage.push(d),
        }
    }
    Ok(Loaded { meta: r.meta, chunks, damage, stats: r.stats })
}

/// Read a whole recording file, with errors that say what to do.
pub fn read_file(path: &Path) -> anyhow::Result<Loaded> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    read_bytes(&bytes).with_context(|| format!("reading the recording {}", path.display()))
}
