//! The differentiable 2DGS rasterizer (method-notes §1.3–1.7): projection,
//! tile binning (depth sort, per-Gaussian emission, stable tile sort, tile
//! ranges), the per-pixel forward, and an atomic-free backward (one gradient
//! slot per intersection, then a fixed-order per-Gaussian reduction fused
//! with the projection backward).
//!
//! Counts stay on the GPU within a view (indirect dispatch); capacities are
//! checked afterwards by [`Rasterizer::fit`].

mod backward;
mod binning;
mod camera;
mod forward;
mod frame;
mod gaussians;
mod kept_weights;
mod reduce_adam;
mod slices;
mod tiles;

pub use camera::Camera;
pub use frame::{Frame, Plane};
pub use gaussians::{array_widths, Gaussians, HostGaussians, Splats, GAUSSIAN_ARRAYS};
pub use kept_weights::KeptWeights;
pub use reduce_adam::{Moments, ReduceAdam};
use tiles::{TileKernels, TileSpec, SMALL_TILE, WIDE_TILE};

use crate::scan::{PrefixSum, ScanScratch};
use crate::shaders;
use crate::sort::{RadixSort, SortScratch};
use anyhow::{bail, Result};
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;
use tgs_engine::{groups_2d, Buffer, BufferBinding, Context, Kernel, KernelDesc, Readback};

/// How per-Gaussian features become the rasterized channels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Features {
    /// Spherical harmonics up to `degree` (0..=3) per channel, evaluated for
    /// the view direction, + 0.5, clamped at 0 (colour).
    Sh { degree: u32 },
    /// One plain value per channel (reflectivity, F0, ...), used as is.
    Plain,
}

impl Features {
    pub fn coeffs(self) -> u32 {
        match self {
            Features::Sh { degree } => (degree + 1) * (degree + 1),
            Features::Plain => 1,
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable, Default)]
struct Push {
    n: u32,
    width: u32,
    height: u32,
    tiles_x: u32,
    tiles_y: u32,
    coeffs: u32,
    degree: u32,
    mode: u32,
    capacity: u32,
    span: u32,
    span_index: u32,
    spans: u32,
    /// The Gaussians whose features the bindings hold ([`Rasterizer::feature_slices`]).
    feat_base: u32,
    feat_end: u32,
}

use crate::WG;
/// Dispatches one [`Rasterizer::record_fit_gate`] can gate.
pub const GATE_SLOTS: usize = 8;
/// The gate's push constants: capacity, count, two pads, then x, y, z per
/// slot (`glsl/raster/gate.comp`, whose array holds 3 x GATE_SLOTS).
const GATE_PUSH_WORDS: usize = 4 + 3 * GATE_SLOTS;
/// Floats per Gaussian in a frame's projection buffer (`PROJ_STRIDE` in
/// glsl/raster/common.glsl: the splat, its depth and its pixel box).
const PROJ_STRIDE: usize = 20;
/// Loop iterations per invocation we allow on devices with a loop limiter
/// (lavapipe stops loops after 65,535).
const LOOP_BUDGET: f64 = 50_000.0;
/// Default spans are a multiple of this many splats.
const SPAN_STEP: u32 = 32;
/// Most feature channels a rasterizer takes.
pub const MAX_CHANNELS: u32 = 32;

/// How the per-tile forward and backward kernels map pixels to invocations.
/// Both variants compute the same math and fill the same slots; the
/// backward's per-splat sums are added in a different (fixed) order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RasterKernels {
    /// 256 invocations per tile, one pixel each (GPUs). The forward stages
    /// splats in shared memory; the backward's per-subgroup sums go through
    /// shared memory and are added in subgroup order after a barrier.
    Workgroup,
    /// One subgroup per tile, 256 / subgroup-size pixels per invocation held
    /// in registers (CPU drivers, where a workgroup's subgroups run as
    /// coroutines on one thread and barriers and shared-memory traffic cost
    /// ~3/4 of the Workgroup backward): splats are read directly, a splat's
    /// gradient record is summed in registers, then one subgroupAdd, and
    /// written to its slot; no shared memory, no barriers.
    Subgroup,
}

impl RasterKernels {
    /// `TGS_RASTER_KERNELS=workgroup|subgroup` if set (for measuring one
    /// against the other), else Subgroup on CPU drivers and Workgroup elsewhere.
    pub fn for_device(caps: &tgs_engine::Capabilities) -> RasterKernels {
        match std::env::var("TGS_RASTER_KERNELS").as_deref() {
            Ok("workgroup") => RasterKernels::Workgroup,
            Ok("subgroup") => RasterKernels::Subgroup,
            _ if caps.is_cpu() => RasterKernels::Subgroup,
            _ => RasterKernels::Workgroup,
        }
    }
}

/// How the tile backward and the reduce reach the per-intersection gradient
/// records (15 + C floats per intersection, the largest per-intersection
/// array by far).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RecordAccess {
    /// A storage binding: at most `maxStorageBufferRange` bytes (128 MiB on
    /// lavapipe: 1.86M intersections of 3 channels).
    Binding,
    /// Through the buffer's device address (kept in a small bound buffer):
    /// as many as one allocation holds. Needs `bufferDeviceAddress`.
    Address,
}

impl RecordAccess {
    /// `TGS_RASTER_RECORDS=binding|address` if set (address only where
    /// possible), else Address where the binding range is the tighter limit
    /// (lavapipe: 128 MiB against 2 GiB allocations) and the device has
    /// buffer device addresses; Binding otherwise (most GPUs bind 4 GiB).
    /// On lavapipe the two backwards time the same within noise.
    pub fn for_device(caps: &tgs_engine::Capabilities) -> RecordAccess {
        let address = caps.buffer_device_address;
        match std::env::var("TGS_RASTER_RECORDS").as_deref() {
            Ok("binding") => RecordAccess::Binding,
            Ok("address") if address => RecordAccess::Address,
            _ if address && caps.max_storage_buffer_range < caps.max_memory_allocation => RecordAccess::Address,
            _ => RecordAccess::Binding,
        }
    }
}

/// A frame's per-intersection arrays: keys, values, Gaussian ids, tile-sort
/// scratch, gradient records, and (with [`RecordAccess::Address`]) the
/// buffer holding the records' device address.
type IntersectionBuffers = (Buffer<u32>, Buffer<u32>, Buffer<u32>, SortScratch, Buffer<f32>, Option<Buffer<u32>>);

pub struct Rasterizer {
    ctx: Arc<Context>,
    channels: u32,
    features: Features,
    batch: u32,
    kernels: RasterKernels,
    records: RecordAccess,
    sort: RadixSort,
    scan: PrefixSum,
    gather: Kernel,
    plan: Kernel,
    gate: Kernel,
    ranges: Kernel,
    reduce: Kernel,
    /// The reduce with Adam fused (`reduce_adam.rs`), and its feature-only
    /// variant, each built on first use.
    reduce_adam: [std::sync::OnceLock<Kernel>; 4],
    /// What the tile-size dependent kernels are built for, and those
    /// kernels for 16 x 16 and 8 x 8 tiles, each built on first use
    /// (`tiles.rs`).
    tile_spec: TileSpec,
    tile_sets: [std::sync::OnceLock<TileKernels>; 2],
    /// The kept-weights kernels per tile size (`kept_weights.rs`), likewise.
    kept_kernels: [std::sync::OnceLock<kept_weights::KeptKernels>; 2],
    /// Gaussians per feature slice, forced ([`Rasterizer::feature_slice`]).
    feature_slice: Option<u32>,
}

impl Rasterizer {
    /// A rasterizer for `channels` feature channels.
    pub fn new(ctx: &Arc<Context>, channels: u32, features: Features) -> Result<Rasterizer> {
        Self::with_span(ctx, channels, features, None)
    }

    /// As [`Rasterizer::new`], with the splats-per-span length forced (a
    /// multiple of 32; tests use it to exercise multi-span tiles cheaply).
    /// On a device with a loop limiter it must not exceed the default span.
    pub fn with_span(ctx: &Arc<Context>, channels: u32, features: Features, span: Option<u32>) -> Result<Rasterizer> {
        Self::with_options(ctx, channels, features, span, RasterKernels::for_device(ctx.caps()))
    }

    /// As [`Rasterizer::with_span`], with the backward kernel chosen (tests
    /// run both on one device).
    pub fn with_options(ctx: &Arc<Context>, channels: u32, features: Features, span: Option<u32>, kernels: RasterKernels) -> Result<Rasterizer> {
        Self::with_records(ctx, channels, features, span, kernels, RecordAccess::for_device(ctx.caps()))
    }

    /// As [`Rasterizer::with_options`], with the access to the gradient
    /// records chosen (tests run both on one device).
    pub fn with_records(ctx: &Arc<Context>, channels: u32, features: Features, span: Option<u32>, kernels: RasterKernels, records: RecordAccess) -> Result<Rasterizer> {
        if records == RecordAccess::Address && !ctx.caps().buffer_device_address {
            bail!("gradient records by device address need bufferDeviceAddress, which {} does not have enabled", ctx.caps().device_name);
        }
        if channels == 0 || channels > MAX_CHANNELS {
            bail!("rasterizer channels must be 1..={MAX_CHANNELS}, not {channels}");
        }
        if let Features::Sh { degree } = features {
            if degree > 3 {
                bail!("SH degree must be 0..=3, not {degree}");
            }
        }
        let caps = ctx.caps();
        let min_sg = caps.min_subgroup_size.max(1);
        let max_sg_count = WG / min_sg;
        let krec = 15 + channels;
        let budget = caps.max_shared_memory.min(28 * 1024);
        let mut batch = 32u32;
        while batch > 1 && max_sg_count * batch * krec * 4 > budget {
            batch /= 2;
        }
        if max_sg_count * batch * krec * 4 > caps.max_shared_memory {
            bail!("{channels} channels need {} bytes of shared memory in the backward; the device has {}", max_sg_count * krec * 4, caps.max_shared_memory);
        }
        // The Subgroup backward's workgroup is exactly one subgroup.
        let sg = caps.subgroup_size;
        if kernels == RasterKernels::Subgroup && (caps.min_subgroup_size != caps.max_subgroup_size || sg == 0 || !WG.is_multiple_of(sg)) {
            bail!("the one-subgroup backward needs a fixed subgroup size dividing {WG}; {} has {}..={}", caps.device_name, caps.min_subgroup_size, caps.max_subgroup_size);
        }
        if let Some(s) = span {
            if s == 0 || s % SPAN_STEP != 0 {
                bail!("span must be a positive multiple of {SPAN_STEP}, not {s}");
            }
        }
        let spec = [(0, WG), (1, min_sg), (4, channels), (5, batch)];
        let k = |name, spirv, push_bytes, full| Kernel::new(ctx, &KernelDesc { name, spirv, spec: &spec, push_bytes, subgroup_size: None, full_subgroups: full });
        let push = std::mem::size_of::<Push>() as u32;
        let by_address = records == RecordAccess::Address;
        let reduce = if by_address { shaders::RASTER_REDUCE_RECORDS_BDA } else { shaders::RASTER_REDUCE };
        Ok(Rasterizer {
            ctx: ctx.clone(),
            channels,
            features,
            batch,
            kernels,
            records,
            sort: RadixSort::new(ctx)?,
            scan: PrefixSum::new(ctx)?,
            gather: k("raster.gather", shaders::RASTER_GATHER, 4, false)?,
            plan: Kernel::new(ctx, &KernelDesc { name: "raster.plan", spirv: shaders::RASTER_PLAN, spec: &[], push_bytes: 16, subgroup_size: None, full_subgroups: false })?,
            gate: Kernel::new(
                ctx,
                &KernelDesc { name: "raster.gate", spirv: shaders::RASTER_GATE, spec: &[], push_bytes: 4 * GATE_PUSH_WORDS as u32, subgroup_size: None, full_subgroups: false },
            )?,
            ranges: k("raster.ranges", shaders::RASTER_RANGES, 0, false)?,
            reduce: k("raster.reduce", reduce, push, false)?,
            reduce_adam: std::array::from_fn(|_| std::sync::OnceLock::new()),
            tile_spec: TileSpec { kernels, records, channels, batch, span, small: TileSpec::small_tiles_allowed()? },
            tile_sets: [std::sync::OnceLock::new(), std::sync::OnceLock::new()],
            kept_kernels: [std::sync::OnceLock::new(), std::sync::OnceLock::new()],
            feature_slice: None,
        })
    }

    pub fn channels(&self) -> u32 {
        self.channels
    }
    pub fn features(&self) -> Features {
        self.features
    }
    /// Which tile kernels this rasterizer records.
    pub fn kernels(&self) -> RasterKernels {
        self.kernels
    }
    /// How the backward reaches the gradient records.
    pub fn records(&self) -> RecordAccess {
        self.records
    }

    /// Splats per span (longer tiles take several passes), tiles as [`Rasterizer::tile`].
    pub fn span(&self) -> u32 {
        self.span_of(self.tile())
    }
    /// Splats per span with `tile` x `tile` tiles.
    pub(crate) fn span_of(&self, tile: u32) -> u32 {
        self.tile_spec.span(self.ctx.caps(), tile)
    }
    /// The tile side of the frames this rasterizer makes where the loop
    /// budget allows (16; 8 with the Subgroup kernels unless
    /// `TGS_RASTER_TILE=16`; `tiles.rs`).
    pub fn tile(&self) -> u32 {
        self.tile_spec.tile_for(1, 1, |_| true)
    }
    /// This rasterizer with the Subgroup kernels' 8 x 8 tiles allowed or
    /// not (the default allows them unless `TGS_RASTER_TILE=16`); tests
    /// compare both sizes in one process.
    pub fn small_tiles(mut self, allowed: bool) -> Rasterizer {
        self.tile_spec.small = allowed;
        self
    }
    /// The tile-size dependent kernels for `tile` x `tile` tiles.
    fn tile_kernels(&self, tile: u32) -> Result<&TileKernels> {
        if !(tile == WIDE_TILE || tile == SMALL_TILE && self.kernels == RasterKernels::Subgroup) {
            bail!("a frame of {tile} x {tile} tiles does not suit this rasterizer's {:?} kernels (make the frame with this rasterizer)", self.kernels);
        }
        let slot = &self.tile_sets[(tile == SMALL_TILE) as usize];
        if let Some(k) = slot.get() {
            return Ok(k);
        }
        let k = self.tile_spec.build(&self.ctx, tile)?;
        Ok(slot.get_or_init(|| k))
    }
    /// Splats per shared-memory reduction round in the backward.
    pub fn batch(&self) -> u32 {
        self.batch
    }
    /// Floats per intersection gradient record.
    pub fn record_len(&self) -> u32 {
        15 + self.channels
    }

    /// Device bytes a frame holds per intersection of capacity: key, value,
    /// Gaussian id, the tile sort's two ping-pong arrays, and the gradient
    /// record (the sort's histograms are per workgroup, not counted).
    pub fn bytes_per_intersection(&self) -> u64 {
        4 * (5 + self.record_len() as u64)
    }

    /// Largest intersection count a frame can hold on this device.
    pub fn max_capacity(&self) -> u32 {
        let caps = self.ctx.caps();
        let record_bytes = 4 * self.record_len() as u64;
        let by_grads = match self.records {
            RecordAccess::Binding => caps.max_storage_buffer_range / record_bytes,
            // Record floats are indexed with 32-bit integers.
            RecordAccess::Address => (caps.max_memory_allocation / record_bytes).min(u32::MAX as u64 / self.record_len() as u64),
        };
        by_grads.min(self.sort.max_keys()).min(u32::MAX as u64 / 2) as u32
    }

    /// The intersection capacity a new frame for `max_gaussians` starts
    /// with: two per Gaussian, within the device's limit ([`Rasterizer::fit`]
    /// grows it when a view needs more).
    pub fn initial_capacity(&self, max_gaussians: u32) -> u32 {
        (2 * max_gaussians).min(self.max_capacity())
    }

    /// Working memory for `width` x `height` views of up to `max_gaussians`
    /// Gaussians and `capacity` intersections (grown by [`Rasterizer::fit`]).
    pub fn frame(&self, width: u32, height: u32, max_gaussians: u32, capacity: u32) -> Result<Frame> {
        let ctx = &self.ctx;
        if width == 0 || height == 0 {
            bail!("image size {width}x{height} is empty");
        }
        let cpu = ctx.caps().is_cpu();
        let fits = |tiles: u64| !cpu || tiles * (3 + self.channels as u64) <= LOOP_BUDGET as u64;
        let tile = self.tile_spec.tile_for(width, height, fits);
        let tiles_x = width.div_ceil(tile);
        let tiles_y = height.div_ceil(tile);
        let tiles = tiles_x as u64 * tiles_y as u64;
        if !fits(tiles) {
            bail!(
                "image {width}x{height} has {tiles} tiles; on a CPU driver (loop limit 65,535 per invocation) at most {} tiles fit with {} channels",
                LOOP_BUDGET as u64 / (3 + self.channels as u64),
                self.channels
            );
        }
        let capacity = capacity.max(1);
        if capacity > self.max_capacity() {
            bail!("intersection capacity {capacity} exceeds this device's maximum of {}", self.max_capacity());
        }
        let n = max_gaussians.max(1) as usize;
        let pixels = (width * height) as usize;
        let planes = Plane::count(self.channels) as usize;
        let buf = |name: &str, len: usize| Buffer::<u32>::new(ctx, name, len);
        let (isect_keys, isect_vals, isect_gid, tile_scratch, isect_grads, records_address) = self.intersection_buffers(capacity)?;
        let fbuf = |name: &str, len: usize| Buffer::<f32>::new(ctx, name, len);
        Ok(Frame {
            width,
            height,
            tile,
            tiles_x,
            tiles_y,
            max_gaussians,
            capacity,
            spans: 1,
            last_intersections: 0,
            cam: fbuf("raster.cam", 20 + MAX_CHANNELS as usize)?,
            proj: fbuf("raster.proj", PROJ_STRIDE * n)?,
            pfeat: fbuf("raster.pfeat", self.channels as usize * n)?,
            rects: buf("raster.rects", 4 * n)?,
            tiles: buf("raster.tiles", n)?,
            tile_masks: buf("raster.tile_masks", 4 * n)?,
            depth_keys: buf("raster.depth_keys", n)?,
            depth_ids: buf("raster.depth_ids", n)?,
            depth_scratch: self.sort.scratch(n as u32)?,
            offsets: buf("raster.offsets", n + 1)?,
            scan_scratch: ScanScratch::new(ctx, n as u32 + 1)?,
            params: buf("raster.params", 4)?,
            args: buf("raster.args", 4)?,
            stats: buf("raster.stats", 2)?,
            stats_host: Readback::new(ctx, "raster.stats_host", 2)?,
            gate: buf("raster.gate", 3 * GATE_SLOTS)?,
            isect_keys,
            isect_vals,
            isect_gid,
            tile_scratch,
            ranges: buf("raster.ranges", 2 * tiles as usize)?,
            out: fbuf("raster.out", planes * pixels)?,
            grad_out: fbuf("raster.grad_out", planes * pixels)?,
            fstate: fbuf("raster.fstate", 3 * pixels)?,
            ustate: buf("raster.ustate", 3 * pixels)?,
            bstate: fbuf("raster.bstate", 2 * pixels)?,
            isect_grads,
            records_address,
            densify: fbuf("raster.densify", 2 * n)?,
            radii: fbuf("raster.radii", n)?,
        })
    }

    fn push(&self, g: &Gaussians, frame: &Frame, degree: u32) -> Push {
        Push {
            n: g.n,
            width: frame.width,
            height: frame.height,
            tiles_x: frame.tiles_x,
            tiles_y: frame.tiles_y,
            coeffs: g.coeffs,
            degree,
            mode: matches!(self.features, Features::Plain) as u32,
            capacity: frame.capacity,
            span: self.span_of(frame.tile),
            span_index: 0,
            spans: frame.spans,
            feat_base: 0,
            feat_end: u32::MAX,
        }
    }

    fn check_inputs(&self, g: &Gaussians, features: &Buffer<f32>, frame: &Frame) -> Result<()> {
        let own = std::ptr::eq(features, &g.features);
        let (channels, coeffs) = if own { (g.channels, g.coeffs) } else { (self.channels, self.features.coeffs()) };
        if channels != self.channels || coeffs != self.features.coeffs() {
            bail!("Gaussian set has {} channels x {} coefficients; this rasterizer takes {} x {}", channels, coeffs, self.channels, self.features.coeffs());
        }
        if features.len() < (channels * coeffs * g.n) as usize {
            bail!("feature buffer '{}' has {} values; {} Gaussians x {} need {}", features.name(), features.len(), g.n, channels * coeffs, channels * coeffs * g.n);
        }
        if g.n > frame.max_gaussians {
            bail!("{} Gaussians exceed the frame's {} (make a larger frame)", g.n, frame.max_gaussians);
        }
        Ok(())
    }

    /// Largest workgroup count per dimension (grids beyond it are 2-D).
    fn max_x(&self) -> u32 {
        self.ctx.caps().max_workgroup_count[0].min(65535)
    }

    /// Grid of one invocation per item.
    fn groups(&self, items: u32) -> [u32; 3] {
        groups_2d(items.div_ceil(WG), self.max_x())
    }

    /// Bindings 0..=8 of the per-tile forward and backward kernels.
    fn tile_bindings(frame: &Frame) -> Vec<BufferBinding> {
        vec![
            frame.cam.binding(),
            frame.ranges.binding(),
            frame.isect_vals.binding(),
            frame.isect_gid.binding(),
            frame.proj.binding(),
            frame.pfeat.binding(),
            frame.out.binding(),
            frame.fstate.binding(),
            frame.ustate.binding(),
        ]
    }
}
