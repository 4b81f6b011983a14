//! Display packing for a window: a frame's colour planes to 8-bit pixels in
//! the swapchain's byte order, quantised exactly as tgs writes PNGs (and
//! enlarged from a smaller frame while the camera moves).

use crate::shaders;
use crate::WG;
use anyhow::{bail, Result};
use std::sync::Arc;
use tgs_engine::{groups_2d, BufferBinding, Context, Kernel, KernelDesc, Recorder};

/// Byte order of a packed pixel (the swapchain image's format).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelOrder {
    Rgba,
    Bgra,
}

/// Packs R, G, B planes of f32 into one u32 per pixel.
pub struct Pack {
    ctx: Arc<Context>,
    kernel: Kernel,
}

impl Pack {
    pub fn new(ctx: &Arc<Context>) -> Result<Pack> {
        let spec = [(0, WG), (1, ctx.caps().min_subgroup_size.max(1)), (2, 1)];
        let kernel = Kernel::new(ctx, &KernelDesc { name: "view.pack", spirv: shaders::VIEW_PACK, spec: &spec, push_bytes: 24, subgroup_size: None, full_subgroups: false })?;
        Ok(Pack { ctx: ctx.clone(), kernel })
    }

    /// `packed[i]` = pixel `i` of the 3 planes of `pixels` floats each in `planes`.
    pub fn record(&self, rec: &mut Recorder, planes: &BufferBinding, pixels: u32, order: PixelOrder, packed: &BufferBinding) -> Result<()> {
        self.record_scaled(rec, planes, (pixels, 1), 1, order, packed)
    }

    /// `packed` (`size` = width x height pixels) from planes `scale` times
    /// smaller on each side (ceil(width / scale) x ceil(height / scale)):
    /// pixel (x, y) shows planes pixel (x / scale, y / scale). Scale 1 is
    /// [`Pack::record`].
    pub fn record_scaled(&self, rec: &mut Recorder, planes: &BufferBinding, size: (u32, u32), scale: u32, order: PixelOrder, packed: &BufferBinding) -> Result<()> {
        let (w, h) = size;
        let pixels = w * h;
        let scale = scale.max(1);
        let (sw, sh) = (w.div_ceil(scale), h.div_ceil(scale));
        let source = sw * sh;
        if planes.range < 12 * source as u64 || packed.range < 4 * pixels as u64 {
            bail!("packing {pixels} pixels from {} bytes of planes ({source} pixels) into {} bytes", planes.range, packed.range);
        }
        let push = [pixels, (order == PixelOrder::Bgra) as u32, w, scale, sw, source];
        let groups = groups_2d(pixels.div_ceil(WG), self.ctx.caps().max_workgroup_count[0].min(65535));
        rec.dispatch(&self.kernel, &[planes.clone(), packed.clone()], bytemuck::cast_slice(&push), groups)
    }
}

/// The host's twin of the kernel: `tgs_dataset`'s PNG quantisation, packed.
pub fn pack_pixel(rgb: [f32; 3], order: PixelOrder) -> u32 {
    let q = |v: f32| (if v.is_finite() { v } else { 0.0 }.clamp(0.0, 1.0) * 255.0).round() as u32;
    let [r, g, b] = rgb.map(q);
    match order {
        PixelOrder::Rgba => r | g << 8 | b << 16 | 255 << 24,
        PixelOrder::Bgra => b | g << 8 | r << 16 | 255 << 24,
    }
}
