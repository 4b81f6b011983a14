//! What the Stage I residual measured and decided when Stage II began
//! (metrics.json's `reflection`, kept in the later stages' checkpoints).

use super::env_init::EnvInit;
use tgs_pipelines::EnvProxy;

/// The measured Stage I residual and what it decided (metrics.json's `reflection`).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ReflDecision {
    /// Mean over the training views of the per-pixel mean_c |I_gt - I_scat|.
    pub residual_mean: f64,
    /// Fraction of training pixels whose residual magnitude exceeds 0.05.
    pub residual_fraction_over_0_05: f64,
    /// The threshold on `residual_mean` (reflection.min_residual).
    pub threshold: f64,
    /// How much the residual changes with the view at a fixed Stage I
    /// surface point (stages/reflection/view_dependence.rs), over how many samples,
    /// and its threshold (reflection.min_view_dependence).
    #[serde(default)]
    pub view_dependence: f64,
    #[serde(default)]
    pub view_dependence_samples: u64,
    #[serde(default)]
    pub view_dependence_threshold: f64,
    /// Whether Stage II ran.
    pub run: bool,
    /// 1, or 2 for the Stage II run again after Stage III (reflection.reseed).
    #[serde(default)]
    pub round: u32,
    pub reflection_gaussians: u32,
    /// Of those: residual-hull seeds, and Stage I Gaussians copied.
    #[serde(default)]
    pub seeds: u32,
    #[serde(default)]
    pub copied: u32,
    /// The residual hull gave no seed, so the set started as a copy of
    /// Stage I's (reflection.init = "hull").
    #[serde(default)]
    pub hull_empty: bool,
    /// No hull point beat chance at reflection.seed_significance (too few
    /// views, or residual over most of every image), so the seeds come
    /// from the hull without that test.
    #[serde(default)]
    pub significance_dropped: bool,
    /// The cube map started from the scene (reflection.env_init = "scene"):
    /// the box it was rendered from and the Gaussians outside it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub env_from: Option<EnvInit>,
    /// The cube map's parallax proxy (reflection.env_radius > 0, or the
    /// centre of a map with depth, env_init = "scene-depth"): centre and
    /// radius in world units, fixed when Stage II starts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub env_proxy: Option<[f32; 4]>,
    /// The hull's seeds came from given glass masks
    /// (reflection.seed_masks or reflection.dataset_masks): the share of
    /// the masked views' pixels they mark.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed_mask_coverage: Option<f64>,
    /// Where those masks came from: the reflection.seed_masks directory,
    /// or "dataset" (the training views' mask_path, reflection.dataset_masks).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed_mask_source: Option<String>,
    /// The training views with a mask, of all: only those seed (the
    /// masks' hull is theirs; the others train as before).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed_mask_views: Option<[u32; 2]>,
    /// With those masks: the looser significance level the seeds beat,
    /// where none beat reflection.seed_significance (few masked views).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed_significance: Option<f64>,
    /// With those masks and reflection.seed_rim: the training views whose
    /// glass rim gave them a plane, and the seeds placed on it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed_rim: Option<[u32; 2]>,
    /// With reflection.seed_rim_curved too: of those views, the ones whose
    /// membrane is curved.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed_rim_curved: Option<u32>,
    /// With those masks and reflection.seed_planes: the views' mask pieces
    /// whose hull points lay on a plane (or two at a corner), and the seeds
    /// moved onto it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed_planes: Option<[u32; 2]>,
    /// With those masks and reflection.seed_faces: the flat faces of the
    /// glass found among the seeds, and the seeds that took their normal.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed_faces: Option<[u32; 2]>,
    /// reflection.seed_faces was skipped: the masks are regions marked in
    /// `tgs view` (masks::marked_regions).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub seed_faces_marked: bool,
    /// With masks marked in `tgs view` as flat panes and
    /// reflection.seed_panes: the panes, and the seeds placed on them
    /// (instead of the masks' hull).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed_panes: Option<[u32; 2]>,
    /// With a validation slice and `reflection.validation_cells`: the set's
    /// pieces as the validation views judged them (the ones not kept were
    /// removed before the stage closed; stages/reflection/pieces.rs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pieces: Option<Vec<super::pieces::PieceVerdict>>,
}

impl ReflDecision {
    /// The setting the glass masks came from, for the progress line.
    pub fn mask_setting(&self) -> &'static str {
        if self.seed_mask_source.as_deref() == Some("dataset") {
            "the dataset's training masks, reflection.dataset_masks"
        } else {
            "reflection.seed_masks"
        }
    }

    /// The recorded parallax proxy of the cube map.
    pub fn proxy(&self) -> Option<EnvProxy> {
        self.env_proxy.map(|p| EnvProxy { centre: [p[0], p[1], p[2]], radius: p[3] })
    }
}
