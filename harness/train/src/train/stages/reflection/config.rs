//! Stage II's settings (`[reflection]` in TOML, `--set reflection.KEY=V`).

use super::seed::SeedNormal;
use crate::train::settings::check_hf;
use crate::train::settings::{EnvStart, ReflectionFresnel, ReflectionInit, RotationGrad};
use anyhow::{bail, Result};
use serde::{Deserialize, Serialize};

/// Stage II: the reflection set and the environment map (method-notes §3.4, §3.7).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReflectionConfig {
    pub iterations: u32,
    /// "off": c = f0 E(w) (the paper's Stage II colour); "schlick": c = E(w)
    /// and Schlick's F with the blended F0 per pixel.
    pub fresnel: ReflectionFresnel,
    /// Cube-map face size. The quick preset's 16 (it was 64): a finer map
    /// memorises each training sample's colour as texel noise and leaves
    /// test views worse; measured after Stage II, 16 against 64: +0.20 dB
    /// on `lantern`, +0.04 `pane`, +0.01 built-in glass, +0.004 `globe`,
    /// and after Stage III within 0.006 dB (perf/RESULTS.md, eighteenth
    /// session). The paper preset keeps the 128.
    pub env_res: u32,
    /// How the cube map starts: "grey" (every texel sigmoid 0.5,
    /// method-notes §3.7) or "scene" (the scattering set rendered from the
    /// reflection set's box, stages/reflection/env_init.rs). Measured (perf/RESULTS.md,
    /// quick preset): "scene" gains after Stage II on `lantern` (+0.21 dB)
    /// and moves the normals no more than grey; after Stage III the two
    /// starts end within 0.002 dB on three scenes: grey stays.
    /// "scene-depth": "scene" with the distance to the surface each texel
    /// shows, the lookup's parallax proxy per direction (each surfel's ray
    /// meets the scene where it would; env_init.rs).
    pub env_init: EnvStart,
    /// Where the cube map's light is: 0, infinitely far (the paper's map);
    /// r > 0, on a sphere around the reflection set's box centre of radius
    /// r x the mean distance from that centre to the training cameras, so
    /// a reflection looks up the direction to where its ray leaves that
    /// sphere (a parallax-corrected, local cube map; glsl/reflection/
    /// color_common.glsl `env_dir`). Near-field content then lands where
    /// each surfel sees it, not where the centre would.
    pub env_radius: f32,
    pub lr_env: f32,
    pub lr_f0: f32,
    pub lr_r: f32,
    /// Opacity of the reflection set. R = sum w r lets opacity and r trade
    /// off; at Stage I's opacity rate (10x lr_r) opacity would do all of
    /// it and prune the glass away, so it moves at r's pace.
    pub lr_opacity: f32,
    /// Rotation (normal) and log-scales of the reflection set. Measured on
    /// the built-in glass scene (perf/RESULTS.md): at Stage I's rates
    /// (1e-3, 5e-3) the colour gradient of a distant cube map fitting
    /// near-field reflections bends the seeded normals (glass MAE 42 -> 46
    /// degrees over 1,000 iterations) without a PSNR gain; scales frozen
    /// and rotations at a tenth keep them.
    pub lr_quats: f32,
    pub lr_scales: f32,
    /// The reflection set's position rate, in multiples of Stage I's final
    /// one (`lr_means_final` x the scene extent). 1: the converged rate of
    /// the paper's Stage II start (method-notes §3.7), so the seeds barely
    /// move; 100: Stage I's starting rate. Measured on `globe`
    /// (perf/RESULTS.md, forty-third entry), 100 spreads the set beside the
    /// glass (normal MAE there 32.4 -> 45.3 degrees) and leaves it no nearer
    /// the glass (22.5 -> 22.9): not the default.
    pub lr_means_scale: f32,
    /// What turns the surfels ("all" or "reflection": the reflected colour
    /// alone, the rasterizer's rotation gradient dropped; settings.rs).
    pub rotation_grad: RotationGrad,
    /// Initial f0 (all channels) and reflectivity r of every reflection
    /// Gaussian. With the paper's c = f0 E the reflection term is R f0 E:
    /// at f0 = 0.04, r = 0.01 (method-notes' first guess) it starts at 4e-4
    /// and r hardly moves in 1,000 iterations; f0 = 0.5, r = 0.1 (its
    /// fallback) lets Stage II show reflections (PSNR +0.15 dB, measured).
    pub f0_init: f32,
    pub r_init: f32,
    /// Normal consistency on the reflection set.
    pub lambda_normal: f32,
    /// Prune reflection Gaussians below `prune_opacity` every this many iterations (0: never).
    pub prune_interval: u32,
    /// Stage II runs only when the Stage I residual's mean magnitude
    /// (mean over training views and pixels of mean_c |I_gt - I_scat|)
    /// reaches this.
    pub min_residual: f32,
    /// ... and only when the residual changes with the view: the median
    /// over Stage I surface points of the spread of the signed residual
    /// across the views that see the point (stages/reflection/view_dependence.rs)
    /// reaches this.
    pub min_view_dependence: f32,
    /// How the reflection set starts (method-notes §3.4): "copy" = the whole
    /// converged Stage I set (the paper's words); "hull" = seeds on the
    /// residual hull (stages/reflection/seed/) only; "copy+hull" = both. Measured on
    /// the glass scene: the copy sits behind the glass (normal MAE 70.7
    /// degrees after Stage II vs Stage I's 63.1); the seeds start at 43.
    pub init: ReflectionInit,
    /// Residual hull: rays cast (at most one seed each) and the fraction of
    /// the views seeing a point that must see residual there.
    pub seed_rays: u32,
    pub seed_agree: f32,
    /// Residual hull: a point also needs more agreeing views than masks
    /// placed at random would give it this often (binomial tail at the
    /// masks' mean coverage; 1: no test; stages/reflection/seed/ `min_hits`). Where
    /// path-tracing noise and textures put residual on 60% of the pixels,
    /// a point near the cameras that ten views see agrees by chance and
    /// seeds in front of the glass. Measured after Stage II (perf/RESULTS.md,
    /// twenty-first session), 1 -> 1e-6: share of the reflection set within
    /// a tenth of the radius of the glass 0.4% -> 10% on `globe` (1e-10:
    /// 56%, but fewer and worse normals after Stage II), test PSNR +0.01 to
    /// +0.15 dB on four scenes, glass normal MAE where the set covers the
    /// glass lower on three (`globe` 39.7 -> 35.1 degrees, `lantern` 45.4
    /// -> 42.8, `pane` 49.5 -> 48.4; built-in glass 40.1 -> 40.3), with
    /// less coverage on `lantern` and `pane`. Where no point can pass it
    /// (masks on nearly every pixel), each ray seeds at the point the most
    /// views agree on (stages/reflection/seed/ `hull_seeding`): on the
    /// path-traced room fronts glass normal MAE after Stage II 27.6-32.1
    /// -> 16.6-20.9 degrees (thirty-third session).
    pub seed_significance: f32,
    /// A seed's normal: "auto" (the default): "plane" with
    /// `seed_masks`, "halfway" without. With the suite's exact glass
    /// masks, glass normal MAE after Stage II, plane against halfway, on
    /// the eight scenes (seed 0): mean 18.9 against 27.6 degrees, better
    /// on six, 4.0 against 13.6 on `globe` (seed 1: 4.0 against 13.6),
    /// 24.7 against 55.9 on `pane` (seed 1: 25.2 against 56.6), worse on
    /// the one-sided `facade` (37.8 against 31.2; perf/RESULTS.md,
    /// forty-fourth entry). "halfway": the unit bisector of
    /// "view" (towards the camera whose ray found it) and "gradient"
    /// (against the gradient of the views' blurred residual masks summed
    /// at the seed's projections: the normal of the residual hull's
    /// silhouette cones; stages/reflection/seed/), or "plane" (the plane
    /// of its neighbouring seeds). Measured on nine path-traced scenes
    /// (the eight of `mitsuba_scenes.py --scene suite` and `lantern`, 50²,
    /// seeds 0 and 1; perf/RESULTS.md, thirty-third entry), glass normal
    /// MAE after Stage II, mean, view / gradient / halfway: 41.8 / 37.8 /
    /// 36.8 degrees; worst Stage II / Stage I 0.98 / 1.06 / 1.00 (all
    /// `lantern`). The hull's normal is right where the residual's hull is
    /// the glass (the closed `globe`, `globe_far`, `dome`, `cabinet`: 9 to
    /// 15 degrees better than "view" with either) and wrong where the glass
    /// is a flat pane or an open tube inside a blob of residual or under
    /// the hull's lid (`pane` 7 to 10 worse with "gradient", 4 to 7 with
    /// halfway; `lantern` 1 to 4 and 1); halfway keeps nearly all of the
    /// first and about halves the second. (Where no hull point beats
    /// chance, the seeds face their camera whatever this says:
    /// `SeedNormal::without_outline`.) "plane": built-in glass 45.1
    /// against view's 40.2 (fifteenth session): a real residual's hull
    /// places seeds with depth noise that turns their plane nearly random.
    pub seed_normal: SeedNormal,
    /// A directory of glass masks, one per training view that has one (`DIR/VIEW.png`,
    /// VIEW the view image's name without its extension; 8-bit, at least
    /// 128 where the pixel's first hit is glass; at the dataset's image
    /// size, reduced by `downscale` as the images are): the residual hull
    /// is then these masks' hull, carved in front of Stage I's surface as
    /// the residual's is, and Stage II runs whatever the residual measured
    /// (the masks say where the glass is), and not at all where they mark
    /// no glass in any view. A view without a mask takes no part in the
    /// seeding (the hull is the masked views'); a directory that holds no
    /// view's mask is refused. Empty (the default): the
    /// dataset's training masks (`dataset_masks`), else the residual's. A relative path is taken from the working
    /// directory where it is given and saved absolute, so that a resumed
    /// or continued run finds the masks from anywhere. For masks a user has (or a segmentation gives), and for
    /// measuring what exact masks are worth: on the path-traced suite
    /// Stage I reproduces about half of the glass's reflection, so the
    /// residual does not mark the glass (perf/RESULTS.md, forty-third and
    /// forty-fourth entries; `mitsuba_scenes.py --train-masks` writes the
    /// suite's exact masks).
    pub seed_masks: String,
    /// Without `seed_masks`: take the glass masks the dataset gives for its
    /// training views (`mask_path` in transforms_train.json, the format's
    /// evaluation key; the built-in scenes write them) as if they were
    /// given there, from the training views that have one. With the
    /// hull's seeds only (`init` "hull" or "copy+hull"). On the path-traced suite mask seeds took the glass normal MAE
    /// after Stage II from 34.2° (residual seeds) to 13.4° on the mean and
    /// kept the normals beside the glass at Stage I's (perf/RESULTS.md,
    /// forty-fourth to forty-sixth entries). false: the residual's seeds
    /// whatever the dataset holds.
    pub dataset_masks: bool,
    /// With glass masks (`seed_masks` or `dataset_masks`): place the seeds of a view whose glass is ringed
    /// by Stage I surface that every view sees at its masks' edges (a
    /// window in a wall or frame) on the plane of that rim, where the hull
    /// holds it (seed/rim.rs). A front captured from one side has a
    /// wedge for a hull, and its first hull points lie far in front of the
    /// glass; closed objects and free-standing panes have no such rim and
    /// are seeded as before (perf/RESULTS.md, forty-fifth entry).
    pub seed_rim: bool,
    /// Initial opacity of a seed.
    pub seed_opacity: f32,
    /// High-frequency loss (method-notes §3.6): weight of the mean error of
    /// the pixels at or above the `hf_percentile`-th percentile (0: off).
    pub lambda_hf: f32,
    pub hf_percentile: f32,
    /// Weight of a penalty on the mean of R = sum w r over the pixels
    /// (0: off), which pulls r down where the reflection term buys little.
    /// Off by default: the reflection set covers most pixels off the glass,
    /// where R (I_refl - I_scat) corrects Stage I's misfit; at 1 (both
    /// stages) the built-in glass lost 0.13 dB after Stage III while Phi's
    /// share of pixels fell from 94% to 48% (perf/RESULTS.md).
    pub lambda_r: f32,
    /// Weight of a cost on the area the reflection set covers: a penalty
    /// on the mean of its alpha over the pixels (0: off). A reflection
    /// surfel then stays only where the colour it adds lowers the image
    /// loss by more than this per pixel it covers; elsewhere its opacity
    /// falls and the pruning removes it, so that the normals there are
    /// Stage I's again.
    pub lambda_area: f32,
    /// The output geometry (normal, depth) of a pixel is the reflection
    /// set's where it covers the pixel (alpha >= 0.5) and its reflection
    /// weight R = sum w r there reaches this; elsewhere Stage I's (0: where
    /// it covers). A pixel where the reflection set adds little colour is
    /// no evidence of a surface there, so its normals do not replace
    /// Stage I's (issue 42, "do no harm"); `metrics.json`'s
    /// `reflection_coverage` is the share of the glass it decides.
    pub normal_min_r: f32,
    /// The highest SH degree of the frozen scattering layer that Stage II
    /// composites with, trains against and evaluates (at most Stage I's
    /// `sh_degree`; 3: Stage I's colour as it is). 0 leaves the scattering
    /// layer its view-independent colour, so the view-dependent light that
    /// Stage I baked into SH degrees 1-3 (at low resolution most of the
    /// glass's reflections) is residual the reflection set must explain.
    /// The decision whether Stage II runs and the residual-hull seeds keep
    /// Stage I's full colour. Stage III composites with Stage I's degree.
    pub scattering_sh: u32,
    /// Train the scattering set's SH colour in Stage II too (its geometry
    /// and opacity stay Stage I's), against the composite, at Stage I's
    /// colour rates: the reflection term then takes over the
    /// view-dependent colour Stage I baked into the scattering set.
    pub train_scattering: bool,
    /// After Stage III, run Stages II and III once more ("II.2", "III.2"),
    /// Stage II seeded afresh from the residual of the scattering set as
    /// Stage III left it: with its colour trained against the composite
    /// (light_field.scattering_params = "colour"), that set no longer holds
    /// the reflections Stage I baked into it, so the residual shows the
    /// glass more cleanly. Needs Stage III; doubles Stages II and III.
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
            // Measured (lavapipe, quick preset): converged glass 0.0118,
            // diffuse spheres-128 0.0041 (0.0094 with the sixth session's
            // defaults, and 0.0146 / 0.0273 on the path-traced `diffuse`:
            // this gate only stops scenes Stage I fits outright; the view
            // dependence below is the test that tells misfit from reflection).
            min_residual: 0.007,
            // Measured (lavapipe, quick preset, median spread): diffuse
            // scenes spheres-128 0.0042, Mitsuba `diffuse` 0.0068 (50²) and
            // 0.0046 (100²); glass scenes `pane` 0.0108 / 0.0096, built-in
            // glass 0.0120, `lantern` 0.0142, `globe` 0.0145, glass-tiny
            // 0.047. With the twentieth session's far-field init (a better
            // Stage I, so less misfit everywhere) `diffuse` 0.0061 and
            // `pane` 0.0082 / 0.0085 (two seeds), `lantern` 0.0140, `globe`
            // 0.0115: the geometric mean of the closest pair, 0.007, leaves
            // ~1.16x on both sides (the residual mean alone does not separate
            // them: `diffuse` 0.0146 at 50², 0.0273 at 100²).
            min_view_dependence: 0.007,
            init: ReflectionInit::Hull,
            seed_rays: 8192,
            seed_agree: 0.9,
            seed_significance: 1e-6,
            seed_normal: SeedNormal::Auto,
            seed_masks: String::new(),
            dataset_masks: true,
            seed_rim: true,
            seed_opacity: 0.5,
            lambda_hf: 0.1,
            hf_percentile: 90.0,
            lambda_r: 0.0,
            lambda_area: 0.0,
            normal_min_r: 0.0,
            scattering_sh: 3,
            train_scattering: false,
            reseed: false,
        }
    }
}

impl ReflectionConfig {
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
        if !(0.0..=1.0).contains(&self.normal_min_r) {
            bail!("reflection.normal_min_r must be in [0, 1] (a reflection weight), not {}", self.normal_min_r);
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
