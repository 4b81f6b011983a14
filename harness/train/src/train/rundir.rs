//! The files of a run directory: their names, and the list a new run
//! claims before it starts (tgs never writes over a file it did not
//! create; `outdir`).

pub const CHECKPOINT: &str = "checkpoint.bin";
/// The run's state at the end of Stage I and of Stage II, written as the
/// next stage begins: `--from RUN` starts from them, since the later
/// stages change what checkpoint.bin holds (Stage III trains the
/// scattering set's colour by default).
pub const STAGE_ONE_CHECKPOINT: &str = "checkpoint-stage1.bin";
pub const STAGE_TWO_CHECKPOINT: &str = "checkpoint-stage2.bin";
pub const DEFAULT_SCENE: &str = "glass";
/// The run's identity (its id and dataset), written when it starts: a
/// `--resume` whose checkpoint.bin names another run is refused.
pub const RUN_RECORD: &str = "run.json";

/// Every file a run writes directly into its directory (renders and
/// residual maps go into directories of their own). A new run claims them
/// all in the directory's `.tgs-written` before it starts, so a directory
/// holding a file of these names that tgs did not write is refused.
pub const RUN_FILES: [&str; 17] = [
    RUN_RECORD,
    "config.toml",
    "log.jsonl",
    CHECKPOINT,
    STAGE_ONE_CHECKPOINT,
    STAGE_TWO_CHECKPOINT,
    "checkpoint-nonfinite.bin",
    super::clock::CLOCK_FILE,
    "stages.json",
    "point_cloud.ply",
    "reflection.ply",
    "light_field.safetensors",
    "envmap.exr",
    "envmap.png",
    "envmap_depth.exr",
    "envmap_depth.png",
    "metrics.json",
];
