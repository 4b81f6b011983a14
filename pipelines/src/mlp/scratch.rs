//! The light field's activations and gradients for a number of samples
//! (what [`Mlp::scratch`](super::Mlp::scratch) allocates), and where each
//! layer's input, output and dZ lie in them.

use super::fused::{Fused, FusedIo};
use super::{MlpShape, OUT};
use tgs_engine::Buffer;

/// Samples [base, base + m) of a forward or backward taken as one block.
#[derive(Clone, Copy)]
pub(super) struct Block {
    pub(super) base: u32,
    pub(super) m: u32,
}

/// Activations and gradients of up to `capacity` samples.
pub struct MlpScratch {
    pub(super) shape: MlpShape,
    pub(super) capacity: u32,
    /// Rows of the activation buffers: the samples are taken in blocks of
    /// this many when the capacity's activations exceed one binding
    /// ([`Mlp::scratch_in_blocks`](super::Mlp::scratch_in_blocks)); the capacity otherwise.
    pub(super) block: u32,
    /// Inputs, [`SAMPLE`](super::SAMPLE) floats per sample (normalized x, unit w); the caller writes them.
    pub samples: Buffer<f32>,
    /// Outputs, RGB per sample, after [`Mlp::record_forward`](super::Mlp::record_forward).
    pub out: Buffer<f32>,
    pub(super) in0: Buffer<f32>,
    pub(super) cat: Buffer<f32>,
    /// Hidden outputs by layer; the layer before the skip writes into `cat`.
    pub(super) hidden: Vec<Option<Buffer<f32>>>,
    /// dZ of the layer-by-layer backward, two buffers it alternates
    /// between (none with the fused kernels, which keep every layer's).
    pub(super) d: Vec<Buffer<f32>>,
    pub(super) part: Buffer<f32>,
    /// The indirect arguments of the counted dispatches ([`Mlp::record_grid`](super::Mlp)).
    pub(super) grid: Buffer<u32>,
    /// The fused kernels of this shape and their activations
    /// ([`Gemm::Fused`](super::Gemm::Fused); the hidden layers' outputs and dZ are theirs then).
    pub(super) fused: Option<Fused>,
}

impl MlpScratch {
    pub fn capacity(&self) -> u32 {
        self.capacity
    }
    /// The first `n` samples cut into blocks (one, [0, n), unless `n`
    /// exceeds the block; none for `n` = 0).
    pub(super) fn blocks(&self, n: u32) -> Vec<Block> {
        (0..n.div_ceil(self.block)).map(|k| Block { base: k * self.block, m: (n - k * self.block).min(self.block) }).collect()
    }
    /// Samples one pass of the kernels takes: the capacity, or the block
    /// it is cut into ([`Mlp::scratch_in_blocks`](super::Mlp::scratch_in_blocks)). The GPU-count paths
    /// need the capacity within one block.
    pub fn block(&self) -> u32 {
        self.block
    }
    pub fn shape(&self) -> MlpShape {
        self.shape
    }
    /// Bytes of device memory held.
    pub fn bytes(&self) -> u64 {
        let mut b = self.samples.bytes() + self.out.bytes() + self.in0.bytes() + self.cat.bytes() + self.part.bytes() + self.grid.bytes();
        b += self.hidden.iter().flatten().map(|h| h.bytes()).sum::<u64>();
        b += self.fused.as_ref().map_or(0, |f| f.bytes());
        b + self.d.iter().map(|d| d.bytes()).sum::<u64>()
    }
    /// The workgroups (x, y, z) the last counted dispatch ran: those its
    /// GPU-held count needed, not the capacity's (tests).
    pub fn last_counted_grid(&self) -> anyhow::Result<[u32; 3]> {
        let g = self.grid.download()?;
        Ok([g[0], g[1], g[2]])
    }
    /// gamma(x) per sample (row stride `dx`), after a forward.
    pub fn first_input(&self) -> &Buffer<f32> {
        &self.in0
    }
    /// The skip layer's input [h, gamma(x), gamma(w)] per sample (row
    /// stride `cat_width`), after a forward.
    pub fn skip_input(&self) -> &Buffer<f32> {
        &self.cat
    }
    /// Layer `l`'s input: buffer, row stride and first float.
    pub(super) fn input(&self, l: u32) -> (&Buffer<f32>, u32, u32) {
        let s = &self.shape;
        match l {
            0 => (&self.in0, s.dx(), 0),
            l if l == s.skip => (&self.cat, s.cat_width(), 0),
            _ => self.hidden_output(l - 1),
        }
    }
    /// Layer `l`'s output: buffer, row stride and first float.
    pub(super) fn output(&self, l: u32) -> (&Buffer<f32>, u32, u32) {
        let s = &self.shape;
        if l == s.depth {
            (&self.out, OUT, 0)
        } else if l + 1 == s.skip {
            (&self.cat, s.cat_width(), 0)
        } else {
            self.hidden_output(l)
        }
    }
    /// Hidden layer `l`'s own output buffer (not the skip layer's input).
    pub(super) fn hidden_output(&self, l: u32) -> (&Buffer<f32>, u32, u32) {
        match &self.fused {
            Some(f) => (&f.stack, self.shape.width, l * f.layer_stride),
            None => (self.hidden[l as usize].as_ref().expect("hidden layer buffer"), self.shape.width, 0),
        }
    }
    /// Layer `l`'s dZ in a backward: buffer and first float (row stride
    /// its fan-out). The layer-by-layer kernels alternate two buffers; the
    /// fused backward keeps every layer's.
    pub(super) fn dz(&self, l: u32) -> (&Buffer<f32>, u32) {
        match &self.fused {
            Some(f) => (&f.dz, l * f.layer_stride),
            None => (&self.d[(l % 2) as usize], 0),
        }
    }
    pub(super) fn fused_io<'a>(&'a self, params: &'a Buffer<f32>) -> FusedIo<'a> {
        FusedIo { samples: &self.samples, params, in0: &self.in0, cat: &self.cat, out: &self.out }
    }
}
