//! Checkpoints: everything a run needs to continue bit-identically (the
//! parameters, Adam moments, densification statistics, iteration, generator
//! state and the remaining view order), written atomically (temp file, then
//! rename). Layout: `TGSCKPT2`, u32 header length, JSON header, the
//! header's CRC-32 (u32), then each array as little-endian f32 in header
//! order followed by its CRC-32. A checksum that does not match is refused,
//! naming the header or the array. The header records the dataset's
//! fingerprint and the run's identity: a checkpoint restored on a dataset
//! that changed is refused, saying what changed. (`TGSCKPT1` files, from
//! before the checksums, are still read.)

use super::config::TrainConfig;
use super::trainer::Trainer;
use crate::data::fingerprint::Fingerprint;
use crate::data::Dataset;
use anyhow::{bail, Context as _, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;
use tgs_engine::{Buffer, Context};
use tgs_pipelines::Rng;
use tgs_pipelines::{HostGaussians, TrainableSet};

use super::arrays::{check_arrays, host_set, upload_set};
use super::stage::Stage;
use super::stages::kind::{by_key, by_stage, parse, LaterKind};
pub use super::stages::light_field::checkpoint::LightFieldHeader;
pub use super::stages::reflection::checkpoint::ReflHeader;
use std::collections::BTreeMap;

const MAGIC: &[u8; 8] = b"TGSCKPT2";
const MAGIC_V1: &[u8; 8] = b"TGSCKPT1";

/// Who wrote a checkpoint: the run (an id made when it started, kept by
/// `--resume`, new for `--from`) and the dataset as it was then.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Identity {
    pub run_id: String,
    pub fingerprint: Fingerprint,
}

/// A new run's id: the time and the process, hashed (unique per run
/// directory in practice; it only has to tell two runs apart).
pub fn new_run_id() -> String {
    let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
    let mut h = crc32fast::Hasher::new();
    h.update(&t.to_le_bytes());
    h.update(&std::process::id().to_le_bytes());
    let a = h.finalize();
    h = crc32fast::Hasher::new_with_initial(a);
    h.update(&t.to_be_bytes());
    format!("{:08x}{:08x}", a, h.finalize())
}

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
    /// The run and its dataset's fingerprint (absent in checkpoints from
    /// before they were recorded).
    #[serde(default)]
    pub identity: Option<Identity>,
    /// The running later stage's state, under its key (`"reflection"`
    /// for Stage II, `"light_field"` for Stage III; `stages::later()`): its
    /// arrays follow the scattering set's (the reflection set in
    /// `TrainableSet::layout` order with the prefix `refl.`, then the
    /// stage's own: the cube map's, the network's). Files from before
    /// this map wrote `null` under the keys of the stages not running.
    #[serde(flatten)]
    pub later: BTreeMap<String, serde_json::Value>,
    /// Settings of this version of tgs that the header's `config` does
    /// not hold (a checkpoint written by an earlier tgs): `config` has
    /// this version's defaults for them, so a continued run may differ
    /// from how it began ([`missing_settings_note`] says which). Found by
    /// [`read`]; not written.
    #[serde(skip)]
    pub missing_settings: Vec<String>,
}

impl Header {
    /// The later stage whose state the header holds (None in Stage I),
    /// with its JSON part.
    pub fn later_state(&self) -> Result<Option<(&'static dyn LaterKind, &serde_json::Value)>> {
        let mut found = None;
        for (key, v) in self.later.iter().filter(|(_, v)| !v.is_null()) {
            let kind = by_key(key).with_context(|| format!("the header names '{key}', which is no stage of this version of tgs"))?;
            if found.is_some() {
                bail!("the header holds the states of two stages");
            }
            found = Some((kind, v));
        }
        Ok(found)
    }

    /// The later stage's arrays (names and lengths, in file order), none in
    /// Stage I.
    pub fn later_arrays(&self) -> Result<Vec<(String, usize)>> {
        match self.later_state()? {
            Some((kind, v)) => kind.arrays(v),
            None => Ok(Vec::new()),
        }
    }

    /// The state of `stage` as its own header type (e.g. [`ReflHeader`]
    /// for Stage II), None when the header holds another stage's or none.
    pub fn state_of<T: serde::de::DeserializeOwned>(&self, stage: Stage) -> Result<Option<T>> {
        match self.later_state()? {
            Some((kind, v)) if kind.stage() == stage => Ok(Some(parse(kind, v)?)),
            _ => Ok(None),
        }
    }

    /// Whether the header holds the state of `stage`.
    pub fn holds(&self, stage: Stage) -> bool {
        self.later_state().ok().flatten().is_some_and(|(k, _)| k.stage() == stage)
    }

    /// Drop the later stage's state and its arrays (the last in
    /// `arrays`), leaving the scattering set's.
    pub fn drop_later(&mut self, arrays: &mut Vec<Vec<f32>>) -> Result<()> {
        let n = self.later_arrays()?.len();
        arrays.truncate(arrays.len().saturating_sub(n));
        self.later.clear();
        Ok(())
    }
}

/// The buffers and lengths of a checkpoint's arrays, in file order.
type ArrayBuffers<'a> = Vec<(&'a Buffer<f32>, usize)>;

/// The header a checkpoint of `tr` gets, with its arrays' buffers (the
/// scattering set's, then the later stage's).
fn header_and_buffers<'a>(tr: &'a Trainer, dataset: &str, identity: Option<&Identity>) -> Result<(Header, ArrayBuffers<'a>)> {
    let set = &tr.scattering.set;
    let n = set.len() as usize;
    let arrays = set.arrays();
    let mut header = Header {
        iteration: tr.iteration,
        config: tr.cfg.clone(),
        dataset: dataset.to_string(),
        rng: tr.rng.0,
        stack: tr.stack.clone(),
        n: set.len(),
        channels: set.params.channels,
        coeffs: set.params.coeffs,
        extent: tr.views.extent,
        arrays: arrays.iter().map(|(name, _, w)| (name.clone(), w * n)).collect(),
        identity: identity.cloned(),
        later: BTreeMap::new(),
        missing_settings: Vec::new(),
    };
    let mut bufs: ArrayBuffers = arrays.iter().map(|(_, buf, w)| (*buf, w * n)).collect();
    if let (Some(m), Some(d)) = (&tr.later, &tr.decision) {
        let kind = by_stage(m.stage()).context("the running stage is not in stages::later()")?;
        let mut later_arrays = Vec::new();
        header.later.insert(kind.key().to_string(), m.save_state(d, &mut later_arrays)?);
        bufs.extend(later_arrays);
    }
    Ok((header, bufs))
}

pub fn save(tr: &Trainer, path: &Path, dataset: &str, identity: &Identity) -> Result<()> {
    let (header, bufs) = header_and_buffers(tr, dataset, Some(identity))?;
    let json = serde_json::to_vec(&header)?;
    crate::export::atomic_write_with(path, |f| {
        f.write_all(MAGIC)?;
        f.write_all(&(json.len() as u32).to_le_bytes())?;
        f.write_all(&json)?;
        f.write_all(&crc32fast::hash(&json).to_le_bytes())?;
        for (buf, len) in bufs {
            let data = buf.download_range(0, len)?;
            let bytes: &[u8] = bytemuck::cast_slice(&data);
            f.write_all(bytes)?;
            f.write_all(&crc32fast::hash(bytes).to_le_bytes())?;
        }
        Ok(())
    })
    .context("writing the checkpoint")
}

/// What [`save`] would write, in memory: the header and the arrays as
/// [`read`] returns them (for a live view of a run while it trains).
pub fn snapshot(tr: &Trainer, dataset: &str) -> Result<(Header, Vec<Vec<f32>>)> {
    let (header, bufs) = header_and_buffers(tr, dataset, None)?;
    let arrays = bufs.into_iter().map(|(buf, len)| buf.download_range(0, len)).collect::<Result<Vec<_>>>()?;
    Ok((header, arrays))
}

/// Read a checkpoint's header and arrays.
pub fn read(path: &Path) -> Result<(Header, Vec<Vec<f32>>)> {
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read the checkpoint", path.display()))?;
    let bad = |what: &str| anyhow::anyhow!("{}: not a tgs checkpoint or corrupt ({what})", path.display());
    if bytes.len() < 12 || (&bytes[..8] != MAGIC && &bytes[..8] != MAGIC_V1) {
        return Err(bad("magic"));
    }
    // Version 2 has a CRC-32 after the header and after every array.
    let sums = &bytes[..8] == MAGIC;
    let crc_at = |at: usize| -> Option<u32> { bytes.get(at..at + 4).map(|b| u32::from_le_bytes(b.try_into().unwrap())) };
    let hlen = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
    let hbytes = 12usize.checked_add(hlen).and_then(|end| bytes.get(12..end)).ok_or_else(|| bad("header length"))?;
    let mut at = 12 + hlen;
    if sums {
        if crc_at(at) != Some(crc32fast::hash(hbytes)) {
            return Err(bad("the header's checksum does not match: the file was damaged"));
        }
        at += 4;
    }
    // Parsed once: the settings it lacks are read off the same JSON.
    let raw: serde_json::Value = serde_json::from_slice(hbytes).map_err(|e| bad(&format!("header: {e}")))?;
    let missing = missing_settings(&raw).map_err(|e| bad(&format!("header: {e:#}")))?;
    let mut header: Header = serde_json::from_value(raw).map_err(|e| bad(&format!("header: {e}")))?;
    header.missing_settings = missing;
    let mut arrays = Vec::new();
    let later = header.later_arrays().map_err(|e| bad(&format!("{e:#}")))?;
    for (name, len) in header.arrays.iter().chain(&later) {
        let b = len.checked_mul(4).and_then(|n| at.checked_add(n)).and_then(|end| bytes.get(at..end)).ok_or_else(|| bad(&format!("array {name} of {len} values is truncated")))?;
        at += 4 * len;
        if sums {
            if crc_at(at) != Some(crc32fast::hash(b)) {
                return Err(bad(&format!("array {name}'s checksum does not match: the file was damaged")));
            }
            at += 4;
        }
        arrays.push(b.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect());
    }
    if at != bytes.len() {
        return Err(bad("trailing bytes"));
    }
    Ok((header, arrays))
}

/// The settings (`key` or `section.key`, as `--set` names them) of this
/// version's configuration that the header's `config` lacks.
fn missing_settings(header: &serde_json::Value) -> Result<Vec<String>> {
    let saved = setting_keys(header.get("config").context("no settings")?);
    let now = setting_keys(&serde_json::to_value(TrainConfig::default())?);
    Ok(now.into_iter().filter(|k| !saved.contains(k)).collect())
}

/// The keys of a configuration as JSON, a section's as `section.key` (one
/// level, as `config::flatten` lists a TOML table).
fn setting_keys(v: &serde_json::Value) -> Vec<String> {
    let mut out = Vec::new();
    if let serde_json::Value::Object(m) = v {
        for (k, v) in m {
            match v {
                serde_json::Value::Object(sub) => out.extend(sub.keys().map(|k2| format!("{k}.{k2}"))),
                _ => out.push(k.clone()),
            }
        }
    }
    out
}

/// For a checkpoint at `path` written by an earlier tgs: the settings its
/// header lacks with the values `cfg` (the settings the run continues
/// with) gives them, as a warning; None when it lacks none.
pub fn missing_settings_note(path: &Path, h: &Header, cfg: &TrainConfig) -> Result<Option<String>> {
    if h.missing_settings.is_empty() {
        return Ok(None);
    }
    let values = super::config::flatten(&toml::Table::try_from(cfg).context("serialising the settings")?);
    let lines: Vec<String> = h
        .missing_settings
        .iter()
        .map(|k| match values.iter().find(|(key, _)| key == k) {
            Some((_, v)) => format!("{k} = {v}"),
            None => k.clone(),
        })
        .collect();
    Ok(Some(format!(
        "{}: written by an earlier version of tgs, without these settings; they take this version's defaults, so the run may go on differently from how it began:\n  {}",
        path.display(),
        lines.join("\n  ")
    )))
}

/// Print [`missing_settings_note`] as a warning unless `quiet` (what
/// `--resume` and `--from` do with a checkpoint from an earlier tgs).
pub fn warn_missing_settings(path: &Path, h: &Header, cfg: &TrainConfig, quiet: bool) -> Result<()> {
    if let (Some(note), false) = (missing_settings_note(path, h, cfg)?, quiet) {
        eprintln!("tgs: warning: {note}");
    }
    Ok(())
}

/// Parameters (the first five arrays) of a checkpoint as a host set.
pub fn gaussians(h: &Header, arrays: &[Vec<f32>]) -> Result<HostGaussians> {
    if arrays.len() < 5 {
        bail!("checkpoint has {} arrays, expected at least 5", arrays.len());
    }
    let g = host_set(h.channels, h.coeffs, arrays);
    g.validate()?;
    Ok(g)
}

/// A trainer restored from the checkpoint `path` on `data` (the same
/// dataset), given its header and arrays as [`read`] returned them (the
/// caller needs the header first, to find the dataset). Every array must
/// have exactly the length its header's Gaussian count implies.
pub fn restore(ctx: &Arc<Context>, path: &Path, (h, arrays): (Header, Vec<Vec<f32>>), data: &Dataset) -> Result<Trainer> {
    let bad = |what: String| anyhow::anyhow!("{}: corrupt checkpoint ({what})", path.display());
    if let Some(id) = &h.identity {
        let now = data.fingerprint()?;
        if let Some(c) = id.fingerprint.changes(&now) {
            bail!(
                "{}: the dataset {} changed since this checkpoint was written: {c}; the run cannot continue on other data (train a new run)",
                path.display(),
                data.root.display()
            );
        }
    }
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
    let mut arrays = arrays;
    let refl_arrays = arrays.split_off(layout.len().min(arrays.len()));
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
    upload_set(&tr.scattering.set, &arrays)?;
    match h.later_state().map_err(|e| bad(format!("{e:#}")))? {
        Some((kind, v)) => {
            let name = kind.stage().name();
            let (m, d) = kind.restore(v, ctx, &tr.cfg, refl_arrays).map_err(|e| bad(format!("Stage {name} state: {e:#}")))?;
            tr.later = Some(m);
            tr.decision = Some(d);
        }
        None if !refl_arrays.is_empty() => return Err(bad(format!("{} arrays after the scattering set without a later stage's header", refl_arrays.len()))),
        None => {}
    }
    tr.iteration = h.iteration;
    tr.stack = h.stack;
    tr.views.extent = h.extent;
    // Inside a later stage the views were held out and the order is over those left.
    if tr.iteration > tr.cfg.iterations {
        tr.hold_out_validation(false);
    }
    Ok(tr)
}

pub use super::stages::layer::RenderLayer;

/// What rendering a checkpoint needs: the parameters only (no Adam moments,
/// no dataset), checked as [`restore`] checks them; the later stage's
/// reflection layer already on the device (None after Stage I).
pub struct RenderState {
    pub stage: &'static str,
    /// The SH degree the scattering layer is rendered at, as the trainer
    /// renders this checkpoint (`LaterKind::scattering_sh`).
    pub sh_degree: u32,
    pub scattering: HostGaussians,
    pub layer: Option<Box<dyn RenderLayer>>,
}

pub fn render_state(h: &Header, mut arrays: Vec<Vec<f32>>, ctx: &Arc<Context>) -> Result<RenderState> {
    h.config.validate().context("settings")?;
    let layout = TrainableSet::layout((h.channels * h.coeffs) as usize);
    if arrays.len() < layout.len() {
        bail!("{} arrays, the scattering set alone has {}", arrays.len(), layout.len());
    }
    let refl = arrays.split_off(layout.len());
    let have: Vec<(String, usize)> = h.arrays.clone();
    let want: Vec<(String, usize)> = layout.iter().map(|(name, w)| (name.clone(), w * h.n as usize)).collect();
    check_arrays(&want, &have, &arrays)?;
    let scattering = gaussians(h, &arrays)?;
    let stage1 = h.config.sh_degree_at(h.iteration.min(h.config.iterations));
    let (stage, sh_degree, layer) = match h.later_state()? {
        None if refl.is_empty() => (Stage::SCATTERING.name(), stage1, None),
        None => bail!("{} arrays after the scattering set without a later stage's header", refl.len()),
        Some((kind, v)) => {
            let name = kind.stage().name();
            (name, kind.scattering_sh(&h.config, stage1), Some(kind.render_layer(v, &h.config, refl, ctx).with_context(|| format!("Stage {name} state"))?))
        }
    };
    Ok(RenderState { stage, sh_degree, scattering, layer })
}
