//! `tgs train`: the dataset (the built-in scene by default), the training
//! loop with a progress bar and a JSON-lines log, the switches between the
//! stages, periodic test evaluation and atomic checkpoints, Ctrl-C
//! handling, and the outputs (point_cloud.ply, test renders, metrics.json).
//! The settings are [`super::args`]'s; `--from RUN` is [`super::from`].

pub use super::args::{config_from_args, dataset_dir, load_dataset, TrainArgs};
use super::checkpoint;
use super::clock::{Before, Clocks};
use super::config::paper_schedule_note;
use super::divergence::{high_learning_rates, likely_cause, DivergenceGuard, LR_WARN_FACTOR, MEANS_LIMIT};
pub use super::from::inherited_settings;
use super::live::Live;
pub use super::open::{open_run, set_output_settings};
use super::open::{open_trainer, Opened};
use super::piece_verdict::judge;
use super::records::{close_stage, read_stage_records, reflection_record, stage_record, write_stage_records, Closing};
use super::report::{lpips_text, Reporter};
pub use super::rundir::{run_files, stage_checkpoint, CHECKPOINT, DEFAULT_SCENE, RUN_RECORD, STAGE_ONE_CHECKPOINT, STAGE_TWO_CHECKPOINT};
use super::signals::{arm, stop_requested};
pub use super::signals::{install_signal_handler, request_stop, signals_received};
use super::stages::{LaterKind, RunPaths};
use super::trainer::{StepReport, Trainer};
use super::validation::{back_to_before, before, end_here, Validation};
use crate::data::Dataset;
use crate::eval::{evaluate, Metrics};
use crate::export::atomic_write;
use crate::export::ply::write_splats;
use crate::outdir::OutDir;
use anyhow::{bail, Context as _, Result};
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;
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

/// The dataset's warnings on stderr (unless quiet).
fn show_warnings(data: &Dataset, quiet: bool) {
    if !quiet {
        for w in &data.warnings {
            eprintln!("tgs: warning: {w}");
        }
    }
}

/// Everything of a run beside its trainer: where it writes, what it has
/// measured and recorded so far.
struct Run<'a> {
    ctx: &'a Arc<Context>,
    a: &'a TrainArgs,
    ckpt: PathBuf,
    data: Dataset,
    dataset: String,
    identity: checkpoint::Identity,
    validation: Validation,
    report: Reporter,
    clocks: Clocks,
    stages: Vec<Value>,
    /// The later stages' views (the validation views held out).
    view_names: Vec<String>,
    /// GPU milliseconds and samples per kernel scope.
    timing_sums: BTreeMap<String, (f64, u64)>,
    first_loss: Option<f64>,
    last_loss: f64,
    loop_start: Instant,
    start_it: u32,
    /// The schedule's length as the run began (the progress bar's and the
    /// periodic checkpoints' end).
    total: u32,
    /// Set when a dropped or skipped stage closed the last stage for good.
    last_closed: bool,
    live: Option<Live>,
}

pub fn train(ctx: &Arc<Context>, a: &TrainArgs) -> Result<Outcome> {
    crate::outdir::refuse_dataset(&a.out, a.dataset.as_deref())?;
    // One writer per run directory, for the whole run (released on return).
    let _lock = crate::lock::create_and_lock(&a.out, "tgs train", a.quiet)?;
    let signals_at_start = signals_received();
    let ckpt = a.out.join(CHECKPOINT);
    let start = Instant::now();
    let Opened { mut tr, data, dataset, identity, from_record } = open_trainer(ctx, a, &ckpt)?;
    show_warnings(&data, a.quiet);
    let validation = Validation::of(&data, &tr.cfg);
    preflight(&tr, &data, &validation, a.quiet)?;
    atomic_write(&a.out.join("config.toml"), toml::to_string(&tr.cfg)?.as_bytes())?;
    install_signal_handler();
    arm(signals_at_start);
    let guard = DivergenceGuard::install(&mut tr)?;
    let total = tr.schedule.total();
    let report = Reporter::open(&a.out, a.resume, a.quiet, total, tr.iteration)?;
    say_start(ctx, a, &tr, &data);
    let loop_start = Instant::now();
    let mut stages = read_stage_records(&a.out, a.resume);
    stages.extend(from_record);
    let before = if a.resume { Before::read(&a.out, tr.iteration) } else { Before::default() };
    let view_names = validation.later_view_names(&data);
    let start_it = tr.iteration;
    let clocks = Clocks::new(start, before);
    let mut run = Run {
        ctx,
        a,
        ckpt,
        data,
        dataset,
        identity,
        validation,
        report,
        clocks,
        stages,
        view_names,
        timing_sums: BTreeMap::new(),
        first_loss: None,
        last_loss: f64::NAN,
        loop_start,
        start_it,
        total,
        last_closed: false,
        live: a.live.as_ref().map(Live::new),
    };
    // A run whose later stage was dropped ended there (stages.json says
    // so): past that stage's start, its checkpoint holds the model before it.
    if let Some((kind, _)) = run.validation.dropped(&run.stages).filter(|_| a.resume) {
        let holds_it = tr.later.as_ref().is_some_and(|m| m.stage() == kind.stage());
        if tr.iteration > tr.schedule.start_of(kind.stage()) && !holds_it {
            end_here(&mut tr);
        }
    }
    while !tr.done() {
        let (entry, label) = tr.next_entry();
        if let Some(kind) = tr.next_begins() {
            run.between_stages(&mut tr, kind, entry, &label)?;
            run.show(&tr, &label, true)?;
            continue;
        }
        let r = tr.step(a.profile)?;
        run.stop_if_diverged(&tr, &guard, &r)?;
        run.after_step(&mut tr, &r, &label)?;
        run.show(&tr, &label, false)?;
        if stop_requested() {
            return run.interrupted(&tr);
        }
    }
    run.finish(tr)
}

/// A stage's validation record with the number of its pieces kept, when judged.
fn with_pieces(validation: Option<Value>, kept: Option<usize>) -> Option<Value> {
    let mut v = validation?;
    if let Some(k) = kept {
        v["pieces_kept"] = json!(k);
    }
    Some(v)
}

/// The paper schedule's note for a preset and what the run trains on, on stderr.
fn say_start(ctx: &Arc<Context>, a: &TrainArgs, tr: &Trainer, data: &Dataset) {
    if a.quiet {
        return;
    }
    let sizes: Vec<(u32, u32)> = data.train.iter().map(|v| (v.camera.width, v.camera.height)).collect();
    if let Some(n) = a.preset.as_deref().filter(|_| !a.resume).and_then(|p| paper_schedule_note(p, &sizes)) {
        eprintln!("tgs: {n}");
    }
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

impl Run<'_> {
    /// Hand the live view the model (`now`: whatever the time since the last).
    fn show(&mut self, tr: &Trainer, label: &str, now: bool) -> Result<()> {
        match self.live.as_mut() {
            Some(l) => l.offer(tr, &self.dataset, label, self.total, now),
            None => Ok(()),
        }
    }

    /// checkpoint.bin and, beside it, the clocks at its iteration.
    fn save(&self, tr: &Trainer) -> Result<()> {
        checkpoint::save(tr, &self.ckpt, &self.dataset, &self.identity)?;
        self.clocks.save(&self.a.out, tr.iteration)
    }

    /// Between stages: close the last one (or drop it), start the next
    /// (`kind`, at schedule entry `entry`), say so.
    fn between_stages(&mut self, tr: &mut Trainer, kind: &dyn LaterKind, entry: usize, label: &str) -> Result<()> {
        let out = &self.a.out;
        let first_round = tr.schedule.round(entry) == 1;
        // A resume inside the stage begins it again (to rebuild what is
        // not checkpointed) without closing the stage before.
        let resumed = tr.later.as_ref().map(|m| m.stage()) == Some(kind.stage());
        if !resumed {
            let prev = tr.schedule.label(entry.saturating_sub(1));
            let pieces_kept = self.judge_pieces(tr, &prev)?;
            // The state at the end of the stage before (checkpoint-stage1.bin,
            // ...), for --from; not as a stage begins again (reflection.reseed).
            if first_round {
                checkpoint::save(tr, &out.join(stage_checkpoint(entry)), &self.dataset, &self.identity)?;
            }
            let validation = with_pieces(self.validation.measure(tr)?, pieces_kept);
            close_stage(tr, &self.data, out, &mut self.stages, Closing { stage: &prev, clock: &self.clocks, validation })?;
            if !self.a.quiet {
                eprintln!("Stage {prev} done");
            }
            if let Some(dropped) = self.validation.drops(&self.stages, &prev) {
                *tr = self.drop_stage(tr, dropped)?;
                self.last_closed = true;
                return write_stage_records(out, &self.stages);
            }
        }
        let files = RunPaths { dir: out, dataset: &self.data.root, view_names: &self.view_names };
        let b = tr.begin_next(Some(files), self.a.quiet)?;
        let mut event = json!({"iteration": tr.iteration, "stage": label, "event": "begin"});
        event.as_object_mut().expect("an object").extend(b.event);
        // A stage begun again on --resume was logged when it first began.
        self.report.stage_event(&b.message, (!resumed).then_some(&event), tr.schedule.total())?;
        self.clocks.next_stage();
        self.last_closed = tr.done();
        write_stage_records(out, &self.stages)
    }

    /// Before a Stage II round closes: its pieces judged on the validation
    /// views and those not kept removed ([`judge`]), said, logged and kept
    /// in the decision. The number kept, when judged.
    fn judge_pieces(&mut self, tr: &mut Trainer, label: &str) -> Result<Option<usize>> {
        let Some(o) = judge(tr, &self.validation)? else { return Ok(None) };
        let event = json!({"iteration": tr.iteration, "stage": label, "event": "pieces", "kept": o.kept(), "gaussians": [o.before, o.after], "pieces": o.verdicts});
        self.report.stage_event(&o.message(label), Some(&event), tr.schedule.total())?;
        let kept = o.kept();
        if let Some(d) = tr.decision.as_mut() {
            d.pieces = Some(o.verdicts);
        }
        Ok(Some(kept))
    }

    /// The stage of `kind`, adding `what` (Stage II's reflection set), did
    /// not raise the validation views' PSNR: the run goes back to the model
    /// before it ([`back_to_before`]), says so and logs it.
    fn drop_stage(&mut self, tr: &Trainer, (kind, what): (&dyn LaterKind, &str)) -> Result<Trainer> {
        let (stage, label) = (kind.stage(), kind.stage().name());
        let t = back_to_before(self.ctx, &self.a.out, &self.data, tr, stage)?;
        let b = before(stage).name();
        let msg = format!("Stage {label} dropped: its {what} did not raise the validation views' PSNR over Stage {b}'s (validation_margin_db); Stage {b}'s model is the result");
        let event = json!({"iteration": t.iteration, "stage": label, "event": "dropped", "validation": self.validation.verdicts(&self.stages)});
        self.report.stage_event(&msg, Some(&event), t.schedule.total())?;
        Ok(t)
    }

    /// A non-finite loss or a set the guard flags ends the run with the
    /// diverged state saved apart and the likely cause named.
    fn stop_if_diverged(&self, tr: &Trainer, guard: &DivergenceGuard, r: &StepReport) -> Result<()> {
        let bad = guard.check(tr)?;
        if r.loss.is_finite() && bad.is_empty() {
            return Ok(());
        }
        let what = if r.loss.is_finite() { format!("{} went non-finite or past {MEANS_LIMIT:e} scene extents", bad.join(", ")) } else { format!("the loss is {}", r.loss) };
        checkpoint::save(tr, &self.a.out.join("checkpoint-nonfinite.bin"), &self.dataset, &self.identity)?;
        let kept = checkpoint::read(&self.ckpt)
            .map(|(h, _)| format!("{} holds iteration {}, the last state saved before", self.ckpt.display(), h.iteration))
            .unwrap_or_else(|_| format!("no checkpoint was saved before (checkpoint_interval {})", tr.cfg.checkpoint_interval));
        bail!(
            "iteration {}: training diverged: {what}; {}. Stopped; {kept}, and the diverged state is in checkpoint-nonfinite.bin",
            r.iteration,
            likely_cause(&tr.cfg, &self.data)
        );
    }

    /// After a step: the losses and timings, the log line (with the test
    /// metrics when due) and the periodic checkpoint.
    fn after_step(&mut self, tr: &mut Trainer, r: &StepReport, label: &str) -> Result<()> {
        self.first_loss.get_or_insert(r.loss);
        self.last_loss = r.loss;
        for t in &r.timings {
            let e = self.timing_sums.entry(t.name.clone()).or_insert((0.0, 0));
            e.0 += t.ms;
            e.1 += 1;
        }
        let total = self.total;
        let elapsed = self.loop_start.elapsed().as_secs_f64();
        let its = (r.iteration - self.start_it) as f64 / elapsed.max(1e-9);
        let phi = tr.later.as_mut().and_then(|m| m.take_coverage());
        let mut line = Reporter::iteration_line(r, label, its, self.clocks.total_s(), phi);
        let cfg = &tr.cfg;
        if cfg.test_interval > 0 && r.iteration.is_multiple_of(cfg.test_interval) && r.iteration < total && !self.data.test.is_empty() {
            let m = evaluate(tr, &self.data.test, None)?;
            self.report.test_metrics(&mut line, r.iteration, &m);
        }
        self.report.iteration(r, &line, total, its)?;
        let ck = tr.cfg.checkpoint_interval;
        if ck > 0 && r.iteration.is_multiple_of(ck) && r.iteration < total {
            self.save(tr)?;
        }
        Ok(())
    }

    /// Stopped by a signal or request_stop(): the checkpoint, and how to go on.
    fn interrupted(self, tr: &Trainer) -> Result<Outcome> {
        self.report.finish();
        self.save(tr)?;
        if !self.a.quiet {
            eprintln!("stopped at iteration {}; checkpoint {}; continue with --resume", tr.iteration, self.ckpt.display());
        }
        Ok(Outcome { iteration: tr.iteration, interrupted: true, first_loss: self.first_loss, last_loss: self.last_loss, metrics: None, wall_s: self.clocks.total_s() })
    }

    /// The test metrics of the model as it is (renders in OUT/renders/test).
    fn test_metrics(&self, tr: &mut Trainer) -> Result<Option<Metrics>> {
        if self.data.test.is_empty() {
            return Ok(None);
        }
        Ok(Some(evaluate(tr, &self.data.test, Some(&mut OutDir::open(&self.a.out.join("renders/test"), Some(&self.data.root))?))?))
    }

    /// The end of training: the last stage closed (or dropped), the outputs
    /// and metrics.json written, the summary said.
    fn finish(mut self, mut tr: Trainer) -> Result<Outcome> {
        let last_stage = tr.schedule.label(tr.schedule.stages.len().saturating_sub(1));
        let pieces_kept = if self.last_closed { None } else { self.judge_pieces(&mut tr, &last_stage)? };
        self.report.finish();
        self.save(&tr)?;
        let train_s = self.clocks.train_s();
        let mut metrics = self.test_metrics(&mut tr)?;
        if !self.last_closed {
            self.stages.retain(|s| s["stage"] != last_stage.as_str());
            let mut rec = stage_record(&last_stage, &tr, self.clocks.stage_s(), metrics.as_ref());
            rec["validation"] = json!(with_pieces(self.validation.measure(&mut tr)?, pieces_kept));
            self.stages.push(rec);
            if let Some(dropped) = self.validation.drops(&self.stages, &last_stage) {
                tr = self.drop_stage(&tr, dropped)?;
                self.save(&tr)?;
                metrics = self.test_metrics(&mut tr)?;
            }
        }
        write_splats(&self.a.out.join("point_cloud.ply"), &tr.gaussians()?)?;
        if let Some(l) = self.live.as_mut() {
            l.offer(&tr, &self.dataset, "done", self.total, true)?;
        }
        if let Some(m) = &tr.later {
            m.write_outputs(&self.a.out)?;
        }
        let timings: BTreeMap<String, f64> = self.timing_sums.iter().map(|(k, (ms, _))| (k.clone(), ms / (tr.iteration - self.start_it).max(1) as f64)).collect();
        let doc = json!({
            "dataset": self.dataset,
            "device": self.ctx.caps().describe(),
            "iterations": tr.iteration,
            "gaussians": tr.scattering.set.len(),
            "train_wall_s": train_s,
            "total_wall_s": self.clocks.total_s(),
            "first_loss": self.first_loss,
            "final_loss": self.last_loss,
            "test": metrics,
            "stages": self.stages,
            "reflection": reflection_record(&tr, &self.validation, &self.stages),
            "validation": self.validation.report(&self.stages),
            "gpu_ms_per_iteration": if self.a.profile { json!(timings) } else { json!(null) },
        });
        atomic_write(&self.a.out.join("metrics.json"), serde_json::to_string_pretty(&doc)?.as_bytes())?;
        self.say_done(&tr, metrics.as_ref(), train_s, &timings);
        Ok(Outcome { iteration: tr.iteration, interrupted: false, first_loss: self.first_loss, last_loss: self.last_loss, metrics, wall_s: self.clocks.total_s() })
    }

    /// The summary on stderr (unless quiet).
    fn say_done(&self, tr: &Trainer, metrics: Option<&Metrics>, train_s: f64, timings: &BTreeMap<String, f64>) {
        if self.a.quiet {
            return;
        }
        if let Some(m) = metrics {
            let mae = m.normals.normal_mae_deg.map(|v| format!(", normal MAE {v:.2}°")).unwrap_or_default();
            eprintln!(
                "done: {} iterations in {train_s:.1}s, {} Gaussians; test PSNR {:.2}, SSIM {:.4}{}{mae}",
                tr.iteration,
                tr.scattering.set.len(),
                m.psnr,
                m.ssim,
                lpips_text(m.lpips)
            );
        }
        if self.a.profile {
            eprintln!("GPU ms per iteration by kernel:");
            for (k, v) in timings {
                eprintln!("  {k:24} {v:9.3}");
            }
        }
        eprintln!("outputs in {}", self.a.out.display());
    }
}

/// What can be checked before any training: learning rates far above the
/// presets' (warned; above the limit they were refused with the settings)
/// and the inputs the later stages will read ([`super::stages::LaterKind::preflight`]:
/// `reflection.seed_masks`), read now rather than after Stage I has trained.
fn preflight(tr: &Trainer, data: &Dataset, validation: &Validation, quiet: bool) -> Result<()> {
    if !quiet {
        for w in high_learning_rates(&tr.cfg)? {
            eprintln!("tgs: warning: {w}: {LR_WARN_FACTOR}x or more the presets'; training may diverge");
        }
    }
    if tr.later.is_some() {
        return Ok(());
    }
    // The names of the views the trainer holds (without the validation views once held out).
    let names: Vec<String> = if tr.held_out { validation.later_view_names(data) } else { data.train.iter().map(|v| v.name.clone()).collect() };
    for k in super::stages::later().into_iter().filter(|k| tr.cfg.wants(k.stage().name())) {
        k.preflight(&tr.cfg, &names, &tr.views.cameras).context("checked before training")?;
    }
    Ok(())
}
