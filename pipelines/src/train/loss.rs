//! The image loss of 2DGS training (method-notes §1.8) on the GPU:
//! (1 - λ) L1 + λ (1 - SSIM) with an 11x11 Gaussian window (σ 1.5, zero
//! padding), normal consistency between the rendered normal and the normal
//! of the expected-depth map, and a weight on the distortion plane. Writes
//! the render's full upstream gradient (`Frame::grad_out`) and per-workgroup
//! partial sums for logging; no atomics, fixed summation order.

use super::{grid, grid_len, kernel};
use crate::raster::{Camera, Frame, Plane};
use crate::shaders;
use anyhow::{bail, Result};
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Kernel, Readback, Recorder};

/// What a loss reads and writes: a render's planes (`Plane` order), the
/// target image (its colour planes), and the gradient of the render's
/// planes (written, or added to).
#[derive(Clone, Copy)]
pub struct LossIo<'a> {
    pub render: &'a Buffer<f32>,
    pub target: &'a Buffer<f32>,
    pub grad: &'a Buffer<f32>,
}

/// Loss weights. The photometric term is (1 - ssim) L1 + ssim D-SSIM.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossWeights {
    pub ssim: f32,
    /// Normal consistency (0 = off).
    pub normal: f32,
    /// Depth distortion (0 = off).
    pub dist: f32,
}

/// Means of the loss terms over one view (from the partial sums).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LossValues {
    pub l1: f64,
    pub mse: f64,
    pub ssim: f64,
    /// Mean of (1 - alpha N.s); NaN when normal consistency was off.
    pub normal: f64,
}

impl LossValues {
    pub fn psnr(&self) -> f64 {
        -10.0 * self.mse.max(1e-20).log10()
    }
    /// The photometric loss (1 - λ) L1 + λ (1 - SSIM).
    pub fn photometric(&self, ssim_weight: f64) -> f64 {
        (1.0 - ssim_weight) * self.l1 + ssim_weight * (1.0 - self.ssim)
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable, Default)]
struct Push {
    width: u32,
    height: u32,
    channels: u32,
    pad1: u32,
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    w_l1: f32,
    w_ssim: f32,
    w_normal: f32,
    w_dist: f32,
    mode: u32,
    pad0: u32,
    plane_alpha: u32,
    plane_depth: u32,
    plane_normal: u32,
    plane_median: u32,
    plane_dist: u32,
    pad: u32,
}

pub struct ImageLoss {
    ctx: Arc<Context>,
    blur: Kernel,
    ssim: Kernel,
    normal: Kernel,
    grad: Kernel,
}

/// Working buffers of the loss for one image size.
pub struct LossScratch {
    pub width: u32,
    pub height: u32,
    pub channels: u32,
    a: Buffer<f32>,
    b: Buffer<f32>,
    normal: Buffer<f32>,
    /// 4 floats per workgroup: sums of L1, squared error, SSIM, normal term.
    pub partials: Buffer<f32>,
    /// `partials` as the last submitted recording of this loss left them.
    partials_host: Readback<f32>,
    normal_on: bool,
}

impl LossScratch {
    /// Average the partial sums the last recorded loss brought back with its
    /// submission (call after that submission completed; no GPU work).
    pub fn values(&self) -> Result<LossValues> {
        let p = self.partials_host.read()?;
        let mut s = [0f64; 4];
        for chunk in p.chunks(4) {
            for k in 0..4 {
                s[k] += chunk[k] as f64;
            }
        }
        let n = self.width as f64 * self.height as f64;
        let nc = n * self.channels as f64;
        Ok(LossValues { l1: s[0] / nc, mse: s[1] / nc, ssim: s[2] / nc, normal: if self.normal_on { s[3] / n } else { f64::NAN } })
    }
}

impl ImageLoss {
    pub fn new(ctx: &Arc<Context>) -> Result<ImageLoss> {
        let pb = std::mem::size_of::<Push>() as u32;
        let cpu = ctx.caps().is_cpu();
        Ok(ImageLoss {
            ctx: ctx.clone(),
            // CPU devices read the images through texel buffers (variant TEXEL).
            blur: kernel(ctx, "loss.blur", if cpu { shaders::LOSS_BLUR_TEXEL } else { shaders::LOSS_BLUR }, pb)?,
            ssim: kernel(ctx, "loss.ssim", if cpu { shaders::LOSS_SSIM_TEXEL } else { shaders::LOSS_SSIM }, pb)?,
            normal: kernel(ctx, "loss.normal", shaders::LOSS_NORMAL, pb)?,
            grad: kernel(ctx, "loss.grad", shaders::LOSS_GRAD, pb)?,
        })
    }

    pub fn scratch(&self, width: u32, height: u32, channels: u32) -> Result<LossScratch> {
        let n = width as usize * height as usize;
        if n == 0 {
            bail!("loss on an empty {width}x{height} image");
        }
        let c = channels as usize;
        let groups = grid_len(&self.ctx, n as u32);
        Ok(LossScratch {
            width,
            height,
            channels,
            a: Buffer::new(&self.ctx, "loss.a", 5 * c * n)?,
            b: Buffer::new(&self.ctx, "loss.b", 5 * c * n)?,
            normal: Buffer::new(&self.ctx, "loss.normal", 6 * n)?,
            partials: Buffer::new(&self.ctx, "loss.partials", 4 * groups as usize)?,
            partials_host: Readback::new(&self.ctx, "loss.partials_host", 4 * groups as usize)?,
            normal_on: false,
        })
    }

    /// Record the loss of `frame`'s render against `target` (`channels`
    /// planes of width x height, planar) and write `frame.grad_out`.
    pub fn record(&self, rec: &mut Recorder, frame: &Frame, target: &Buffer<f32>, cam: &Camera, w: &LossWeights, s: &mut LossScratch) -> Result<()> {
        if frame.width != s.width || frame.height != s.height {
            bail!("loss scratch is {}x{} but the render is {}x{}", s.width, s.height, frame.width, frame.height);
        }
        self.record_planes(rec, LossIo { render: &frame.out, target, grad: &frame.grad_out }, cam, w, s)
    }

    /// As [`ImageLoss::record`] on planes laid out as a render with
    /// `s.channels` channels (`Plane` order) held in `io.render`, writing
    /// the gradient of every plane to `io.grad` (e.g. a deferred composite
    /// followed by another render's geometry planes).
    pub fn record_planes(&self, rec: &mut Recorder, io: LossIo, cam: &Camera, w: &LossWeights, s: &mut LossScratch) -> Result<()> {
        let LossIo { render: out, target, grad: grad_out } = io;
        let (width, height, c) = (s.width, s.height, s.channels);
        let n = width * height;
        let need = (Plane::count(c) * n) as usize;
        if out.len() < need || grad_out.len() < need {
            bail!("loss planes '{}'/'{}' hold {}/{} values; {width}x{height} with {c} channels needs {need}", out.name(), grad_out.name(), out.len(), grad_out.len());
        }
        if target.len() < (c * n) as usize {
            bail!("target '{}' has {} values; a {width}x{height} image with {c} channels needs {}", target.name(), target.len(), c * n);
        }
        let base = Push {
            width,
            height,
            channels: c,
            pad1: 0,
            fx: cam.fx,
            fy: cam.fy,
            cx: cam.cx,
            cy: cam.cy,
            w_l1: 1.0 - w.ssim,
            w_ssim: w.ssim,
            w_normal: w.normal,
            w_dist: w.dist,
            mode: 0,
            pad0: 0,
            plane_alpha: Plane::Alpha.index(c),
            plane_depth: Plane::Depth.index(c),
            plane_normal: Plane::Normal(0).index(c),
            plane_median: Plane::Median.index(c),
            plane_dist: Plane::Distortion.index(c),
            pad: 0,
        };
        let (out, tgt) = (out.binding(), target.binding());
        let sc = rec.begin_scope("loss.ssim");
        // Horizontal passes in loss.blur (one invocation per channel and
        // pixel), vertical ones summed by loss.ssim (moments) and loss.grad
        // (coefficients): a then holds the rows of the moments, b the SSIM
        // coefficients, a their rows.
        let blur = |rec: &mut Recorder, mode: u32, src: &Buffer<f32>, dst: &Buffer<f32>| {
            let p = Push { mode, ..base };
            rec.dispatch(&self.blur, &[out.clone(), tgt.clone(), src.binding(), dst.binding()], bytemuck::bytes_of(&p), grid(&self.ctx, c * n))
        };
        blur(rec, 0, &s.b, &s.a)?;
        rec.dispatch(&self.ssim, &[out.clone(), tgt.clone(), s.a.binding(), s.b.binding(), s.partials.binding()], bytemuck::bytes_of(&base), grid(&self.ctx, n))?;
        if w.ssim != 0.0 {
            blur(rec, 1, &s.b, &s.a)?;
        }
        rec.end_scope(sc);
        s.normal_on = w.normal != 0.0;
        let sc = rec.begin_scope("loss.grad");
        if s.normal_on {
            rec.dispatch(&self.normal, &[out.clone(), s.normal.binding(), grad_out.binding(), s.partials.binding()], bytemuck::bytes_of(&base), grid(&self.ctx, n))?;
        }
        rec.dispatch(&self.grad, &[out, tgt, s.a.binding(), s.normal.binding(), grad_out.binding()], bytemuck::bytes_of(&base), grid(&self.ctx, n))?;
        rec.end_scope(sc);
        rec.read_back(&s.partials, 0, &s.partials_host)
    }
}
