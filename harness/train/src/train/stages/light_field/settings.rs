//! Stage III's settings that take one of a few names (`light_field.*`).

use crate::train::settings::name_enum;

name_enum!(
    /// Stage III's reflected colour (`light_field.fresnel`).
    LightFresnel, "light_field.fresnel", {
        /// I_refl = F(F0, cos) Phi (the paper's Stage III).
        Schlick = "schlick",
        /// I_refl = F0 Phi.
        Off = "off",
    }
);

name_enum!(
    /// Stage III's network (`light_field.preset`).
    LightPreset, "light_field.preset", {
        /// The paper's: 8 x 256, skip at layer 5, L = 12.
        Paper = "paper",
        /// 4 x 64, skip at layer 3, L = 8 / 4 (the quick preset's).
        Small = "small",
    }
);

impl LightPreset {
    pub fn shape(self) -> tgs_pipelines::MlpShape {
        match self {
            Self::Paper => tgs_pipelines::MlpShape::PAPER,
            Self::Small => tgs_pipelines::MlpShape::SMALL,
        }
    }
}

name_enum!(
    /// What of the scattering set Stage III trains with
    /// `light_field.train_scattering` (`light_field.scattering_params`).
    ScatteringParams, "light_field.scattering_params", {
        /// The SH colour only (positions, scales, rotations and opacity
        /// keep Stage I's values and Adam moments).
        Colour = "colour",
        /// Everything.
        All = "all",
    }
);
