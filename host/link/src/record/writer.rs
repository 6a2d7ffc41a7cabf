//! Writing a recording: the header once, then one unbuffered `write_all` per chunk.

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result, bail};
use subnav_wire::frame::FRAME_CRC;

use super::{MAGIC, MAX_CHUNK, Meta, SYNC, Stream, VERSION};

/// Writes chunks to any `Write` (a `File` for recordings: each chunk reaches the OS at once).
pub struct Writer<W: Write> {
    out: W,
    buf: Vec<u8>,
    /// Chunks and data bytes written, per stream (index = `Stream::code`).
    pub chunks: [u64; 4],
    pub bytes: [u64; 4],
}

impl Writer<std::fs::File> {
    /// Create (or truncate) a recording file.
    pub fn create(path: &Path, meta: &Meta) -> Result<Self> {
        let f = std::fs::File::create(path)
            .with_context(|| format!("creating the recording {} (check the directory exists and is writable)", path.display()))?;
        Writer::new(f, meta)
    }
}

impl Writer<crate::output::AtomicFile> {
    /// Create a recording under a temporary name beside `path`: an old file at `path` is
    /// replaced only when [`Writer::publish`] (first data arrived) or the file's
    /// [`AtomicFile::commit`](crate::output::AtomicFile::commit) is called; a run that fails
    /// before leaves it untouched and no temporary file behind.
    pub fn create_atomic(path: &Path, meta: &Meta) -> Result<Self> {
        let f = crate::output::AtomicFile::create(path).with_context(|| format!("creating the recording {}", path.display()))?;
        Writer::new(f, meta)
    }

    /// Give the recording its name now (see [`crate::output::AtomicFile::publish`]).
    pub fn publish(&mut self) -> Result<()> {
        self.out.publish()
    }
}

impl<W: Write> Writer<W> {
    /// Write the header.
    pub fn new(mut out: W, meta: &Meta) -> Result<Self> {
        let json = serde_json::to_vec(meta)?;
        let mut h = Vec::with_capacity(json.len() + 18);
        h.extend_from_slice(&MAGIC);
        h.extend_from_slice(&VERSION.to_le_bytes());
        h.extend_from_slice(&(json.len() as u32).to_le_bytes());
        h.extend_from_slice(&json);
        let crc = FRAME_CRC.checksum(&h[MAGIC.len()..]);
        h.extend_from_slice(&crc.to_le_bytes());
        out.write_all(&h).context("writing the recording header")?;
        Ok(Self { out, buf: Vec::new(), chunks: [0; 4], bytes: [0; 4] })
    }

    /// Append one chunk. Data longer than [`MAX_CHUNK`] is split into several chunks.
    pub fn chunk(&mut self, stream: Stream, t_host_us: u64, data: &[u8]) -> Result<()> {
        if data.is_empty() {
            return Ok(());
        }
        for part in data.chunks(MAX_CHUNK) {
            self.buf.clear();
            self.buf.extend_from_slice(&SYNC);
            self.buf.push(stream.code());
            self.buf.extend_from_slice(&t_host_us.to_le_bytes());
            self.buf.extend_from_slice(&(part.len() as u32).to_le_bytes());
            self.buf.extend_from_slice(part);
            let crc = FRAME_CRC.checksum(&self.buf[SYNC.len()..]);
            self.buf.extend_from_slice(&crc.to_le_bytes());
            if let Err(e) = self.out.write_all(&self.buf) {
                bail!("writing the recording failed ({e}); chunks written so far are readable");
            }
            let i = usize::from(stream.code());
            self.chunks[i] += 1;
            self.bytes[i] += part.len() as u64;
        }
        Ok(())
    }

    /// Append a chunk stamped with the current host time.
    pub fn chunk_now(&mut self, stream: Stream, data: &[u8]) -> Result<()> {
        self.chunk(stream, super::now_unix_us(), data)
    }

    pub fn flush(&mut self) -> Result<()> {
        self.out.flush().context("flushing the recording")
    }

    pub fn into_inner(self) -> W {
        self.out
    }
}
