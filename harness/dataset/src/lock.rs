//! One writer per output directory: an advisory lock (`flock`) on the
//! directory's `.tgs-lock`, held for as long as a command writes there.
//! The file names its holder (command, PID, host, start time) so that a
//! second writer is refused with who holds it; the kernel releases the
//! lock when the holder exits however it ends, and a lock file still
//! naming a holder that is gone is taken over with a message. Readers
//! (eval without --out, render into another directory) take no lock.

use anyhow::{bail, Context as _, Result};
use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::Path;

/// The lock file in a locked directory.
pub const LOCK_FILE: &str = ".tgs-lock";

/// A held directory lock; released (and its holder line cleared) on drop.
#[derive(Debug)]
pub struct DirLock {
    file: File,
}

impl Drop for DirLock {
    fn drop(&mut self) {
        // An empty file says "released cleanly"; the lock itself goes with the descriptor.
        let _ = self.file.set_len(0);
    }
}

/// This machine's host name (for the holder line).
fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .ok()
        .filter(|s| !s.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok())
        .unwrap_or_else(|| "unknown host".into())
}

/// Lock `dir` (which must exist) for `command` ("tgs train", ...). A
/// directory another process holds is refused at once, naming it. With
/// `quiet` false, taking over a lock whose holder ended without
/// releasing it (killed, crashed, its machine gone) is said on stderr.
pub fn lock_dir(dir: &Path, command: &str, quiet: bool) -> Result<DirLock> {
    let path = dir.join(LOCK_FILE);
    if std::fs::symlink_metadata(&path).is_ok_and(|m| !m.file_type().is_file()) {
        bail!("{}: exists and is not a regular file (tgs keeps its lock there); move it away", path.display());
    }
    let mut file = OpenOptions::new().read(true).write(true).create(true).truncate(false).open(&path).with_context(|| format!("{}: cannot open the lock file", path.display()))?;
    let mut holder = String::new();
    match file.try_lock() {
        Ok(()) => {}
        Err(TryLockError::WouldBlock) => {
            let _ = file.read_to_string(&mut holder);
            let who = holder.trim();
            let who = if who.is_empty() { "another process (it has not written its name yet)".to_string() } else { who.to_string() };
            bail!("{}: in use by {who}; one command writes a run directory at a time: wait for it to end, stop it, or choose another --out", dir.display());
        }
        // A file system without locks (some FUSE mounts; Linux ENOLCK 37,
        // ENOSYS 38, EOPNOTSUPP 95): said, not fatal.
        Err(TryLockError::Error(e)) if matches!(e.raw_os_error(), Some(37 | 38 | 95)) || e.kind() == std::io::ErrorKind::Unsupported => {
            eprintln!("tgs: warning: {}: this file system cannot lock ({e}); a second command writing here would not be refused", path.display());
        }
        Err(TryLockError::Error(e)) => return Err(e).with_context(|| format!("{}: cannot lock", path.display())),
    }
    let _ = file.read_to_string(&mut holder);
    if !holder.trim().is_empty() && !quiet {
        eprintln!("tgs: {}: taking over the lock of {}, which ended without releasing it", dir.display(), holder.trim());
    }
    let since = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
    let line = format!("{command} (PID {} on {}, since Unix time {since})\n", std::process::id(), host_name());
    file.set_len(0)
        .and_then(|_| file.seek(SeekFrom::Start(0)))
        .and_then(|_| file.write_all(line.as_bytes()))
        .and_then(|_| file.flush())
        .with_context(|| format!("{}: cannot write", path.display()))?;
    Ok(DirLock { file })
}

/// Create `dir` (and its parents) and lock it as [`lock_dir`] does.
pub fn create_and_lock(dir: &Path, command: &str, quiet: bool) -> Result<DirLock> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the output directory", dir.display()))?;
    lock_dir(dir, command, quiet)
}

/// Lock for a command that reads the run directory `run` and writes into
/// `out` (which exists): the run itself when `out` lies inside it (its
/// renders, its meshes: the run's writer would write there too), else
/// `out`.
pub fn lock_output(out: &Path, run: &Path, command: &str, quiet: bool) -> Result<DirLock> {
    let o = crate::outdir::resolved(out)?;
    let r = crate::outdir::resolved(run)?;
    lock_dir(if o.starts_with(&r) && r.is_dir() { run } else { out }, command, quiet)
}
