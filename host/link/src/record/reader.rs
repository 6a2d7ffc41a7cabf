//! Reading a recording: never panics, never allocates more than the input's size, reports every
//! damaged region (offset, length, why) and recovers every intact chunk after it.
//!
//! Resynchronising after damage tries every `SYNC` candidate; a candidate's CRC covers up to
//! [`MAX_CHUNK`] bytes, so checksumming each one directly made a file of fake chunk headers
//! quadratic (1.3 MB: 41 s). Candidates are checked with [`RangeCrc`] instead: prefix CRCs at
//! every [`RangeCrc::STEP`] bytes, computed once, give the CRC of any range in O(STEP + log n)
//! (CRC-32 is linear: the zlib `crc32_combine` algebra), so a whole read stays linear.

use std::cell::OnceCell;

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
    /// The magic's `\r\n` was changed: a copy in text mode (FTP ASCII, git autocrlf).
    TextMode,
}

impl std::fmt::Display for RecordError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RecordError::NotARecording => {
                write!(f, "not a subnav recording (no magic); raw uplink byte files are read by `subnav decode --file`")
            }
            RecordError::UnsupportedVersion(v) if *v > VERSION => write!(
                f,
                "recording format version {v} is newer than this host reads (found version {v}, expected 1..={VERSION}); update subnav"
            ),
            RecordError::UnsupportedVersion(v) => {
                write!(f, "recording format version {v} does not exist (found version {v}, expected 1..={VERSION}): the header is damaged")
            }
            RecordError::TruncatedHeader => write!(f, "the recording header is truncated (the file was cut before any data)"),
            RecordError::HeaderCrc => write!(f, "the recording header is damaged (CRC mismatch)"),
            RecordError::BadMeta(e) => write!(f, "the recording header metadata is not valid JSON: {e}"),
            RecordError::TextMode => write!(
                f,
                "the recording was mangled by a text-mode copy (its magic's \\r\\n was changed, so are its data bytes); copy it again in binary mode"
            ),
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
    /// Built on the first resynchronisation.
    range_crc: OnceCell<RangeCrc>,
    pub meta: Meta,
    pub version: u16,
    pub stats: ReadStats,
    /// Set by [`Reader::open`] when the header was damaged: the metadata is lost (defaults),
    /// the chunks after it are read as usual.
    pub header_error: Option<RecordError>,
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
            let magic_bits: u32 = bytes[..MAGIC.len()].iter().zip(MAGIC).map(|(a, b)| (a ^ b).count_ones()).sum();
            if bytes.starts_with(&MAGIC[..6]) && magic_bits > 2 {
                return Err(RecordError::TextMode);
            }
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
        Ok(Self { bytes, pos: meta_end + 4, range_crc: OnceCell::new(), meta, version, stats: ReadStats::default(), header_error: None })
    }

    /// Like [`Reader::new`], but a damaged header (CRC mismatch or unreadable metadata behind
    /// an intact magic) costs only the header: the metadata is lost ([`Meta::default`]),
    /// [`Reader::header_error`] says why, the header bytes are reported as the first damaged
    /// region and every intact chunk after it is read. A file without the magic, cut inside
    /// the header, or of a newer version is still refused.
    pub fn open(bytes: &'a [u8]) -> Result<Self, RecordError> {
        // A magic one or two bits away from the real one is a damaged recording, not another file.
        let near_magic =
            |b: &[u8]| b.get(..MAGIC.len()).is_some_and(|m| m.iter().zip(MAGIC).map(|(x, y)| (x ^ y).count_ones()).sum::<u32>() <= 2);
        match Self::new(bytes) {
            Err(RecordError::NotARecording) if near_magic(bytes) => Ok(Self {
                bytes,
                pos: MAGIC.len(),
                range_crc: OnceCell::new(),
                meta: Meta::default(),
                version: VERSION,
                stats: ReadStats::default(),
                header_error: Some(RecordError::HeaderCrc),
            }),
            Err(e @ (RecordError::HeaderCrc | RecordError::BadMeta(_))) => Ok(Self {
                bytes,
                pos: MAGIC.len(),
                range_crc: OnceCell::new(),
                meta: Meta::default(),
                version: VERSION,
                stats: ReadStats::default(),
                header_error: Some(e),
            }),
            // A damaged metadata length can point past the end: if a valid chunk follows, the
            // header is damaged, not the file cut inside it.
            Err(RecordError::TruncatedHeader) if bytes.len() > MAGIC.len() => {
                let r = Self {
                    bytes,
                    pos: MAGIC.len(),
                    range_crc: OnceCell::new(),
                    meta: Meta::default(),
                    version: VERSION,
                    stats: ReadStats::default(),
                    header_error: Some(RecordError::HeaderCrc),
                };
                if r.resync(MAGIC.len()) < bytes.len() { Ok(r) } else { Err(RecordError::TruncatedHeader) }
            }
            r => r,
        }
    }

    /// Byte offset of the next chunk to read (right after the header when new).
    pub fn offset(&self) -> usize {
        self.pos
    }

    /// The chunk at `at`, its CRC computed directly (reading in order: each byte once).
    fn attempt(&self, at: usize) -> Attempt {
        self.attempt_with(at, &|s, e| FRAME_CRC.checksum(&self.bytes[s..e]))
    }

    /// The chunk at `at`; `crc(s, e)` is the CRC of `bytes[s..e]` (always in bounds).
    fn attempt_with(&self, at: usize, crc_of: &dyn Fn(usize, usize) -> u32) -> Attempt {
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
        if b.get(at + 2..data_start + len).is_none() {
            return Attempt::Truncated;
        }
        if crc_of(at + 2, data_start + len) != crc {
            return Attempt::Bad("chunk CRC mismatch");
        }
        Attempt::Ok(Chunk { stream, t_host_us, data: data.to_vec() }, data_start + len + 4)
    }

    /// After damage at `from`, the offset of the next position where a valid chunk starts (or
    /// the end of the input).
    fn resync(&self, from: usize) -> usize {
        let mut i = from;
        let table = self.range_crc.get_or_init(|| RangeCrc::new(self.bytes));
        let crc_of = |s: usize, e: usize| table.crc(self.bytes, s, e);
        while let Some(rest) = self.bytes.get(i..) {
            let Some(k) = rest.windows(2).position(|w| w == SYNC) else { break };
            let cand = i + k;
            if let Attempt::Ok(..) = self.attempt_with(cand, &crc_of) {
                return cand;
            }
            i = cand + 1;
        }
        self.bytes.len()
    }
}

/// CRC-32/ISO-HDLC of any range of one buffer: prefix CRCs every [`Self::STEP`] bytes (4 bytes
/// per STEP of memory), combined with GF(2) polynomial arithmetic as zlib's `crc32_combine`.
pub struct RangeCrc {
    /// `prefix[j]` = CRC of `bytes[..j * STEP]`.
    prefix: Vec<u32>,
}

/// The reflected CRC-32 polynomial.
const POLY: u32 = 0xEDB8_8320;

/// `a * b mod p` in the reflected bit order of the CRC.
fn mult_mod_p(a: u32, mut b: u32) -> u32 {
    let mut m = 1u32 << 31;
    let mut p = 0;
    while m != 0 {
        if a & m != 0 {
            p ^= b;
        }
        m >>= 1;
        b = if b & 1 != 0 { (b >> 1) ^ POLY } else { b >> 1 };
    }
    p
}

/// `x^(8 n) mod p`: the operator that shifts a CRC over `n` zero bytes.
fn x8n_mod_p(mut n: u64) -> u32 {
    // x^(2^k) mod p for k = 3 (one byte = 8 bits) upwards, squared as we go.
    let mut sq = mult_mod_p(1 << 30, 1 << 30); // x^2
    sq = mult_mod_p(sq, sq); // x^4
    sq = mult_mod_p(sq, sq); // x^8
    let mut p = 1u32 << 31; // x^0
    while n != 0 {
        if n & 1 != 0 {
            p = mult_mod_p(sq, p);
        }
        n >>= 1;
        sq = mult_mod_p(sq, sq);
    }
    p
}

/// CRC of `A || B` from the CRCs of A and B and the length of B.
fn crc_combine(crc_a: u32, crc_b: u32, len_b: usize) -> u32 {
    mult_mod_p(x8n_mod_p(len_b as u64), crc_a) ^ crc_b
}

impl RangeCrc {
    pub const STEP: usize = 256;

    pub fn new(bytes: &[u8]) -> Self {
        let mut prefix = Vec::with_capacity(bytes.len() / Self::STEP + 1);
        prefix.push(0);
        let mut acc = 0;
        for block in bytes.chunks(Self::STEP) {
            acc = crc_combine(acc, FRAME_CRC.checksum(block), block.len());
            prefix.push(acc);
        }
        Self { prefix }
    }

    /// CRC of `bytes[..k]` (`bytes` is the buffer the table was built from).
    fn prefix_crc(&self, bytes: &[u8], k: usize) -> u32 {
        let j = k / Self::STEP;
        let base = self.prefix.get(j).copied().unwrap_or(0);
        let tail = bytes.get(j * Self::STEP..k).unwrap_or(&[]);
        crc_combine(base, FRAME_CRC.checksum(tail), tail.len())
    }

    /// CRC of `bytes[s..e]`.
    pub fn crc(&self, bytes: &[u8], s: usize, e: usize) -> u32 {
        let (a, ab) = (self.prefix_crc(bytes, s), self.prefix_crc(bytes, e));
        ab ^ mult_mod_p(x8n_mod_p(e.saturating_sub(s) as u64), a)
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
            Attempt::Bad(_) if at == MAGIC.len() && self.header_error.is_some() => "damaged recording header (metadata lost)",
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
    /// Why the header was unreadable, if it was (its metadata is then the default).
    pub header_error: Option<RecordError>,
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

/// Read a whole recording from memory (a damaged header costs only the header: [`Reader::open`]).
pub fn read_bytes(bytes: &[u8]) -> Result<Loaded, RecordError> {
    let mut r = Reader::open(bytes)?;
    let (mut chunks, mut damage) = (vec![], vec![]);
    for item in r.by_ref() {
        match item {
            Item::Chunk(c) => chunks.push(c),
            Item::Damage(d) => damage.push(d),
        }
    }
    Ok(Loaded { meta: r.meta, chunks, damage, stats: r.stats, header_error: r.header_error })
}

/// Read a whole recording file, with errors that say what to do.
pub fn read_file(path: &Path) -> anyhow::Result<Loaded> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    read_bytes(&bytes).with_context(|| format!("reading the recording {}", path.display()))
}

#[cfg(test)]
mod version_tests {
    use super::*;

    /// "version 0 is newer than this host reads (1)": a version error says what was found and
    /// what is expected.
    #[test]
    fn a_version_error_says_found_and_expected() {
        let old = RecordError::UnsupportedVersion(0).to_string();
        assert!(old.contains("found version 0") && old.contains("expected 1..=1") && !old.contains("newer"), "{old}");
        let new = RecordError::UnsupportedVersion(7).to_string();
        assert!(new.contains("found version 7") && new.contains("expected 1..=1") && new.contains("newer"), "{new}");
    }
}
