//! Which pixels of a Stage II/III render take the reflection set's normal
//! and depth as the output geometry (`reflection.normal_min_alpha`,
//! `normal_min_r`); Stage I's elsewhere.

use crate::train::stages::rendered::ReflRendered;
use tgs_pipelines::Plane;

/// What a pixel of a Stage II/III render needs for the reflection set to
/// decide its normal and depth ([`reflection_decides`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NormalGate {
    /// Its alpha there (`reflection.normal_min_alpha`).
    pub min_alpha: f32,
    /// Its reflection weight R (`reflection.normal_min_r` or `residual_normal_min_r`).
    pub min_r: f32,
}

/// Whether the reflection set decides the geometry of pixel `i`: its alpha
/// there reaches the gate's `min_alpha` and its reflection weight R `min_r`.
pub fn reflection_decides(refl: &ReflRendered, i: usize, gate: NormalGate) -> bool {
    refl.refl_plane(Plane::Alpha)[i] >= gate.min_alpha && refl.r()[i] >= gate.min_r
}
