//! Which pixels of a Stage II/III render take the reflection set's normal
//! and depth as the output geometry (`reflection.normal_min_alpha`,
//! `normal_edge_alpha`, `normal_min_r`); Stage I's elsewhere.

use crate::train::stages::rendered::ReflRendered;
use tgs_pipelines::Plane;

/// What a pixel of a Stage II/III render needs for the reflection set to
/// decide its normal and depth ([`reflection_decides`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NormalGate {
    /// Its alpha there (`reflection.normal_min_alpha`).
    pub min_alpha: f32,
    /// The alpha enough beside a pixel it decides (`reflection.normal_edge_alpha`; at or above `min_alpha`: none).
    pub edge_alpha: f32,
    /// Its reflection weight R (`reflection.normal_min_r` or `residual_normal_min_r`).
    pub min_r: f32,
}

/// The pixels of a render whose geometry the reflection set decides: where
/// its alpha reaches the gate's `min_alpha` and R its `min_r`, and, where
/// `edge_alpha` is lower, the pixels next to (8-neighbours of) those whose
/// alpha reaches `edge_alpha` (and R `min_r`): the glass's outline, which
/// the set covers thinly where the masks' hull stops short of it.
pub fn reflection_decides(refl: &ReflRendered, gate: NormalGate) -> Vec<bool> {
    let (w, h) = (refl.width as usize, refl.height as usize);
    let (alpha, r) = (refl.refl_plane(Plane::Alpha), refl.r());
    let core: Vec<bool> = (0..w * h).map(|i| alpha[i] >= gate.min_alpha && r[i] >= gate.min_r).collect();
    if gate.edge_alpha >= gate.min_alpha {
        return core;
    }
    let beside = |x: usize, y: usize| {
        let (xs, ys) = (x.saturating_sub(1)..(x + 2).min(w), y.saturating_sub(1)..(y + 2).min(h));
        ys.flat_map(|yy| xs.clone().map(move |xx| yy * w + xx)).any(|j| core[j])
    };
    (0..w * h).map(|i| core[i] || (alpha[i] >= gate.edge_alpha && r[i] >= gate.min_r && beside(i % w, i / w))).collect()
}
