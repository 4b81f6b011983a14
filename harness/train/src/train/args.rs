//! The settings of a `tgs train` run: a preset with the config file,
//! `--set` and the flags on top, and the settings a resumed run keeps.

use super::config::{flatten, TrainConfig};
use super::rundir::DEFAULT_SCENE;
use super::stages::later;
use crate::data::{Dataset, LoadOptions};
use anyhow::{bail, Context as _, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Clone, Debug, Default)]
pub struct TrainArgs {
    /// Dataset directory; None trains on the built-in scene (written to OUT/scene).
    pub dataset: Option<PathBuf>,
    pub out: PathBuf,
    pub preset: Option<String>,
    pub config: Option<PathBuf>,
    pub set: Vec<String>,
    pub iterations: Option<u32>,
    /// `--downscale N` (the `downscale` setting).
    pub downscale: Option<u32>,
    /// `--background white|black|r,g,b` (the `background` setting).
    pub background: Option<String>,
    pub resume: bool,
    /// `--stages I|I,II|I,II,III` (the `stages` setting; with `from`, the
    /// stages after Stage I: "II" or "II,III").
    pub stages: Option<String>,
    /// `--from RUN`: start Stage II from RUN's finished Stage I instead of
    /// training Stage I again.
    pub from: Option<PathBuf>,
    /// Collect per-kernel GPU timings for every iteration (timings.json).
    pub profile: bool,
    /// No progress bar or periodic lines.
    pub quiet: bool,
    /// A live view's receiver of the model while it trains (`tgs train --view`).
    pub live: Option<super::live::LiveSink>,
}

/// The dataset directory, writing the built-in scene first when none is given.
pub fn dataset_dir(a: &TrainArgs, quiet: bool) -> Result<PathBuf> {
    if let Some(d) = &a.dataset {
        return Ok(d.clone());
    }
    let dir = a.out.join("scene");
    if !dir.join("transforms_train.json").is_file() {
        let spec = crate::scene::spec(DEFAULT_SCENE)?;
        if !quiet {
            eprintln!("no dataset given: writing the built-in scene '{}' to {}", spec.name, dir.display());
        }
        crate::scene::make(&spec, &dir, |_, _| {})?;
    }
    Ok(dir)
}

pub fn load_dataset(dir: &Path, cfg: &TrainConfig) -> Result<Dataset> {
    let opts = LoadOptions { downscale: cfg.downscale, background: cfg.background_rgb()?, holdout: cfg.holdout };
    Dataset::load(dir, &opts)
}

/// Settings `--resume` may change: the schedule's length and reporting,
/// and each later stage's own ([`super::stages::LaterKind::resumable`]); changing any
/// other would train another model than the one checkpointed.
pub fn resumable_settings() -> Vec<&'static str> {
    let stages = later().into_iter().flat_map(|k| k.resumable().iter().copied());
    std::iter::once("iterations").chain(stages).chain(["test_interval", "checkpoint_interval"]).collect()
}

/// Settings that change only what a trained model outputs (which set
/// decides a pixel's normal and depth), not what it learned: `tgs eval
/// --set` may change them on a finished run ([`super::stages::LaterKind::output_settings`]).
pub fn output_settings() -> Vec<&'static str> {
    later().into_iter().flat_map(|k| k.output_settings().iter().copied()).collect()
}

pub fn config_from_args(a: &TrainArgs) -> Result<TrainConfig> {
    let cfg = TrainConfig::preset(a.preset.as_deref().unwrap_or("quick"))?;
    apply_args(cfg, a)
}

/// Overlay the config file, `--set`, `--stages`, `--downscale`,
/// `--background` and `--iterations` on `cfg`. A key given both by `--set`
/// and by its own flag is refused: there is no order to remember.
pub(crate) fn apply_args(mut cfg: TrainConfig, a: &TrainArgs) -> Result<TrainConfig> {
    let flags = [
        ("iterations", a.iterations.is_some(), "--iterations"),
        ("stages", a.stages.is_some(), "--stages"),
        ("downscale", a.downscale.is_some(), "--downscale"),
        ("background", a.background.is_some(), "--background"),
    ];
    for kv in &a.set {
        let key = kv.split_once('=').map(|(k, _)| k.trim()).unwrap_or("");
        if let Some((_, _, flag)) = flags.iter().find(|(k, given, _)| *given && *k == key) {
            bail!("--set {kv} and {flag} both set '{key}': give one of them");
        }
    }
    let masks_before = cfg.reflection.seed_masks.clone();
    if let Some(p) = &a.config {
        cfg.merge_toml_file(p)?;
    }
    for kv in &a.set {
        cfg.set(kv)?;
    }
    if cfg.reflection.seed_masks != masks_before {
        cfg.reflection.seed_masks = absolute_setting("reflection.seed_masks", &cfg.reflection.seed_masks)?;
    }
    if let Some(st) = &a.stages {
        // With --from, RUN's stages before the first named are kept: "II"
        // means "I,II", "III" "I,II,III" (RUN's Stage II kept).
        let first = st.split(',').next().unwrap_or("").trim();
        let all = super::stage::Stage::all();
        let before = all.iter().position(|s| s.name() == first).unwrap_or(1).max(1);
        cfg.stages = match a.from.is_some() && first != "I" {
            true => all[..before].iter().map(|s| s.name()).chain(st.split(',').map(str::trim)).collect::<Vec<_>>().join(","),
            false => st.clone(),
        };
        cfg.validate().with_context(|| format!("--stages '{st}'"))?;
    }
    if let Some(d) = a.downscale {
        cfg.downscale = d;
        cfg.validate().with_context(|| format!("--downscale {d}"))?;
    }
    if let Some(b) = &a.background {
        cfg.background = b.clone();
        cfg.validate().with_context(|| format!("--background '{b}'"))?;
    }
    if let Some(n) = a.iterations {
        cfg.iterations = n;
        cfg.validate().with_context(|| format!("--iterations {n}"))?;
    }
    cfg.validate()?;
    cfg.validate_together()?;
    Ok(cfg)
}

/// A path setting given now, made absolute against the working directory,
/// so that the run's saved settings name the same directory when it is
/// resumed, continued with `--from` or evaluated from anywhere else. Empty
/// stays empty (the setting's "none").
fn absolute_setting(key: &str, value: &str) -> Result<String> {
    if value.is_empty() {
        return Ok(String::new());
    }
    let abs = std::path::absolute(value).with_context(|| format!("{key} = \"{value}\": making the path absolute"))?;
    Ok(abs.to_string_lossy().into_owned())
}

/// A setting's value as the user typed it (settings are f32: no f64 digits).
pub(crate) fn show(v: &toml::Value) -> String {
    match v {
        toml::Value::Float(f) => format!("{}", *f as f32),
        v => v.to_string(),
    }
}

/// The settings of a resumed run: the checkpoint's, with the options given
/// now applied on top (a `--preset` replaces them all). Any difference
/// outside [`resumable_settings`] would silently train another model than
/// the one checkpointed, so it is refused with the key and both values.
pub fn resume_config(a: &TrainArgs, saved: &TrainConfig) -> Result<TrainConfig> {
    let base = match &a.preset {
        Some(p) => TrainConfig::preset(p)?,
        None => saved.clone(),
    };
    let cfg = apply_args(base, a)?;
    let free = resumable_settings();
    let conflicts = changed_settings(saved, &cfg, |k| free.contains(&k))?;
    if !conflicts.is_empty() {
        bail!(
            "--resume continues a run with the settings it was started with; these options change them:\n  {}\nonly {} may change when resuming (start a new run with another --out to train with other settings)",
            conflicts.join("\n  "),
            free.join(", ")
        );
    }
    Ok(cfg)
}

/// Every setting by its dotted key.
pub(crate) fn settings(c: &TrainConfig) -> Result<BTreeMap<String, toml::Value>> {
    Ok(flatten(&toml::Table::try_from(c)?).into_iter().collect())
}

/// The settings of `new` that differ from `saved`, except those `free`
/// lets change, as "key = old in the checkpoint, new given" lines.
pub(crate) fn changed_settings(saved: &TrainConfig, new: &TrainConfig, free: impl Fn(&str) -> bool) -> Result<Vec<String>> {
    let old = settings(saved)?;
    let new = settings(new)?;
    Ok(new
        .iter()
        .filter(|(k, v)| !free(k) && old.get(*k) != Some(*v))
        .map(|(k, v)| format!("{k} = {} in the checkpoint, {} given", old.get(k).map(show).unwrap_or_default(), show(v)))
        .collect())
}
