//! tgs-pipelines: the compute kernels, compiled from `glsl/` at build time,
//! with one typed Rust wrapper per kernel family.

/// Embedded SPIR-V of every `glsl/*.comp` (name in upper case).
pub mod shaders {
    include!(concat!(env!("OUT_DIR"), "/shaders.rs"));
}

/// The workgroup size of the one-dimensional kernels (specialization
/// constant 0, which `WG` in `glsl/common.glsl` reads back as
/// `gl_WorkGroupSize.x`): one value for every kernel family.
pub(crate) const WG: u32 = 256;

/// How arrays too large for one storage binding are cut (the SH 3 features
/// of a million Gaussians and their moments are 183 MiB; lavapipe binds
/// 128): units per dispatch, or `None` for one dispatch with the whole
/// buffers bound, which is what happens when `whole_fits` and no slice is
/// `forced` (tests force slices on small sets). Otherwise the units that
/// fit one binding (`fit`, or `forced` when smaller), rounded down to a
/// multiple of 64 so that every slice starts at an offset any device
/// allows; `None` too when that leaves none. The rasterizer's feature
/// slices, Adam's own pass and the densification's copy all cut by it.
pub(crate) fn slice_units(whole_fits: bool, fit: u64, forced: Option<u64>) -> Option<u64> {
    if whole_fits && forced.is_none() {
        return None;
    }
    let per = forced.unwrap_or(fit).min(fit) / 64 * 64;
    (per > 0).then_some(per)
}

pub mod rng;
pub mod scan;
pub mod sort;
pub mod util;

pub use rng::Rng;
pub use scan::{Count, PrefixSum, ScanScratch};
pub use sort::{RadixSort, SortConfig, SortScratch};
pub use util::Iota;
pub mod raster;
pub use raster::{Camera, Features, Frame, Gaussians, HostGaussians, KeptWeights, Moments, Plane, RasterKernels, Rasterizer, RecordAccess, Splats, GATE_SLOTS};
pub mod train;
pub use train::{
    Adam, AdamArrays, AdamGroup, Densifier, DensifyParams, DensifyReport, Guard, HfLoss, HfStats, ImageLoss, LossIo, LossScratch, LossValues, LossWeights, SetGuard, TrainableSet,
};
pub mod reflection;
pub use reflection::{ColorInputs, CompositePriors, EnvMap, EnvProxy, Fresnel, HostEnvMap, ReflectionShading, TexelScratch};
pub mod mlp;
pub use mlp::{Mlp, MlpScratch, MlpShape};
pub mod lightfield;
pub use lightfield::{LightFieldShading, SampleScratch, ShadeParams};
pub mod mesh;
pub mod view;
pub use mesh::{HostTsdf, TsdfFusion, TsdfGrid, TsdfVolume, BYTES_PER_VOXEL};
pub use view::{pack_pixel, Pack, PixelOrder};
