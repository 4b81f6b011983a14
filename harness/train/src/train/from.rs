//! `tgs train --from RUN`: a new run that starts from the finished Stage I
//! (or, with `--stages III`, Stage II) of another, with only the later
//! stages' settings free to change.

use super::args::{apply_args, changed_settings, settings, show};
use super::args::{load_dataset, TrainArgs};
use super::checkpoint;
use super::config::TrainConfig;
use super::rundir::{CHECKPOINT, STAGE_ONE_CHECKPOINT, STAGE_TWO_CHECKPOINT};
use super::stages::{light_field, reflection};
use super::trainer::Trainer;
use crate::data::Dataset;
use anyhow::{bail, Context as _, Result};
use serde_json::json;
use std::path::Path;
use std::sync::Arc;
use tgs_engine::Context;

/// Settings that only shape the stages after Stage I: `--from RUN` may
/// change them (everything else trained RUN's Stage I and must stay).
fn later_stage_setting(k: &str) -> bool {
    k.starts_with("reflection.") || k.starts_with("light_field.") || matches!(k, "stages" | "test_interval" | "checkpoint_interval" | "validation_every" | "validation_margin_db")
}

/// `--from RUN --stages III`: Stage III starts from RUN's finished Stage II.
fn from_stage_two(a: &TrainArgs) -> bool {
    a.from.is_some() && a.stages.as_deref().is_some_and(|s| s.split(',').next().unwrap_or("").trim() == "III")
}

/// Settings `--from RUN --stages III` may change: only Stage III's.
fn stage_three_setting(k: &str) -> bool {
    k.starts_with("light_field.") || matches!(k, "stages" | "test_interval" | "checkpoint_interval" | "reflection.reseed")
}

/// The later-stage settings a `--from` run takes from RUN unchanged
/// (`saved` RUN's, `cfg` the new run's) where they differ from this
/// version's defaults in both presets, as "key = value (default ...)"
/// lines: a run written before a default changed keeps its old value, and
/// the user should see that rather than assume today's default. With
/// `stage_three` (`--stages III`) only those that may still change are
/// listed (Stage III's and `reflection.reseed`), and Stage III's only when
/// it runs.
pub fn inherited_settings(saved: &TrainConfig, cfg: &TrainConfig, stage_three: bool) -> Result<Vec<String>> {
    let (old, new) = (settings(saved)?, settings(cfg)?);
    let presets = [settings(&TrainConfig::preset("quick")?)?, settings(&TrainConfig::preset("paper")?)?];
    // What this `--from` may change (the refusals' own lists), of the stages' settings.
    let may_change: fn(&str) -> bool = if stage_three { stage_three_setting } else { later_stage_setting };
    let later = |k: &str| may_change(k) && (k.starts_with("reflection.") || (cfg.wants_light_field() && k.starts_with("light_field.")));
    Ok(new
        .iter()
        .filter(|(k, v)| later(k) && old.get(*k) == Some(*v) && presets.iter().all(|p| p.get(*k) != Some(*v)))
        .map(|(k, v)| {
            let d: Vec<String> = presets.iter().map(|p| p.get(k).map(show).unwrap_or_else(|| "none".into())).collect();
            let d = if d[0] == d[1] { d[0].clone() } else { format!("{} quick, {} paper", d[0], d[1]) };
            format!("{k} = {} (default {d})", show(v))
        })
        .collect())
}

/// `--from RUN`: a trainer at the end of RUN's Stage I (its scattering set;
/// any later stage of RUN is dropped) or, with `--stages III`, at the end
/// of RUN's Stage II (both sets), the dataset, its path, and RUN's records
/// of the stages kept, for metrics.json. RUN's settings are the base;
/// options may change only the later stages' settings.
pub(crate) fn start_from(ctx: &Arc<Context>, a: &TrainArgs, run: &Path) -> Result<(Trainer, Dataset, String, Vec<serde_json::Value>)> {
    let keep_two = from_stage_two(a);
    // The state at the end of the stage kept, where the run went past it.
    let snapshot = run.join(if keep_two { STAGE_TWO_CHECKPOINT } else { STAGE_ONE_CHECKPOINT });
    let ckpt = if snapshot.is_file() { snapshot } else { run.join(CHECKPOINT) };
    if !ckpt.is_file() {
        bail!("--from {}: no {CHECKPOINT} there (a finished `tgs train` run directory is expected)", run.display());
    }
    let (mut h, mut arrays) = checkpoint::read(&ckpt)?;
    check_stage_one(run, &h, keep_two)?;
    if a.preset.is_some() {
        bail!("--from {}: the run's own settings are used (--preset would change how its Stage I was trained); change Stage II with --set reflection.KEY=VALUE", run.display());
    }
    let mut base = h.config.clone();
    // A Stage I-only run: the stages after it are the default ones.
    if base.stages.trim() == "I" {
        base.stages = TrainConfig::default().stages;
    }
    let cfg = apply_args(base, a).with_context(|| format!("--from {}", run.display()))?;
    check_settings(run, &h, &cfg, keep_two)?;
    checkpoint::warn_missing_settings(&ckpt, &h, &cfg, a.quiet)?;
    let inherited = inherited_settings(&h.config, &cfg, keep_two)?;
    if !a.quiet && !inherited.is_empty() {
        eprintln!("--from {}: these settings are that run's, not today's defaults (change them with --set KEY=VALUE):\n  {}", run.display(), inherited.join("\n  "));
    }
    if let Some(given) = &a.dataset {
        let same = std::fs::canonicalize(given).map(|g| g == Path::new(&h.dataset)).unwrap_or(false);
        if !same {
            bail!("--from {} trained on {}; {} was given (leave the dataset out)", run.display(), h.dataset, given.display());
        }
    }
    let data = load_dataset(Path::new(&h.dataset), &h.config).with_context(|| format!("--from {}: loading its dataset {}", run.display(), h.dataset))?;
    if !keep_two {
        h.drop_later(&mut arrays).with_context(|| format!("--from {}", ckpt.display()))?;
    }
    let dataset = h.dataset.clone();
    let mut tr = checkpoint::restore(ctx, &ckpt, (h, arrays), &data)?;
    tr.iteration = if keep_two { cfg.iterations + cfg.reflection.iterations } else { cfg.iterations };
    tr.cfg = cfg;
    tr.schedule = super::schedule::Schedule::from_config(&tr.cfg);
    let recs = kept_records(run, keep_two);
    Ok((tr, data, dataset, recs))
}

/// RUN's Stage I state is there to start from: finished, and not changed
/// by a later stage that trained the scattering set (unless Stage II is kept).
fn check_stage_one(run: &Path, h: &checkpoint::Header, keep_two: bool) -> Result<()> {
    // Past Stage I, a stage that trained the scattering set changed it.
    let stage_two_trained = h.iteration > h.config.iterations && h.config.reflection.train_scattering;
    let stage_three_trained = h.holds(light_field::stage::STAGE) && h.config.light_field.train_scattering;
    if !keep_two && (stage_two_trained || stage_three_trained) {
        bail!(
            "--from {}: its Stage {} trained the scattering set, and the run has no {STAGE_ONE_CHECKPOINT} (Stage I's own state; runs from before it was written lack it): train Stage I again",
            run.display(),
            if stage_two_trained { "II" } else { "III" }
        );
    }
    if h.iteration < h.config.iterations {
        bail!(
            "--from {}: its Stage I stopped at iteration {} of {}; finish it first (tgs train --out {} --resume)",
            run.display(),
            h.iteration,
            h.config.iterations,
            run.display()
        );
    }
    Ok(())
}

/// The settings may change only the stages that train again: with
/// `--stages III`, RUN's Stage II must be finished and stay as trained.
fn check_settings(run: &Path, h: &checkpoint::Header, cfg: &TrainConfig, keep_two: bool) -> Result<()> {
    if keep_two {
        let end = h.config.iterations + h.config.reflection.iterations;
        if !h.holds(reflection::stage::STAGE) || h.iteration != end {
            bail!(
                "--from {} --stages III starts from that run's finished Stage II; it is at iteration {} (Stage II ends at {end}{}) and has no {STAGE_TWO_CHECKPOINT}",
                run.display(),
                h.iteration,
                if !h.holds(reflection::stage::STAGE) { ", and it holds no Stage II state" } else { "" }
            );
        }
        let conflicts = changed_settings(&h.config, cfg, stage_three_setting)?;
        if !conflicts.is_empty() {
            bail!("--from {} --stages III reuses that run's Stages I and II; these options would change how they were trained:\n  {}\nonly light_field.*, reflection.reseed, stages, test_interval and checkpoint_interval may differ", run.display(), conflicts.join("\n  "));
        }
    }
    let conflicts = changed_settings(&h.config, cfg, later_stage_setting)?;
    if !conflicts.is_empty() {
        bail!("--from {} reuses that run's Stage I; these options would change how it was trained:\n  {}\nonly reflection.*, light_field.*, stages, test_interval and checkpoint_interval may differ", run.display(), conflicts.join("\n  "));
    }
    if !cfg.wants_reflection() {
        bail!("--from {}: stages = \"{}\" leaves nothing to run after its Stage I", run.display(), cfg.stages);
    }
    Ok(())
}

/// RUN's records of the stages kept, each marked with where it came from.
fn kept_records(run: &Path, keep_two: bool) -> Vec<serde_json::Value> {
    let abs = std::fs::canonicalize(run).unwrap_or_else(|_| run.to_path_buf());
    let kept: &[&str] = if keep_two { &["I", "II"] } else { &["I"] };
    let records = stage_records_of(run);
    kept.iter()
        .map(|st| {
            let mut rec = records.iter().find(|s| s["stage"] == *st).cloned().unwrap_or_else(|| json!({"stage": st}));
            rec["from"] = json!(abs.to_string_lossy());
            rec
        })
        .collect()
}

/// A finished run's stage records: stages.json (written when Stage II
/// begins), else metrics.json's `stages`.
fn stage_records_of(run: &Path) -> Vec<serde_json::Value> {
    let read = |f: &str| std::fs::read(run.join(f)).ok().and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok());
    if let Some(serde_json::Value::Array(v)) = read("stages.json") {
        return v;
    }
    match read("metrics.json").map(|m| m["stages"].clone()) {
        Some(serde_json::Value::Array(v)) => v,
        _ => Vec::new(),
    }
}
