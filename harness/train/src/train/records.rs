//! What a run writes about its stages: the per-stage records of
//! `metrics.json` / `stages.json`, the test renders of each closed stage,
//! and the log kept consistent with the checkpoint on `--resume`.

use super::clock::Clocks;
use super::schedule::Stage;
use super::trainer::Trainer;
use super::validation::Validation;
use crate::data::Dataset;
use crate::eval::{evaluate, Metrics};
use crate::export::atomic_write;
use crate::outdir::OutDir;
use anyhow::{Context as _, Result};
use serde_json::{json, Value};
use std::path::Path;

/// metrics.json's `reflection`: the Stage II decision and, with a
/// validation slice and a Stage II that ran, whether its set was kept.
pub fn reflection_record(tr: &Trainer, validation: &Validation, stages: &[Value]) -> Value {
    let mut r = json!(tr.decision);
    let ran = tr.decision.as_ref().is_some_and(|d| d.run);
    if let (true, true, Some(o)) = (validation.is_on(), ran, r.as_object_mut()) {
        // Stage II's own verdict (a stage after it may be dropped instead).
        let stage_two = crate::train::stages::reflection::stage::STAGE.name();
        o.insert("kept".into(), json!(validation.drops(stages, stage_two).is_none()));
    }
    r
}

/// metrics.json's record of a finished stage.
pub fn stage_record(stage: &str, tr: &Trainer, wall_s: f64, m: Option<&Metrics>) -> Value {
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
pub fn read_stage_records(out: &Path, resume: bool) -> Vec<Value> {
    if !resume {
        return Vec::new();
    }
    std::fs::read(out.join("stages.json")).ok().and_then(|b| serde_json::from_slice(&b).ok()).unwrap_or_default()
}

/// Write the stage records to `OUT/stages.json`.
pub fn write_stage_records(out: &Path, stages: &[Value]) -> Result<()> {
    atomic_write(&out.join("stages.json"), serde_json::to_string_pretty(stages)?.as_bytes())
}

/// Where a closed stage's test renders go: renders/stage1, stage2,
/// stage3, and stage2.2 / stage3.2 for a second round.
pub fn renders_dir(label: &str) -> String {
    let (name, round) = label.split_once('.').map(|(n, r)| (n, format!(".{r}"))).unwrap_or((label, String::new()));
    let n = Stage::named(name).map(Stage::number).unwrap_or(0);
    format!("stage{n}{round}")
}

/// A stage to close: its label, the run's clocks and its validation record.
pub struct Closing<'a> {
    pub stage: &'a str,
    pub clock: &'a Clocks,
    pub validation: Option<Value>,
}

/// Close a stage: its test metrics (renders in OUT/renders/stageN) into
/// its record in `stages`. A stage taken from another run (--from) keeps
/// that run's record (its wall time, where it came from); the test
/// metrics are re-measured.
pub fn close_stage(tr: &mut Trainer, data: &Dataset, out: &Path, stages: &mut Vec<Value>, c: Closing) -> Result<()> {
    let dir = out.join("renders").join(renders_dir(c.stage));
    let m = if data.test.is_empty() { None } else { Some(evaluate(tr, &data.test, Some(&mut OutDir::open(&dir, Some(&data.root))?))?) };
    let from = stages.iter().find(|s| s["stage"] == c.stage && s.get("from").is_some()).cloned();
    stages.retain(|s| s["stage"] != c.stage);
    let mut rec = stage_record(c.stage, tr, c.clock.stage_s(), m.as_ref());
    rec["validation"] = json!(c.validation);
    if let Some(f) = from {
        rec["wall_s"] = f["wall_s"].clone();
        rec["from"] = f["from"].clone();
    }
    stages.push(rec);
    Ok(())
}

/// Drop the log lines of iterations after `iteration` (those a killed run
/// logged past its last checkpoint, which the resumed run logs again).
pub fn truncate_log(path: &Path, iteration: u32) -> Result<()> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(e).with_context(|| format!("{}: cannot read", path.display())),
    };
    let mut kept = String::new();
    for line in text.lines() {
        // A line torn by the kill does not parse: it is dropped too.
        let it = serde_json::from_str::<Value>(line).ok().and_then(|v| v["iteration"].as_u64());
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
