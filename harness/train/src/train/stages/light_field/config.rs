//! Stage III's settings (`[light_field]` in TOML, `--set light_field.KEY=V`).

use super::settings::{LightFresnel, LightPreset, ScatteringParams};
use crate::train::settings::check_hf;
use anyhow::{bail, Context as _, Result};
use serde::{Deserialize, Serialize};

/// Stage III: the reflection light field MLP (paper §3.4, method-notes §3.5, §3.7).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LightFieldConfig {
    pub iterations: u32,
    /// Network: "paper" (8 x 256, skip at layer 5, L = 12) or "small"
    /// (4 x 64, skip at layer 3, L = 8 / 4; about 1/25 of the work).
    pub preset: LightPreset,
    /// Fourier octaves of gamma(x) and gamma(w); 0 keeps the preset's
    /// (paper 12 / 12, small 8 / 4).
    pub levels_x: u32,
    pub levels_w: u32,
    /// Adam learning rate of the MLP, exponential from `lr` to `lr_final`
    /// over the stage (NeRF / Ref-GS: 5e-4 -> 5e-5).
    pub lr: f32,
    pub lr_final: f32,
    /// Reflection material rates (the geometry is frozen).
    pub lr_f0: f32,
    pub lr_r: f32,
    /// Phi is evaluated only at pixels whose R = sum w r exceeds this; the
    /// others take I_refl = 0 (an error of at most this in the composite).
    pub threshold: f32,
    /// "schlick": I_refl = F(F0, cos) Phi (the paper's Stage III); "off": F0 Phi.
    pub fresnel: LightFresnel,
    /// Train the scattering set too (the paper's joint training; no
    /// densification, positions at Stage I's final rate), what of it
    /// `scattering_params` says. On by default, its colour only.
    pub train_scattering: bool,
    /// What of the scattering set trains when `train_scattering` is on:
    /// "colour" (the SH colour alone; the default) or "all" (which gains a
    /// little on most suite scenes but lost 0.44 dB on a room front, at up
    /// to 3.7× Stage III's time; perf/journal/2026-11-22-tenth.md,
    /// perf/journal/2026-12-02-fifty-first.md).
    pub scattering_params: ScatteringParams,
    /// High-frequency loss weight and percentile (as in `[reflection]`).
    pub lambda_hf: f32,
    pub hf_percentile: f32,
    /// Penalty on the mean of R (as in `[reflection]`).
    pub lambda_r: f32,
    /// Device memory (MiB, per set) for what the training views keep while
    /// the geometry is frozen: their blend weights, the scattering set's
    /// when only its colour trains, and the reflection set's with its
    /// geometry planes. Each view is then rendered in full once, and later
    /// its colour and the colour's gradient come from the weights
    /// (`stages/kept_views.rs`; about 3 MB per view of 33k Gaussians at
    /// 64²); views past the budget capture their weights at every visit, a
    /// view whose weights alone exceed it walks the tiles; 0 renders and
    /// differentiates every view in full every time. (The name is from
    /// when the views kept their binnings.)
    pub kept_binning_mib: u32,
}

impl Default for LightFieldConfig {
    fn default() -> Self {
        LightFieldConfig {
            iterations: 20_000,
            preset: LightPreset::Paper,
            levels_x: 0,
            levels_w: 0,
            lr: 5e-4,
            lr_final: 5e-5,
            lr_f0: 0.0075,
            lr_r: 0.005,
            threshold: 0.01,
            fresnel: LightFresnel::Schlick,
            train_scattering: true,
            scattering_params: ScatteringParams::Colour,
            lambda_hf: 0.1,
            hf_percentile: 90.0,
            lambda_r: 0.0,
            kept_binning_mib: 512,
        }
    }
}

impl LightFieldConfig {
    /// The quick preset's Stage III: 2,000 iterations (better than 1,000 on
    /// all eight path-traced scene-seed pairs, perf/journal/2026-12-03-fifty-fourth.md)
    /// of the small network.
    pub fn quick() -> LightFieldConfig {
        LightFieldConfig { iterations: 2000, preset: LightPreset::Small, ..LightFieldConfig::default() }
    }

    pub fn shape(&self) -> Result<tgs_pipelines::MlpShape> {
        let mut shape = self.preset.shape();
        if self.levels_x > 0 {
            shape.levels_x = self.levels_x;
        }
        if self.levels_w > 0 {
            shape.levels_w = self.levels_w;
        }
        shape.validate().context("light_field.levels_x / levels_w")?;
        Ok(shape)
    }
    pub fn schlick(&self) -> bool {
        self.fresnel == LightFresnel::Schlick
    }
    /// Whether Stage III trains the scattering set's colour only (geometry
    /// and opacity frozen); meaningful with `train_scattering`.
    pub fn scattering_colour_only(&self) -> bool {
        self.scattering_params == ScatteringParams::Colour
    }
    pub(crate) fn validate(&self) -> Result<()> {
        self.shape()?;
        if self.iterations == 0 {
            bail!("light_field.iterations must be at least 1 (leave Stage III out with stages = \"I,II\")");
        }
        for (k, v) in [("lr", self.lr), ("lr_final", self.lr_final), ("lr_f0", self.lr_f0), ("lr_r", self.lr_r), ("lambda_r", self.lambda_r)] {
            if !(v >= 0.0 && v.is_finite()) {
                bail!("light_field.{k} must be non-negative and finite, not {v}");
            }
        }
        if !(0.0..1.0).contains(&self.threshold) {
            bail!("light_field.threshold must be in [0, 1), not {}", self.threshold);
        }
        check_hf("light_field", self.lambda_hf, self.hf_percentile)
    }
}
