//! Checkpoints: everything a run needs to continue bit-identically (the
//! parameters, Adam moments, densification statistics, iteration, generator
//! state and the remaining view order), written atomically (temp file, then
//! rename). Layout: `TGSCKPT1`, u32 header length, JSON header, then the
//! arrays as little-endian f32 in header order.

use super::config::TrainConfig;
use super::rng::Rng;
use super::trainer::Trainer;
use crate::data::Dataset;
use anyhow::{bail, Context as _, Result};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::Path;
use std::sync::Arc;
use tgs_engine::Context;
use tgs_pipelines::HostGaussians;

const MAGIC: &[u8; 8] = b"TGSCKPT1";

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Header {
    pub iteration: u32,
    pub config: TrainConfig,
    /// The dataset the run trained on (as given on the command line).
    pub dataset: String,
    pub rng: u64,
    pub stack: Vec<u32>,
    pub n: u32,
    pub channels: u32,
    pub coeffs: u32,
    pub extent: f32,
    pub arrays: Vec<(String, usize)>,
}

pub fn save(tr: &Trainer, path: &Path, dataset: &str) -> Result<()> {
    let set = &tr.set;
    let n = set.len() as usize;
    let arrays = set.arrays();
    let header = Header {
        iteration: tr.iteration,
        config: tr.cfg.clone(),
        dataset: dataset.to_string(),
        rng: tr.rng.0,
        stack: tr.stack.clone(),
        n: set.len(),
        channels: set.params.channels,
        coeffs: set.params.coeffs,
        extent: tr.extent,
        arrays: arrays.iter().map(|(name, _, w)| (name.clone(), w * n)).collect(),
    };
    let json = serde_json::to_vec(&header)?;
    let tmp = path.with_extension("tmp");
    let write = || -> Result<()> {
        let mut f = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        f.write_all(MAGIC)?;
        f.write_all(&(json.len() as u32).to_le_bytes())?;
        f.write_all(&json)?;
        for (_, buf, w) in &arrays {
            let data = buf.download_range(0, w * n)?;
            f.write_all(bytemuck::cast_slice(&data))?;
        }
        f.into_inner().map_err(|e| e.into_error())?.sync_all()?;
        Ok(())
    };
    write().with_context(|| format!("{}: cannot write the checkpoint", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("{}: cannot move the checkpoint into place", path.display()))
}

/// Read a checkpoint's header and arrays.
pub fn read(path: &Path) -> Result<(Header, Vec<Vec<f32>>)> {
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read the checkpoint", path.display()))?;
    let bad = |what: &str| anyhow::anyhow!("{}: not a tgs checkpoint or corrupt ({what})", path.display());
    if bytes.len() < 12 || &bytes[..8] != MAGIC {
        return Err(bad("magic"));
    }
    let hlen = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
    let hbytes = bytes.get(12..12 + hlen).ok_or_else(|| bad("header length"))?;
    let header: Header = serde_json::from_slice(hbytes).map_err(|e| bad(&format!("header: {e}")))?;
    let mut at = 12 + hlen;
    let mut arrays = Vec::new();
    for (name, len) in &header.arrays {
        let b = bytes.get(at..at + 4 * len).ok_or_else(|| bad(&format!("array {name} truncated")))?;
        arrays.push(b.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect());
        at += 4 * len;
    }
    if at != bytes.len() {
        return Err(bad("trailing bytes"));
    }
    Ok((header, arrays))
}

/// Parameters (the first five arrays) of a checkpoint as a host set.
pub fn gaussians(h: &Header, arrays: &[Vec<f32>]) -> Result<HostGaussians> {
    if arrays.len() < 5 {
        bail!("checkpoint has {} arrays, expected at least 5", arrays.len());
    }
    let g = HostGaussians {
        channels: h.channels,
        coeffs: h.coeffs,
        means: arrays[0].clone(),
        log_scales: arrays[1].clone(),
        quats: arrays[2].clone(),
        opacity: arrays[3].clone(),
        features: arrays[4].clone(),
    };
    g.validate()?;
    Ok(g)
}

/// A trainer restored from a checkpoint on `data` (the same dataset).
pub fn restore(ctx: &Arc<Context>, path: &Path, data: &Dataset) -> Result<Trainer> {
    let (h, arrays) = read(path)?;
    let g = gaussians(&h, &arrays)?;
    let mut tr = Trainer::with_gaussians(ctx, h.config.clone(), data, &g, Rng(h.rng))?;
    let bufs = tr.set.arrays();
    if bufs.len() != arrays.len() {
        bail!("{}: {} arrays, this version of tgs expects {}", path.display(), arrays.len(), bufs.len());
    }
    for ((name, buf, _), (hname, data)) in bufs.iter().zip(h.arrays.iter().map(|a| &a.0).zip(&arrays)) {
        if name != hname {
            bail!("{}: array '{hname}' where '{name}' was expected", path.display());
        }
        if !data.is_empty() {
            buf.upload(data)?;
        }
    }
    tr.iteration = h.iteration;
    tr.stack = h.stack;
    tr.extent = h.extent;
    Ok(tr)
}
