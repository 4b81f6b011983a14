//! Stage II's verdict piece by piece (issue 77): before a Stage II round
//! closes, each spatially separate piece of its reflection set
//! ([`pieces::partition`]) is rendered in and out on the validation views;
//! a piece that does not lower their error on the pixels it changes by more
//! than `validation_margin_db` is removed, so the output there is Stage I's.

use super::stages::reflection::pieces::{self, PieceErrors, PieceVerdict};
use super::trainer::Trainer;
use super::validation::Validation;
use anyhow::{Context as _, Result};
use tgs_engine::Buffer;

/// What the verdict did to the set.
pub struct PiecesOutcome {
    pub verdicts: Vec<PieceVerdict>,
    /// Gaussians before and after the removal.
    pub before: u32,
    pub after: u32,
}

impl PiecesOutcome {
    pub fn kept(&self) -> usize {
        self.verdicts.iter().filter(|v| v.kept).count()
    }

    /// The progress line.
    pub fn message(&self, label: &str) -> String {
        let n = self.verdicts.len();
        let k = self.kept();
        if k == 0 {
            return format!("Stage {label}: none of the reflection set's {n} pieces lowered the validation views' error (reflection.validation_cells)");
        }
        format!("Stage {label}: {k} of the reflection set's {n} pieces lowered the validation views' error and stay; {} of {} Gaussians kept", self.after, self.before)
    }
}

/// Judge the running Stage II's pieces on `validation`'s views and remove
/// those not kept (all stay when none is: the stage's own verdict then
/// drops it). None when there is nothing to judge (no validation slice,
/// `reflection.validation_cells` 0, or Stage II not running).
pub fn judge(tr: &mut Trainer, validation: &Validation) -> Result<Option<PiecesOutcome>> {
    let (cells, z) = (tr.cfg.reflection.validation_cells, tr.cfg.reflection.validation_z as f64);
    if !validation.is_on() || cells == 0 || tr.reflection().is_none() {
        return Ok(None);
    }
    // The whole model per view: the scattering colour to composite over, and the target.
    let mut views = Vec::new();
    for v in &validation.views {
        let r = tr.render(&v.camera).with_context(|| format!("validation view {}", v.name))?;
        let n = (r.width * r.height) as usize;
        let layers = r.layers.context("a Stage II render without its layers")?;
        let scat = Buffer::from_slice(&tr.views.ctx, "verdict.scat", &layers.0.planes[..3 * n])?;
        views.push((v.camera, scat, v.image.planar(), r.planes[..3 * n].to_vec()));
    }
    let model = tr.reflection_mut().context("Stage II's model")?;
    let means = model.set.params.means.download()?;
    let opacity = model.opacities()?;
    let labels = pieces::partition(&means, cells);
    let mut errors = vec![PieceErrors::default(); pieces::count(&labels)];
    for (p, e) in errors.iter_mut().enumerate() {
        let hidden: Vec<bool> = labels.iter().map(|&l| l as usize == p).collect();
        for (cam, scat, target, with) in &views {
            let without = model.render_without(cam, scat, &opacity, &hidden)?;
            let n = (cam.width * cam.height) as usize;
            e.add(with, &without.composite[..3 * n], target, cam.width as usize, cam.height as usize);
        }
    }
    let verdicts = pieces::verdicts(&labels, &means, &errors, validation.margin_db, z);
    let before = labels.len() as u32;
    let kept: Vec<bool> = verdicts.iter().map(|v| v.kept).collect();
    let after = if kept.iter().any(|&k| k) {
        let drop: Vec<bool> = labels.iter().map(|&l| !kept[l as usize]).collect();
        model.remove(&drop)?.1
    } else {
        before
    };
    Ok(Some(PiecesOutcome { verdicts, before, after }))
}
