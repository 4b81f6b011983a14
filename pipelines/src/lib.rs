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

pub mod scan;
pub mod sort;
pub mod rng;
pub mod util;

pub use scan::{Count, PrefixSum, ScanScratch};
pub use sort::{RadixSort, SortConfig, SortScratch};
pub use rng::Rng;
pub use util::Iota;
pub mod raster;
pub use raster::{Camera, Features, Frame, Gaussians, HostGaussians, Moments, Plane, RasterKernels, Rasterizer, RecordAccess, Splats, GATE_SLOTS};
pub mod train;
pub use train::{Adam, AdamArrays, AdamGroup, DensifyParams, DensifyReport, Densifier, HfLoss, HfStats, ImageLoss, LossIo, LossScratch, LossValues, LossWeights, TrainableSet};
pub mod reflection;
pub use reflection::{ColorInputs, CompositePriors, EnvMap, EnvProxy, Fresnel, HostEnvMap, ReflectionShading, TexelScratch};
pub mod mlp;
pub use mlp::{Mlp, MlpScratch, MlpShape};
pub mod lightfield;
pub use lightfield::{LightFieldShading, SampleScratch, ShadeParams};
pub mod mesh;
pub use mesh::{HostTsdf, TsdfFusion, TsdfGrid, TsdfVolume, BYTES_PER_VOXEL};
