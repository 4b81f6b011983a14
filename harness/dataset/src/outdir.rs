//! Where tgs writes files for people, and the two rules it keeps there:
//! nothing is written into a dataset, and no file is written over unless
//! tgs wrote it. Each output directory keeps a list of the files tgs wrote
//! into it (`.tgs-written`, one name a line, appended before the file is
//! written); an existing file not on that list is never replaced: the
//! command stops with its path.

use anyhow::{bail, Context as _, Result};
use std::collections::BTreeSet;
use std::io::Write;
use std::path::{Component, Path, PathBuf};

/// The list of files tgs wrote into a directory.
pub const MANIFEST: &str = ".tgs-written";

/// A directory that holds a dataset: the Blender layout's transforms or a
/// COLMAP model directory.
pub fn is_dataset_dir(dir: &Path) -> bool {
    ["transforms_train.json", "transforms_test.json", "transforms.json"].iter().any(|f| dir.join(f).is_file())
        || [dir.join("sparse/0"), dir.join("sparse")].iter().any(|d| ["cameras.txt", "cameras.bin"].iter().any(|f| d.join(f).is_file()))
}

/// `path` made absolute with `.` and `..` resolved through the file system
/// as far as it exists (symbolic links followed), the rest appended.
pub fn resolved(path: &Path) -> Result<PathBuf> {
    let abs = if path.is_absolute() { path.to_path_buf() } else { std::env::current_dir().context("the current directory")?.join(path) };
    let mut base = abs.as_path();
    let mut rest: Vec<&std::ffi::OsStr> = Vec::new();
    loop {
        if let Ok(c) = std::fs::canonicalize(base) {
            let mut out = c;
            for part in rest.iter().rev() {
                match Path::new(part).components().next() {
                    Some(Component::ParentDir) => {
                        out.pop();
                    }
                    Some(Component::CurDir) | None => {}
                    _ => out.push(part),
                }
            }
            return Ok(out);
        }
        match (base.parent(), base.file_name()) {
            (Some(p), Some(name)) => {
                rest.push(name);
                base = p;
            }
            (Some(p), None) => {
                // A trailing `..` or `.`.
                rest.push(base.components().next_back().map(|c| c.as_os_str()).unwrap_or_default());
                base = p;
            }
            _ => return Ok(abs),
        }
    }
}

/// Refuse to write into `dir` when it is, or lies inside, a dataset
/// directory (`dataset`, the one the command read, or any directory that
/// holds a dataset's transforms or COLMAP model).
pub fn refuse_dataset(dir: &Path, dataset: Option<&Path>) -> Result<()> {
    let d = resolved(dir)?;
    refuse_system_dir(dir, &d)?;
    if let Some(ds) = dataset {
        let ds = resolved(ds)?;
        if d.starts_with(&ds) {
            bail!("{}: inside the dataset {}; tgs never writes into a dataset: choose an --out outside it", dir.display(), ds.display());
        }
    }
    for a in d.ancestors() {
        if is_dataset_dir(a) {
            bail!(
                "{}: inside the dataset {} (it holds a transforms file or a COLMAP model); tgs never writes into a dataset: choose an --out outside it",
                dir.display(),
                a.display()
            );
        }
    }
    Ok(())
}

/// The folders of the system itself: an output there, or inside the
/// first six, is a slip (`--out /`), never a place for a run.
const SYSTEM_DIRS: [&str; 12] = ["/proc", "/sys", "/dev", "/boot", "/etc", "/usr", "/bin", "/sbin", "/lib", "/lib64", "/var", "/run"];

/// Refuse the root directory, the user's home itself, the system's
/// folders ([`SYSTEM_DIRS`]) and anything inside /proc, /sys, /dev,
/// /boot, /etc or /usr (`resolved` is `dir` through [`resolved`]).
fn refuse_system_dir(dir: &Path, resolved: &Path) -> Result<()> {
    let home = std::env::var_os("HOME").filter(|h| !h.is_empty()).map(PathBuf::from).and_then(|h| std::fs::canonicalize(h).ok());
    let inside = SYSTEM_DIRS[..6].iter().any(|s| resolved.starts_with(s));
    if resolved.parent().is_none() || SYSTEM_DIRS.iter().any(|s| resolved == Path::new(s)) || inside || home.as_deref() == Some(resolved) {
        bail!("{}: a system folder ({}); tgs writes its outputs into a directory of their own: choose an --out such as runs/NAME", dir.display(), resolved.display());
    }
    Ok(())
}

/// An output directory (see the module's rules).
pub struct OutDir {
    dir: PathBuf,
    written: BTreeSet<String>,
    manifest: Option<std::fs::File>,
}

impl OutDir {
    /// Open `dir` (created if missing) for outputs, after [`refuse_dataset`].
    pub fn open(dir: &Path, dataset: Option<&Path>) -> Result<OutDir> {
        refuse_dataset(dir, dataset)?;
        std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the output directory", dir.display()))?;
        let written = match std::fs::read_to_string(dir.join(MANIFEST)) {
            Ok(t) => t.lines().filter(|l| !l.is_empty()).map(String::from).collect(),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => BTreeSet::new(),
            Err(e) => return Err(e).with_context(|| format!("{}: cannot read", dir.join(MANIFEST).display())),
        };
        Ok(OutDir { dir: dir.to_path_buf(), written, manifest: None })
    }

    pub fn path(&self) -> &Path {
        &self.dir
    }

    /// Whether `name` may be written: it does not exist, or tgs wrote it.
    pub fn check(&self, name: &str) -> Result<()> {
        let p = self.dir.join(name);
        if p.symlink_metadata().is_ok() && !self.written.contains(name) {
            bail!(
                "{}: exists and was not written by tgs (it is not in {}); tgs never writes over files it did not create: move it away or choose another --out",
                p.display(),
                self.dir.join(MANIFEST).display()
            );
        }
        Ok(())
    }

    /// The path to write `name` (a file directly in the directory) to,
    /// recorded as tgs's before it is written; refused per [`Self::check`].
    pub fn file(&mut self, name: &str) -> Result<PathBuf> {
        if name.is_empty() || name.contains('/') || name.contains('\\') || name == MANIFEST || name == "." || name == ".." {
            bail!("'{name}' is not a plain file name for {}", self.dir.display());
        }
        self.check(name)?;
        if self.written.insert(name.to_string()) {
            if self.manifest.is_none() {
                let m = self.dir.join(MANIFEST);
                self.manifest = Some(std::fs::OpenOptions::new().create(true).append(true).open(&m).with_context(|| format!("{}: cannot write", m.display()))?);
            }
            let f = self.manifest.as_mut().unwrap();
            writeln!(f, "{name}").with_context(|| format!("{}: cannot write", self.dir.join(MANIFEST).display()))?;
        }
        Ok(self.dir.join(name))
    }
}
