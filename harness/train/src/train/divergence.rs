//! Divergence caught as it happens: after every iteration the GPU checks
//! the positions of the sets being trained (NaN, infinity, beyond
//! [`MEANS_LIMIT`] scene extents) into a flag per set, read back with a
//! word each; any other non-finite parameter shows in the loss, which the
//! driver checks too (`tgs_pipelines::SetGuard` says why that suffices).
//! The driver stops at the first tripped flag with the likely cause: a
//! setting far above the presets', or a camera far outside the others.

use super::args::settings;
use super::config::{is_learning_rate, TrainConfig};
use super::trainer::Trainer;
use crate::data::Dataset;
use anyhow::{Context as _, Result};
use tgs_engine::Recorder;
use tgs_pipelines::SetGuard;

/// Positions farther than this many scene extents (plus the scene's
/// distance from the origin) are divergence: the far-field initial points
/// lie at `init_far_depth` (30) extents.
pub const MEANS_LIMIT: f32 = 1e6;

/// A learning rate this many times the larger of the two presets' is
/// warned about before training.
pub const LR_WARN_FACTOR: f64 = 100.0;

/// The guards of a training run: Stage I's is recorded into each of its
/// steps; in the later stages both sets are checked in a submission of
/// their own after the step (those steps cost 1-7 times a Stage I one).
pub struct DivergenceGuard {
    scattering: SetGuard,
    later: SetGuard,
}

impl DivergenceGuard {
    /// Guards for `tr`'s sets; Stage I's goes into its steps from now on.
    pub fn install(tr: &mut Trainer) -> Result<DivergenceGuard> {
        let centre = tr.views.centre.iter().map(|c| c * c).sum::<f32>().sqrt();
        let limit = MEANS_LIMIT * (tr.views.extent + centre);
        let ctx = tr.context();
        tr.scattering.guard = Some(SetGuard::new(&ctx, limit)?);
        Ok(DivergenceGuard { scattering: SetGuard::new(&ctx, limit)?, later: SetGuard::new(&ctx, limit)? })
    }

    /// The sets whose positions after the last step hold a NaN, an
    /// infinity or one past [`MEANS_LIMIT`] scene extents, as "the
    /// scattering set's means" and the like.
    pub fn check(&self, tr: &Trainer) -> Result<Vec<String>> {
        let name = |set: &str, bad: bool| bad.then(|| format!("the {set} set's means"));
        let Some(m) = &tr.later else {
            let g = tr.scattering.guard.as_ref().context("Stage I's guard was not installed")?;
            return Ok(name("scattering", g.tripped()?).into_iter().collect());
        };
        let mut rec = Recorder::new(&tr.context())?;
        self.scattering.record(&mut rec, &tr.scattering.set)?;
        self.later.record(&mut rec, m.set())?;
        rec.submit_and_wait()?;
        Ok([name("scattering", self.scattering.tripped()?), name("reflection", self.later.tripped()?)].into_iter().flatten().collect())
    }
}

/// The numeric settings of `cfg` by key; only learning rates (every
/// setting named `lr...`) with `lr_only`.
fn numbers(cfg: &TrainConfig, lr_only: bool) -> Result<Vec<(String, f64)>> {
    Ok(settings(cfg)?.into_iter().filter(|(k, _)| !lr_only || is_learning_rate(k)).filter_map(|(k, v)| v.as_float().or(v.as_integer().map(|i| i as f64)).map(|f| (k, f))).collect())
}

/// Settings (learning rates only with `lr_only`) at least
/// [`LR_WARN_FACTOR`] times both presets' positive values, as
/// "lr_means = 0.5 (quick / paper presets: 0.00016 / 0.00016)".
fn far_above_presets(cfg: &TrainConfig, lr_only: bool) -> Result<Vec<String>> {
    let presets = [numbers(&TrainConfig::quick(), lr_only)?, numbers(&TrainConfig::paper(), lr_only)?];
    let preset_value = |p: &[(String, f64)], k: &str| p.iter().find(|(q, _)| q == k).map(|(_, v)| *v);
    Ok(numbers(cfg, lr_only)?
        .into_iter()
        .filter_map(|(k, v)| {
            let ps: Vec<f64> = presets.iter().filter_map(|p| preset_value(p, &k)).collect();
            let top = ps.iter().copied().fold(0.0, f64::max);
            (top > 0.0 && v >= LR_WARN_FACTOR * top)
                .then(|| format!("{k} = {} (quick / paper presets: {})", short(v), ps.iter().map(|p| short(*p)).collect::<Vec<_>>().join(" / ")))
        })
        .collect())
}

/// A setting's value as f32 text, in exponent form when far from 1.
fn short(v: f64) -> String {
    let f = v as f32;
    if f != 0.0 && !(1e-4..1e6).contains(&f.abs()) {
        format!("{f:e}")
    } else {
        format!("{f}")
    }
}

/// Learning rates at least [`LR_WARN_FACTOR`] times both presets', said
/// before training.
pub fn high_learning_rates(cfg: &TrainConfig) -> Result<Vec<String>> {
    far_above_presets(cfg, true)
}

/// What most likely made a run diverge: settings (learning rates, initial
/// extents, ...) far above the presets', else the training camera
/// farthest out among the others.
pub fn likely_cause(cfg: &TrainConfig, data: &Dataset) -> String {
    let high = far_above_presets(cfg, false).unwrap_or_default();
    if !high.is_empty() {
        return format!("likely cause: {} ({LR_WARN_FACTOR}x or more the presets')", high.join(", "));
    }
    match crate::data::camera_outlier(&data.train, 100.0) {
        Some(o) => format!("likely cause: {o}"),
        None => "no setting or camera stands out; lower the learning rates (lr_*) and check the dataset's poses".into(),
    }
}
