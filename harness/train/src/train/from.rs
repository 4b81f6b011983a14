//! `tgs train --from RUN`: a new run that starts from the finished Stage I
//! (or, with `--stages III`, Stage II) of another, with only the later
//! stages' settings free to change.

use super::args::{apply_args, changed_settings, settings, show};
use super::args::{load_dataset, TrainArgs};
use super::checkpoint;
use super::config::TrainConfig;
use super::rundir::{stage_checkpoint, CHECKPOINT};
use super::stage::Stage;
use super::stages::kind::in_section;
use super::stages::later;
use super::trainer::Trainer;
use crate::data::Dataset;
use anyhow::{bail, Context as _, Result};
use serde_json::json;
use std::path::Path;
use std::sync::Arc;
use tgs_engine::Context;

/// Settings of the whole run that any `--from` may change.
const FROM_RUN_SETTINGS: [&str; 3] = ["stages", "test_interval", "checkpoint_interval"];
/// And those a `--from` that keeps only RUN's Stage I may change (the
/// validation slice is held out of the later stages).
const FROM_STAGE_ONE_SETTINGS: [&str; 2] = ["validation_every", "validation_margin_db"];

/// The first later stage a `--from` run trains (its index in [`later`]):
/// the first of `--stages` (RUN's stages before it are kept), else the
/// first after Stage I.
fn start_index(a: &TrainArgs) -> usize {
    let first = a.stages.as_deref().and_then(|s| s.split(',').next()).map(str::trim).unwrap_or("");
    later().iter().position(|k| k.stage().name() == first).unwrap_or(0)
}

/// Whether a `--from` run that trains from `later()[start]` on may change
/// the setting `k`: the sections of the stages it trains, what the first
/// of them frees ([`LaterKind::frees_earlier_settings`]) and the run's own.
fn from_setting(start: usize, k: &str) -> bool {
    FROM_RUN_SETTINGS.contains(&k)
        || (start == 0 && FROM_STAGE_ONE_SETTINGS.contains(&k))
        || later()[start..].iter().any(|s| in_section(*s, k))
        || later()[start].frees_earlier_settings().contains(&k)
}

/// [`from_setting`]'s list for people ("light_field.*, reflection.reseed,
/// stages, test_interval and checkpoint_interval").
fn from_settings_text(start: usize) -> String {
    let stages = later();
    let mut v: Vec<String> = stages[start..].iter().map(|s| format!("{}.*", s.key())).collect();
    v.extend(stages[start].frees_earlier_settings().iter().chain(&FROM_RUN_SETTINGS).map(|k| k.to_string()));
    let last = v.pop().unwrap_or_default();
    format!("{} and {last}", v.join(", "))
}

/// The stages a `--from` run starting at `later()[start]` keeps from RUN
/// (Stage I and the later stages before it), by name.
fn kept_stages(start: usize) -> Vec<&'static str> {
    std::iter::once(Stage::SCATTERING).chain(later()[..start].iter().map(|k| k.stage())).map(|s| s.name()).collect()
}

/// The iteration at which RUN's kept stages end under `cfg`.
fn kept_end(cfg: &TrainConfig, start: usize) -> u32 {
    cfg.iterations + later()[..start].iter().map(|k| k.iterations(cfg)).sum::<u32>()
}

/// The later-stage settings a `--from` run takes from RUN unchanged
/// (`saved` RUN's, `cfg` the new run's) where they differ from this
/// version's defaults in both presets, as "key = value (default ...)"
/// lines: a run written before a default changed keeps its old value, and
/// the user should see that rather than assume today's default. Only
/// those the run starting at `later()[start]` may still change are listed
/// (with `--stages III`, Stage III's and `reflection.reseed`), and a
/// stage's own only when it runs.
pub fn inherited_settings(saved: &TrainConfig, cfg: &TrainConfig, start: usize) -> Result<Vec<String>> {
    let (old, new) = (settings(saved)?, settings(cfg)?);
    let presets = [settings(&TrainConfig::preset("quick")?)?, settings(&TrainConfig::preset("paper")?)?];
    // What this `--from` may change (the refusals' own lists), of the stages' settings.
    let may_change = |k: &str| from_setting(start, k) && later().iter().any(|s| in_section(*s, k) && cfg.wants(s.stage().name()));
    Ok(new
        .iter()
        .filter(|(k, v)| may_change(k) && old.get(*k) == Some(*v) && presets.iter().all(|p| p.get(*k) != Some(*v)))
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
    let start = start_index(a);
    // The state at the end of the last stage kept, where the run went past it.
    let snapshot = run.join(stage_checkpoint(start + 1));
    let ckpt = if snapshot.is_file() { snapshot } else { run.join(CHECKPOINT) };
    if !ckpt.is_file() {
        bail!("--from {}: no {CHECKPOINT} there (a finished `tgs train` run directory is expected)", run.display());
    }
    let (mut h, mut arrays) = checkpoint::read(&ckpt)?;
    check_kept(run, &h, start)?;
    if a.preset.is_some() {
        bail!("--from {}: the run's own settings are used (--preset would change how its Stage I was trained); change Stage II with --set reflection.KEY=VALUE", run.display());
    }
    let mut base = h.config.clone();
    // A Stage I-only run: the stages after it are the default ones.
    if base.stages.trim() == "I" {
        base.stages = TrainConfig::default().stages;
    }
    let cfg = apply_args(base, a).with_context(|| format!("--from {}", run.display()))?;
    check_settings(run, &h, &cfg, start)?;
    checkpoint::warn_missing_settings(&ckpt, &h, &cfg, a.quiet)?;
    let inherited = inherited_settings(&h.config, &cfg, start)?;
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
    if start == 0 {
        h.drop_later(&mut arrays).with_context(|| format!("--from {}", ckpt.display()))?;
    }
    let dataset = h.dataset.clone();
    let mut tr = checkpoint::restore(ctx, &ckpt, (h, arrays), &data)?;
    tr.iteration = kept_end(&cfg, start);
    tr.cfg = cfg;
    tr.schedule = super::schedule::Schedule::from_config(&tr.cfg);
    let recs = kept_records(run, start);
    Ok((tr, data, dataset, recs))
}

/// RUN's state at the end of the stages kept is there to start from: its
/// Stage I finished and, when only Stage I is kept, its scattering set not
/// changed since by a later stage that trained it (RUN went past Stage I
/// and has no snapshot of its end). Starting at a later stage, RUN must
/// stand at the end of the stages kept instead ([`check_settings`]).
fn check_kept(run: &Path, h: &checkpoint::Header, start: usize) -> Result<()> {
    // A stage that ran (the run went past its start) and trained the scattering set changed it.
    let ran = |i: usize| h.iteration > kept_end(&h.config, i);
    if start == 0 {
        if let Some((_, k)) = later().into_iter().enumerate().find(|(i, k)| ran(*i) && k.trains_scattering(&h.config)) {
            bail!(
                "--from {}: its Stage {} trained the scattering set, and the run has no {} (Stage I's own state; runs from before it was written lack it): train Stage I again",
                run.display(),
                k.stage().name(),
                stage_checkpoint(1)
            );
        }
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

/// The settings may change only the stages that train again: starting at
/// a later stage (`--stages III`), RUN's stages before it must be finished
/// and stay as trained.
fn check_settings(run: &Path, h: &checkpoint::Header, cfg: &TrainConfig, start: usize) -> Result<()> {
    if start > 0 {
        let (end, before, first) = (kept_end(&h.config, start), later()[start - 1].stage(), later()[start].stage().name());
        if !h.holds(before) || h.iteration != end {
            bail!(
                "--from {} --stages {first} starts from that run's finished Stage {}; it is at iteration {} (Stage {} ends at {end}{}) and has no {}",
                run.display(),
                before.name(),
                h.iteration,
                before.name(),
                if !h.holds(before) { format!(", and it holds no Stage {} state", before.name()) } else { String::new() },
                stage_checkpoint(start + 1)
            );
        }
        let conflicts = changed_settings(&h.config, cfg, |k| from_setting(start, k))?;
        if !conflicts.is_empty() {
            bail!(
                "--from {} --stages {first} reuses that run's Stages {}; these options would change how they were trained:\n  {}\nonly {} may differ",
                run.display(),
                kept_stages(start).join(" and "),
                conflicts.join("\n  "),
                from_settings_text(start)
            );
        }
    }
    let conflicts = changed_settings(&h.config, cfg, |k| from_setting(0, k))?;
    if !conflicts.is_empty() {
        bail!(
            "--from {} reuses that run's Stage I; these options would change how it was trained:\n  {}\nonly {} may differ",
            run.display(),
            conflicts.join("\n  "),
            from_settings_text(0)
        );
    }
    if !cfg.wants(later()[0].stage().name()) {
        bail!("--from {}: stages = \"{}\" leaves nothing to run after its Stage I", run.display(), cfg.stages);
    }
    Ok(())
}

/// RUN's records of the stages kept, each marked with where it came from.
fn kept_records(run: &Path, start: usize) -> Vec<serde_json::Value> {
    let abs = std::fs::canonicalize(run).unwrap_or_else(|_| run.to_path_buf());
    let kept = kept_stages(start);
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
