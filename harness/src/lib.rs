//! The `tgs` command line and the benchmark code shared with `cargo bench`.

pub mod bench;
pub mod bench_raster;
pub mod devices;
