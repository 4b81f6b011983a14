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
use std::path::Path;
use std::sync::Arc;
use tgs_engine::Context;
use tgs_pipelines::{HostGaussians, TrainableSet};

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
    let set = &tr.scattering.set;
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
    crate::export::atomic_write_with(path, |f| {
        f.write_all(MAGIC)?;
        f.write_all(&(json.len() as u32).to_le_bytes())?;
        f.write_all(&json)?;
        for (_, buf, w) in &arrays {
            let data = buf.download_range(0, w * n)?;
            f.write_all(bytemuck::cast_slice(&data))?;
        }
        Ok(())
    })
    .context("writing the checkpoint")
}

/// Read a checkpoint's header and arrays.
pub fn read(path: &Path) -> Result<(Header, Vec<Vec<f32>>)> {
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read the checkpoint", path.display()))?;
    let bad = |what: &str| anyhow::anyhow!("{}: not a tgs checkpoint or corrupt ({what})", path.display());
    if bytes.len() < 12 || &bytes[..8] != MAGIC {
        return Err(bad("magic"));
    }
    let hlen = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
    let hbytes = 12usize.checked_add(hlen).and_then(|end| bytes.get(12..end)).ok_or_else(|| bad("header length"))?;
    let header: Header = serde_json::from_slice(hbytes).map_err(|e| bad(&format!("header: {e}")))?;
    let mut at = 12 + hlen;
    let mut arrays = Vec::new();
    for (name, len) in &header.arrays {
        let b = len.checked_mul(4).and_then(|n| at.checked_add(n)).and_then(|end| bytes.get(at..end)).ok_or_else(|| bad(&format!("array {name} of {len} values is truncated")))?;
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

/// A trainer restored from the checkpoint `path` on `data` (the same
/// dataset), given its header and arrays as [`read`] returned them (the
/// caller needs the header first, to find the dataset). Every array must
/// have exactly the length its header's Gaussian count implies.
pub fn restore(ctx: &Arc<Context>, path: &Path, (h, arrays): (Header, Vec<Vec<f32>>), data: &Dataset) -> Result<Trainer> {
    let bad = |what: String| anyhow::anyhow!("{}: corrupt checkpoint ({what})", path.display());
    h.config.validate().map_err(|e| bad(format!("settings: {e:#}")))?;
    let k = (h.config.sh_degree + 1).pow(2);
    if h.channels != 3 || h.coeffs != k {
        return Err(bad(format!("{} channels x {} coefficients; sh_degree {} needs 3 x {k}", h.channels, h.coeffs, h.config.sh_degree)));
    }
    if !(h.extent.is_finite() && h.extent > 0.0) {
        return Err(bad(format!("scene extent {}", h.extent)));
    }
    if let Some(v) = h.stack.iter().find(|&&v| v as usize >= data.train.len()) {
        return Err(bad(format!("view {v} in the view order, the dataset has {} training views", data.train.len())));
    }
    let layout = TrainableSet::layout((h.channels * h.coeffs) as usize);
    if layout.len() != arrays.len() {
        bail!("{}: {} arrays, this version of tgs expects {}", path.display(), arrays.len(), layout.len());
    }
    for ((name, width), (hname, data)) in layout.iter().zip(h.arrays.iter().map(|a| &a.0).zip(&arrays)) {
        if name != hname {
            return Err(bad(format!("array '{hname}' where '{name}' was expected")));
        }
        let want = (h.n as usize).checked_mul(*width).ok_or_else(|| bad(format!("{} Gaussians", h.n)))?;
        if data.len() != want {
            return Err(bad(format!("array '{name}' has {} values, {} Gaussians need {want}", data.len(), h.n)));
        }
        if data.iter().any(|v| !v.is_finite()) {
            return Err(bad(format!("array '{name}' holds NaN or infinite values")));
        }
    }
    let g = gaussians(&h, &arrays).map_err(|e| bad(format!("{e:#}")))?;
    let mut tr = Trainer::with_gaussians(ctx, h.config.clone(), data, &g, Rng(h.rng))?;
    let bufs = tr.scattering.set.arrays();
    for ((_, buf, _), data) in bufs.iter().zip(&arrays) {
        if !data.is_empty() {
            buf.upload(data)?;
        }
    }
    tr.iteration = h.iteration;
    tr.stack = h.stack;
    tr.extent = h.extent;
    Ok(tr)
}
