//! Fused Adam (PyTorch form) over one parameter buffer per dispatch.

use super::TrainableSet;
use super::{dispatch_items, grid, kernel};
use crate::raster::ReduceAdam;
use crate::shaders;
use anyhow::{bail, Result};
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;
use tgs_engine::{Buffer, BufferBinding, Context, Kernel, Recorder};

/// One parameter group: a learning rate, or two (elements with index modulo
/// `stride` below `split` use `lr`, the others `lr_rest`). Only the first
/// `active` elements of each block of `stride` are stepped (the SH
/// coefficients of degrees not yet active: their gradients are exactly
/// zero, so their moments and values would not move anyway).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamGroup {
    pub lr: f32,
    pub lr_rest: f32,
    pub stride: u32,
    pub split: u32,
    pub active: u32,
}

impl AdamGroup {
    pub fn single(lr: f32) -> AdamGroup {
        AdamGroup { lr, lr_rest: lr, stride: 1, split: 1, active: 1 }
    }

    /// Two rates over blocks of `stride`, every element stepped.
    pub fn split(lr: f32, lr_rest: f32, stride: u32, split: u32) -> AdamGroup {
        AdamGroup { lr, lr_rest, stride, split, active: stride }
    }

    /// The elements stepped of an array of `len`.
    pub fn items(&self, len: usize) -> usize {
        if self.active >= self.stride {
            len
        } else {
            len / self.stride.max(1) as usize * self.active as usize
        }
    }
}

/// One parameter array of a set: parameter, gradient, first and second
/// moments, and its length in floats.
/// The four arrays one Adam step reads and writes (glsl/adam/step.comp's
/// bindings 0..=3), over their first `n` elements.
#[derive(Clone, Copy)]
pub struct AdamArrays<'a> {
    pub param: &'a Buffer<f32>,
    pub grad: &'a Buffer<f32>,
    /// First and second moments.
    pub m: &'a Buffer<f32>,
    pub v: &'a Buffer<f32>,
    pub n: usize,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Push {
    n: u32,
    stride: u32,
    split: u32,
    active: u32,
    lr_a: f32,
    lr_b: f32,
    beta1: f32,
    beta2: f32,
    eps: f32,
    bc1: f32,
    bc2: f32,
}

pub struct Adam {
    ctx: Arc<Context>,
    kernel: Kernel,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    /// Elements per dispatch, forced ([`Adam::slice`]).
    slice: Option<usize>,
}

impl Adam {
    /// Adam with betas (0.9, 0.999) and the given epsilon.
    pub fn new(ctx: &Arc<Context>, eps: f32) -> Result<Adam> {
        Ok(Adam { ctx: ctx.clone(), kernel: kernel(ctx, "adam", shaders::ADAM_STEP, std::mem::size_of::<Push>() as u32)?, beta1: 0.9, beta2: 0.999, eps, slice: None })
    }

    /// This Adam with every array stepped in slices of about `elements`
    /// (whole blocks of its group's stride, 64 blocks at a time) even when
    /// it fits one binding: tests compare the sliced step with the whole.
    pub fn slice(mut self, elements: usize) -> Adam {
        self.slice = Some(elements);
        self
    }

    /// Elements per dispatch for an array of `n` in blocks of `stride`:
    /// all of them, unless they exceed one storage binding (the SH 3
    /// features of a million Gaussians and their moments: 183 MiB; lavapipe
    /// binds 128) or a slice is forced; then whole multiples of 64 blocks,
    /// so each slice starts at an offset every device allows.
    fn slice_len(&self, n: usize, stride: usize) -> usize {
        let (fit, stride) = ((self.ctx.caps().max_storage_buffer_range / 4) as usize, stride.max(1));
        match crate::slice_units(n <= fit, (fit / stride) as u64, self.slice.map(|e| (e / stride) as u64)) {
            None => n,
            Some(blocks) => blocks as usize * stride,
        }
    }

    /// Record step `t` (1-based) over the first `a.n` elements of `a`.
    pub fn record(&self, rec: &mut Recorder, a: AdamArrays, group: &AdamGroup, t: u64) -> Result<()> {
        self.record_on(rec, a, group, t, None)
    }

    /// As [`Adam::record`], the workgroup counts read from `args` (written
    /// on the GPU from [`Adam::grid`], e.g. by `Rasterizer::record_fit_gate`;
    /// zero groups skip the step).
    pub fn record_gated(&self, rec: &mut Recorder, a: AdamArrays, group: &AdamGroup, t: u64, args: &BufferBinding) -> Result<()> {
        self.record_on(rec, a, group, t, Some(args))
    }

    /// The grid [`Adam::record`] dispatches for `n` elements.
    pub fn grid(&self, n: usize) -> [u32; 3] {
        grid(&self.ctx, n as u32)
    }

    /// The body of [`Adam::record`] (`args` None) and [`Adam::record_gated`].
    fn record_on(&self, rec: &mut Recorder, a: AdamArrays, group: &AdamGroup, t: u64, args: Option<&BufferBinding>) -> Result<()> {
        let AdamArrays { param, grad, m, v, n } = a;
        if n == 0 {
            return Ok(());
        }
        if [grad.len(), m.len(), v.len(), param.len()].iter().any(|&l| l < n) {
            bail!("Adam on '{}': {n} elements but a buffer is shorter", param.name());
        }
        if t == 0 || group.stride == 0 || group.active == 0 {
            bail!("Adam step must be >= 1, stride and active >= 1");
        }
        let active = group.active.min(group.stride);
        if active < group.stride && n % group.stride as usize != 0 {
            bail!("Adam on '{}': {n} elements are not whole blocks of {}", param.name(), group.stride);
        }
        let p = Push {
            n: group.items(n) as u32,
            stride: group.stride,
            split: group.split,
            active,
            lr_a: group.lr,
            lr_b: group.lr_rest,
            beta1: self.beta1,
            beta2: self.beta2,
            eps: self.eps,
            bc1: 1.0 - self.beta1.powf(t as f32),
            bc2: 1.0 - self.beta2.powf(t as f32),
        };
        let per = self.slice_len(n, group.stride as usize);
        if per >= n {
            return dispatch_items(rec, &self.kernel, &[param.binding(), grad.binding(), m.binding(), v.binding()], bytemuck::bytes_of(&p), p.n, args);
        }
        // Slices of whole blocks: element i of a slice is element
        // start + i of the array, in the same place of its block. A gated
        // step's grid covers the whole array; each slice's invocations past
        // its own elements return.
        for start in (0..n).step_by(per) {
            let len = per.min(n - start);
            let ps = Push { n: group.items(len) as u32, ..p };
            let bindings = [param.slice(start, len), grad.slice(start, len), m.slice(start, len), v.slice(start, len)];
            dispatch_items(rec, &self.kernel, &bindings, bytemuck::bytes_of(&ps), ps.n, args)?;
        }
        Ok(())
    }

    /// Record step `t` over every parameter array of `set`, in its layout
    /// order (means, log-scales, quaternions, opacity, features), each with
    /// its group.
    pub fn record_set(&self, rec: &mut Recorder, set: &TrainableSet, groups: &[AdamGroup; 5], t: u64) -> Result<()> {
        self.record_set_on(rec, set, groups, t, None)
    }

    /// Record step `t` over `set`'s features (SH colour) alone, with `group`;
    /// the other arrays and their moments are left as they are.
    pub fn record_set_features(&self, rec: &mut Recorder, set: &TrainableSet, group: &AdamGroup, t: u64) -> Result<()> {
        self.record_on(rec, Self::arrays(set)[4], group, t, None)
    }

    /// The grids of [`Adam::record_set`]'s five dispatches (means, scales,
    /// rotations, opacity, features) with `groups`, for a gate
    /// (`Rasterizer::record_fit_gate`).
    pub fn set_grids(&self, set: &TrainableSet, groups: &[AdamGroup; 5]) -> [[u32; 3]; 5] {
        let arrays = Self::arrays(set);
        std::array::from_fn(|k| self.grid(groups[k].items(arrays[k].n)))
    }

    /// As [`Adam::record_set`], dispatch k taking its workgroup counts from
    /// `args[k]` (see [`Adam::set_grids`]).
    pub fn record_set_gated(&self, rec: &mut Recorder, set: &TrainableSet, groups: &[AdamGroup; 5], t: u64, args: &[BufferBinding]) -> Result<()> {
        if args.len() != 5 {
            bail!("a gated Adam step over a Gaussian set needs 5 argument slots, got {}", args.len());
        }
        self.record_set_on(rec, set, groups, t, Some(args))
    }

    /// The constants of step `t` with `groups` for the reduce with Adam fused
    /// (`Rasterizer::record_backward_adam`), which steps means, log-scales,
    /// rotations and opacity at one rate each and the features in blocks of
    /// the set's features per Gaussian.
    pub fn reduce_constants(&self, set: &TrainableSet, groups: &[AdamGroup; 5], t: u64) -> Result<ReduceAdam> {
        if t == 0 {
            bail!("Adam step must be >= 1");
        }
        if let Some(k) = groups[..4].iter().position(|g| g.stride != 1 || g.lr != g.lr_rest) {
            bail!("the fused Adam step takes one rate for parameter array {k}, got {:?}", groups[k]);
        }
        let f = &groups[4];
        let per = set.params.channels * set.params.coeffs;
        if f.stride != per {
            bail!("the fused Adam step takes the features in blocks of {per} per Gaussian, got {}", f.stride);
        }
        Ok(ReduceAdam {
            lr_means: groups[0].lr,
            lr_scales: groups[1].lr,
            lr_quats: groups[2].lr,
            lr_opacity: groups[3].lr,
            lr_feats: f.lr,
            lr_rest: f.lr_rest,
            feat_split: f.split.min(per),
            feat_active: f.active.min(per),
            beta1: self.beta1,
            beta2: self.beta2,
            eps: self.eps,
            bc1: 1.0 - self.beta1.powf(t as f32),
            bc2: 1.0 - self.beta2.powf(t as f32),
        })
    }

    fn arrays(set: &TrainableSet) -> [AdamArrays<'_>; 5] {
        let n = set.len() as usize;
        let f = (set.params.channels * set.params.coeffs) as usize;
        let (p, g, m, v) = (set.params.buffers(), set.grads.buffers(), set.m.buffers(), set.v.buffers());
        let w = crate::raster::array_widths(f);
        std::array::from_fn(|i| AdamArrays { param: p[i], grad: g[i], m: m[i], v: v[i], n: w[i] * n })
    }

    fn record_set_on(&self, rec: &mut Recorder, set: &TrainableSet, groups: &[AdamGroup; 5], t: u64, args: Option<&[BufferBinding]>) -> Result<()> {
        for (k, (a, group)) in Self::arrays(set).into_iter().zip(groups).enumerate() {
            self.record_on(rec, a, group, t, args.map(|a| &a[k]))?;
        }
        Ok(())
    }
}
