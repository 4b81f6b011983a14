//! Opening a run: a new one, OUT's own resumed (`--resume`), one started
//! from another run's Stage I (`--from`), or a finished one for `tgs eval`,
//! `render` and `view`.

use super::args::{config_from_args, dataset_dir, load_dataset, output_settings, resume_config, TrainArgs};
use super::checkpoint;
use super::from::start_from;
use super::records::truncate_log;
use super::rundir::{run_files, CHECKPOINT, RUN_RECORD};
use super::trainer::Trainer;
use crate::data::Dataset;
use crate::export::atomic_write;
use crate::outdir::OutDir;
use anyhow::{bail, Context as _, Result};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use tgs_engine::Context;

/// A trainer ready to run, with its dataset and where it came from.
pub(super) struct Opened {
    pub(super) tr: Trainer,
    pub(super) data: Dataset,
    /// The dataset's path as the run records it.
    pub(super) dataset: String,
    pub(super) identity: checkpoint::Identity,
    /// With --from: the other run's records of the stages kept (metrics.json `stages`).
    pub(super) from_record: Vec<Value>,
}

/// The trainer the arguments ask for (`--resume`, `--from` or a new run),
/// with OUT prepared and its run record (run.json) written.
pub(super) fn open_trainer(ctx: &Arc<Context>, a: &TrainArgs, ckpt: &Path) -> Result<Opened> {
    if a.resume && a.from.is_some() {
        bail!("--resume continues OUT's own run; --from starts a new one from another run's Stage I: give one of them");
    }
    if !a.resume && ckpt.is_file() {
        bail!("{} already holds a run (checkpoint.bin): pass --resume to continue it, or choose another --out", a.out.display());
    }
    if !a.resume {
        let mut dir = OutDir::open(&a.out, a.dataset.as_deref())?;
        for f in run_files() {
            dir.file(&f)?;
        }
    }
    let opened = if a.resume {
        resume_trainer(ctx, a, ckpt)?
    } else if let Some(run) = &a.from {
        let (tr, data, dataset, kept) = start_from(ctx, a, run)?;
        let identity = checkpoint::Identity { run_id: checkpoint::new_run_id(), fingerprint: data.fingerprint()? };
        Opened { tr, data, dataset, identity, from_record: kept }
    } else {
        new_trainer(ctx, a)?
    };
    if !a.resume || !a.out.join(RUN_RECORD).is_file() {
        let (identity, dataset) = (&opened.identity, &opened.dataset);
        let rec = json!({"run_id": identity.run_id, "dataset": dataset, "dataset_files": identity.fingerprint.files.len(), "dataset_digest": format!("{:016x}", identity.fingerprint.digest())});
        atomic_write(&a.out.join(RUN_RECORD), serde_json::to_string_pretty(&rec)?.as_bytes())?;
    }
    Ok(opened)
}

/// Continue OUT's own run from its checkpoint, with the settings
/// `--resume` may change.
fn resume_trainer(ctx: &Arc<Context>, a: &TrainArgs, ckpt: &Path) -> Result<Opened> {
    if !ckpt.is_file() {
        bail!("{}: no checkpoint to resume from", ckpt.display());
    }
    let (h, arrays) = checkpoint::read(ckpt)?;
    let cfg = resume_config(a, &h.config)?;
    checkpoint::warn_missing_settings(ckpt, &h, &cfg, a.quiet)?;
    let dir = PathBuf::from(&h.dataset);
    if let Some(given) = &a.dataset {
        let same = std::fs::canonicalize(given).map(|g| g == dir).unwrap_or(false);
        if !same {
            bail!("--resume continues the run on its own dataset {}; {} was given (leave it out, or start a new run with another --out)", dir.display(), given.display());
        }
    }
    check_run_record(&a.out, &h)?;
    let data = load_dataset(&dir, &h.config)?;
    let dataset = h.dataset.clone();
    let identity = match &h.identity {
        Some(id) => id.clone(),
        None => checkpoint::Identity { run_id: checkpoint::new_run_id(), fingerprint: data.fingerprint()? },
    };
    let h_stage1 = h.config.iterations;
    let mut tr = checkpoint::restore(ctx, ckpt, (h, arrays), &data)?;
    let total = super::schedule::Schedule::from_config(&cfg).total();
    if total < tr.iteration || cfg.iterations < tr.iteration.min(h_stage1) {
        bail!("--iterations {} ({total} in all stages): the checkpoint is already at iteration {}", cfg.iterations, tr.iteration);
    }
    if tr.iteration > h_stage1 && cfg.iterations != h_stage1 {
        bail!("iterations {}: the run finished Stage I at {h_stage1} and is in Stage II; Stage I's length cannot change now", cfg.iterations);
    }
    tr.cfg = cfg;
    tr.schedule = super::schedule::Schedule::from_config(&tr.cfg);
    truncate_log(&a.out.join("log.jsonl"), tr.iteration)?;
    Ok(Opened { tr, data, dataset, identity, from_record: Vec::new() })
}

/// A new run on the dataset and settings the arguments give.
fn new_trainer(ctx: &Arc<Context>, a: &TrainArgs) -> Result<Opened> {
    let cfg = config_from_args(a)?;
    let dir = dataset_dir(a, a.quiet)?;
    let data = load_dataset(&dir, &cfg)?;
    let tr = Trainer::new(ctx, cfg, &data)?;
    // Absolute, so that --resume, eval and render work from any directory.
    let abs = std::fs::canonicalize(&dir).unwrap_or(dir);
    let identity = checkpoint::Identity { run_id: checkpoint::new_run_id(), fingerprint: data.fingerprint()? };
    Ok(Opened { tr, data, dataset: abs.to_string_lossy().into_owned(), identity, from_record: Vec::new() })
}

/// A `--resume`'s checkpoint must be this run directory's own: the run id
/// in run.json (written when the run started) and the checkpoint's agree.
fn check_run_record(out: &Path, h: &checkpoint::Header) -> Result<()> {
    let path = out.join(RUN_RECORD);
    let Ok(bytes) = std::fs::read(&path) else { return Ok(()) };
    let rec: serde_json::Value = serde_json::from_slice(&bytes).with_context(|| format!("{}: not valid JSON", path.display()))?;
    let mine = rec["run_id"].as_str().unwrap_or("");
    match &h.identity {
        Some(id) if id.run_id != mine => bail!(
            "{}: the checkpoint belongs to another run (run {} on {}), not to this directory's run {mine} on {} ({}): a checkpoint cannot be moved between runs; train a new run",
            out.join(CHECKPOINT).display(),
            id.run_id,
            h.dataset,
            rec["dataset"].as_str().unwrap_or("?"),
            path.display()
        ),
        _ => Ok(()),
    }
}

/// Load a run directory's checkpoint with its dataset.
pub fn open_run(ctx: &Arc<Context>, run: &Path) -> Result<(Trainer, Dataset)> {
    let ckpt = run.join(CHECKPOINT);
    let (h, arrays) = checkpoint::read(&ckpt)?;
    let data = load_dataset(Path::new(&h.dataset), &h.config).with_context(|| format!("loading the run's dataset {}", h.dataset))?;
    let tr = checkpoint::restore(ctx, &ckpt, (h, arrays), &data)?;
    Ok((tr, data))
}

/// Overlay `KEY=VALUE` pairs of [`output_settings`] on an opened run's
/// settings (in memory: the run is not changed); any other key is refused.
pub fn set_output_settings(tr: &mut Trainer, set: &[String]) -> Result<()> {
    // On a copy: a refused value leaves the run's settings as they were.
    let mut cfg = tr.cfg.clone();
    for kv in set {
        let key = kv.split_once('=').map_or(kv.as_str(), |(k, _)| k.trim());
        let allowed = output_settings();
        if !allowed.contains(&key) {
            bail!("--set '{kv}': only settings that change a trained model's output, not its training, can be given here ({})", allowed.join(", "));
        }
        cfg.set(kv)?;
    }
    tr.cfg = cfg;
    Ok(())
}
