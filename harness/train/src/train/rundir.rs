//! The files of a run directory: their names, and the list a new run
//! claims before it starts (tgs never writes over a file it did not
//! create; `outdir`).

use super::stages::later;

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

/// `checkpoint-stageN.bin`: the state at the end of stage N (1: Stage I,
/// 2: Stage II, ...), written as the next stage begins.
pub fn stage_checkpoint(n: usize) -> String {
    format!("checkpoint-stage{n}.bin")
}

/// Every file a run writes directly into its directory (renders and
/// residual maps go into directories of their own): these, a
/// `checkpoint-stageN.bin` for each stage a later one follows, and each
/// later stage's own outputs. A new run claims them all in the
/// directory's `.tgs-written` before it starts, so a directory holding a
/// file of these names that tgs did not write is refused.
pub fn run_files() -> Vec<String> {
    let mut files: Vec<String> = RUN_FILES.iter().map(|f| f.to_string()).collect();
    let stages = later();
    files.extend((1..=stages.len()).map(stage_checkpoint));
    for f in stages.iter().flat_map(|k| k.files()) {
        if !files.iter().any(|g| g == f) {
            files.push(f.to_string());
        }
    }
    files
}

/// The files every run writes directly into its directory.
const RUN_FILES: [&str; 9] =
    [RUN_RECORD, "config.toml", "log.jsonl", CHECKPOINT, "checkpoint-nonfinite.bin", super::clock::CLOCK_FILE, "stages.json", "point_cloud.ply", "metrics.json"];
