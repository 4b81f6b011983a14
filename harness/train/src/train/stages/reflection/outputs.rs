//! What Stage II writes: the Stage I residual maps it was decided on
//! (`residual/NAME.exr`, and a heat map `NAME.png`), the message that
//! reports the decision, and at the end of a run that stops in Stage II
//! the reflection set (`reflection.ply`) and its light (`envmap.exr` /
//! `.png`, with `envmap_depth.exr` / `.png` for a depth-mapped light).

use super::{ReflDecision, ReflectionModel};
use crate::data::image_io::{write_exr, write_png, ImageF};
use crate::export::ply::write_reflection_splats;
use crate::outdir::OutDir;
use anyhow::Result;
use std::path::Path;
use tgs_pipelines::Camera;

/// One training view's residual planes `r` (r, g, b, then mean |r|) into
/// `maps`: the signed residual as EXR, its magnitude as a heat map.
pub(crate) fn write_residual(maps: &mut OutDir, name: &str, cam: &Camera, r: &[f32]) -> Result<()> {
    let n = (cam.width * cam.height) as usize;
    write_exr(&maps.file(&format!("{name}.exr"))?, &ImageF::from_planar(cam.width, cam.height, 3, &r[..3 * n]))?;
    // Heat map of mean |r|: 0 black, >= 0.25 white.
    let heat: Vec<f32> = r[3 * n..4 * n].iter().map(|v| v / 0.25).collect();
    write_png(&maps.file(&format!("{name}.png"))?, &ImageF { width: cam.width, height: cam.height, channels: 1, data: heat })
}

/// Appended to the message of a Stage II seeded from the residual (not
/// the paper's copy start, which seeds from nothing): what
/// glass masks would change, and the quickest way to them (the
/// forty-third, forty-sixth and fifty-seventh entries of perf/journal).
const RESIDUAL_NOTE: &str = ". Seeded without glass masks: the residual marks thin glass poorly, so the output keeps Stage I's normals wherever this set reflects little; glass masks place the seeds on it: mark the glass in `tgs view RUN` (key G, a few clicks in a few views) and train `--from RUN --set reflection.seed_masks=DIR`, or give mask_path on the training frames (docs/view.md, docs/stage2.md)";

impl ReflDecision {
    /// What was measured and decided, for the progress output (`reseed`:
    /// the second round, after Stage III; `iterations`: Stage II's).
    pub fn message(&self, reseed: bool, iterations: u32) -> String {
        let d = self;
        if d.run {
            format!(
                "Stage {}: residual {:.4} ({} {:.4}; {:.1}% of pixels above 0.05), view dependence {:.4} ({} {:.4}): {} reflection Gaussians ({} {}-hull seeds, {} from Stage I{}), {} iterations",
                if reseed { "II.2, seeded again after Stage III" } else { "II" },
                d.residual_mean,
                if d.residual_mean >= d.threshold { ">=" } else { "<" },
                d.threshold,
                100.0 * d.residual_fraction_over_0_05,
                d.view_dependence,
                if d.view_dependence >= d.view_dependence_threshold { ">=" } else { "<" },
                d.view_dependence_threshold,
                d.reflection_gaussians,
                d.seeds,
                match d.seed_mask_coverage {
                    Some(c) => format!(
                        "glass-mask ({:.1}% of the pixels{}; {}{}{}{}{}{})",
                        100.0 * c,
                        match d.seed_mask_views {
                            Some([n, all]) if n < all => format!(" of the {n} of {all} training views that have one"),
                            _ => String::new(),
                        },
                        d.mask_setting(),
                        match d.seed_panes {
                            Some([panes, seeds]) => format!("; {seeds} on the {panes} flat panes marked in tgs view (reflection.seed_panes)"),
                            None => String::new(),
                        },
                        match d.seed_rim {
                            Some([views, seeds]) if views > 0 => format!(
                                "; {seeds} on the glass rim's plane of {views} views{}",
                                match d.seed_rim_curved {
                                    Some(c) if c > 0 => format!(" ({c} of them curved)"),
                                    _ => String::new(),
                                }
                            ),
                            _ => String::new(),
                        },
                        match d.seed_planes {
                            Some([pieces, seeds]) if pieces > 0 => format!("; {seeds} moved onto the plane their hull points gave {pieces} pieces of mask"),
                            _ => String::new(),
                        },
                        match d.seed_faces {
                            Some([faces, seeds]) if faces > 0 => format!("; {seeds} took the normal of the {faces} flat faces of the glass they lie over"),
                            _ if d.seed_faces_marked => "; no flat faces sought (reflection.seed_faces): the masks are regions marked in tgs view, whose flat facets are the marking's".into(),
                            _ => String::new(),
                        },
                        d.seed_significance.map(|a| format!("; hull points beat chance at {a:e} only, too few masked views for reflection.seed_significance")).unwrap_or_default()
                    ),
                    None => "residual".into(),
                },
                d.copied,
                if d.hull_empty && d.seed_panes.is_some() {
                    ": no masked ray met a marked pane in front of Stage I's surface, so the set starts as a copy of Stage I's"
                } else if d.hull_empty {
                    ": no ray crossed carved space into the residual hull, so the set starts as a copy of Stage I's"
                } else if d.significance_dropped {
                    ": no hull point beat chance at reflection.seed_significance, so the seeds come from the hull without that test (on each ray the point the most views agree on)"
                } else {
                    ""
                },
                iterations,
            ) + if d.seed_mask_coverage.is_none() && (d.seeds > 0 || d.hull_empty) { RESIDUAL_NOTE } else { "" }
        } else if d.seed_mask_coverage.is_some() {
            format!("Stage II skipped: the glass masks ({}) mark no pixel of any training view: no glass to reflect", d.mask_setting())
        } else if d.residual_mean < d.threshold {
            format!(
                "Stage II skipped: the Stage I residual {:.4} is below reflection.min_residual {:.4} ({:.1}% of pixels above 0.05): the scene shows no view-dependent energy worth a reflection set",
                d.residual_mean,
                d.threshold,
                100.0 * d.residual_fraction_over_0_05
            )
        } else {
            format!(
                "Stage II skipped: the Stage I residual {:.4} barely changes with the view (view dependence {:.4} over {} surface points, below reflection.min_view_dependence {:.4}): it is Stage I misfit, not reflection",
                d.residual_mean,
                d.view_dependence,
                d.view_dependence_samples,
                d.view_dependence_threshold
            )
        }
    }
}

impl ReflectionModel {
    /// The reflection set and its light into the run directory `out`.
    pub fn write_outputs(&self, out: &Path) -> Result<()> {
        write_reflection_splats(&out.join("reflection.ply"), &self.set.params.download()?)?;
        let env = self.env.download()?;
        let (w, h, px) = env.cross();
        let img = ImageF { width: w, height: h, channels: 3, data: px.into_iter().flatten().collect() };
        write_exr(&out.join("envmap.exr"), &img)?;
        write_png(&out.join("envmap.png"), &img)?;
        // The light's depth (env_init = "scene-depth"): distances from the
        // box centre in the EXR, near white and far black in the PNG.
        if let Some((w, h, d)) = env.depth_cross() {
            write_exr(&out.join("envmap_depth.exr"), &ImageF { width: w, height: h, channels: 1, data: d.clone() })?;
            // The farthest surface at 0.2, apart from the texels that show none.
            let far = env.proxy.map(|p| p.radius).unwrap_or(f32::INFINITY);
            write_png(&out.join("envmap_depth.png"), &ImageF { width: w, height: h, channels: 1, data: crate::data::image_io::depth_grey(&d, far, 0.8) })?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_residuals_seeds_say_what_masks_would_change() {
        let residual = ReflDecision { run: true, reflection_gaussians: 10, seeds: 10, ..Default::default() };
        assert!(residual.message(false, 100).ends_with(RESIDUAL_NOTE), "{}", residual.message(false, 100));
        // An empty residual hull: masks would have given seeds too.
        let empty = ReflDecision { seeds: 0, hull_empty: true, ..residual.clone() };
        assert!(empty.message(false, 100).ends_with(RESIDUAL_NOTE));
        // Seeded from masks, or the paper's copy start: no note.
        let masked = ReflDecision { seed_mask_coverage: Some(0.3), seed_mask_source: Some("dataset".into()), ..residual.clone() };
        assert!(!masked.message(false, 100).contains("without glass masks"), "{}", masked.message(false, 100));
        // Marked panes: their seeds counted; none left in front of Stage I's surface, said so.
        let panes = ReflDecision { seed_panes: Some([2, 10]), ..masked.clone() };
        assert!(panes.message(false, 100).contains("10 on the 2 flat panes marked in tgs view"), "{}", panes.message(false, 100));
        let hidden = ReflDecision { seeds: 0, hull_empty: true, seed_panes: Some([2, 0]), ..masked.clone() };
        assert!(hidden.message(false, 100).contains("no masked ray met a marked pane"), "{}", hidden.message(false, 100));
        let copy = ReflDecision { seeds: 0, copied: 10, ..residual.clone() };
        assert!(!copy.message(false, 100).contains("without glass masks"));
        // A skipped Stage II says why, without the note.
        let skipped = ReflDecision { run: false, residual_mean: 0.001, threshold: 0.007, ..Default::default() };
        assert!(skipped.message(false, 100).starts_with("Stage II skipped") && !skipped.message(false, 100).contains("without glass masks"));
    }
}
