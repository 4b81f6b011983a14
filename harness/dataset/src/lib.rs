//! tgs datasets and the files tgs reads and writes: the Blender and COLMAP
//! layouts (`data`), images, PLY and the light field's safetensors
//! (`data::image_io`, `export`), atomic writes and the rule that tgs never
//! writes into a dataset or over files it did not create (`outdir`), one
//! writer per output directory (`lock`), and
//! the built-in procedural scenes written as datasets (`scene`).

pub mod data;
pub mod export;
pub mod lock;
pub mod outdir;
pub mod scene;
