//! Stage II's settings that take one of a few names (`reflection.*`).

use crate::train::settings::name_enum;

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
