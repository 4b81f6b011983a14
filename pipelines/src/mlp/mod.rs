//! Stage III's reflection light field Phi(x, w) (paper §3.4, method-notes
//! §3.5), GLSL in `glsl/mlp/`:
//! - `encode`: the Fourier features gamma(x), gamma(w) of each sample;
//! - `gemm` / `gemm_rows`: one GEMM for the three products of every layer
//!   (forward with bias and activation; the input gradient dX = dZ W; the
//!   weight gradient dW = dZ^T [X, 1] as per-chunk partials in their own
//!   slots), in two kernels with bit-identical results ([`Gemm`]): tiled
//!   through shared memory on GPUs, rows per invocation on CPU devices;
//! - `head_grad`: the head's output gradient turned into dZ (the hidden
//!   layers' dZ is written by the input-gradient product itself, the ReLU's
//!   derivative in its epilogue);
//! - `reduce`: the partials summed per parameter in a fixed order.
//!
//! No atomics: every output has one writer and a fixed summation order that
//! depends on the sample count only, so gradients are bit-identical across
//! reruns and subgroup sizes. The parameters are one flat vector (layer by
//! layer, each [W | b] row-major, [`MlpShape::offset`]) that a single Adam
//! dispatch updates.

mod fused;
mod gemm;
mod scratch;
mod shape;

use fused::Fused;
pub use fused::FUSED_MAX_WIDTH;
use scratch::Block;
pub use scratch::MlpScratch;

use gemm::{row_column_blocks, Product, BLOCKS, MAX_CHUNKS, MIN_CHUNK, NONE, RELU, RELU_DERIV, ROW_CONFIGS, SIGMOID};
pub use gemm::{Gemm, GEMM_ENV};

pub use shape::{MlpShape, OUT, SAMPLE};

use crate::shaders;
use crate::train::{grid, kernel};
use crate::WG;
use anyhow::{bail, Result};
use std::sync::Arc;
use tgs_engine::{Buffer, BufferBinding, Context, Kernel, KernelDesc, Recorder};

/// Chunk of samples per weight-gradient partial for `n` samples, and the
/// number of chunks (at most [`MAX_CHUNKS`]). `glsl/mlp/chunks.glsl` is the
/// same split for a count the GPU holds.
pub fn weight_chunks(n: u32) -> (u32, u32) {
    let chunk = n.div_ceil(MAX_CHUNKS).next_multiple_of(16).max(MIN_CHUNK);
    (chunk, n.div_ceil(chunk).max(1))
}

pub struct Mlp {
    ctx: Arc<Context>,
    gemm_kind: Gemm,
    /// The GEMM, one pipeline per block size of [`BLOCKS`] (tiled) or
    /// configuration of [`ROW_CONFIGS`] (rows).
    gemm: Vec<Kernel>,
    encode: Kernel,
    head_grad: Kernel,
    reduce: Kernel,
    /// The grid of a counted dispatch from the GPU-held count (glsl/mlp/grid.comp).
    grid: Kernel,
}

/// Where a block's backward reads the output gradient and writes the
/// weight gradients; `rows`: the GPU-held count of a counted backward.
#[derive(Clone, Copy)]
struct Grads<'a> {
    d_out: &'a Buffer<f32>,
    grads: &'a Buffer<f32>,
    rows: Option<&'a Buffer<u32>>,
    accumulate: bool,
}

/// The samples a backward covers: the first `n`, or (counted) the first
/// `count[0]` of at most `n`, the count read on the device.
#[derive(Clone, Copy)]
struct Rows<'a> {
    n: u32,
    count: Option<&'a Buffer<u32>>,
}

impl Mlp {
    /// The MLP on the kernel this device runs best ([`Gemm::for_device`]).
    pub fn new(ctx: &Arc<Context>) -> Result<Mlp> {
        Self::with_gemm(ctx, Gemm::for_device(ctx)?)
    }

    /// The MLP on a chosen kernel (tests compare the two; `tgs bench mlp --gemm`).
    pub fn with_gemm(ctx: &Arc<Context>, gemm_kind: Gemm) -> Result<Mlp> {
        let push = std::mem::size_of::<Product>() as u32;
        // The row kernel broadcasts B across SB lanes: a power of two no
        // larger than the device's smallest subgroup (every pipeline's
        // subgroup has at least that many lanes) nor the smallest block.
        let sb = ctx.caps().min_subgroup_size.clamp(1, ROW_CONFIGS[0].nb);
        let pipeline = |name, spirv, spec: &[(u32, u32)]| Kernel::new(ctx, &KernelDesc { name, spirv, spec, push_bytes: push, subgroup_size: None, full_subgroups: false });
        let gemm = match gemm_kind {
            // The fused kernels are the scratch's (they depend on the
            // shape); the weight gradients run on the tiled GEMM.
            Gemm::Tiled | Gemm::Fused => BLOCKS.iter().map(|&b| pipeline("mlp.gemm", shaders::MLP_GEMM, &[(3, b)])).collect::<Result<Vec<_>>>()?,
            Gemm::Rows => ROW_CONFIGS.iter().map(|c| pipeline("mlp.gemm_rows", shaders::MLP_GEMM_ROWS, &[(3, c.nb), (4, sb), (5, c.rr), (6, c.wg)])).collect::<Result<Vec<_>>>()?,
        };
        Ok(Mlp {
            ctx: ctx.clone(),
            gemm_kind,
            gemm,
            encode: kernel(ctx, "mlp.encode", shaders::MLP_ENCODE, 24)?,
            head_grad: kernel(ctx, "mlp.head_grad", shaders::MLP_HEAD_GRAD, 12)?,
            reduce: kernel(ctx, "mlp.reduce", shaders::MLP_REDUCE, 20)?,
            grid: kernel(ctx, "mlp.grid", shaders::MLP_GRID, 20)?,
        })
    }

    /// The kernel the products run on.
    pub fn gemm(&self) -> Gemm {
        self.gemm_kind
    }

    /// The most samples whose activations one block of a scratch of
    /// `shape` holds on this device (its widest activation buffer within
    /// one binding); more are taken in blocks.
    pub fn max_capacity(&self, shape: &MlpShape) -> u32 {
        let max = self.gemm_kind.max_binding_floats(self.ctx.caps());
        (max / self.widest(shape)).min(u32::MAX as u64) as u32
    }

    /// Floats per sample of the widest activation buffer of a block.
    fn widest(&self, shape: &MlpShape) -> u64 {
        let widest = shape.cat_width().max(shape.dx()).max(1) as u64;
        if self.gemm_kind == Gemm::Fused {
            widest.max(Fused::floats_per_sample(shape))
        } else {
            widest
        }
    }

    /// Memory for up to `capacity` samples of `shape`, in one block when
    /// their activations fit one storage binding (then as
    /// [`Mlp::scratch`] always was), else in blocks of the most that do
    /// ([`Mlp::scratch_in_blocks`]).
    pub fn scratch(&self, shape: MlpShape, capacity: u32) -> Result<MlpScratch> {
        self.scratch_in_blocks(shape, capacity, self.max_capacity(&shape))
    }

    /// As [`Mlp::scratch`], with the activations held for `block` samples
    /// at a time (tests force small blocks). The host-count forward and
    /// backward of more samples than a block run block after block: the
    /// forward rows are the same, bit for bit; the backward recomputes each
    /// block's activations before its gradients, and sums the weight
    /// gradients block by block in order (each block's own chunks, then
    /// added to the blocks before it), so they are deterministic but not
    /// summed in the one-block order. The GPU-count paths take one block.
    pub fn scratch_in_blocks(&self, shape: MlpShape, capacity: u32, block: u32) -> Result<MlpScratch> {
        shape.validate()?;
        let ctx = &self.ctx;
        let cap = capacity.max(1);
        let block = block.clamp(1, cap);
        let max = self.gemm_kind.max_binding_floats(self.ctx.caps());
        let widest = self.widest(&shape);
        if block as u64 * widest > max || MAX_CHUNKS as u64 * shape.params() as u64 > max || cap as u64 * SAMPLE as u64 > max {
            bail!(
                "a light field of {} x {} on {capacity} samples in blocks of {block} needs {} floats in one buffer; this device binds at most {max}",
                shape.depth,
                shape.width,
                (block as u64 * widest).max(MAX_CHUNKS as u64 * shape.params() as u64).max(cap as u64 * SAMPLE as u64)
            );
        }
        let (c, blk) = (cap as usize, block as usize);
        let w = shape.width as usize;
        let fused = if self.gemm_kind == Gemm::Fused { Some(Fused::new(ctx, shape, block)?) } else { None };
        let hidden = (0..shape.depth)
            .map(|l| if l + 1 == shape.skip || fused.is_some() { Ok(None) } else { Buffer::uninit(ctx, &format!("mlp.h{l}"), blk * w).map(Some) })
            .collect::<Result<Vec<_>>>()?;
        // dZ of a hidden layer (width wide) or of the head (OUT wide); the
        // fused backward keeps its own.
        let d = if fused.is_some() { Vec::new() } else { (0..2).map(|i| Buffer::uninit(ctx, &format!("mlp.d{i}"), blk * w.max(OUT as usize))).collect::<Result<Vec<_>>>()? };
        Ok(MlpScratch {
            shape,
            capacity: cap,
            block,
            samples: Buffer::uninit(ctx, "mlp.samples", c * SAMPLE as usize)?,
            out: Buffer::uninit(ctx, "mlp.out", c * OUT as usize)?,
            in0: Buffer::uninit(ctx, "mlp.in0", blk * shape.dx() as usize)?,
            cat: Buffer::uninit(ctx, "mlp.cat", blk * shape.cat_width() as usize)?,
            hidden,
            d,
            part: Buffer::uninit(ctx, "mlp.partials", (MAX_CHUNKS * shape.params()) as usize)?,
            grid: Buffer::uninit(ctx, "mlp.grid", 3)?,
            fused,
        })
    }

    fn check(s: &MlpScratch, params: &Buffer<f32>, n: u32) -> Result<()> {
        if n > s.capacity {
            bail!("{n} light-field samples exceed the scratch's {}", s.capacity);
        }
        if params.len() < s.shape.params() as usize {
            bail!("'{}' holds {} values; the light field has {} parameters", params.name(), params.len(), s.shape.params());
        }
        Ok(())
    }

    /// The workgroups for a counted dispatch's items, at most `capacity`
    /// and `per_group` a workgroup, written from the GPU-held `count` into
    /// the scratch's argument slot (glsl/mlp/grid.comp): `[x, groups, z]`,
    /// or with `x` 0 the groups laid out as [`grid`] would. One slot serves
    /// every counted dispatch: each is recorded right after its grid.
    fn record_grid(&self, rec: &mut Recorder, count: &Buffer<u32>, s: &MlpScratch, capacity: u32, per_group: u32, [x, z]: [u32; 2]) -> Result<BufferBinding> {
        let max = self.ctx.caps().max_workgroup_count;
        let max_x = max[0].min(65535);
        // The most rows of workgroups the count can ask for (x = 0: rows of max_x).
        let rows = if x == 0 { capacity.div_ceil(per_group).div_ceil(max_x) } else { capacity.div_ceil(per_group) };
        if rows > max[1] {
            bail!("the light field's {capacity} samples need {rows} rows of workgroups; this device dispatches at most {}", max[1]);
        }
        let push = [capacity, per_group, x, z, max_x];
        rec.dispatch(&self.grid, &[count.binding(), s.grid.binding()], bytemuck::cast_slice(&push), [1, 1, 1])?;
        Ok(s.grid.binding())
    }

    /// One GEMM; `rows` (binding 4) is read only with `p.m_count` or
    /// `p.k_count` set. Counted rows (`p.m_count`) are dispatched for the
    /// count alone ([`Mlp::record_grid`]).
    fn dispatch(&self, rec: &mut Recorder, p: &Product, bufs: [&Buffer<f32>; 4], chunks: u32, rows: Option<&Buffer<u32>>, s: &MlpScratch) -> Result<()> {
        let [a, b, y, c] = bufs.map(|b| b.binding());
        let r = rows.map(|r| r.binding()).unwrap_or_else(|| a.clone());
        let counted = rows.filter(|_| p.m_count != 0);
        let go = |rec: &mut Recorder, kernel: &Kernel, push: &Product, x: u32, per_group: u32| -> Result<()> {
            let bindings = [a.clone(), b.clone(), y.clone(), c.clone(), r.clone()];
            match counted {
                Some(count) => {
                    let args = self.record_grid(rec, count, s, p.m, per_group, [x, chunks])?;
                    rec.dispatch_indirect(kernel, &bindings, bytemuck::bytes_of(push), &args)
                }
                None => rec.dispatch(kernel, &bindings, bytemuck::bytes_of(push), [x, p.m.div_ceil(per_group), chunks]),
            }
        };
        if self.gemm_kind == Gemm::Rows {
            for (j0, cols, k) in row_column_blocks(p.m, p.n) {
                let cfg = ROW_CONFIGS[k];
                // Columns [j0, j0 + cols) as a product of their own: B and C
                // start j0 columns on (the implicit ones column moves with them).
                let q = Product {
                    n: cols,
                    b_off: p.b_off + j0 * p.b_cs,
                    b_ones_j: if p.b_ones_j == NONE { NONE } else { p.b_ones_j.wrapping_sub(j0) },
                    c_off: p.c_off + j0,
                    y_off: p.y_off + j0 * p.y_cs,
                    ..*p
                };
                go(rec, &self.gemm[k], &q, cols.div_ceil(cfg.nb), cfg.wg * cfg.rr)?;
            }
            return Ok(());
        }
        let side = p.m.min(p.n).max(32);
        let k = BLOCKS.iter().rposition(|&rb| 8 * rb <= side).unwrap_or(0);
        let tile = 8 * BLOCKS[k];
        go(rec, &self.gemm[k], p, p.n.div_ceil(tile), tile)
    }

    /// Record Phi on the first `n` samples of `s.samples` into `s.out`.
    pub fn record_forward(&self, rec: &mut Recorder, params: &Buffer<f32>, n: u32, s: &MlpScratch) -> Result<()> {
        self.record_forward_rows(rec, params, n, None, s)
    }

    /// Record Phi on the first `count[0]` samples of `s.samples` (at most
    /// the scratch's capacity), a count a kernel of the same recording
    /// wrote: the host never reads it (the light field rendered inside a
    /// host's command buffer, or a Stage III step in one submission). The
    /// grid covers the capacity; workgroups past the count skip their work,
    /// and the busy ones are spread over the grid (glsl/mlp/gemm.comp).
    pub fn record_forward_counted(&self, rec: &mut Recorder, params: &Buffer<f32>, count: &Buffer<u32>, s: &MlpScratch) -> Result<()> {
        self.record_forward_rows(rec, params, s.capacity, Some(count), s)
    }

    fn record_forward_rows(&self, rec: &mut Recorder, params: &Buffer<f32>, n: u32, rows: Option<&Buffer<u32>>, s: &MlpScratch) -> Result<()> {
        Self::check(s, params, n)?;
        if rows.is_some() && s.block < s.capacity {
            bail!("the light field on a GPU-held count takes its capacity ({}) in one block; this scratch holds {} samples' activations", s.capacity, s.block);
        }
        for b in s.blocks(n) {
            self.record_forward_block(rec, params, b, rows, s)?;
        }
        Ok(())
    }

    /// The forward of samples [b.base, b.base + b.m): their activations in
    /// the scratch's block buffers, their outputs at their place in `s.out`.
    fn record_forward_block(&self, rec: &mut Recorder, params: &Buffer<f32>, b: Block, rows: Option<&Buffer<u32>>, s: &MlpScratch) -> Result<()> {
        let Block { base, m: n } = b;
        let sh = s.shape;
        if let Some(f) = &s.fused {
            let sc = rec.begin_scope("mlp.forward");
            f.record_forward(rec, &sh, s.fused_io(params), b, rows)?;
            rec.end_scope(sc);
            return Ok(());
        }
        let m_count = rows.is_some() as u32;
        let sc = rec.begin_scope("mlp.encode");
        let push = [n, sh.levels_x, sh.levels_w, sh.width, m_count, base];
        let bindings = [s.samples.binding(), s.in0.binding(), s.cat.binding(), rows.map(|r| r.binding()).unwrap_or_else(|| s.samples.binding())];
        match rows {
            Some(count) => {
                let args = self.record_grid(rec, count, s, n, WG, [0, 1])?;
                rec.dispatch_indirect(&self.encode, &bindings, bytemuck::cast_slice(&push), &args)?;
            }
            None => rec.dispatch(&self.encode, &bindings, bytemuck::cast_slice(&push), grid(&self.ctx, n))?,
        }
        rec.end_scope(sc);
        let sc = rec.begin_scope("mlp.forward");
        for l in 0..sh.layers() {
            let (x, k, x_off) = s.input(l);
            let (out, ld, out_off) = s.output(l);
            // C (n x J) = act([X, 1] [W | b]^T).
            let p = Product {
                m: n,
                n: sh.fan_out(l),
                kdim: k + 1,
                k_chunk: k + 1,
                a_off: x_off,
                a_rs: k,
                a_cs: 1,
                a_ones_k: k,
                b_off: sh.offset(l),
                b_rs: 1,
                b_cs: k + 1,
                b_ones_j: NONE,
                c_off: if l == sh.depth { base * OUT } else { out_off },
                c_rs: ld,
                c_act: if l == sh.depth { SIGMOID } else { RELU },
                m_count,
                ..Default::default()
            };
            self.dispatch(rec, &p, [x, params, x, out], 1, rows, s)?;
        }
        rec.end_scope(sc);
        Ok(())
    }

    /// Record the backward of the last [`Mlp::record_forward`] (same `n`,
    /// same parameters): `d_out` (RGB per sample, dL/dPhi) to `grads`
    /// (every parameter, overwritten). The inputs get no gradient (the
    /// reflection geometry is frozen in Stage III).
    pub fn record_backward(&self, rec: &mut Recorder, params: &Buffer<f32>, n: u32, d_out: &Buffer<f32>, grads: &Buffer<f32>, s: &MlpScratch) -> Result<()> {
        self.record_backward_rows(rec, params, Rows { n, count: None }, d_out, grads, s)
    }

    /// The backward of the last [`Mlp::record_forward_counted`], on the
    /// first `count[0]` samples (at most the scratch's capacity), the host
    /// never reading the count: the same products, chunks and summation
    /// order as [`Mlp::record_backward`] with that count, so the gradients
    /// are bit-identical to it.
    pub fn record_backward_counted(&self, rec: &mut Recorder, params: &Buffer<f32>, count: &Buffer<u32>, d_out: &Buffer<f32>, grads: &Buffer<f32>, s: &MlpScratch) -> Result<()> {
        self.record_backward_rows(rec, params, Rows { n: s.capacity, count: Some(count) }, d_out, grads, s)
    }

    fn record_backward_rows(&self, rec: &mut Recorder, params: &Buffer<f32>, r: Rows, d_out: &Buffer<f32>, grads: &Buffer<f32>, s: &MlpScratch) -> Result<()> {
        let Rows { n, count: rows } = r;
        Self::check(s, params, n)?;
        let sh = s.shape;
        if grads.len() < sh.params() as usize {
            bail!("'{}' holds {} values; the light field has {} parameters", grads.name(), grads.len(), sh.params());
        }
        if d_out.len() < (n * OUT) as usize {
            bail!("'{}' holds {} values; {n} samples need {}", d_out.name(), d_out.len(), n * OUT);
        }
        if n == 0 {
            rec.fill(&grads.slice(0, sh.params() as usize), 0)?;
            return Ok(());
        }
        if rows.is_some() && s.block < s.capacity {
            bail!("the light field on a GPU-held count takes its capacity ({}) in one block; this scratch holds {} samples' activations", s.capacity, s.block);
        }
        // Block after block: the activations of every block but the last
        // were overwritten, so each is computed again before its gradients
        // (one block, the usual case: nothing again); its weight gradients
        // are added to those of the blocks before it.
        let blocks = s.blocks(n);
        let again = blocks.len() > 1;
        for (i, b) in blocks.into_iter().enumerate() {
            if again {
                self.record_forward_block(rec, params, b, None, s)?;
            }
            self.record_backward_block(rec, params, Grads { d_out, grads, rows, accumulate: i > 0 }, b, s)?;
        }
        Ok(())
    }

    /// The backward of samples [b.base, b.base + b.m) after their forward:
    /// their weight gradients into `g.grads` (added to it with
    /// `g.accumulate`).
    fn record_backward_block(&self, rec: &mut Recorder, params: &Buffer<f32>, g: Grads, b: Block, s: &MlpScratch) -> Result<()> {
        let Grads { d_out, grads, rows, accumulate } = g;
        let Block { base, m: n } = b;
        let sh = s.shape;
        // Counted: every chunk the capacity could need is dispatched; those
        // past the count's skip their work.
        let (chunk, chunks) = if rows.is_some() { (0, MAX_CHUNKS) } else { weight_chunks(n) };
        let counted = rows.is_some() as u32;
        let sc = rec.begin_scope("mlp.backward");
        if let Some(f) = &s.fused {
            // Every layer's dZ in one dispatch; the weight gradients below.
            f.record_backward(rec, &sh, s.fused_io(params), d_out, b, rows)?;
        } else {
            // The head's dZ = dY * sigmoid'(Z), from the caller's output
            // gradient at the block's place into the ping-pong buffer the
            // head reads (3 wide); the hidden layers' dZ is written by the
            // input-gradient product of the layer above, the ReLU's
            // derivative taken in its epilogue. Both products of a layer
            // read dZ as it is.
            let push = [n, base * OUT, counted];
            let r = rows.map(|r| r.binding()).unwrap_or_else(|| d_out.binding());
            let (z, _) = s.dz(sh.depth);
            rec.dispatch(&self.head_grad, &[d_out.binding(), s.out.binding(), z.binding(), r], bytemuck::cast_slice(&push), grid(&self.ctx, n * OUT))?;
        }
        for l in (0..sh.layers()).rev() {
            let (x, k, x_off) = s.input(l);
            // This layer's dZ (row stride OUT for the head, width else).
            let ((dz, dz_off), d_ld) = (s.dz(l), sh.fan_out(l));
            let j = sh.fan_out(l);
            // [dW | db] (J x (K + 1)) = dZ^T [X, 1], per chunk of samples.
            let pw = Product {
                m: j,
                n: k + 1,
                kdim: n,
                k_chunk: chunk,
                a_off: dz_off,
                a_rs: 1,
                a_cs: d_ld,
                a_ones_k: NONE,
                b_off: x_off,
                b_rs: k,
                b_cs: 1,
                b_ones_j: k,
                c_off: sh.offset(l),
                c_rs: k + 1,
                c_zstride: sh.params(),
                k_count: counted,
                ..Default::default()
            };
            self.dispatch(rec, &pw, [dz, x, dz, &s.part], chunks, rows, s)?;
            if l > 0 && s.fused.is_none() {
                // dZ_{l-1} (n x width) = (dZ W[:, :width]) * ReLU'(Y_{l-1})
                // (the skip layer's encoded columns need no gradient).
                let (y, y_ld, y_off) = s.output(l - 1);
                let (dz_below, dz_below_off) = s.dz(l - 1);
                let pd = Product {
                    m: n,
                    n: sh.width,
                    kdim: j,
                    k_chunk: j,
                    a_rs: d_ld,
                    a_cs: 1,
                    a_ones_k: NONE,
                    b_off: sh.offset(l),
                    b_rs: k + 1,
                    b_cs: 1,
                    b_ones_j: NONE,
                    y_off,
                    y_rs: y_ld,
                    y_cs: 1,
                    c_off: dz_below_off,
                    c_rs: sh.width,
                    c_act: RELU_DERIV,
                    m_count: counted,
                    ..Default::default()
                };
                self.dispatch(rec, &pd, [dz, params, y, dz_below], 1, rows, s)?;
            }
        }
        rec.end_scope(sc);
        let sc = rec.begin_scope("mlp.reduce");
        let push = [sh.params(), chunks, sh.params(), if rows.is_some() { n } else { 0 }, accumulate as u32];
        let count = rows.map(|r| r.binding()).unwrap_or_else(|| grads.binding());
        rec.dispatch(&self.reduce, &[s.part.binding(), grads.binding(), count], bytemuck::cast_slice(&push), grid(&self.ctx, sh.params()))?;
        rec.end_scope(sc);
        Ok(())
    }
}
