//! The `tgs` command line and library: the commands (render, mesh, sweep,
//! devices), the benchmark code shared with `cargo bench`, and the
//! embedding API (`embed`). Datasets and files are the `tgs-dataset`
//! crate's, training and evaluation the `tgs-train` crate's; both are
//! re-exported here under their module names (`tgs::data`, `tgs::train`, ...).

pub use tgs_train::{data, eval, export, lock, lpips, outdir, scene, train};

pub mod bench;
pub mod bench_light_field;
pub mod bench_mlp;
pub mod bench_raster;
pub mod bench_stages;
pub mod bench_train;
pub mod bench_view;
pub mod devices;
pub mod embed;
pub mod marks;
pub mod mesh;
pub mod render;
pub mod sweep;
pub mod view;
