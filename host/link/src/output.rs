//! Output files that a failed run never leaves half-written and never uses to destroy an old
//! file or its own input.
//!
//! [`AtomicFile`] writes to a temporary name beside the target (`.NAME.tmp-PID-N`, same
//! directory, so the final rename stays on one file system and is atomic) and renames it over
//! the target only on [`AtomicFile::commit`]; dropped without a commit (an error, a panic
//! unwinding), it removes the temporary file and the target is untouched. A live recording,
//! which must survive Ctrl-C, calls [`AtomicFile::publish`] once the first data has arrived:
//! the file takes the target's name and the writes go on into it.
//!
//! [`refuse_input_as_output`] is the one check that an output path does not name one of the
//! run's inputs (`export r.snrec --mcap r.snrec`, `run --record scenario.json`), by file
//! identity, so `./a` and `a` or a symbolic link are caught too.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use anyhow::{Context, Result, bail};

/// A file written under a temporary name and renamed to its target on success.
#[derive(Debug)]
pub struct AtomicFile {
    target: PathBuf,
    tmp: PathBuf,
    file: File,
    published: bool,
}

static COUNTER: AtomicU64 = AtomicU64::new(0);

impl AtomicFile {
    /// Create the temporary file beside `target` (the target itself is not touched yet).
    pub fn create(target: &Path) -> Result<Self> {
        let name = target.file_name().with_context(|| format!("{} is not a file name", target.display()))?;
        if target.is_dir() {
            bail!("{} is a directory, not a file to write", target.display());
        }
        let dir = match target.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let tmp = dir.join(format!(".{}.tmp-{}-{n}", name.to_string_lossy(), std::process::id()));
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
            .with_context(|| format!("creating {} (check the directory {} exists and is writable)", target.display(), dir.display()))?;
        Ok(Self { target: target.to_path_buf(), tmp, file, published: false })
    }

    /// The path the file will have (has, once published).
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Give the file its target's name now, replacing any old file, and keep writing into it
    /// (the open handle follows the rename). Idempotent.
    pub fn publish(&mut self) -> Result<()> {
        if !self.published {
            std::fs::rename(&self.tmp, &self.target)
                .with_context(|| format!("moving the new file into place as {}", self.target.display()))?;
            self.published = true;
        }
        Ok(())
    }

    /// Flush, sync to disk and publish: after this the target holds the complete file.
    pub fn commit(mut self) -> Result<PathBuf> {
        self.file.flush().with_context(|| format!("writing {}", self.target.display()))?;
        self.file.sync_all().with_context(|| format!("writing {} (syncing to disk)", self.target.display()))?;
        self.publish()?;
        Ok(self.target.clone())
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.file.write(buf)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

impl std::io::Seek for AtomicFile {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        self.file.seek(pos)
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if !self.published {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// Write `bytes` to `target` atomically (temporary file, then rename).
pub fn write_atomic(target: &Path, bytes: &[u8]) -> Result<()> {
    let mut f = AtomicFile::create(target)?;
    f.write_all(bytes).with_context(|| format!("writing {}", target.display()))?;
    f.commit()?;
    Ok(())
}

/// Whether two paths name the same existing file (same device and inode on Unix).
pub fn same_file(a: &Path, b: &Path) -> bool {
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        #[cfg(unix)]
        (Ok(ma), Ok(mb)) => {
            use std::os::unix::fs::MetadataExt;
            ma.dev() == mb.dev() && ma.ino() == mb.ino()
        }
        #[cfg(not(unix))]
        (Ok(_), Ok(_)) => matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y),
        _ => false,
    }
}

/// Refuses an output that names one of the inputs: `what` names the output's flag.
pub fn refuse_input_as_output(what: &str, output: &Path, inputs: &[&Path]) -> Result<()> {
    for input in inputs {
        if same_file(output, input) {
            bail!("{what} {} is also an input of this run: writing it would destroy the input; choose another path", output.display());
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_uncommitted_file_leaves_the_old_target_intact_and_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.bin");
        std::fs::write(&p, b"old").unwrap();
        {
            let mut f = AtomicFile::create(&p).unwrap();
            f.write_all(b"half of the new").unwrap();
            assert_eq!(std::fs::read(&p).unwrap(), b"old");
        }
        assert_eq!(std::fs::read(&p).unwrap(), b"old");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "a temporary file was left behind");
        write_atomic(&p, b"new").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"new");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn a_published_file_keeps_its_writes() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("rec");
        let mut f = AtomicFile::create(&p).unwrap();
        f.write_all(b"a").unwrap();
        f.publish().unwrap();
        f.write_all(b"b").unwrap();
        drop(f);
        assert_eq!(std::fs::read(&p).unwrap(), b"ab");
    }

    #[test]
    fn an_input_is_refused_as_output_by_identity() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a");
        std::fs::write(&a, b"x").unwrap();
        let dotted = dir.path().join(".").join("a");
        let e = refuse_input_as_output("--out", &dotted, &[&a]).unwrap_err().to_string();
        assert!(e.contains("--out") && e.contains("also an input"), "{e}");
        assert!(refuse_input_as_output("--out", &dir.path().join("b"), &[&a]).is_ok());
        assert!(AtomicFile::create(dir.path()).is_err());
    }
}
