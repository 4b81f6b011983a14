//! The validation slice (`validation_every`): training views that Stage I
//! trains on but the later stages never see (not in their seeding, cache
//! or gradients), measured after every stage. A later stage that cannot
//! raise their PSNR by `validation_margin_db` has shown no evidence that
//! what it changed is right: a stage that says so (Stage II's reflection
//! set) is then dropped and the model before it is the run's result; the
//! others' verdicts (Stage III's) are reported.

use super::checkpoint;
use super::config::TrainConfig;
use super::rundir::stage_checkpoint;
use super::stage::Stage;
use super::stages::{later, LaterKind, Views};
use super::trainer::Trainer;
use crate::data::{Dataset, View};
use crate::eval::evaluate;
use anyhow::{Context as _, Result};
use serde_json::{json, Value};
use std::path::Path;
use std::sync::Arc;
use tgs_engine::Context;

pub struct Validation {
    pub views: Vec<View>,
    pub every: u32,
    pub margin_db: f64,
}

impl Validation {
    /// The validation views of `data` under `cfg` (none when off).
    pub fn of(data: &Dataset, cfg: &TrainConfig) -> Validation {
        let views = data.train.iter().enumerate().filter(|(i, _)| Views::is_validation(*i, cfg.validation_every)).map(|(_, v)| v.clone()).collect();
        Validation { views, every: cfg.validation_every, margin_db: cfg.validation_margin_db as f64 }
    }

    pub fn is_on(&self) -> bool {
        !self.views.is_empty()
    }

    /// The names of the training views the later stages train on.
    pub fn later_view_names(&self, data: &Dataset) -> Vec<String> {
        data.train.iter().enumerate().filter(|(i, _)| !Views::is_validation(*i, self.every)).map(|(_, v)| v.name.clone()).collect()
    }

    /// The current model on the validation views, for a stage's record.
    pub fn measure(&self, tr: &mut Trainer) -> Result<Option<Value>> {
        if !self.is_on() {
            return Ok(None);
        }
        let m = evaluate(tr, &self.views, None).context("measuring the validation views")?;
        Ok(Some(json!({"psnr": m.psnr, "ssim": m.ssim, "views": m.views})))
    }

    /// Each stage record's validation PSNR, its gain over the last stage
    /// kept before it, and whether it is kept (Stage I always is).
    pub fn verdicts(&self, stages: &[Value]) -> Vec<Value> {
        let mut best: Option<f64> = None;
        let mut out = Vec::new();
        for s in stages {
            let Some(psnr) = s["validation"]["psnr"].as_f64() else { continue };
            let gain = best.map(|b| psnr - b);
            // A stage none of whose pieces was kept is not kept either (piece_verdict.rs).
            let kept = gain.is_none_or(|g| g > self.margin_db) && s["validation"]["pieces_kept"].as_u64() != Some(0);
            if kept {
                best = Some(psnr);
            }
            out.push(json!({"stage": s["stage"], "psnr": psnr, "gain_db": gain, "kept": kept}));
        }
        out
    }

    /// The stage the records say is to be dropped, with what it adds (its
    /// `LaterKind::dropped_unless_kept`): one whose kind falls back when not
    /// kept and whose first round's verdict is "not kept".
    pub fn dropped(&self, stages: &[Value]) -> Option<(&'static dyn LaterKind, &'static str)> {
        if !self.is_on() {
            return None;
        }
        let verdicts = self.verdicts(stages);
        let not_kept = |s: Stage| verdicts.iter().any(|v| v["stage"] == s.name() && v["kept"] == false);
        later().into_iter().find_map(|k| k.dropped_unless_kept().filter(|_| not_kept(k.stage())).map(|what| (k, what)))
    }

    /// [`Validation::dropped`] when it is the schedule entry `label` ("II", "II.2", ...).
    pub fn drops(&self, stages: &[Value], label: &str) -> Option<(&'static dyn LaterKind, &'static str)> {
        self.dropped(stages).filter(|(k, _)| k.stage().name() == label)
    }

    /// metrics.json's `validation`.
    pub fn report(&self, stages: &[Value]) -> Value {
        if !self.is_on() {
            return Value::Null;
        }
        let acted_on: Vec<String> = later()
            .into_iter()
            .map(|k| match k.dropped_unless_kept() {
                Some(_) => format!("Stage {}: a set not kept is dropped (Stage {}'s model is the result)", k.stage().name(), before(k.stage()).name()),
                None => format!("Stage {}: reported only", k.stage().name()),
            })
            .collect();
        json!({"every": self.every, "views": self.views.len(), "margin_db": self.margin_db, "stages": self.verdicts(stages), "acted_on": acted_on.join("; ")})
    }
}

/// The stage that runs before `stage` (Stage I before the first later one).
pub fn before(stage: Stage) -> Stage {
    Stage::all().get(stage.number().saturating_sub(2)).copied().unwrap_or(Stage::SCATTERING)
}

/// The trainer as the stage before `stage` left it
/// (`OUT/checkpoint-stageN.bin`), at `tr`'s iteration with the schedule
/// ended there: what a run whose `stage` was dropped keeps.
pub fn back_to_before(ctx: &Arc<Context>, out: &Path, data: &Dataset, tr: &Trainer, stage: Stage) -> Result<Trainer> {
    let path = out.join(stage_checkpoint(stage.number() - 1));
    let mut t = checkpoint::restore(ctx, &path, checkpoint::read(&path)?, data)
        .with_context(|| format!("{}: Stage {}'s model, kept over Stage {}'s", path.display(), before(stage).name(), stage.name()))?;
    t.iteration = tr.iteration;
    // What the dropped stage measured and decided stays on record.
    t.decision = tr.decision.clone();
    end_here(&mut t);
    Ok(t)
}

/// End `tr`'s schedule at its iteration (nothing more to train).
pub fn end_here(tr: &mut Trainer) {
    if !tr.done() {
        let (entry, _) = tr.next_entry();
        tr.schedule.end_before(entry);
    }
}
