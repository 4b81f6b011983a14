//! Stage III's deferred kernels around the light-field MLP (paper §3.4,
//! method-notes §3.5), GLSL in `glsl/lightfield/`:
//! - `material`: the reflection set's features, sigmoid of its material
//!   [f0 (3), r], and the material gradient;
//! - `mask` + the project's prefix sum + `compact`: the list of pixels whose
//!   R exceeds a threshold, each with its sample (x_refl normalized, w_r),
//!   so that the MLP runs on those pixels only;
//! - `composite` / `composite_backward`: I = (1 - R) I_scat + R F Phi.

use crate::raster::{Camera, Plane};
use crate::reflection::check_planes;
use crate::scan::{Count, PrefixSum, ScanScratch};
use crate::shaders;
use crate::train::{grid, kernel};
use crate::WG;
use anyhow::{bail, Result};
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Kernel, KernelDesc, Recorder};

/// Rasterized feature channels of the reflection set in Stage III: [F0 sum (3), R].
pub const CHANNELS: u32 = 4;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Push {
    width: u32,
    height: u32,
    threshold: f32,
    schlick: u32,
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    rot: [[f32; 4]; 3],
    centre: [f32; 4],
    scale: [f32; 4],
    max_samples: u32,
    r_prior: f32,
    pad: [u32; 2],
}

/// What places a view's samples: the camera, the box mapped to [-1, 1]^3,
/// the evaluation threshold on R and the Fresnel switch.
#[derive(Clone, Copy, Debug)]
pub struct ShadeParams {
    /// Centre of the normalization box (world).
    pub centre: [f32; 3],
    /// Half its size per axis.
    pub half_extent: [f32; 3],
    /// Phi is evaluated where R > threshold.
    pub threshold: f32,
    pub schlick: bool,
}

/// Per-frame-size memory of the sample list.
pub struct SampleScratch {
    pixels: u32,
    flags: Buffer<u32>,
    scan: ScanScratch,
    /// Per pixel: its sample index or u32::MAX.
    pub sample_of: Buffer<u32>,
    /// The number of samples, after [`LightFieldShading::record_samples`].
    pub count: Buffer<u32>,
}

pub struct LightFieldShading {
    ctx: Arc<Context>,
    scan: PrefixSum,
    material: Kernel,
    mask: Kernel,
    compact: Kernel,
    composite: Kernel,
    composite_backward: [Kernel; 2],
}

fn push(cam: &Camera, p: &ShadeParams, max_samples: u32, r_prior: f32) -> Push {
    let m = &cam.world_to_view;
    let h = p.half_extent.map(|v| if v > 0.0 { 1.0 / v } else { 1.0 });
    Push {
        width: cam.width,
        height: cam.height,
        threshold: p.threshold,
        schlick: p.schlick as u32,
        fx: cam.fx,
        fy: cam.fy,
        cx: cam.cx,
        cy: cam.cy,
        rot: *m,
        centre: [p.centre[0], p.centre[1], p.centre[2], 0.0],
        scale: [h[0], h[1], h[2], 0.0],
        max_samples,
        r_prior,
        pad: [0; 2],
    }
}

impl LightFieldShading {
    pub fn new(ctx: &Arc<Context>) -> Result<LightFieldShading> {
        let pb = std::mem::size_of::<Push>() as u32;
        let sg = ctx.caps().min_subgroup_size.max(1);
        let backward = |flag: u32| {
            let spec = [(0, WG), (1, sg), (2, 1), (3, flag)];
            Kernel::new(
                ctx,
                &KernelDesc {
                    name: "lf.composite_backward",
                    spirv: shaders::LIGHTFIELD_COMPOSITE_BACKWARD,
                    spec: &spec,
                    push_bytes: pb,
                    subgroup_size: None,
                    full_subgroups: false,
                },
            )
        };
        Ok(LightFieldShading {
            ctx: ctx.clone(),
            scan: PrefixSum::new(ctx)?,
            material: kernel(ctx, "lf.material", shaders::LIGHTFIELD_MATERIAL, 8)?,
            mask: kernel(ctx, "lf.mask", shaders::LIGHTFIELD_MASK, pb)?,
            compact: kernel(ctx, "lf.compact", shaders::LIGHTFIELD_COMPACT, pb)?,
            composite: kernel(ctx, "lf.composite", shaders::LIGHTFIELD_COMPOSITE, pb)?,
            composite_backward: [backward(0)?, backward(1)?],
        })
    }

    pub fn sample_scratch(&self, width: u32, height: u32) -> Result<SampleScratch> {
        let n = width as usize * height as usize;
        if n == 0 {
            bail!("light-field samples of an empty {width}x{height} image");
        }
        Ok(SampleScratch {
            pixels: n as u32,
            flags: Buffer::uninit(&self.ctx, "lf.flags", n)?,
            scan: ScanScratch::new(&self.ctx, n as u32)?,
            sample_of: Buffer::uninit(&self.ctx, "lf.sample_of", n)?,
            count: Buffer::new(&self.ctx, "lf.count", 1)?,
        })
    }

    /// Record the features sigmoid(material) of `n` Gaussians (4 floats each).
    pub fn record_material(&self, rec: &mut Recorder, material: &Buffer<f32>, n: u32, feat: &Buffer<f32>) -> Result<()> {
        let len = n * CHANNELS;
        if material.len() < len as usize || feat.len() < len as usize {
            bail!("material '{}' / features '{}' hold fewer than {len} values", material.name(), feat.name());
        }
        rec.dispatch(&self.material, &[material.binding(), feat.binding(), feat.binding()], bytemuck::cast_slice(&[len, 0u32]), grid(&self.ctx, len.max(1)))
    }

    /// Record the material gradient (overwritten) from the features' gradient.
    pub fn record_material_backward(&self, rec: &mut Recorder, material: &Buffer<f32>, n: u32, d_feat: &Buffer<f32>, d_material: &Buffer<f32>) -> Result<()> {
        let len = n * CHANNELS;
        if [material.len(), d_feat.len(), d_material.len()].iter().any(|&l| l < len as usize) {
            bail!("material gradient buffers hold fewer than {len} values");
        }
        rec.dispatch(&self.material, &[material.binding(), d_feat.binding(), d_material.binding()], bytemuck::cast_slice(&[len, 1u32]), grid(&self.ctx, len.max(1)))
    }

    /// The pixel count of `cam` after checking `bufs` (buffer, planes) and
    /// that the sample scratch is this view's.
    fn check(cam: &Camera, s: &SampleScratch, bufs: &[(&Buffer<f32>, u32)]) -> Result<u32> {
        check_planes(cam, bufs)?;
        let n = cam.width * cam.height;
        if s.pixels != n {
            bail!("sample scratch for {} pixels does not fit a {}x{} view", s.pixels, cam.width, cam.height);
        }
        Ok(n)
    }

    /// Record the sample list of the reflection render `refl` (CHANNELS
    /// features): `s.sample_of`, `s.count` (every pixel above the
    /// threshold) and the samples (6 floats each, at their rank) into
    /// `samples`, which holds `samples.len() / 6` of them: pixels ranked
    /// beyond are not evaluated (the caller checks the count).
    pub fn record_samples(&self, rec: &mut Recorder, cam: &Camera, p: &ShadeParams, refl: &Buffer<f32>, s: &SampleScratch, samples: &Buffer<f32>) -> Result<()> {
        let n = Self::check(cam, s, &[(refl, Plane::count(CHANNELS))])?;
        let pc = push(cam, p, (samples.len() / 6).min(u32::MAX as usize) as u32, 0.0);
        let g = grid(&self.ctx, n);
        rec.dispatch(&self.mask, &[refl.binding(), s.flags.binding()], bytemuck::bytes_of(&pc), g)?;
        self.scan.record(rec, &s.flags, &s.flags, &Count::Host(n), &s.scan)?;
        rec.dispatch(&self.compact, &[refl.binding(), s.flags.binding(), s.sample_of.binding(), samples.binding(), s.count.binding()], bytemuck::bytes_of(&pc), g)
    }

    /// Record the composite into `loss_in` (3-channel render layout) from
    /// the inputs `x` (glsl/lightfield/composite.comp).
    pub fn record_composite(&self, rec: &mut Recorder, cam: &Camera, p: &ShadeParams, x: &CompositeInputs, loss_in: &Buffer<f32>) -> Result<()> {
        let n = Self::check(cam, x.samples, &[(x.refl, Plane::count(CHANNELS)), (x.scat, 3), (loss_in, Plane::count(3))])?;
        let pc = push(cam, p, 0, 0.0);
        let b = [x.refl.binding(), x.scat.binding(), x.samples.sample_of.binding(), x.phi.binding(), loss_in.binding()];
        rec.dispatch(&self.composite, &b, bytemuck::bytes_of(&pc), grid(&self.ctx, n))
    }

    /// Record the composite's backward (glsl/lightfield/composite_backward.comp):
    /// `g.loss_grad` (colour planes) to `g.d_phi` (per sample), `g.refl_grad`
    /// (every plane of the reflection render, overwritten) and, when given,
    /// `g.scat_grad` (3 planes). `r_prior` is added to dL/dR at every pixel,
    /// evaluated or not (the gradient of `lambda * mean(R)` is `lambda / pixels`).
    pub fn record_composite_backward(&self, rec: &mut Recorder, cam: &Camera, p: &ShadeParams, x: &CompositeInputs, g: &CompositeGrads, r_prior: f32) -> Result<()> {
        let n = Self::check(cam, x.samples, &[(x.refl, Plane::count(CHANNELS)), (x.scat, 3), (g.loss_grad, 3), (g.refl_grad, Plane::count(CHANNELS))])?;
        if let Some(sg) = g.scat_grad {
            check_planes(cam, &[(sg, 3)])?;
        }
        let pc = push(cam, p, 0, r_prior);
        let sg = g.scat_grad.unwrap_or(g.refl_grad);
        let b = [x.refl.binding(), x.scat.binding(), x.samples.sample_of.binding(), x.phi.binding(), g.loss_grad.binding(), g.d_phi.binding(), g.refl_grad.binding(), sg.binding()];
        rec.dispatch(&self.composite_backward[g.scat_grad.is_some() as usize], &b, bytemuck::bytes_of(&pc), grid(&self.ctx, n))
    }
}

/// What Stage III's composite reads (its forward and backward bind them in
/// this order of meaning: reflection render, scattering colour, sample
/// list, Phi).
pub struct CompositeInputs<'a> {
    /// The scattering colour (3 planes).
    pub scat: &'a Buffer<f32>,
    /// The reflection render (CHANNELS features, `Plane` order).
    pub refl: &'a Buffer<f32>,
    /// This view's sample list (which pixels Phi ran on).
    pub samples: &'a SampleScratch,
    /// Phi at the samples (3 floats each).
    pub phi: &'a Buffer<f32>,
}

/// The gradients of Stage III's composite backward: in `loss_grad`, out the
/// rest (each overwritten).
pub struct CompositeGrads<'a> {
    /// dL/d(composite colour), 3 planes.
    pub loss_grad: &'a Buffer<f32>,
    /// dL/dPhi per sample.
    pub d_phi: &'a Buffer<f32>,
    /// dL/d(reflection render), every plane.
    pub refl_grad: &'a Buffer<f32>,
    /// dL/d(scattering colour), 3 planes, when the scattering set trains.
    pub scat_grad: Option<&'a Buffer<f32>>,
}
