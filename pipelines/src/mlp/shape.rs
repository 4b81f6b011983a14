//! The light field's network shape and its flat parameter layout.

use anyhow::{bail, Result};

/// A NeRF-style MLP (method-notes §3.5): `depth` ReLU layers of `width` on
/// gamma(x); the layer with index `skip` takes [h, gamma(x), gamma(w)]; a
/// sigmoid head to RGB. gamma has `levels_x` / `levels_w` octaves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MlpShape {
    pub depth: u32,
    pub width: u32,
    pub skip: u32,
    pub levels_x: u32,
    pub levels_w: u32,
}

/// RGB out.
pub const OUT: u32 = 3;
/// Floats per sample of the input: normalized position, unit direction.
pub const SAMPLE: u32 = 6;

impl MlpShape {
    /// The paper's network: 8 x 256, skip at layer 5 (index 4), L = 12.
    pub const PAPER: MlpShape = MlpShape { depth: 8, width: 256, skip: 4, levels_x: 12, levels_w: 12 };

    /// The cheaper network of the accuracy/time table: 4 x 64, skip at
    /// layer 3, L = 8 for x and 4 for w (about 1/30 of the paper's work).
    pub const SMALL: MlpShape = MlpShape { depth: 4, width: 64, skip: 2, levels_x: 8, levels_w: 4 };

    /// A preset by name: "paper" or "small".
    pub fn preset(name: &str) -> Result<MlpShape> {
        match name {
            "paper" => Ok(MlpShape::PAPER),
            "small" => Ok(MlpShape::SMALL),
            _ => bail!("unknown light-field preset '{name}' (paper, small)"),
        }
    }

    pub fn validate(&self) -> Result<()> {
        if self.depth < 2 || self.depth > 16 {
            bail!("light field depth {} is outside 2..=16", self.depth);
        }
        if self.skip == 0 || self.skip >= self.depth {
            bail!("light field skip layer {} must be in 1..{} (the depth)", self.skip, self.depth);
        }
        if self.width == 0 || self.width > 1024 {
            bail!("light field width {} is outside 1..=1024", self.width);
        }
        // sin(2^k pi a) in f32 needs 2^k a to keep fraction bits.
        if self.levels_x > 16 || self.levels_w > 16 {
            bail!("Fourier levels ({}, {}) exceed 16", self.levels_x, self.levels_w);
        }
        Ok(())
    }

    /// Width of gamma(x).
    pub fn dx(&self) -> u32 {
        3 + 6 * self.levels_x
    }
    /// Width of gamma(w).
    pub fn dw(&self) -> u32 {
        3 + 6 * self.levels_w
    }
    /// Width of the skip layer's input [h, gamma(x), gamma(w)].
    pub fn cat_width(&self) -> u32 {
        self.width + self.dx() + self.dw()
    }
    /// Layers including the head (index `depth`).
    pub fn layers(&self) -> u32 {
        self.depth + 1
    }
    /// Inputs of layer `l` (without the bias column).
    pub fn fan_in(&self, l: u32) -> u32 {
        match l {
            0 => self.dx(),
            l if l == self.skip => self.cat_width(),
            _ => self.width,
        }
    }
    /// Outputs of layer `l`.
    pub fn fan_out(&self, l: u32) -> u32 {
        if l == self.depth {
            OUT
        } else {
            self.width
        }
    }
    /// Start of layer `l`'s augmented weights [W | b] (fan_out rows of
    /// fan_in + 1, row-major: the PyTorch layout with the bias as a last
    /// column) in the flat parameter vector.
    pub fn offset(&self, l: u32) -> u32 {
        (0..l).map(|k| self.fan_out(k) * (self.fan_in(k) + 1)).sum()
    }
    /// Parameters in all.
    pub fn params(&self) -> u32 {
        self.offset(self.layers())
    }
    /// Multiply-adds per sample, forward.
    pub fn macs(&self) -> u64 {
        (0..self.layers()).map(|l| self.fan_out(l) as u64 * (self.fan_in(l) + 1) as u64).sum()
    }

    /// PyTorch's default initialisation of nn.Linear (Kaiming-uniform with
    /// a = sqrt(5): weights and biases U(-1/sqrt(fan_in), 1/sqrt(fan_in))),
    /// from a SplitMix64 stream seeded with `seed`.
    pub fn init_params(&self, seed: u64) -> Vec<f32> {
        let mut rng = crate::Rng(seed);
        let mut next = || (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        let mut out = Vec::with_capacity(self.params() as usize);
        for l in 0..self.layers() {
            let bound = 1.0 / (self.fan_in(l) as f64).sqrt();
            for _ in 0..self.fan_out(l) * (self.fan_in(l) + 1) {
                out.push(((2.0 * next() - 1.0) * bound) as f32);
            }
        }
        out
    }
}
