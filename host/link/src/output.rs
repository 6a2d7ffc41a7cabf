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
//! A target that exists and is not a regular file (`/dev/null`, `/dev/full`, a FIFO, a
//! terminal, any device node) is written in place: renaming a file over it would replace the
//! device with a regular file. Every write error names the target (`/dev/full: No space left on
//! device`), so a full device is an error, never a silent success. A symbolic link to a file
//! stays a link: the file it points to is replaced (`/dev/stdout` redirected to a file is
//! never renamed over).
//!
//! [`refuse_input_as_output`] is the one check that an output path does not name one of the
//! run's inputs (`export r.snrec --mcap r.snrec`, `run --record scenario.json`), by file
//! identity, so `./a` and `a` or a symbolic link are caught too. [`check_outputs`] adds that
//! no two outputs of a command are the same file (`run --record X --truth X`, also through
//! `..`, a directory or a symbolic link, and for files that do not exist yet), and
//! [`refuse_dir_holding_input`] that an output directory does not hold an input.

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
    /// Where the new file is renamed to: the target, or the file a symbolic link at the target
    /// points to (the link stays a link; `/dev/stdout` is never replaced).
    rename_to: PathBuf,
    /// The target is not a regular file (a device, a FIFO): written in place, never renamed.
    in_place: bool,
}

static COUNTER: AtomicU64 = AtomicU64::new(0);

impl AtomicFile {
    /// Create the temporary file beside `target` (the target itself is not touched yet), or,
    /// when `target` is a device or a FIFO, open it for writing in place.
    pub fn create(target: &Path) -> Result<Self> {
        if target.is_dir() {
            bail!("{} is a directory, not a file to write", target.display());
        }
        if is_special(target) {
            let file = std::fs::OpenOptions::new()
                .write(true)
                .open(target)
                .with_context(|| format!("opening {} (not a regular file: written in place)", target.display()))?;
            let t = target.to_path_buf();
            return Ok(Self { target: t.clone(), tmp: t.clone(), file, published: true, rename_to: t, in_place: true });
        }
        // A symbolic link to a file: the file is replaced, the link kept.
        let is_link = std::fs::symlink_metadata(target).is_ok_and(|m| m.file_type().is_symlink());
        let rename_to = match target.canonicalize() {
            Ok(real) if is_link => real,
            _ => target.to_path_buf(),
        };
        let name = rename_to.file_name().with_context(|| format!("{} is not a file name", target.display()))?;
        let dir = match rename_to.parent() {
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
        Ok(Self { target: target.to_path_buf(), tmp, file, published: false, rename_to, in_place: false })
    }

    /// Whether the target is a device or a FIFO written in place (no temporary file).
    pub fn in_place(&self) -> bool {
        self.in_place
    }

    /// The path the file will have (has, once published).
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Give the file its target's name now, replacing any old file, and keep writing into it
    /// (the open handle follows the rename). Idempotent.
    pub fn publish(&mut self) -> Result<()> {
        if !self.published {
            std::fs::rename(&self.tmp, &self.rename_to)
                .with_context(|| format!("moving the new file into place as {}", self.target.display()))?;
            self.published = true;
        }
        Ok(())
    }

    /// Flush, sync to disk and publish: after this the target holds the complete file.
    pub fn commit(mut self) -> Result<PathBuf> {
        self.file.flush().with_context(|| format!("writing {}", self.target.display()))?;
        if !self.in_place {
            self.file.sync_all().with_context(|| format!("writing {} (syncing to disk)", self.target.display()))?;
        }
        self.publish()?;
        Ok(self.target.clone())
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.file.write(buf).map_err(|e| named(&self.target, e))
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush().map_err(|e| named(&self.target, e))
    }
}

/// The error `e` with the path it happened on (`/dev/full: No space left on device (os error 28)`).
fn named(path: &Path, e: std::io::Error) -> std::io::Error {
    std::io::Error::new(e.kind(), format!("{}: {e}", path.display()))
}

/// Whether `path` exists and is neither a regular file nor a directory (a device, a FIFO, a
/// socket), following symbolic links.
pub fn is_special(path: &Path) -> bool {
    std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir())
}

/// Whether `path` is a character device (`/dev/null`): the one kind two outputs may share.
fn is_char_device(path: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        std::fs::metadata(path).is_ok_and(|m| m.file_type().is_char_device())
    }
    #[cfg(not(unix))]
    {
        let _ = path;
        false
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

/// Write `bytes` to `target` atomically (temporary file, then rename; a device in place).
pub fn write_atomic(target: impl AsRef<Path>, bytes: impl AsRef<[u8]>) -> Result<()> {
    let mut f = AtomicFile::create(target.as_ref())?;
    f.write_all(bytes.as_ref())?;
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

/// Where `path` points, as an absolute path without `.`, `..` or symbolic links, also for a
/// file that does not exist yet (its directory is resolved, or the path normalized lexically).
pub fn resolved(path: &Path) -> PathBuf {
    if let Ok(p) = path.canonicalize() {
        return p;
    }
    let abs = if path.is_absolute() { path.to_path_buf() } else { std::env::current_dir().unwrap_or_default().join(path) };
    let mut out = PathBuf::new();
    for c in abs.components() {
        match c {
            std::path::Component::ParentDir => {
                out.pop();
            }
            std::path::Component::CurDir => {}
            other => out.push(other),
        }
    }
    // The longest existing prefix resolved (symbolic links in the directories).
    let mut rest = Vec::new();
    let mut head = out.clone();
    loop {
        if let Ok(c) = head.canonicalize() {
            let mut p = c;
            for r in rest.iter().rev() {
                p.push(r);
            }
            return p;
        }
        match (head.file_name().map(|n| n.to_os_string()), head.parent().map(Path::to_path_buf)) {
            (Some(n), Some(parent)) => {
                rest.push(n);
                head = parent;
            }
            _ => return out,
        }
    }
}

/// Whether two output paths would write the same file (by identity when both exist, else by
/// their resolved paths). Character devices (`/dev/null`) may be shared.
pub fn same_target(a: &Path, b: &Path) -> bool {
    if is_char_device(a) && is_char_device(b) {
        return false;
    }
    same_file(a, b) || resolved(a) == resolved(b)
}

/// The outputs of one command (`(flag, path)`) against its inputs and each other: no output
/// may be an input, and no two outputs the same file. Call before reading anything.
pub fn check_outputs(outputs: &[(&str, &Path)], inputs: &[&Path]) -> Result<()> {
    for (i, (flag, out)) in outputs.iter().enumerate() {
        refuse_input_as_output(flag, out, inputs)?;
        for (flag2, out2) in &outputs[i + 1..] {
            if same_target(out, out2) {
                bail!(
                    "{flag} {} and {flag2} {} are the same file: one output would overwrite the other; choose two paths",
                    out.display(),
                    out2.display()
                );
            }
        }
    }
    Ok(())
}

/// Refuses an output directory (`what` names its flag) that holds one of the inputs, directly
/// or below: the command writes files there and could overwrite the input. Call before reading.
pub fn refuse_dir_holding_input(what: &str, dir: &Path, inputs: &[&Path]) -> Result<()> {
    let d = resolved(dir);
    for input in inputs {
        let i = resolved(input);
        if i != d && i.starts_with(&d) {
            bail!(
                "{what} {} holds the input {}: the command writes its files there and could overwrite it; choose another directory",
                dir.display(),
                input.display()
            );
        }
        if i == d {
            bail!("{what} {} is also an input of this run; choose another directory", dir.display());
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

    /// A character device `c 1 minor` (3 = null, 7 = full) made with `mknod` in `dir`, or, where
    /// this process may not make nodes, the system's own (`/dev/null`, `/dev/full`).
    pub(crate) fn device(dir: &Path, minor: u32) -> PathBuf {
        let p = dir.join(format!("dev{minor}"));
        let made = std::process::Command::new("mknod").arg(&p).args(["c", "1", &minor.to_string()]).status().is_ok_and(|s| s.success());
        if made { p } else { PathBuf::from(if minor == 3 { "/dev/null" } else { "/dev/full" }) }
    }

    fn is_char_dev(p: &Path) -> bool {
        use std::os::unix::fs::FileTypeExt;
        std::fs::symlink_metadata(p).unwrap().file_type().is_char_device()
    }

    #[test]
    fn a_device_output_is_written_in_place_not_renamed_over() {
        let dir = tempfile::tempdir().unwrap();
        let null = device(dir.path(), 3);
        write_atomic(&null, b"into the void").unwrap();
        assert!(is_char_dev(&null), "{} was replaced", null.display());
        let mut f = AtomicFile::create(&null).unwrap();
        assert!(f.in_place());
        f.write_all(b"more").unwrap();
        f.publish().unwrap();
        f.commit().unwrap();
        assert!(is_char_dev(&null));
        // No temporary file was made beside a device made here.
        if null.starts_with(dir.path()) {
            assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        }
    }

    #[test]
    fn a_fifo_output_is_written_in_place_for_its_reader() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("pipe");
        assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
        let f2 = fifo.clone();
        let reader = std::thread::spawn(move || std::fs::read(&f2).unwrap());
        write_atomic(&fifo, b"through the pipe").unwrap();
        assert_eq!(reader.join().unwrap(), b"through the pipe");
        use std::os::unix::fs::FileTypeExt;
        assert!(std::fs::symlink_metadata(&fifo).unwrap().file_type().is_fifo());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn a_full_device_is_an_error_naming_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let full = device(dir.path(), 7);
        let e = format!("{:#}", write_atomic(&full, b"data").unwrap_err());
        assert!(e.contains(&full.display().to_string()) && e.contains("No space left"), "{e}");
        assert!(is_char_dev(&full));
    }

    #[test]
    fn a_symbolic_link_stays_a_link_and_its_file_gets_the_new_contents() {
        let dir = tempfile::tempdir().unwrap();
        let real = dir.path().join("real.csv");
        std::fs::write(&real, b"old").unwrap();
        let link = dir.path().join("link.csv");
        std::os::unix::fs::symlink(&real, &link).unwrap();
        write_atomic(&link, b"new").unwrap();
        assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
        assert_eq!(std::fs::read(&real).unwrap(), b"new");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }

    #[test]
    fn two_outputs_that_are_one_file_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::create_dir(d.join("sub")).unwrap();
        std::os::unix::fs::symlink(d.join("sub"), d.join("link")).unwrap();
        let a = d.join("x.csv");
        // Not existing yet, through `..`, through a symbolic link to the directory.
        for b in [d.join("x.csv"), d.join("sub").join("..").join("x.csv"), d.join(".").join("x.csv")] {
            let e = check_outputs(&[("--out", &a), ("--decisions", &b)], &[]).unwrap_err().to_string();
            assert!(e.contains("--out") && e.contains("--decisions") && e.contains("same file"), "{e}");
        }
        let e = check_outputs(&[("--png", &d.join("sub/p")), ("--table", &d.join("link/p"))], &[]).unwrap_err().to_string();
        assert!(e.contains("same file"), "{e}");
        std::fs::write(&a, b"x").unwrap();
        assert!(check_outputs(&[("--out", &a), ("--truth", &d.join("sub/../x.csv"))], &[]).is_err());
        assert!(check_outputs(&[("--out", &a), ("--truth", &d.join("y.csv"))], &[]).is_ok());
        // The input check comes with it.
        assert!(check_outputs(&[("--out", &d.join("y.csv")), ("--truth", &a)], &[&a]).unwrap_err().to_string().contains("--truth"));
        // Two outputs to the null device are fine.
        let null = device(d, 3);
        assert!(check_outputs(&[("--out", &null), ("--truth", &null)], &[]).is_ok());
        assert_eq!(std::fs::read(&a).unwrap(), b"x");
    }

    #[test]
    fn an_output_directory_holding_an_input_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let input = d.join("dive.snrec");
        std::fs::write(&input, b"rec").unwrap();
        let e = refuse_dir_holding_input("--out", d, &[&input]).unwrap_err().to_string();
        assert!(e.contains("--out") && e.contains("holds the input") && e.contains("dive.snrec"), "{e}");
        assert!(refuse_dir_holding_input("--out", &d.join("new").join(".."), &[&input]).is_err());
        std::fs::create_dir(d.join("deep")).unwrap();
        let deep = d.join("deep/nav.csv");
        std::fs::write(&deep, b"n").unwrap();
        assert!(refuse_dir_holding_input("--out", d, &[&deep]).is_err());
        assert!(refuse_dir_holding_input("--out", &d.join("deep"), &[&input]).is_ok());
        assert!(refuse_dir_holding_input("--out", &d.join("other"), &[&input]).is_ok());
        assert_eq!(std::fs::read(&input).unwrap(), b"rec");
    }
}
