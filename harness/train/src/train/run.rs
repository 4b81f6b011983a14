//! `tgs train`: the dataset (the built-in scene by default), the training
//! loop with a progress bar and a JSON-lines log, the switches between the
//! stages, periodic test evaluation and atomic checkpoints, Ctrl-C
//! handling, and the outputs (point_cloud.ply, test renders, metrics.json).
//! The settings are [`super::args`]'s; `--from RUN` is [`super::from`].

use super::args::resume_config;
pub use super::args::{config_from_args, dataset_dir, load_dataset, TrainArgs, RESUMABLE_SETTINGS};
pub use super::rundir::{run_files, stage_checkpoint, CHECKPOINT, DEFAULT_SCENE, RUN_RECORD, STAGE_ONE_CHECKPOINT, STAGE_TWO_CHECKPOINT};
use super::checkpoint;
use super::from::start_from;
pub use super::from::inherited_settings;
use super::config::paper_schedule_note;
use super::trainer::Trainer;
use crate::data::Dataset;
use crate::eval::{evaluate, Metrics};
use crate::outdir::OutDir;
use crate::export::atomic_write;
use crate::export::ply::write_splats;
use super::schedule::Stage;
use super::stages::RunPaths;
use anyhow::{bail, Context as _, Result};
use serde_json::json;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::Arc;
use std::time::Instant;
use super::clock::{Before, Clocks};
use super::validation::{back_to_stage_one, end_here, Validation};
use super::divergence::{high_learning_rates, likely_cause, DivergenceGuard, LR_WARN_FACTOR, MEANS_LIMIT};
use super::report::{lpips_text, Reporter};
use tgs_engine::Context;

/// What a finished (or interrupted) run reports.
#[derive(Clone, Debug)]
pub struct Outcome {
    pub iteration: u32,
    pub interrupted: bool,
    pub first_loss: Option<f64>,
    pub last_loss: f64,
    pub metrics: Option<Metrics>,
    pub wall_s: f64,
}

static INTERRUPTED: AtomicBool = AtomicBool::new(false);
/// Signals received by this process: never reset, so that a caller
/// running several trainings (a sweep) sees a signal that arrived while
/// none was in its loop, and a second signal aborts whatever runs.
static SIGNALS: AtomicU32 = AtomicU32::new(0);

/// Ctrl-C (SIGINT), SIGTERM (what batch schedulers send before killing a
/// job) and SIGHUP all stop training at the end of the iteration with a
/// checkpoint (a sweep: at the next safe point); a second one exits at
/// once. Installed once per process; later calls do nothing.
pub fn install_signal_handler() {
    // A second installation in one process (tests) fails harmlessly.
    let _ = ctrlc::set_handler(|| {
        INTERRUPTED.store(true, Ordering::SeqCst);
        if SIGNALS.fetch_add(1, Ordering::SeqCst) >= 1 {
            eprintln!("\nsecond interrupt: exiting at once");
            std::process::exit(130);
        }
        eprintln!("\ninterrupted (Ctrl-C or SIGTERM): stopping at the next safe point with a checkpoint (interrupt again to abort)");
    });
}

/// Signals this process has received so far (see [`install_signal_handler`]).
pub fn signals_received() -> u32 {
    SIGNALS.load(Ordering::SeqCst)
}

/// Ask a running `train` in this process to stop at the next iteration (as Ctrl-C does).
pub fn request_stop() {
    INTERRUPTED.store(true, Ordering::SeqCst);
}

/// The dataset's warnings on stderr (unless quiet).
fn show_warnings(data: &Dataset, quiet: bool) {
    if !quiet {
        for w in &data.warnings {
            eprintln!("tgs: warning: {w}");
        }
    }
}

pub fn train(ctx: &Arc<Context>, a: &TrainArgs) -> Result<Outcome> {
    crate::outdir::refuse_dataset(&a.out, a.dataset.as_deref())?;
    // One writer per run directory, for the whole run (released on return).
    let _lock = crate::lock::create_and_lock(&a.out, "tgs train", a.quiet)?;
    let signals_at_start = signals_received();
    let ckpt = a.out.join(CHECKPOINT);
    let start = Instant::now();
    if a.resume && a.from.is_some() {
        bail!("--resume continues OUT's own run; --from starts a new one from another run's Stage I: give one of them");
    }
    // With --from: the other run's records of the stages kept (metrics.json `stages`).
    let mut from_record: Vec<serde_json::Value> = Vec::new();
    if !a.resume && ckpt.is_file() {
        bail!("{} already holds a run (checkpoint.bin): pass --resume to continue it, or choose another --out", a.out.display());
    }
    if !a.resume {
        let mut dir = OutDir::open(&a.out, a.dataset.as_deref())?;
        for f in run_files() {
            dir.file(&f)?;
        }
    }
    let (mut tr, data, dataset_str, identity) = if a.resume {
        if !ckpt.is_file() {
            bail!("{}: no checkpoint to resume from", ckpt.display());
        }
        let (h, arrays) = checkpoint::read(&ckpt)?;
        let cfg = resume_config(a, &h.config)?;
        checkpoint::warn_missing_settings(&ckpt, &h, &cfg, a.quiet)?;
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
        let mut tr = checkpoint::restore(ctx, &ckpt, (h, arrays), &data)?;
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
        (tr, data, dataset, identity)
    } else if let Some(run) = &a.from {
        let (tr, data, dataset, kept) = start_from(ctx, a, run)?;
        from_record = kept;
        let identity = checkpoint::Identity { run_id: checkpoint::new_run_id(), fingerprint: data.fingerprint()? };
        (tr, data, dataset, identity)
    } else {
        let cfg = config_from_args(a)?;
        let dir = dataset_dir(a, a.quiet)?;
        let data = load_dataset(&dir, &cfg)?;
        let tr = Trainer::new(ctx, cfg, &data)?;
        // Absolute, so that --resume, eval and render work from any directory.
        let abs = std::fs::canonicalize(&dir).unwrap_or(dir);
        let identity = checkpoint::Identity { run_id: checkpoint::new_run_id(), fingerprint: data.fingerprint()? };
        (tr, data, abs.to_string_lossy().into_owned(), identity)
    };
    if !a.resume || !a.out.join(RUN_RECORD).is_file() {
        let rec = json!({"run_id": identity.run_id, "dataset": dataset_str, "dataset_files": identity.fingerprint.files.len(), "dataset_digest": format!("{:016x}", identity.fingerprint.digest())});
        atomic_write(&a.out.join(RUN_RECORD), serde_json::to_string_pretty(&rec)?.as_bytes())?;
    }
    show_warnings(&data, a.quiet);
    let validation = Validation::of(&data, &tr.cfg);
    preflight(&tr, &data, &validation, a.quiet)?;
    atomic_write(&a.out.join("config.toml"), toml::to_string(&tr.cfg)?.as_bytes())?;
    install_signal_handler();
    // A request_stop() of an earlier training in this process is spent;
    // a signal that arrived since this one started is not.
    INTERRUPTED.store(signals_received() > signals_at_start, Ordering::SeqCst);
    let guard = DivergenceGuard::install(&mut tr)?;

    let total = tr.schedule.total();
    let mut report = Reporter::open(&a.out, a.resume, a.quiet, total, tr.iteration)?;
    let note = if a.resume { None } else { a.preset.as_deref().and_then(|p| paper_schedule_note(p, &data.train.iter().map(|v| (v.camera.width, v.camera.height)).collect::<Vec<_>>())) };
    if let (Some(n), false) = (&note, a.quiet) {
        eprintln!("tgs: {n}");
    }
    if !a.quiet {
        eprintln!(
            "training on {} ({} train / {} test views, {}) with {} Gaussians on {}",
            data.root.display(),
            data.train.len(),
            data.test.len(),
            data.format,
            tr.scattering.set.len(),
            ctx.caps().describe()
        );
    }
    let mut timing_sums: BTreeMap<String, (f64, u64)> = BTreeMap::new();
    let mut first_loss = None;
    let mut last_loss = f64::NAN;
    let loop_start = Instant::now();
    let start_it = tr.iteration;
    let mut interrupted = false;
    let mut stages: Vec<serde_json::Value> = read_stage_records(&a.out, a.resume);
    stages.extend(from_record);
    let before = if a.resume { Before::read(&a.out, tr.iteration) } else { Before::default() };
    let mut clocks = Clocks::new(start, before);
    // checkpoint.bin and, beside it, the clocks at its iteration.
    let save_run = |tr: &Trainer, clocks: &Clocks| -> Result<()> {
        checkpoint::save(tr, &ckpt, &dataset_str, &identity)?;
        clocks.save(&a.out, tr.iteration)
    };
    // The later stages' views (the validation views held out).
    let view_names = validation.later_view_names(&data);
    // A run whose Stage II was dropped ended there (stages.json says so).
    if a.resume && validation.drops_stage_two(&stages) && tr.iteration > tr.cfg.iterations && tr.later.is_none() {
        end_here(&mut tr);
    }
    // Set when a skipped Stage II closed the last stage for good.
    let mut last_closed = false;
    while !tr.done() {
        // Between stages: close the last one, start the next, say so.
        let (entry, label) = tr.next_entry();
        let first_round = tr.schedule.round(entry) == 1;
        let begun = if let Some(kind) = tr.next_begins() {
            // A resume inside the stage begins it again (to rebuild what
            // is not checkpointed) without closing the stage before.
            let resumed = tr.later.as_ref().map(|m| m.stage()) == Some(kind.stage());
            let prev = tr.schedule.label(entry.saturating_sub(1));
            if !resumed {
                // The state at the end of the stage before
                // (checkpoint-stage1.bin, ...), for --from; not as a
                // stage begins again (reflection.reseed).
                if first_round {
                    checkpoint::save(&tr, &a.out.join(stage_checkpoint(entry)), &dataset_str, &identity)?;
                }
                let val = validation.measure(&mut tr)?;
                close_stage(&mut tr, &data, &a.out, &mut stages, &clocks, &prev, val)?;
                if !a.quiet {
                    eprintln!("Stage {prev} done");
                }
                if prev == "II" && validation.drops_stage_two(&stages) {
                    tr = drop_stage_two(ctx, &a.out, &data, &tr, &mut report, &validation, &stages)?;
                    last_closed = true;
                    atomic_write(&a.out.join("stages.json"), serde_json::to_string_pretty(&stages)?.as_bytes())?;
                    continue;
                }
            }
            let files = RunPaths { dir: &a.out, dataset: &data.root, view_names: &view_names };
            let b = tr.begin_next(Some(files), a.quiet)?;
            let mut event = json!({"iteration": tr.iteration, "stage": label, "event": "begin"});
            event.as_object_mut().expect("an object").extend(b.event);
            Some((b.message, event, resumed))
        } else {
            None
        };
        if let Some((msg, event, resumed)) = begun {
            // A stage begun again on --resume was logged when it first began.
            report.stage_event(&msg, (!resumed).then_some(&event), tr.schedule.total())?;
            clocks.next_stage();
            last_closed = tr.done();
            atomic_write(&a.out.join("stages.json"), serde_json::to_string_pretty(&stages)?.as_bytes())?;
            continue;
        }
        let r = tr.step(a.profile)?;
        let bad = guard.check(&tr)?;
        if !r.loss.is_finite() || !bad.is_empty() {
            let what = if r.loss.is_finite() { format!("{} went non-finite or past {MEANS_LIMIT:e} scene extents", bad.join(", ")) } else { format!("the loss is {}", r.loss) };
            checkpoint::save(&tr, &a.out.join("checkpoint-nonfinite.bin"), &dataset_str, &identity)?;
            let kept = checkpoint::read(&ckpt).map(|(h, _)| format!("{} holds iteration {}, the last state saved before", ckpt.display(), h.iteration)).unwrap_or_else(|_| format!("no checkpoint was saved before (checkpoint_interval {})", tr.cfg.checkpoint_interval));
            bail!("iteration {}: training diverged: {what}; {}. Stopped; {kept}, and the diverged state is in checkpoint-nonfinite.bin", r.iteration, likely_cause(&tr.cfg, &data));
        }
        first_loss.get_or_insert(r.loss);
        last_loss = r.loss;
        for t in &r.timings {
            let e = timing_sums.entry(t.name.clone()).or_insert((0.0, 0));
            e.0 += t.ms;
            e.1 += 1;
        }
        let elapsed = loop_start.elapsed().as_secs_f64();
        let its = (r.iteration - start_it) as f64 / elapsed.max(1e-9);
        let phi = tr.later.as_mut().and_then(|m| m.take_coverage());
        let mut line = Reporter::iteration_line(&r, &label, its, clocks.total_s(), phi);
        let cfg = &tr.cfg;
        if cfg.test_interval > 0 && r.iteration % cfg.test_interval == 0 && r.iteration < total && !data.test.is_empty() {
            let m = evaluate(&mut tr, &data.test, None)?;
            report.test_metrics(&mut line, r.iteration, &m);
        }
        report.iteration(&r, &line, total, its)?;
        let ck = tr.cfg.checkpoint_interval;
        if ck > 0 && r.iteration % ck == 0 && r.iteration < total {
            save_run(&tr, &clocks)?;
        }
        if INTERRUPTED.load(Ordering::SeqCst) {
            interrupted = true;
            break;
        }
    }
    report.finish();
    save_run(&tr, &clocks)?;
    if interrupted {
        if !a.quiet {
            eprintln!("stopped at iteration {}; checkpoint {}; continue with --resume", tr.iteration, ckpt.display());
        }
        return Ok(Outcome { iteration: tr.iteration, interrupted, first_loss, last_loss, metrics: None, wall_s: clocks.total_s() });
    }
    let train_s = clocks.train_s();
    let test_metrics = |tr: &mut Trainer| -> Result<Option<Metrics>> { if data.test.is_empty() { Ok(None) } else { Ok(Some(evaluate(tr, &data.test, Some(&mut OutDir::open(&a.out.join("renders/test"), Some(&data.root))?))?)) } };
    let mut metrics = test_metrics(&mut tr)?;
    if !last_closed {
        let last_stage = tr.schedule.label(tr.schedule.stages.len().saturating_sub(1));
        stages.retain(|s| s["stage"] != last_stage.as_str());
        let mut rec = stage_record(&last_stage, &tr, clocks.stage_s(), metrics.as_ref());
        rec["validation"] = json!(validation.measure(&mut tr)?);
        stages.push(rec);
        if last_stage == "II" && validation.drops_stage_two(&stages) {
            tr = drop_stage_two(ctx, &a.out, &data, &tr, &mut report, &validation, &stages)?;
            save_run(&tr, &clocks)?;
            metrics = test_metrics(&mut tr)?;
        }
    }
    write_splats(&a.out.join("point_cloud.ply"), &tr.gaussians()?)?;
    if let Some(m) = &tr.later {
        m.write_outputs(&a.out)?;
    }
    let timings: BTreeMap<String, f64> = timing_sums.iter().map(|(k, (ms, _))| (k.clone(), ms / (tr.iteration - start_it).max(1) as f64)).collect();
    let doc = json!({
        "dataset": dataset_str,
        "device": ctx.caps().describe(),
        "iterations": tr.iteration,
        "gaussians": tr.scattering.set.len(),
        "train_wall_s": train_s,
        "total_wall_s": clocks.total_s(),
        "first_loss": first_loss,
        "final_loss": last_loss,
        "test": metrics,
        "stages": stages,
        "reflection": reflection_record(&tr, &validation, &stages),
        "validation": validation.report(&stages),
        "gpu_ms_per_iteration": if a.profile { json!(timings) } else { json!(null) },
    });
    atomic_write(&a.out.join("metrics.json"), serde_json::to_string_pretty(&doc)?.as_bytes())?;
    if !a.quiet {
        if let Some(m) = &metrics {
            let mae = m.normals.normal_mae_deg.map(|v| format!(", normal MAE {v:.2}°")).unwrap_or_default();
            eprintln!("done: {} iterations in {train_s:.1}s, {} Gaussians; test PSNR {:.2}, SSIM {:.4}{}{mae}", tr.iteration, tr.scattering.set.len(), m.psnr, m.ssim, lpips_text(m.lpips));
        }
        if a.profile {
            eprintln!("GPU ms per iteration by kernel:");
            for (k, v) in &timings {
                eprintln!("  {k:24} {v:9.3}");
            }
        }
        eprintln!("outputs in {}", a.out.display());
    }
    Ok(Outcome { iteration: tr.iteration, interrupted, first_loss, last_loss, metrics, wall_s: clocks.total_s() })
}


/// What can be checked before any training: learning rates far above the
/// presets' (warned; above the limit they were refused with the settings)
/// and the paths the later stages will read (`reflection.seed_masks`),
/// read now rather than after Stage I has trained.
fn preflight(tr: &Trainer, data: &Dataset, validation: &Validation, quiet: bool) -> Result<()> {
    if !quiet {
        for w in high_learning_rates(&tr.cfg)? {
            eprintln!("tgs: warning: {w}: {LR_WARN_FACTOR}x or more the presets'; training may diverge");
        }
    }
    let rc = &tr.cfg.reflection;
    if tr.cfg.wants_reflection() && !rc.seed_masks.is_empty() && tr.later.is_none() {
        // The names of the views the trainer holds (without the validation views once held out).
        let names: Vec<String> = if tr.held_out { validation.later_view_names(data) } else { data.train.iter().map(|v| v.name.clone()).collect() };
        super::stages::reflection::stage::seed_masks(Path::new(&rc.seed_masks), &names, &tr.views.cameras, tr.cfg.downscale).context("checked before training")?;
    }
    Ok(())
}

/// Stage II's set did not raise the validation views' PSNR: the run goes
/// back to Stage I's model ([`back_to_stage_one`]), says so and logs it.
fn drop_stage_two(ctx: &Arc<Context>, out: &Path, data: &Dataset, tr: &Trainer, report: &mut Reporter, validation: &Validation, stages: &[serde_json::Value]) -> Result<Trainer> {
    let t = back_to_stage_one(ctx, out, data, tr)?;
    let msg = "Stage II dropped: its reflection set did not raise the validation views' PSNR over Stage I's (validation_margin_db); Stage I's model is the result";
    report.stage_event(msg, Some(&json!({"iteration": t.iteration, "stage": "II", "event": "dropped", "validation": validation.verdicts(stages)})), t.schedule.total())?;
    Ok(t)
}

/// metrics.json's `reflection`: the Stage II decision and, with a
/// validation slice and a Stage II that ran, whether its set was kept.
fn reflection_record(tr: &Trainer, validation: &Validation, stages: &[serde_json::Value]) -> serde_json::Value {
    let mut r = json!(tr.decision);
    let ran = tr.decision.as_ref().is_some_and(|d| d.run);
    if let (true, true, Some(o)) = (validation.is_on(), ran, r.as_object_mut()) {
        o.insert("kept".into(), json!(!validation.drops_stage_two(stages)));
    }
    r
}

/// metrics.json's record of a finished stage.
fn stage_record(stage: &str, tr: &Trainer, wall_s: f64, m: Option<&Metrics>) -> serde_json::Value {
    let its = tr.schedule.iterations_of(stage);
    let test = m.map(|m| {
        json!({"psnr": m.psnr, "ssim": m.ssim, "lpips": m.lpips, "normal_mae_deg": m.normals.normal_mae_deg, "normal_mae_scattering_deg": m.normals.normal_mae_scattering_deg,
               "reflection_coverage": m.normals.reflection_coverage, "normal_mae_covered_deg": m.normals.normal_mae_covered_deg,
               "reflection_outside_mask": m.normals.reflection_outside_mask, "normal_mae_ray_facing_deg": m.normals.normal_mae_ray_facing_deg,
               "normal_mae_outside_deg": m.normals.normal_mae_outside_deg,
               "reflection_gain_mask": m.normals.reflection_gain_mask, "reflection_gain_outside": m.normals.reflection_gain_outside,
               "residual_contrast": m.normals.residual_contrast})
    });
    json!({"stage": stage, "iterations": its, "wall_s": wall_s, "test": test})
}

/// The stage records of the run so far (kept in stages.json across a resume).
fn read_stage_records(out: &Path, resume: bool) -> Vec<serde_json::Value> {
    if !resume {
        return Vec::new();
    }
    std::fs::read(out.join("stages.json")).ok().and_then(|b| serde_json::from_slice(&b).ok()).unwrap_or_default()
}

/// Where a closed stage's test renders go: renders/stage1, stage2,
/// stage3, and stage2.2 / stage3.2 for a second round.
fn renders_dir(label: &str) -> String {
    let (name, round) = label.split_once('.').map(|(n, r)| (n, format!(".{r}"))).unwrap_or((label, String::new()));
    let n = Stage::named(name).map(Stage::number).unwrap_or(0);
    format!("stage{n}{round}")
}

/// Close `stage`: its test metrics (renders in OUT/renders/stageN) into
/// its record in `stages`. A stage taken
/// from another run (--from) keeps that run's record (its wall time, where
/// it came from); the test metrics are re-measured.
fn close_stage(tr: &mut Trainer, data: &Dataset, out: &Path, stages: &mut Vec<serde_json::Value>, clock: &Clocks, stage: &str, validation: Option<serde_json::Value>) -> Result<()> {
    let dir = out.join("renders").join(renders_dir(stage));
    let m = if data.test.is_empty() { None } else { Some(evaluate(tr, &data.test, Some(&mut OutDir::open(&dir, Some(&data.root))?))?) };
    let from = stages.iter().find(|s| s["stage"] == stage && s.get("from").is_some()).cloned();
    stages.retain(|s| s["stage"] != stage);
    let mut rec = stage_record(stage, tr, clock.stage_s(), m.as_ref());
    rec["validation"] = json!(validation);
    if let Some(f) = from {
        rec["wall_s"] = f["wall_s"].clone();
        rec["from"] = f["from"].clone();
    }
    stages.push(rec);
    Ok(())
}

/// Drop the log lines of iterations after `iteration` (those a killed run
/// logged past its last checkpoint, which the resumed run logs again).
fn truncate_log(path: &Path, iteration: u32) -> Result<()> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(e).with_context(|| format!("{}: cannot read", path.display())),
    };
    let mut kept = String::new();
    for line in text.lines() {
        // A line torn by the kill does not parse: it is dropped too.
        let it = serde_json::from_str::<serde_json::Value>(line).ok().and_then(|v| v["iteration"].as_u64());
        if it.is_some_and(|i| i <= iteration as u64) {
            kept.push_str(line);
            kept.push('\n');
        }
    }
    if kept.len() != text.len() {
        atomic_write(path, kept.as_bytes())?;
    }
    Ok(())
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
