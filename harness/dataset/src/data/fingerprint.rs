//! A dataset's fingerprint: every file its load read (the transforms or
//! COLMAP model, so every pose and the file list; every image, normal map,
//! mask and point cloud), each with its size and the CRC-32 of its bytes.
//! A checkpoint records it, so that `--resume`, `eval` and `render` refuse
//! a dataset that changed under the run and say what changed; a sweep keys
//! its rows by it.

use anyhow::{Context as _, Result};
use serde::{Deserialize, Serialize};
use std::io::Read;
use std::path::{Path, PathBuf};

#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileEntry {
    /// Relative to the dataset root ('/'-separated), or absolute when outside it.
    pub path: String,
    pub size: u64,
    pub crc32: u32,
}

#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Fingerprint {
    /// Sorted by path, each file once.
    pub files: Vec<FileEntry>,
}

/// The CRC-32 and length of a file's bytes, read in 1 MiB blocks.
pub fn crc32_file(path: &Path) -> Result<(u64, u32)> {
    let mut f = std::fs::File::open(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let mut h = crc32fast::Hasher::new();
    let mut buf = vec![0u8; 1 << 20];
    let mut size = 0u64;
    loop {
        let n = f.read(&mut buf).with_context(|| format!("{}: cannot read", path.display()))?;
        if n == 0 {
            break;
        }
        size += n as u64;
        h.update(&buf[..n]);
    }
    Ok((size, h.finalize()))
}

/// FNV-1a's 64-bit offset basis: the hash of nothing.
pub const FNV_START: u64 = 0xcbf2_9ce4_8422_2325;

/// 64-bit FNV-1a of `bytes`, continuing from `h`.
pub fn fnv1a(h: u64, bytes: &[u8]) -> u64 {
    bytes.iter().fold(h, |h, b| (h ^ *b as u64).wrapping_mul(0x0100_0000_01b3))
}

impl Fingerprint {
    /// Hash `files` (paths as the loader opened them) under `root`.
    pub fn of(root: &Path, files: &[PathBuf]) -> Result<Fingerprint> {
        let mut entries: Vec<FileEntry> = Vec::with_capacity(files.len());
        for p in files {
            let (size, crc32) = crc32_file(p)?;
            let rel = p.strip_prefix(root).unwrap_or(p);
            let path = rel.components().map(|c| c.as_os_str().to_string_lossy()).collect::<Vec<_>>().join("/");
            entries.push(FileEntry { path, size, crc32 });
        }
        entries.sort_by(|a, b| a.path.cmp(&b.path));
        entries.dedup_by(|a, b| a.path == b.path);
        Ok(Fingerprint { files: entries })
    }

    /// One number for the whole set (FNV-1a over paths, sizes and CRCs):
    /// what a sweep row is keyed by.
    pub fn digest(&self) -> u64 {
        self.files.iter().fold(FNV_START, |h, f| {
            let h = fnv1a(fnv1a(h, f.path.as_bytes()), &[0]);
            fnv1a(fnv1a(h, &f.size.to_le_bytes()), &f.crc32.to_le_bytes())
        })
    }

    /// What changed from `self` (as recorded) to `now`, in a sentence
    /// naming up to three files of each kind; None when nothing did.
    pub fn changes(&self, now: &Fingerprint) -> Option<String> {
        let names = |v: &[&str]| {
            let mut s = v.iter().take(3).map(|p| p.to_string()).collect::<Vec<_>>().join(", ");
            if v.len() > 3 {
                s.push_str(&format!(" and {} more", v.len() - 3));
            }
            s
        };
        let find = |set: &Fingerprint, p: &str| set.files.binary_search_by(|f| f.path.as_str().cmp(p)).ok().map(|i| set.files[i].clone());
        let removed: Vec<&str> = self.files.iter().filter(|f| find(now, &f.path).is_none()).map(|f| f.path.as_str()).collect();
        let added: Vec<&str> = now.files.iter().filter(|f| find(self, &f.path).is_none()).map(|f| f.path.as_str()).collect();
        let changed: Vec<&str> = self.files.iter().filter(|f| find(now, &f.path).is_some_and(|g| g != **f)).map(|f| f.path.as_str()).collect();
        let mut parts = Vec::new();
        if !changed.is_empty() {
            parts.push(format!("{} file(s) changed ({})", changed.len(), names(&changed)));
        }
        if !removed.is_empty() {
            parts.push(format!("{} file(s) no longer used or gone ({})", removed.len(), names(&removed)));
        }
        if !added.is_empty() {
            parts.push(format!("{} file(s) new ({})", added.len(), names(&added)));
        }
        (!parts.is_empty()).then(|| parts.join("; "))
    }
}
