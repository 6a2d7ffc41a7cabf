//! defmt log decoding against the firmware ELF (defmt-decoder), for the QEMU board's semihosting
//! stream and for recorded RTT streams.

use anyhow::{Context, Result, bail};

/// Largest firmware ELF read for its defmt table (a header naming `/dev/zero` read until out of
/// memory).
pub const MAX_ELF_BYTES: u64 = 256 << 20;
use defmt_decoder::{DecodeError, StreamDecoder, Table};
use serde::Serialize;

/// One decoded log line.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LogLine {
    pub level: Option<String>,
    pub timestamp: Option<String>,
    pub message: String,
}

impl std::fmt::Display for LogLine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(ts) = &self.timestamp {
            write!(f, "{ts} ")?;
        }
        write!(f, "{:<5} {}", self.level.as_deref().unwrap_or("PRINT").to_uppercase(), self.message)
    }
}

/// The defmt table of a firmware ELF.
pub struct DefmtTable {
    table: Table,
}

impl DefmtTable {
    pub fn from_elf(elf: &[u8]) -> Result<Self> {
        let table = Table::parse(elf)
            .context("reading defmt data from the ELF")?
            .context("the ELF has no defmt data (was it built with defmt and -Tdefmt.x?)")?;
        Ok(Self { table })
    }

    /// The table of the ELF at `path`: a regular file of at most [`MAX_ELF_BYTES`] that starts
    /// like an ELF; every error names the path.
    pub fn from_elf_path(path: &std::path::Path) -> Result<Self> {
        use std::io::Read;
        let md = std::fs::metadata(path).with_context(|| format!("reading the firmware ELF {}", path.display()))?;
        if !md.is_file() {
            bail!("the firmware ELF {} is not a regular file", path.display());
        }
        if md.len() > MAX_ELF_BYTES {
            bail!("the firmware ELF {} has {} bytes, more than the {MAX_ELF_BYTES} read for a defmt table", path.display(), md.len());
        }
        let mut bytes = Vec::new();
        std::fs::File::open(path)
            .and_then(|f| f.take(MAX_ELF_BYTES).read_to_end(&mut bytes))
            .with_context(|| format!("reading the firmware ELF {}", path.display()))?;
        if !bytes.starts_with(b"\x7fELF") {
            bail!("{} is not an ELF file (no ELF magic): give the firmware ELF the defmt logs were built with", path.display());
        }
        Self::from_elf(&bytes).with_context(|| format!("the firmware ELF {}", path.display()))
    }

    pub fn stream(&self) -> LogStream<'_> {
        LogStream { decoder: self.table.new_stream_decoder(), malformed: 0 }
    }
}

/// Incremental decoder of a defmt byte stream.
pub struct LogStream<'t> {
    decoder: Box<dyn StreamDecoder + Send + Sync + 't>,
    /// Malformed frames skipped (the rzcobs encoding lets the decoder resynchronise).
    pub malformed: u64,
}

impl LogStream<'_> {
    pub fn feed(&mut self, bytes: &[u8], mut on_line: impl FnMut(LogLine)) {
        self.decoder.received(bytes);
        loop {
            match self.decoder.decode() {
                Ok(frame) => on_line(LogLine {
                    level: frame.level().map(|l| l.as_str().to_string()),
                    timestamp: frame.display_timestamp().map(|t| t.to_string()),
                    message: frame.display_message().to_string(),
                }),
                Err(DecodeError::UnexpectedEof) => break,
                Err(DecodeError::Malformed) => {
                    self.malformed += 1;
                    // The stream decoder skips the bad frame on the next call; stop if the
                    // buffered data cannot make progress.
                    if self.malformed > 1_000_000 {
                        break;
                    }
                }
            }
        }
    }
}
