//! Stage II's settings (`[reflection]` in TOML, `--set reflection.KEY=V`).

use super::seed::SeedNormal;
use super::settings::{EnvStart, ReflectionFresnel, ReflectionInit, RotationGrad};
use crate::train::settings::check_hf;
use anyhow::{bail, Result};
use serde::{Deserialize, Serialize};

/// Stage II: the reflection set and the environment map (method-notes §3.4, §3.7).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReflectionConfig {
    pub iterations: u32,
    /// "off": c = f0 E(w), the paper's Stage II colour; "schlick": c = E(w)
    /// with Schlick's F from the blended F0 per pixel.
    pub fresnel: ReflectionFresnel,
    /// Cube-map face size. A finer map memorises training samples as texel
    /// noise, so the quick preset keeps 16 (perf/journal/2026-11-24-eighteenth.md).
    pub env_res: u32,
    /// How the cube map starts: "grey" (sigmoid 0.5, method-notes §3.7),
    /// "scene" (the scattering set rendered from the reflection set's box)
    /// or "scene-depth" (with each texel's distance, a parallax proxy);
    /// grey and scene end alike after Stage III (perf/journal/2026-11-23-thirteenth.md).
    pub env_init: EnvStart,
    /// Where the light is: 0, infinitely far (the paper's map); r > 0, on a
    /// sphere of r × the mean camera distance around the reflection set's
    /// centre (a parallax-corrected local cube map, `env_dir` in
    /// glsl/reflection/color_common.glsl).
    pub env_radius: f32,
    pub lr_env: f32,
    pub lr_f0: f32,
    pub lr_r: f32,
    /// Opacity moves at r's pace: R = Σ w r lets the two trade off, and at
    /// Stage I's rate opacity would do it all and prune the glass away.
    pub lr_opacity: f32,
    /// Rotation (normal) and log-scale rates: a distant cube map's colour
    /// gradient bends the seeded normals at Stage I's rates without a PSNR
    /// gain, so rotations run at a tenth and scales are frozen
    /// (perf/journal/2026-11-21-first.md; perf/journal/2026-11-27-thirty-seventh.md).
    pub lr_quats: f32,
    pub lr_scales: f32,
    /// Position rate in multiples of Stage I's final one (1: the seeds
    /// barely move, as the paper's Stage II starts converged; 100 spreads
    /// the set beside the glass, perf/journal/2026-11-28-forty-third.md).
    pub lr_means_scale: f32,
    /// What turns the surfels: "all", or "reflection" (the reflected colour
    /// alone, the rasterizer's rotation gradient dropped).
    pub rotation_grad: RotationGrad,
    /// Initial f0 (every channel) and reflectivity r: 0.5 and 0.1 let Stage
    /// II show reflections within its iterations (0.04 / 0.01 start the
    /// term at 4e-4, and r hardly moves).
    pub f0_init: f32,
    pub r_init: f32,
    /// Normal consistency on the reflection set.
    pub lambda_normal: f32,
    /// Prune reflection Gaussians below `prune_opacity` every this many iterations (0: never).
    pub prune_interval: u32,
    /// Stage II runs only when the Stage I residual's mean magnitude over
    /// the training views reaches this (scenes Stage I fits outright stop here).
    pub min_residual: f32,
    /// ... and only when the residual changes with the view: the median
    /// spread of the signed residual over the views that see a Stage I
    /// surface point (view_dependence.rs) reaches this (perf/journal/2026-11-24-twentieth.md).
    pub min_view_dependence: f32,
    /// How the reflection set starts (method-notes §3.4): "copy" (the
    /// converged Stage I set, the paper's words; it sits behind the glass),
    /// "hull" (seeds on the residual's or the masks' hull, seed/) or
    /// "copy+hull".
    pub init: ReflectionInit,
    /// Residual hull: rays cast (at most one seed each) and the fraction of
    /// the views seeing a point that must see residual there.
    pub seed_rays: u32,
    pub seed_agree: f32,
    /// Residual hull: a point needs more agreeing views than random masks
    /// of the same coverage would give it this often (binomial tail; 1: no
    /// test), so that noise near the cameras does not seed in front of the
    /// glass (perf/journal/2026-11-24-twenty-first.md, perf/journal/2026-11-27-thirty-third.md).
    pub seed_significance: f32,
    /// A seed's normal: "auto" ("consensus" with masks, "halfway" without),
    /// "view" (towards its camera), "gradient" (the hull's silhouette
    /// normal), "halfway" (their bisector), "plane" (its 16 neighbours'
    /// plane) or "consensus" (the plane most of its 128 neighbours lie on)
    /// (perf/journal/2026-11-27-thirty-third.md, perf/journal/2026-11-28-forty-fourth.md, perf/journal/2026-12-05-sixty-first.md).
    pub seed_normal: SeedNormal,
    /// A directory of glass masks, `DIR/VIEW.png` per training view that
    /// has one (VIEW without its image extension; 8-bit, ≥ 128 on glass, at
    /// the dataset's size): the hull is then theirs and Stage II runs
    /// wherever they mark glass. Empty: the dataset's masks
    /// (`dataset_masks`), else the residual's. Saved absolute
    /// (perf/journal/2026-11-28-forty-fourth.md).
    pub seed_masks: String,
    /// Without `seed_masks`: seed from the glass masks the dataset gives
    /// for its training views (`mask_path`); false: from the residual
    /// whatever the dataset holds (perf/journal/2026-11-28-forty-sixth.md).
    pub dataset_masks: bool,
    /// With masks: seed a view whose glass is ringed by a frame every view
    /// sees on the plane of that rim (a window captured from one side,
    /// whose hull is a wedge; seed/rim.rs, perf/journal/2026-11-28-forty-fifth.md).
    pub seed_rim: bool,
    /// With `seed_rim`, for glass in an object seen from every side (a
    /// house's windows): a view counts for or against a rim point only
    /// where it sees it, and a plane must be ringed by the points on it.
    /// Off by default: it helps a house (18.4° → 8.6°) and harms a cabin
    /// whose windows meet at its corners (21.1° → 25.4°;
    /// perf/journal/2026-12-04-fifty-ninth.md).
    pub seed_rim_all_around: bool,
    /// With `seed_rim`: the masks' own outline is rim too, where no
    /// surface meets the glass's edge (a cabin's windows under a roof seen
    /// edge-on, a pane standing free): the first hull point of each ray at
    /// a mask edge, kept where the views agree it lies on their edges
    /// (seed/rim.rs). On by default: a cabin seen from the front 32.9° →
    /// 9.0°, the suite's fronts and panes better, closed glass unchanged
    /// (perf/journal/2026-12-07-seventy-first.md).
    pub seed_rim_hull: bool,
    /// With `seed_rim`: where a view's rim points lie off their plane the
    /// way a bent front's do (their plane leaves them a median 0.4% of
    /// their depth off or more, and 1 / z quadratic in the image brings
    /// that to 0.7 of it or less), the view seeds on that curved membrane
    /// instead (seed/curved.rs): a windshield, a section of a cylinder
    /// whose plane is its chord (perf/journal/2026-12-07-seventy-third.md).
    pub seed_rim_curved: bool,
    /// With masks: where a view's hull points over one piece of its mask
    /// lie on a plane (or two meeting at a corner), move that piece's seeds
    /// onto it with its normal (flat windows; seed/planes.rs;
    /// perf/journal/2026-12-05-sixtieth.md).
    pub seed_planes: bool,
    /// With masks: one round of bilateral smoothing of the seeds' normals
    /// (seed/smooth.rs): the hull bulges between the views that carve it,
    /// leaning each seed's local plane off a flat face; on by default for
    /// flat glass's sake, at a cost of 1–3° on closed curved glass
    /// (perf/journal/2026-12-06-sixty-fifth.md).
    pub seed_smooth: bool,
    /// With masks: where many seeds lie within a pixel and a half of one
    /// plane, agreeing on its normal, that plane is a flat face of the
    /// glass and the seeds over it take its normal (seed/faces.rs): a box's
    /// pillowed faces, a pane's ridge; curved glass offers no such plane
    /// (perf/journal/2026-12-06-sixty-sixth.md).
    pub seed_faces: bool,
    /// With masks marked in `tgs view` as flat panes by their corners
    /// (every region of their `marks.json`): the seeds lie on the marked
    /// panes with their normals, not on the masks' hull (seed/panes.rs;
    /// perf/journal/2026-12-07-sixty-seventh.md).
    pub seed_panes: bool,
    /// Initial opacity of a seed.
    pub seed_opacity: f32,
    /// High-frequency loss (method-notes §3.6): weight of the mean error of
    /// the pixels at or above the `hf_percentile`-th percentile (0: off).
    pub lambda_hf: f32,
    pub hf_percentile: f32,
    /// Weight of a penalty on the mean of R = Σ w r (0: off): pulls r down
    /// where the reflection term buys little; off because it cost the
    /// built-in glass 0.13 dB after Stage III.
    pub lambda_r: f32,
    /// Weight of a cost on the area the reflection set covers (its mean
    /// alpha; 0: off): a surfel then stays only where its colour lowers the
    /// loss by more than this per pixel, elsewhere the normals are Stage I's.
    pub lambda_area: f32,
    /// Weight of a loss drawing the set's alpha to the glass masks it was
    /// seeded from, mean (alpha - mask)^2 / 2 a view (0: off; no effect
    /// without masks): keeps the set inside the masks, but uncovers the
    /// glass's outline (perf/journal/2026-12-06-sixty-third.md).
    pub lambda_mask: f32,
    /// A pixel's output normal and depth are the reflection set's where it
    /// covers the pixel and R reaches this (0: wherever it covers), else
    /// Stage I's: little reflected colour is no evidence of a surface.
    pub normal_min_r: f32,
    /// The same threshold for a set seeded without glass masks (from the
    /// residual): there the set spreads over the scene with little R; at
    /// 0.07 the normals beside the glass stay within 1° of Stage I's on the
    /// suite (perf/journal/2026-12-04-fifty-seventh.md).
    pub residual_normal_min_r: f32,
    /// The reflection set's alpha a pixel needs for the set to decide its
    /// normal and depth (with the R threshold above). 0.5 leaves the glass's
    /// edge pixels, which exact masks' hulls cover only in part, Stage I's.
    pub normal_min_alpha: f32,
    /// With a validation slice (`validation_every`): the set is cut into
    /// spatially separate pieces, a grid of this many cells along its
    /// longest side, and each piece stays only where it lowers the
    /// validation views' error on the pixels it changes by more than
    /// `validation_margin_db` (0: the whole set judged as one).
    pub validation_cells: u32,
    /// How sure the validation views must be of a piece's gain: it stays
    /// when its gain, less this many standard errors of its spread over
    /// image tiles, clears `validation_margin_db` (negative: when the gain
    /// plus as many could; perf/journal/2026-12-06-sixty-fourth.md).
    pub validation_z: f32,
    /// The frozen scattering layer's SH degree under Stage II (3: Stage I's
    /// colour as it is; 0 leaves the view-dependent light Stage I baked
    /// into degrees 1–3 to the reflection set). The run decision and the
    /// seeds keep Stage I's colour.
    pub scattering_sh: u32,
    /// Train the scattering set's SH colour in Stage II too (its geometry
    /// and opacity stay Stage I's), so the reflection term can take over the
    /// view-dependent colour Stage I baked in.
    pub train_scattering: bool,
    /// After Stage III, run Stages II and III once more ("II.2", "III.2"),
    /// seeded from the residual of the scattering set Stage III left (which
    /// no longer holds the reflections Stage I baked into it).
    pub reseed: bool,
}

impl Default for ReflectionConfig {
    fn default() -> Self {
        ReflectionConfig {
            iterations: 10_000,
            fresnel: ReflectionFresnel::Off,
            env_res: 128,
            env_init: EnvStart::Grey,
            env_radius: 0.0,
            lr_env: 0.01,
            lr_f0: 0.0075,
            lr_r: 0.005,
            lr_opacity: 0.005,
            lr_quats: 0.0001,
            lr_scales: 0.0,
            lr_means_scale: 1.0,
            rotation_grad: RotationGrad::All,
            f0_init: 0.5,
            r_init: 0.1,
            lambda_normal: 0.05,
            prune_interval: 100,
            // Between spheres-128 (0.0041) and the glass (0.0118): it stops
            // only scenes Stage I fits outright (perf/journal/2026-11-22-sixth.md).
            min_residual: 0.007,
            // The geometric mean of the closest diffuse and glass scenes
            // (`diffuse` 0.0061, `pane` 0.0082; perf/journal/2026-11-24-twentieth.md).
            min_view_dependence: 0.007,
            init: ReflectionInit::Hull,
            seed_rays: 8192,
            seed_agree: 0.9,
            seed_significance: 1e-6,
            seed_normal: SeedNormal::Auto,
            seed_masks: String::new(),
            dataset_masks: true,
            seed_rim: true,
            seed_rim_all_around: false,
            seed_rim_hull: true,
            seed_rim_curved: true,
            seed_planes: true,
            seed_smooth: true,
            seed_faces: true,
            seed_panes: true,
            seed_opacity: 0.5,
            lambda_hf: 0.1,
            hf_percentile: 90.0,
            lambda_r: 0.0,
            lambda_area: 0.0,
            lambda_mask: 0.0,
            normal_min_r: 0.0,
            residual_normal_min_r: 0.07,
            normal_min_alpha: 0.5,
            validation_cells: 1,
            validation_z: -2.0,
            scattering_sh: 3,
            train_scattering: false,
            reseed: false,
        }
    }
}

impl ReflectionConfig {
    /// The quick preset's Stage II: 1,000 iterations, a 16² cube map.
    pub fn quick() -> ReflectionConfig {
        ReflectionConfig { iterations: 1000, env_res: 16, prune_interval: 100, ..ReflectionConfig::default() }
    }

    /// The SH degree Stage II renders the frozen scattering set at, for a
    /// Stage I trained up to `stage1` (`scattering_sh`).
    pub fn scattering_degree(&self, stage1: u32) -> u32 {
        stage1.min(self.scattering_sh)
    }

    pub(crate) fn validate(&self) -> Result<()> {
        if !(self.env_radius >= 0.0 && self.env_radius <= 1e6) {
            bail!("reflection.env_radius must be 0 (light infinitely far) or a positive multiple of the camera distance up to 1e6, not {}", self.env_radius);
        }
        if self.env_radius > 0.0 && self.env_init == EnvStart::SceneDepth {
            bail!(
                "reflection.env_radius = {} puts the light on one sphere, and reflection.env_init = \"scene-depth\" at the scene's depth per direction: set one of them",
                self.env_radius
            );
        }
        if self.scattering_sh > 3 {
            bail!("reflection.scattering_sh must be 0..=3 (an SH degree), not {}", self.scattering_sh);
        }
        if !(self.seed_agree > 0.0 && self.seed_agree <= 1.0) {
            bail!("reflection.seed_agree must be in (0, 1], not {}", self.seed_agree);
        }
        if !(self.seed_significance > 0.0 && self.seed_significance <= 1.0) {
            bail!("reflection.seed_significance must be in (0, 1], not {}", self.seed_significance);
        }
        if !self.seed_masks.is_empty() && !self.init.parts().1 {
            bail!("reflection.seed_masks places the hull's seeds; reflection.init = \"{}\" has none (use \"hull\" or \"copy+hull\")", self.init.name());
        }
        if !(self.seed_opacity > 0.0 && self.seed_opacity < 1.0) {
            bail!("reflection.seed_opacity must be in (0, 1), not {}", self.seed_opacity);
        }
        if self.iterations == 0 {
            bail!("reflection.iterations must be at least 1 (leave Stage II out with stages = \"I\")");
        }
        if self.env_res == 0 || self.env_res > tgs_pipelines::reflection::MAX_ENV_RES {
            bail!("reflection.env_res must be 1..={}, not {}", tgs_pipelines::reflection::MAX_ENV_RES, self.env_res);
        }
        for (k, v) in [("f0_init", self.f0_init), ("r_init", self.r_init)] {
            if !(v > 0.0 && v < 1.0) {
                bail!("reflection.{k} must be in (0, 1), not {v}");
            }
        }
        check_hf("reflection", self.lambda_hf, self.hf_percentile)?;
        for (k, v) in [("normal_min_r", self.normal_min_r), ("residual_normal_min_r", self.residual_normal_min_r)] {
            if !(0.0..=1.0).contains(&v) {
                bail!("reflection.{k} must be in [0, 1] (a reflection weight), not {v}");
            }
        }
        if !(self.validation_z.abs() <= 10.0) {
            bail!("reflection.validation_z must be in [-10, 10] (standard errors), not {}", self.validation_z);
        }
        if self.validation_cells > 64 {
            bail!("reflection.validation_cells must be 0 (the whole set judged as one) to 64, not {}", self.validation_cells);
        }
        if !(self.normal_min_alpha > 0.0 && self.normal_min_alpha <= 1.0) {
            bail!("reflection.normal_min_alpha must be in (0, 1] (an alpha), not {}", self.normal_min_alpha);
        }
        for (k, v) in [
            ("lr_env", self.lr_env),
            ("lr_f0", self.lr_f0),
            ("lr_r", self.lr_r),
            ("lr_opacity", self.lr_opacity),
            ("lr_quats", self.lr_quats),
            ("lr_scales", self.lr_scales),
            ("lr_means_scale", self.lr_means_scale),
            ("lambda_normal", self.lambda_normal),
            ("lambda_r", self.lambda_r),
            ("lambda_area", self.lambda_area),
            ("lambda_mask", self.lambda_mask),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                bail!("reflection.{k} must be non-negative and finite, not {v}");
            }
        }
        // Thresholds may be infinite (never run Stage II), not NaN.
        for (k, v) in [("min_residual", self.min_residual), ("min_view_dependence", self.min_view_dependence)] {
            if !(v >= 0.0) {
                bail!("reflection.{k} must be non-negative, not {v}");
            }
        }
        Ok(())
    }
}
