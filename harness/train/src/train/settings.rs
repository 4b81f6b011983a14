//! Settings that take one of a few names: typed enums that read and write
//! as those names (so config.toml, checkpoints and sweep keys are the same
//! text as when they were strings), parsed once where the settings are
//! read, with an error that names the key, the value and every choice.

use anyhow::{bail, Result};

/// `name_enum!(/// doc, Type, "section.key", { /// doc, Variant = "name", ... })`:
/// the enum, `name()`, `parse()`, `NAMES`, and serde as the name.
macro_rules! name_enum {
    ($(#[$m:meta])* $name:ident, $key:literal, { $($(#[$vm:meta])* $var:ident = $text:literal),+ $(,)? }) => {
        $(#[$m])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        pub enum $name {
            $($(#[$vm])* $var),+
        }

        impl $name {
            /// Every accepted name, in declaration order.
            pub const NAMES: &'static [&'static str] = &[$($text),+];
            /// The setting's key.
            pub const KEY: &'static str = $key;

            pub fn name(self) -> &'static str {
                match self {
                    $(Self::$var => $text),+
                }
            }

            pub fn parse(s: &str) -> Result<Self, String> {
                match s {
                    $($text => Ok(Self::$var),)+
                    other => Err($crate::train::settings::choice_error($key, Self::NAMES, other)),
                }
            }
        }

        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(self.name())
            }
        }

        impl serde::Serialize for $name {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_str(self.name())
            }
        }

        impl<'de> serde::Deserialize<'de> for $name {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let s = String::deserialize(d)?;
                Self::parse(&s).map_err(<D::Error as serde::de::Error>::custom)
            }
        }
    };
}
pub(crate) use name_enum;

/// "KEY must be 'a', 'b' or 'c', not 'x'".
pub fn choice_error(key: &str, names: &[&str], got: &str) -> String {
    let q: Vec<String> = names.iter().map(|n| format!("'{n}'")).collect();
    let list = match q.len() {
        1 => q[0].clone(),
        n => format!("{} or {}", q[..n - 1].join(", "), q[n - 1]),
    };
    format!("{key} must be {list}, not '{got}'")
}

name_enum!(
    /// Stage II's colour (`reflection.fresnel`): "off", c = f0 E(w) (the
    /// paper's Stage II colour); "schlick", c = E(w) and Schlick's F with
    /// the blended F0 per pixel.
    ReflectionFresnel, "reflection.fresnel", { Off = "off", Schlick = "schlick" }
);

impl ReflectionFresnel {
    pub fn pipeline(self) -> tgs_pipelines::Fresnel {
        match self {
            Self::Off => tgs_pipelines::Fresnel::Off,
            Self::Schlick => tgs_pipelines::Fresnel::Schlick,
        }
    }
}

name_enum!(
    /// How Stage II's cube map starts (`reflection.env_init`).
    EnvStart, "reflection.env_init", {
        /// Every texel sigmoid 0.5 (method-notes §3.7).
        Grey = "grey",
        /// The scattering set rendered from the reflection set's box (stages/reflection/env_init.rs).
        Scene = "scene",
        /// The same with its depth per texel: each reflection looks up where
        /// its own ray meets the scene seen from the box, not the direction
        /// alone (a depth-corrected local cube map, stages/reflection/env_init.rs).
        SceneDepth = "scene-depth",
    }
);

name_enum!(
    /// How the reflection set starts (`reflection.init`, method-notes §3.4).
    ReflectionInit, "reflection.init", {
        /// The whole converged Stage I set (the paper's words).
        Copy = "copy",
        /// Seeds on the residual hull (stages/reflection/seed/) only.
        Hull = "hull",
        /// Both.
        CopyHull = "copy+hull",
    }
);

impl ReflectionInit {
    /// (copy the Stage I set, seed on the residual hull).
    pub fn parts(self) -> (bool, bool) {
        match self {
            Self::Copy => (true, false),
            Self::Hull => (false, true),
            Self::CopyHull => (true, true),
        }
    }
}

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

name_enum!(
    /// What turns the reflection set's surfels in Stage II
    /// (`reflection.rotation_grad`).
    RotationGrad, "reflection.rotation_grad", {
        /// Every gradient: the reflected colour through the mirror
        /// direction, and the rasterizer's (each surfel's footprint,
        /// depth and normal planes, so also the normal consistency).
        All = "all",
        /// The reflected colour alone: the rasterizer's rotation gradient
        /// is dropped, so a surfel turns only to fetch other light, not to
        /// change which pixels it covers.
        Reflection = "reflection",
    }
);

/// A stage's high-frequency loss settings (`SECTION.lambda_hf`,
/// `SECTION.hf_percentile`), checked.
pub(crate) fn check_hf(section: &str, lambda: f32, pct: f32) -> Result<()> {
    if !(lambda >= 0.0 && lambda.is_finite()) {
        bail!("{section}.lambda_hf must be non-negative and finite, not {lambda}");
    }
    if !(0.0..=100.0).contains(&pct) {
        bail!("{section}.hf_percentile must be in [0, 100], not {pct}");
    }
    Ok(())
}
