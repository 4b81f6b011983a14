//! The glass masks Stage II may seed from: a directory of them
//! (`reflection.seed_masks`) or the dataset's own training masks
//! (`reflection.dataset_masks`), and where they came from for the record.

use super::seed::PanePolygon;
use crate::data::downscale_mask;
use crate::data::image_io::read_grey_mask;
use crate::train::stages::shared::Shared;
use anyhow::{bail, Context as _, Result};
use glam::DVec3;
use std::borrow::Cow;
use std::path::Path;
use std::sync::Arc;
use tgs_engine::{Buffer, Context};
use tgs_pipelines::Camera;

/// Where the hull's glass masks came from (metrics.json's
/// `reflection.seed_mask_source`).
pub(super) enum MaskSource {
    /// `reflection.seed_masks`: this directory.
    Dir(String),
    /// `reflection.dataset_masks`: the training views' `mask_path`.
    Dataset,
    None,
}

impl MaskSource {
    pub(super) fn recorded(&self) -> Option<String> {
        match self {
            MaskSource::Dir(d) => Some(d.clone()),
            MaskSource::Dataset => Some("dataset".into()),
            _ => None,
        }
    }
}

/// Per training view, its glass mask (None: the view has none).
pub(super) type ViewMasks<'a> = Cow<'a, [Option<Vec<bool>>]>;

/// The glass masks Stage II seeds from, per training view (None for a
/// view without one, which then takes no part in the seeding):
/// `reflection.seed_masks` when it names a directory, else the dataset's
/// own training masks when `reflection.dataset_masks` is on, the set has
/// hull seeds and any training view has one; None (the residual's masks)
/// otherwise.
/// The dataset's masks are lent, not copied (a view's mask is a byte per
/// pixel).
pub(super) fn glass_masks<'a>(shared: &Shared<'a>, names: &[String]) -> Result<(Option<ViewMasks<'a>>, MaskSource)> {
    let rc = &shared.cfg.reflection;
    let v = shared.views;
    if !rc.seed_masks.is_empty() {
        if names.len() != v.cameras.len() {
            bail!("reflection.seed_masks needs the training views' names, which only a run with a directory has");
        }
        let m = seed_masks(Path::new(&rc.seed_masks), names, &v.cameras, shared.cfg.downscale)?;
        return Ok((Some(Cow::Owned(m)), MaskSource::Dir(rc.seed_masks.clone())));
    }
    if !rc.dataset_masks || !rc.init.parts().1 {
        return Ok((None, MaskSource::None));
    }
    if v.masks.iter().all(Option::is_none) {
        return Ok((None, MaskSource::None));
    }
    for (i, (m, cam)) in v.masks.iter().zip(&v.cameras).enumerate() {
        let n = (cam.width * cam.height) as usize;
        if let Some(m) = m.as_ref().filter(|m| m.len() != n) {
            bail!(
                "reflection.dataset_masks: training view {} has a glass mask of {} pixels for a {}x{} image",
                names.get(i).cloned().unwrap_or_else(|| i.to_string()),
                m.len(),
                cam.width,
                cam.height
            );
        }
    }
    Ok((Some(Cow::Borrowed(&v.masks[..])), MaskSource::Dataset))
}

/// Whether a `reflection.seed_masks` directory holds masks marked in `tgs
/// view` as regions (its `marks.json` names a region that is not a flat
/// pane): their hull is the few outlined views' polyhedron, whose flat
/// facets are the marking's, not the glass's, so `reflection.seed_faces`
/// must not take them for faces (a sphere marked in four views: glass MAE
/// 13.5° → 20.3° with them, in six 9.2° → 11.1°;
/// perf/journal/2026-12-06-sixty-sixth.md). A missing or unreadable
/// `marks.json` says no.
pub fn marked_regions(dir: &Path) -> bool {
    marks_regions(dir).is_some_and(|r| r.iter().any(|g| !is_flat(g)))
}

/// The regions of `dir/marks.json` (`tgs view`'s record of a marking);
/// None where it is missing or unreadable.
fn marks_regions(dir: &Path) -> Option<Vec<serde_json::Value>> {
    let text = std::fs::read(dir.join("marks.json")).ok()?;
    let mut v = serde_json::from_slice::<serde_json::Value>(&text).ok()?;
    v.get_mut("regions")?.as_array_mut().map(std::mem::take)
}

/// Whether a `marks.json` region is a flat pane (key F).
fn is_flat(region: &serde_json::Value) -> bool {
    region["flat"] == serde_json::Value::Bool(true)
}

/// The flat panes of a `reflection.seed_masks` directory marked in `tgs
/// view` by their corners (its `marks.json`'s `pane` corners), when every
/// region marked there is flat: their seeds lie on them
/// (`seed::pane_seeds`); a flat region whose corners did not meet has no
/// pane and marked no mask. None where any region is not flat (its hull
/// seeds as masks do), or `marks.json` is missing, unreadable or older
/// than the corners; a pane whose corners are not a flat polygon is an
/// error that names the file.
pub fn marked_panes(dir: &Path) -> Result<Option<Vec<PanePolygon>>> {
    let path = dir.join("marks.json");
    let Some(regions) = marks_regions(dir).filter(|r| !r.is_empty() && r.iter().all(is_flat)) else { return Ok(None) };
    let mut panes = Vec::with_capacity(regions.len());
    for (k, r) in regions.iter().enumerate() {
        // A flat region without a pane did not triangulate: it marked no mask either.
        let corners: Option<Vec<DVec3>> =
            r["pane"]["corners"].as_array().and_then(|c| c.iter().map(|p| serde_json::from_value::<[f64; 3]>(p.clone()).ok().map(DVec3::from)).collect());
        if let Some(c) = corners {
            panes.push(PanePolygon::from_corners(&c).map_err(|e| anyhow::anyhow!("{}: region {}: {e}", path.display(), k + 1))?);
        }
    }
    Ok((!panes.is_empty()).then_some(panes))
}

/// The file stem of training view `name`'s glass mask in a
/// `reflection.seed_masks` directory: the name without its extension.
pub fn mask_stem(name: &str) -> String {
    Path::new(name).file_stem().map_or_else(|| name.to_string(), |s| s.to_string_lossy().into_owned())
}

/// `reflection.seed_masks`: each training view's glass mask from
/// `dir/NAME.png` (NAME the view's name without its extension), at the
/// view's size or `downscale` times it (then reduced as the dataset's
/// masks are: glass only where every pixel it covers is); None for a view
/// without one. Refused when no view has one.
pub fn seed_masks(dir: &Path, names: &[String], cameras: &[Camera], downscale: u32) -> Result<Vec<Option<Vec<bool>>>> {
    if !dir.is_dir() {
        bail!("reflection.seed_masks: {} is not a directory", dir.display());
    }
    names
        .iter()
        .zip(cameras)
        .map(|(name, cam)| {
            let stem = mask_stem(name);
            // NAME without its extension; NAME.png (`0000.jpg.png`, as renders were once named) too.
            let Some(path) = [format!("{stem}.png"), format!("{name}.png")].into_iter().map(|f| dir.join(f)).find(|p| p.is_file()) else {
                return Ok(None);
            };
            let (w, h, m) = read_grey_mask(&path).with_context(|| "reflection.seed_masks")?;
            let f = downscale.max(1);
            if (w, h) == (cam.width, cam.height) {
                Ok(Some(m))
            } else if f > 1 && (w / f, h / f) == (cam.width, cam.height) {
                Ok(Some(downscale_mask(w, h, &m, f)))
            } else {
                bail!(
                    "reflection.seed_masks: {} is {w}x{h}; training view {name} is {}x{}{}",
                    path.display(),
                    cam.width,
                    cam.height,
                    if f > 1 { format!(" ({f} times that before downscale)") } else { String::new() }
                )
            }
        })
        .collect::<Result<Vec<_>>>()
        .and_then(|m| {
            if m.iter().all(Option::is_none) {
                bail!(
                    "reflection.seed_masks: {} holds no glass mask of any of the {} training views (VIEW.png, e.g. {}.png)",
                    dir.display(),
                    names.len(),
                    names.first().map(|n| mask_stem(n)).unwrap_or_default()
                );
            }
            Ok(m)
        })
}

/// A training view's glass mask for `reflection.lambda_mask`: on the device
/// (1 glass, 0 not, a float a pixel) and on the host (the loss's value).
pub struct GlassMask {
    pub gpu: Buffer<f32>,
    pub host: Vec<bool>,
}

impl GlassMask {
    pub fn upload(ctx: &Arc<Context>, mask: &[bool]) -> Result<GlassMask> {
        let m: Vec<f32> = mask.iter().map(|&g| if g { 1.0 } else { 0.0 }).collect();
        Ok(GlassMask { gpu: Buffer::from_slice(ctx, "refl.glass_mask", &m)?, host: mask.to_vec() })
    }
}
