//! Files a run writes for people and other tools: PLY splats and points,
//! and the crash-safe way every run file is written.
pub mod mlp;
pub mod ply;

use anyhow::{Context as _, Result};
use std::io::Write;
use std::path::Path;

/// Write `path` so that a crash leaves either the old file or the new one,
/// never a torn one: write `PATH.tmp` beside it through `fill`, flush it to
/// disk, rename it over `path`, then sync the directory so the rename itself
/// survives a power loss.
pub fn atomic_write_with(path: &Path, fill: impl FnOnce(&mut dyn Write) -> Result<()>) -> Result<()> {
    let mut tmp_name = path.file_name().with_context(|| format!("{}: not a file path", path.display()))?.to_os_string();
    tmp_name.push(".tmp");
    let tmp = path.with_file_name(tmp_name);
    let write = || -> Result<()> {
        let mut f = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        fill(&mut f)?;
        f.into_inner().map_err(|e| e.into_error())?.sync_all()?;
        Ok(())
    };
    if let Err(e) = write() {
        let _ = std::fs::remove_file(&tmp);
        return Err(e.context(format!("{}: cannot write", tmp.display())));
    }
    std::fs::rename(&tmp, path).with_context(|| format!("{}: cannot move {} into place", path.display(), tmp.display()))?;
    sync_dir(path)
}

/// [`atomic_write_with`] for bytes in memory.
pub fn atomic_write(path: &Path, bytes: &[u8]) -> Result<()> {
    atomic_write_with(path, |w| Ok(w.write_all(bytes)?))
}

/// Flush the directory entry of `path` (after a rename or create).
pub fn sync_dir(path: &Path) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    // Directories cannot be opened for syncing on every platform; where they
    // can, a failure to sync is an I/O error worth reporting.
    if let Ok(d) = std::fs::File::open(dir) {
        d.sync_all().with_context(|| format!("{}: cannot sync the directory", dir.display()))?;
    }
    Ok(())
}
