//! Stage II's environment map started from the scene (`reflection.env_init
//! = "scene"`): what the glass reflects is the scene around it, and the
//! scattering set Stage I trained is that scene. Each cube face is rendered
//! with the scattering set from the centre of the reflection set's box,
//! leaving out the Gaussians inside the box (the glass and what it holds,
//! which the outside of the glass does not reflect), and each texel takes
//! the colour along its direction. A grey map gives the normals no
//! gradient until the map has learned something; this one makes a wrong
//! normal fetch the wrong part of the scene from the first iteration.
//!
//! With `depth` (`env_init = "scene-depth"`) each texel also keeps the
//! distance from the centre to the surface it shows (the median depth of
//! the face render: where transmittance crossed 0.5), so that a reflection
//! from a surfel away from the centre looks up where its own ray meets that
//! surface (the lookup's parallax proxy takes its radius per direction from
//! this map; glsl/reflection/color_common.glsl `env_dir`): near-field
//! content lands where each surfel sees it. Texels that show no surface
//! (the sky, the background) lie [`FAR`] times the farthest surface away,
//! where the direction alone decides.

use super::bounds::normalization_box;
use crate::train::logit;
use crate::train::stages::scattering::ScatteringModel;
use anyhow::{Context as _, Result};
use std::sync::Arc;
use tgs_engine::Context;
use tgs_pipelines::{Camera, EnvProxy, HostEnvMap, HostGaussians, Plane};

/// Texel colours are clamped into (LO, 1 - LO) before the logit.
const LO: f32 = 0.01;
/// Depth of a texel that shows no surface, in units of the farthest one.
pub const FAR: f32 = 1e3;

/// What [`scene_env_map`] used, for the log.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EnvInit {
    pub centre: [f32; 3],
    pub half_extent: [f32; 3],
    /// Scattering Gaussians rendered (outside the box).
    pub rendered: usize,
    /// With depth: the share of texels that show a surface, and the
    /// nearest and farthest such distance from the centre.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth: Option<DepthInfo>,
}

/// What the depth of a scene-lit map holds.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DepthInfo {
    pub surface_share: f32,
    pub nearest: f32,
    pub farthest: f32,
}

/// The scattering Gaussians of `scat` outside the box (centre, half).
pub fn outside_box(scat: &HostGaussians, centre: [f32; 3], half: [f32; 3]) -> HostGaussians {
    let mut h = HostGaussians::new(scat.channels, scat.coeffs);
    let f = (scat.channels * scat.coeffs) as usize;
    for i in 0..scat.len() {
        let p: [f32; 3] = std::array::from_fn(|a| scat.means[3 * i + a]);
        let inside = (0..3).all(|a| (p[a] - centre[a]).abs() <= half[a]);
        if inside {
            continue;
        }
        let ls = [scat.log_scales[2 * i], scat.log_scales[2 * i + 1]];
        let q = std::array::from_fn(|k| scat.quats[4 * i + k]);
        h.push(p, ls, q, scat.opacity[i], &scat.features[f * i..f * (i + 1)]);
    }
    h
}

/// The camera at `eye` that sees cube face `face` (90 degrees and a margin).
fn face_camera(eye: [f32; 3], face: u32, px: u32) -> Camera {
    // The face's axis: the direction through its centre (one texel a side).
    let axis = HostEnvMap::texel_direction(1, face, 0, 0);
    // Any up not along the axis: the projection below is generic.
    let up = if face < 2 { [0.0, 1.0, 0.0] } else { [1.0, 0.0, 0.0] };
    let target = [eye[0] + axis[0], eye[1] + axis[1], eye[2] + axis[2]];
    // A 45-degree rotation of the face in the image would need tan = sqrt 2.
    Camera::look_at(eye, target, up, 2.0 * 1.5f32.atan(), px, px)
}

/// The bilinear footprint of (u, v) in a w x h image (pixel centres at
/// integer coordinates, clamped): the corner pixels (x0, y0), (x1, y1) and
/// the fractions (fx, fy).
fn footprint(w: u32, h: u32, u: f32, v: f32) -> (u32, u32, u32, u32, f32, f32) {
    let u = u.clamp(0.0, (w - 1) as f32);
    let v = v.clamp(0.0, (h - 1) as f32);
    let (x0, y0) = (u.floor() as u32, v.floor() as u32);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    (x0, y0, x1, y1, u - x0 as f32, v - y0 as f32)
}

/// Bilinear sample of three colour planes ([`footprint`]).
fn sample(planes: [&[f32]; 3], w: u32, h: u32, u: f32, v: f32) -> [f32; 3] {
    let (x0, y0, x1, y1, fx, fy) = footprint(w, h, u, v);
    std::array::from_fn(|c| {
        let p = planes[c];
        let at = |x: u32, y: u32| p[(y * w + x) as usize];
        (at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx) * (1.0 - fy) + (at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx) * fy
    })
}

/// The median depth plane at (u, v): the bilinear blend ([`footprint`]) of
/// the taps that show a surface (median > 0), or None where none does.
fn sample_depth(plane: &[f32], w: u32, h: u32, u: f32, v: f32) -> Option<f32> {
    let (x0, y0, x1, y1, fx, fy) = footprint(w, h, u, v);
    let taps = [(x0, y0, (1.0 - fx) * (1.0 - fy)), (x1, y0, fx * (1.0 - fy)), (x0, y1, (1.0 - fx) * fy), (x1, y1, fx * fy)];
    let (mut sum, mut wsum) = (0.0f32, 0.0f32);
    for (x, y, wt) in taps {
        let z = plane[(y * w + x) as usize];
        if z > 0.0 && z.is_finite() && wt > 0.0 {
            sum += wt * z;
            wsum += wt;
        }
    }
    (wsum > 0.0).then(|| sum / wsum)
}

/// The scene a cube map shows: the scattering set `set` at active SH
/// degree `sh_degree` over `background`.
#[derive(Clone, Copy)]
pub struct SceneLight<'a> {
    pub set: &'a HostGaussians,
    pub sh_degree: u32,
    pub background: &'a [f32; 3],
}

/// The cube map of face size `res` seen from the reflection set's box
/// (`refl_means`) with the Gaussians of `scene` outside it; with `depth`,
/// also the distance from the box's centre to the surface each texel
/// shows (`HostEnvMap::depth`, with the parallax proxy at that centre).
pub fn scene_env_map(ctx: &Arc<Context>, scene: SceneLight, refl_means: &[f32], res: u32, adam_eps: f32, depth: bool) -> Result<(HostEnvMap, EnvInit)> {
    let SceneLight { set: scat, sh_degree: sh, background } = scene;
    let (centre, half) = normalization_box(refl_means);
    let outside = outside_box(scat, centre, half);
    let mut info = EnvInit { centre, half_extent: half, rendered: outside.len(), depth: None };
    let mut env = HostEnvMap::constant(res, 0.0)?;
    if outside.is_empty() {
        return Ok((env, info));
    }
    // The set's own SH degree (its coefficient count); `sh` of it are active.
    let degree = (1..=4).find(|d| d * d == scat.coeffs).context("the scattering set's SH coefficient count is not a square")? - 1;
    let mut model = ScatteringModel::new(ctx, &outside, degree, adam_eps).context("the scattering set for the environment map")?;
    // Render at least 64 pixels a side so that small maps still average a few.
    let px = (res + res / 2).max(64);
    // Distance to the surface per texel (None: no surface).
    let mut dist: Vec<Option<f32>> = vec![None; env.texels()];
    for face in 0..6u32 {
        let cam = face_camera(centre, face, px);
        let r = model.render(&cam, sh, background).with_context(|| format!("rendering cube face {face} for the environment map"))?;
        let planes = [r.plane(Plane::Feature(0)), r.plane(Plane::Feature(1)), r.plane(Plane::Feature(2))];
        let median = r.plane(Plane::Median);
        let m = &cam.world_to_view;
        for row in 0..res {
            for col in 0..res {
                let d = HostEnvMap::texel_direction(res, face, row, col);
                let v: [f32; 3] = std::array::from_fn(|k| m[k][0] * d[0] + m[k][1] * d[1] + m[k][2] * d[2]);
                let (u, w) = (cam.fx * v[0] / v[2] + cam.cx, cam.fy * v[1] / v[2] + cam.cy);
                let c = sample(planes, px, px, u, w);
                let t = ((face * res + row) * res + col) as usize;
                for (raw, v) in env.raw[3 * t..3 * t + 3].iter_mut().zip(c) {
                    *raw = logit(v.clamp(LO, 1.0 - LO));
                }
                if depth {
                    // View depth z along d is at distance z |v| / v_z from the eye.
                    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                    dist[t] = sample_depth(median, px, px, u, w).map(|z| z * len / v[2]).filter(|d| d.is_finite() && *d > 0.0);
                }
            }
        }
    }
    if depth {
        let found: Vec<f32> = dist.iter().flatten().copied().collect();
        let nearest = found.iter().copied().fold(f32::INFINITY, f32::min);
        let farthest = found.iter().copied().fold(0.0f32, f32::max);
        // Nothing found: every texel far beyond the box.
        let far = FAR * if found.is_empty() { half.iter().copied().fold(1e-3f32, f32::max) * 2.0 } else { farthest };
        env.depth = Some(dist.iter().map(|d| d.unwrap_or(far)).collect());
        env.proxy = Some(EnvProxy { centre, radius: far });
        info.depth = Some(DepthInfo {
            surface_share: found.len() as f32 / dist.len() as f32,
            nearest: if found.is_empty() { far } else { nearest },
            farthest: if found.is_empty() { far } else { farthest },
        });
    }
    env.validate()?;
    Ok((env, info))
}
