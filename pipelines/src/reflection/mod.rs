//! Stage II's kernels (paper §3.2–3.3, method-notes §3.2–3.4), GLSL in
//! `glsl/reflection/`:
//! - the per-Gaussian reflection colour c_i = f0_i E(w_i) from the learnable
//!   cube map, forward and backward (to the material, the position, the
//!   quaternion through the mirror direction, and the texels);
//! - the texel gradients without atomics: every Gaussian writes its four
//!   taps to its own slots, the slots are sorted by texel (the project's
//!   stable radix sort) and summed per texel in a fixed order;
//! - the deferred composite I = (1 - R) I_scat + R I_refl (Schlick Fresnel
//!   with the blended F0 as a switch), forward and backward.
//!
//! The reflection set is a `TrainableSet` whose feature block is its
//! material (raw f0 (3), raw r: [`MATERIAL`] floats); the rasterizer takes
//! the colour kernel's output as its features (`Rasterizer::record_forward_with`).

mod envmap;

pub use envmap::{EnvMap, EnvProxy, HostEnvMap, DEPTH_ITERS, MAX_ENV_RES};

use crate::raster::{Camera, Gaussians, Plane};
use crate::scan::Count;
use crate::shaders;
use crate::sort::{RadixSort, SortScratch};
use crate::train::{grid, kernel};
use anyhow::{bail, Result};
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Kernel, Recorder};

/// Check that each buffer holds its number of `cam`-sized planes (and the
/// image is not empty); shared by the deferred shading of Stages II and III.
pub(crate) fn check_planes(cam: &Camera, bufs: &[(&Buffer<f32>, u32)]) -> Result<()> {
    let n = cam.width as usize * cam.height as usize;
    if n == 0 {
        bail!("composite of an empty {}x{} image", cam.width, cam.height);
    }
    for (b, planes) in bufs {
        if b.len() < *planes as usize * n {
            bail!("'{}' holds {} values; {planes} planes of {}x{} need {}", b.name(), b.len(), cam.width, cam.height, *planes as usize * n);
        }
    }
    Ok(())
}

/// Material floats per reflection Gaussian: raw f0 (3), raw r.
pub const MATERIAL: u32 = 4;
/// Sorted texel slots per chunk in the two-pass texel reduction.
const CHUNK: u32 = 128;

/// How the reflection colour reaches the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fresnel {
    /// c_i = f0_i E(w_i), I_refl = sum w c (the paper's Stage II colour,
    /// eq. per_gauss_color): 4 rasterized channels (c, r).
    Off,
    /// c_i = E(w_i), I_refl = F(F0, cos) sum w c with Schlick's F and the
    /// blended F0 = sum w f0 / alpha_R: 7 channels (c, r, f0 sum).
    Schlick,
}

impl Fresnel {
    /// Rasterized feature channels of the reflection set.
    pub fn channels(self) -> u32 {
        match self {
            Fresnel::Off => 4,
            Fresnel::Schlick => 7,
        }
    }
    fn flag(self) -> u32 {
        (self == Fresnel::Schlick) as u32
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ColorPush {
    n: u32,
    channels: u32,
    res: u32,
    schlick: u32,
    centre: [f32; 3],
    /// > 0: the proxy's radius per direction from the map's depth.
    depth_iters: u32,
    /// The map's parallax proxy: centre, radius (0: infinitely far).
    proxy: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct CompositePush {
    width: u32,
    height: u32,
    channels: u32,
    schlick: u32,
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    scat_grad: u32,
    /// Backward: added to dL/dR at every pixel.
    r_prior: f32,
    /// Backward: added to dL/dalpha (the reflection set's) at every pixel.
    alpha_prior: f32,
    /// Backward: the weight of the reflection set's alpha against a glass mask.
    mask_weight: f32,
}

/// Penalties on the means of the reflection render's R and alpha planes,
/// as the per-pixel gradients the composite's backward adds: the gradient
/// of `lambda * mean(P)` over a view is `lambda / pixels`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CompositePriors {
    /// Added to dL/dR.
    pub r: f32,
    /// Added to dL/dalpha: a cost on the area the reflection set covers.
    pub alpha: f32,
    /// With a glass mask m ([`CompositeGrads::mask`]): (alpha - m) times this
    /// added to dL/dalpha, the gradient of mask / 2 * sum (alpha - m)^2.
    pub mask: f32,
}

impl CompositePriors {
    /// The per-pixel gradients of `lambda_r * mean(R) + lambda_alpha * mean(alpha)` over `pixels`.
    pub fn of_means(lambda_r: f32, lambda_alpha: f32, pixels: u32) -> CompositePriors {
        let n = pixels.max(1) as f32;
        CompositePriors { r: lambda_r / n, alpha: lambda_alpha / n, mask: 0.0 }
    }

    /// With the gradient of `lambda_mask * mean((alpha - m)^2) / 2` against a glass mask m.
    pub fn with_mask(self, lambda_mask: f32, pixels: u32) -> CompositePriors {
        CompositePriors { mask: lambda_mask / pixels.max(1) as f32, ..self }
    }
}

/// Working memory of the texel-gradient reduction for up to `capacity` Gaussians.
pub struct TexelScratch {
    capacity: u32,
    keys: Buffer<u32>,
    slots: Buffer<u32>,
    grads: Buffer<f32>,
    sort: SortScratch,
    ranges: Buffer<u32>,
    runs: Buffer<f32>,
    count: Buffer<u32>,
}

pub struct ReflectionShading {
    ctx: Arc<Context>,
    sort: RadixSort,
    color: Kernel,
    color_backward: Kernel,
    ranges: Kernel,
    chunks: Kernel,
    reduce: Kernel,
    composite: Kernel,
    composite_backward: Kernel,
    residual: Kernel,
}

/// What the reflection colour of a view reads (the colour kernels' inputs
/// and push constants): the reflection set, its light, the camera and the
/// Fresnel term.
#[derive(Clone, Copy)]
pub struct ColorInputs<'a> {
    pub g: &'a Gaussians,
    pub env: &'a EnvMap,
    pub cam: &'a Camera,
    pub fresnel: Fresnel,
}

impl ReflectionShading {
    pub fn new(ctx: &Arc<Context>) -> Result<ReflectionShading> {
        let cp = std::mem::size_of::<ColorPush>() as u32;
        let kp = std::mem::size_of::<CompositePush>() as u32;
        Ok(ReflectionShading {
            ctx: ctx.clone(),
            sort: RadixSort::new(ctx)?,
            color: kernel(ctx, "refl.color", shaders::REFLECTION_COLOR, cp)?,
            color_backward: kernel(ctx, "refl.color_backward", shaders::REFLECTION_COLOR_BACKWARD, cp)?,
            ranges: kernel(ctx, "refl.texel_ranges", shaders::RASTER_RANGES, 0)?,
            chunks: kernel(ctx, "refl.texel_chunks", shaders::REFLECTION_TEXEL_CHUNKS, 8)?,
            reduce: kernel(ctx, "refl.texel_reduce", shaders::REFLECTION_TEXEL_REDUCE, 8)?,
            composite: kernel(ctx, "refl.composite", shaders::REFLECTION_COMPOSITE, kp)?,
            composite_backward: kernel(ctx, "refl.composite_backward", shaders::REFLECTION_COMPOSITE_BACKWARD, kp)?,
            residual: kernel(ctx, "refl.residual", shaders::REFLECTION_RESIDUAL, 4)?,
        })
    }

    /// Texel-reduction memory for up to `capacity` Gaussians and `env`'s size.
    pub fn texel_scratch(&self, env: &EnvMap, capacity: u32) -> Result<TexelScratch> {
        let ctx = &self.ctx;
        let cap = capacity.max(1);
        let slots = 4 * cap as u64;
        if slots > self.sort.max_keys() || 3 * slots * 4 > ctx.caps().max_storage_buffer_range {
            bail!("{capacity} reflection Gaussians need {slots} texel slots; this device holds at most {}", self.sort.max_keys().min(ctx.caps().max_storage_buffer_range / 12));
        }
        // The per-texel pass loops over at most slots / CHUNK chunks.
        if ctx.caps().is_cpu() && slots / CHUNK as u64 + CHUNK as u64 > 60_000 {
            bail!("{capacity} reflection Gaussians exceed the per-invocation loop budget of a CPU driver");
        }
        let s = slots as usize;
        Ok(TexelScratch {
            capacity: cap,
            // The colour backward writes every slot [0, 4n) before the sort.
            keys: Buffer::uninit(ctx, "refl.tap_keys", s)?,
            slots: Buffer::uninit(ctx, "refl.tap_slots", s)?,
            grads: Buffer::uninit(ctx, "refl.tap_grads", 3 * s)?,
            sort: self.sort.scratch(slots as u32)?,
            ranges: Buffer::new(ctx, "refl.texel_ranges", 2 * env.texels() as usize)?,
            runs: Buffer::uninit(ctx, "refl.texel_runs", 6 * (s.div_ceil(CHUNK as usize)))?,
            count: Buffer::new(ctx, "refl.slot_count", 1)?,
        })
    }

    fn color_push(g: &Gaussians, env: &EnvMap, cam: &Camera, fresnel: Fresnel) -> ColorPush {
        ColorPush {
            n: g.n,
            channels: fresnel.channels(),
            res: env.res,
            schlick: fresnel.flag(),
            centre: cam.centre(),
            depth_iters: env.depth_iters(),
            proxy: envmap::EnvProxy::packed(env.proxy),
        }
    }

    /// The map's depth, or (never read without one) its texels.
    fn depth_binding(env: &EnvMap) -> tgs_engine::BufferBinding {
        env.depth.as_ref().unwrap_or(&env.params).binding()
    }

    fn check_set(g: &Gaussians, features: &Buffer<f32>, fresnel: Fresnel) -> Result<()> {
        if g.channels != MATERIAL || g.coeffs != 1 {
            bail!("a reflection set has {MATERIAL} material floats per Gaussian, not {} x {}", g.channels, g.coeffs);
        }
        if features.len() < (fresnel.channels() * g.n) as usize {
            bail!("feature buffer '{}' holds {} values; {} Gaussians x {} channels need more", features.name(), features.len(), g.n, fresnel.channels());
        }
        Ok(())
    }

    /// Record the reflection colour of every Gaussian of `x.g` seen from
    /// `x.cam` into `features` (`x.fresnel.channels()` per Gaussian).
    pub fn record_color(&self, rec: &mut Recorder, x: &ColorInputs, features: &Buffer<f32>) -> Result<()> {
        let ColorInputs { g, env, cam, fresnel } = *x;
        Self::check_set(g, features, fresnel)?;
        if g.n == 0 {
            return Ok(());
        }
        let p = Self::color_push(g, env, cam, fresnel);
        let b = [g.means.binding(), g.quats.binding(), g.features.binding(), env.params.binding(), features.binding(), Self::depth_binding(env)];
        rec.dispatch(&self.color, &b, bytemuck::bytes_of(&p), grid(&self.ctx, g.n))
    }

    /// Record the colour's backward: from `d_features` (the rasterizer's
    /// feature gradients) to `grads.features` (material, overwritten),
    /// `grads.means` and `grads.quats` (added to what the rasterizer's
    /// backward wrote) and `env.grads` (overwritten).
    pub fn record_color_backward(&self, rec: &mut Recorder, x: &ColorInputs, d_features: &Buffer<f32>, grads: &Gaussians, s: &TexelScratch) -> Result<()> {
        let ColorInputs { g, env, cam, fresnel } = *x;
        Self::check_set(g, d_features, fresnel)?;
        if grads.n != g.n || grads.channels != MATERIAL {
            bail!("reflection gradients ({} Gaussians) do not match the set ({})", grads.n, g.n);
        }
        if g.n > s.capacity {
            bail!("{} reflection Gaussians exceed the texel scratch's {}", g.n, s.capacity);
        }
        if g.n == 0 {
            rec.fill(&env.grads.binding(), 0)?;
            return Ok(());
        }
        let p = Self::color_push(g, env, cam, fresnel);
        let b = [
            g.means.binding(),
            g.quats.binding(),
            g.features.binding(),
            env.params.binding(),
            d_features.binding(),
            grads.means.binding(),
            grads.quats.binding(),
            grads.features.binding(),
            s.keys.binding(),
            s.slots.binding(),
            s.grads.binding(),
            Self::depth_binding(env),
        ];
        rec.dispatch(&self.color_backward, &b, bytemuck::bytes_of(&p), grid(&self.ctx, g.n))?;
        self.record_texel_sum(rec, env, 4 * g.n, s)
    }

    /// Sort the first `slots` tap slots by texel and sum them per texel into `env.grads`.
    fn record_texel_sum(&self, rec: &mut Recorder, env: &EnvMap, slots: u32, s: &TexelScratch) -> Result<()> {
        let texels = env.texels();
        let bits = 32 - (texels.max(2) - 1).leading_zeros();
        let sc = rec.begin_scope("refl.texel_sort");
        self.sort.record(rec, &s.keys, &s.slots, &Count::Host(slots), bits, &s.sort)?;
        rec.end_scope(sc);
        let sc = rec.begin_scope("refl.texel_reduce");
        rec.update(&s.count.binding(), bytemuck::bytes_of(&slots))?;
        rec.fill(&s.ranges.binding(), 0)?;
        rec.dispatch(&self.ranges, &[s.count.binding(), s.keys.binding(), s.ranges.binding()], &[], grid(&self.ctx, slots))?;
        let chunks = slots.div_ceil(CHUNK);
        rec.dispatch(&self.chunks, &[s.keys.binding(), s.slots.binding(), s.grads.binding(), s.runs.binding()], bytemuck::cast_slice(&[slots, CHUNK]), grid(&self.ctx, chunks))?;
        rec.dispatch(
            &self.reduce,
            &[s.ranges.binding(), s.slots.binding(), s.grads.binding(), s.runs.binding(), env.grads.binding()],
            bytemuck::cast_slice(&[texels, CHUNK]),
            grid(&self.ctx, texels),
        )?;
        rec.end_scope(sc);
        Ok(())
    }

    fn composite_push(cam: &Camera, fresnel: Fresnel, scat_grad: bool, prior: CompositePriors) -> CompositePush {
        CompositePush {
            width: cam.width,
            height: cam.height,
            channels: fresnel.channels(),
            schlick: fresnel.flag(),
            fx: cam.fx,
            fy: cam.fy,
            cx: cam.cx,
            cy: cam.cy,
            scat_grad: scat_grad as u32,
            r_prior: prior.r,
            alpha_prior: prior.alpha,
            mask_weight: prior.mask,
        }
    }

    /// Record the composite of a scattering render `x.scat` (colour in its
    /// first 3 planes) and a reflection render `x.refl` (`fresnel.channels()`
    /// feature channels, `Plane` order) into `loss_in`: the composite colour
    /// followed by the reflection render's alpha..distortion planes, i.e. a
    /// 3-channel render's layout, for `ImageLoss::record_planes`.
    pub fn record_composite(&self, rec: &mut Recorder, cam: &Camera, fresnel: Fresnel, x: &CompositeInputs, loss_in: &Buffer<f32>) -> Result<()> {
        let CompositeInputs { scat, refl } = *x;
        let ch = fresnel.channels();
        check_planes(cam, &[(scat, 3), (refl, Plane::count(ch)), (loss_in, Plane::count(3))])?;
        let p = Self::composite_push(cam, fresnel, false, CompositePriors::default());
        rec.dispatch(&self.composite, &[scat.binding(), refl.binding(), loss_in.binding()], bytemuck::bytes_of(&p), grid(&self.ctx, cam.width * cam.height))
    }

    /// Record the composite's backward: `g.loss_grad` (gradient of every
    /// plane of `loss_in`) to `g.refl_grad` (every plane of the reflection
    /// render, overwritten) and, when given, `g.scat_grad` (the scattering
    /// colour's 3 planes, overwritten). `prior`'s values are added to dL/dR
    /// and to dL/dalpha at every pixel ([`CompositePriors::of_means`]).
    pub fn record_composite_backward(&self, rec: &mut Recorder, cam: &Camera, fresnel: Fresnel, x: &CompositeInputs, g: &CompositeGrads, prior: CompositePriors) -> Result<()> {
        let CompositeInputs { scat, refl } = *x;
        let ch = fresnel.channels();
        check_planes(cam, &[(scat, 3), (refl, Plane::count(ch)), (g.loss_grad, Plane::count(3)), (g.refl_grad, Plane::count(ch))])?;
        if let Some(s) = g.scat_grad {
            check_planes(cam, &[(s, 3)])?;
        }
        if let Some(m) = g.mask {
            check_planes(cam, &[(m, 1)])?;
        }
        let mut p = Self::composite_push(cam, fresnel, g.scat_grad.is_some(), prior);
        if g.mask.is_none() {
            p.mask_weight = 0.0;
        }
        // Without a scattering gradient (a mask) the binding is never
        // written (read); bind the reflection gradient (the loss gradient)
        // in its place.
        let sg = g.scat_grad.unwrap_or(g.refl_grad);
        let mask = g.mask.unwrap_or(g.loss_grad);
        rec.dispatch(
            &self.composite_backward,
            &[scat.binding(), refl.binding(), g.loss_grad.binding(), g.refl_grad.binding(), sg.binding(), mask.binding()],
            bytemuck::bytes_of(&p),
            grid(&self.ctx, cam.width * cam.height),
        )
    }

    /// Record the Stage I residual r = target - scat (3 planes each, `pixels`
    /// per plane) into `residual`: r's 3 planes, then mean_c |r_c|.
    pub fn record_residual(&self, rec: &mut Recorder, pixels: u32, target: &Buffer<f32>, scat: &Buffer<f32>, residual: &Buffer<f32>) -> Result<()> {
        let n = pixels as usize;
        for (b, planes) in [(target, 3), (scat, 3), (residual, 4)] {
            if b.len() < planes * n {
                bail!("'{}' holds {} values; {planes} planes of {pixels} pixels need {}", b.name(), b.len(), planes * n);
            }
        }
        rec.dispatch(&self.residual, &[target.binding(), scat.binding(), residual.binding()], bytemuck::bytes_of(&pixels), grid(&self.ctx, pixels))
    }
}

/// What Stage II's composite reads: the scattering render (colour in its
/// first 3 planes) and the reflection render (`fresnel.channels()`
/// features, `Plane` order).
#[derive(Clone, Copy)]
pub struct CompositeInputs<'a> {
    pub scat: &'a Buffer<f32>,
    pub refl: &'a Buffer<f32>,
}

/// The gradients of Stage II's composite backward: in `loss_grad`, out the
/// rest (each overwritten).
pub struct CompositeGrads<'a> {
    /// dL/d(composite render), every plane of the loss's input.
    pub loss_grad: &'a Buffer<f32>,
    /// dL/d(reflection render), every plane.
    pub refl_grad: &'a Buffer<f32>,
    /// dL/d(scattering colour), 3 planes, when the scattering set trains.
    pub scat_grad: Option<&'a Buffer<f32>>,
    /// The glass mask the reflection set's alpha is drawn to (one plane, 0
    /// or 1) with a [`CompositePriors::mask`] weight.
    pub mask: Option<&'a Buffer<f32>>,
}
