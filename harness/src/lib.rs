//! The `tgs` command line and library: datasets, the trainer, outputs, the
//! procedural scene and the benchmark code shared with `cargo bench`.

pub mod bench;
pub mod bench_mlp;
pub mod bench_raster;
pub mod bench_stages;
pub mod bench_train;
pub mod data;
pub mod devices;
pub mod embed;
pub mod eval;
pub mod export;
pub mod lpips;
pub mod mesh;
pub mod outdir;
pub mod render;
pub mod scene;
pub mod sweep;
pub mod train;
