//! The list of stages (`stages::later()`) and what is built from it: the
//! schedule, the `stages` setting, the run directory's file names and the
//! checkpoint header's later-stage part. No device: these are the pieces a
//! new stage plugs into, checked against what they were when each was
//! written out by hand.

use tgs::train::checkpoint::Header;
use tgs::train::rundir::{run_files, stage_checkpoint, STAGE_ONE_CHECKPOINT, STAGE_TWO_CHECKPOINT};
use tgs::train::stages::kind::{by_key, by_stage};
use tgs::train::stages::{later, BUILT_IN};
use tgs::train::{Schedule, Stage, TrainConfig};

fn names(s: &Schedule) -> Vec<(String, u32)> {
    (0..s.stages.len()).map(|i| (s.label(i), s.stages[i].1)).collect()
}

fn config(stages: &str, reseed: bool) -> TrainConfig {
    let mut c = TrainConfig::quick();
    c.stages = stages.into();
    c.iterations = 30;
    c.reflection.iterations = 20;
    c.light_field.iterations = 10;
    c.reflection.reseed = reseed;
    c
}

#[test]
fn the_stages_are_i_ii_iii_in_order() {
    let all: Vec<&str> = Stage::all().iter().map(|s| s.name()).collect();
    assert_eq!(all, ["I", "II", "III"]);
    assert_eq!(Stage::default(), Stage::SCATTERING);
    // Nothing registered in this test binary: the list is the built-in one.
    assert_eq!(later().iter().map(|k| k.key()).collect::<Vec<_>>(), ["reflection", "light_field"]);
    assert_eq!(BUILT_IN.len(), 2);
    // The later stages' kinds follow the names' order (stage.rs is a leaf
    // of the module graph, so it keeps the names; this holds the two lists together).
    assert_eq!(later().iter().map(|k| k.stage()).collect::<Vec<_>>(), Stage::all()[1..]);
    assert_eq!(Stage::all(), Stage::BUILT_IN);
    assert!(TrainConfig::quick().sections.is_empty() && TrainConfig::paper().sections.is_empty());
    for (i, s) in Stage::all().into_iter().enumerate() {
        assert_eq!(s.number(), i + 1);
        assert_eq!(Stage::named(s.name()), Some(s));
    }
    assert_eq!(Stage::named("IV"), None);
    for k in later() {
        assert_eq!(by_key(k.key()).map(|b| b.stage()), Some(k.stage()));
        assert_eq!(by_stage(k.stage()).map(|b| b.key()), Some(k.key()));
    }
    assert!(by_stage(Stage::SCATTERING).is_none() && by_key("scattering").is_none());
}

#[test]
fn the_schedule_is_built_from_the_list() {
    let s = |st: &str, reseed: bool| names(&Schedule::from_config(&config(st, reseed)));
    let own = |v: &[(&str, u32)]| v.iter().map(|(a, b)| (a.to_string(), *b)).collect::<Vec<_>>();
    assert_eq!(s("I", false), own(&[("I", 30)]));
    assert_eq!(s("I,II", false), own(&[("I", 30), ("II", 20)]));
    assert_eq!(s("I,II,III", false), own(&[("I", 30), ("II", 20), ("III", 10)]));
    // reflection.reseed runs Stages II and III again, only after Stage III.
    assert_eq!(s("I,II,III", true), own(&[("I", 30), ("II", 20), ("III", 10), ("II.2", 20), ("III.2", 10)]));
    assert_eq!(s("I,II", true), own(&[("I", 30), ("II", 20)]));
    let mut sch = Schedule::from_config(&config("I,II,III", false));
    assert_eq!(sch.total(), 60);
    assert_eq!(sch.at(31), Some((Stage("II"), 1)));
    assert_eq!(sch.at(60), Some((Stage("III"), 10)));
    sch.end_before(1);
    assert_eq!(names(&sch), own(&[("I", 30)]));
}

#[test]
fn the_stages_setting_names_the_list() {
    for ok in ["I", "I,II", "I,II,III", " I , II "] {
        assert!(config(ok, false).validate().is_ok(), "{ok}");
    }
    for (bad, says) in [
        ("IV", "unknown stage 'IV' (I, II, III; e.g. \"I,II,III\")"),
        ("I,III", "stages must be \"I\", \"I,II\" or \"I,II,III\", not \"I,III\""),
        ("II", "not \"II\""),
        ("I,I", "not \"I,I\""),
        ("I,II,III,III", "not \"I,II,III,III\""),
        ("", "unknown stage ''"),
    ] {
        let e = format!("{:#}", config(bad, false).validate().unwrap_err());
        assert!(e.contains(says), "{bad}: {e}");
    }
}

#[test]
fn the_run_directory_claims_every_stage_file() {
    assert_eq!(stage_checkpoint(1), STAGE_ONE_CHECKPOINT);
    assert_eq!(stage_checkpoint(2), STAGE_TWO_CHECKPOINT);
    let files = run_files();
    // The list as it was written out by hand before the stages listed
    // their own files.
    for f in [
        "run.json",
        "config.toml",
        "log.jsonl",
        "checkpoint.bin",
        "checkpoint-stage1.bin",
        "checkpoint-stage2.bin",
        "checkpoint-nonfinite.bin",
        "checkpoint-time.json",
        "stages.json",
        "point_cloud.ply",
        "reflection.ply",
        "light_field.safetensors",
        "envmap.exr",
        "envmap.png",
        "envmap_depth.exr",
        "envmap_depth.png",
        "metrics.json",
    ] {
        assert!(files.iter().any(|g| g == f), "{f} is not claimed");
    }
    let mut sorted = files.clone();
    sorted.sort();
    sorted.dedup();
    assert_eq!(sorted.len(), files.len(), "a file is claimed twice: {files:?}");
}

fn header(later: serde_json::Value) -> Result<Header, serde_json::Error> {
    let mut h = serde_json::json!({
        "iteration": 5, "config": {}, "dataset": "d", "rng": 1, "stack": [], "n": 0, "channels": 3, "coeffs": 16, "extent": 1.0, "arrays": []
    });
    h.as_object_mut().unwrap().extend(later.as_object().unwrap().clone());
    serde_json::from_value(h)
}

#[test]
fn the_header_holds_at_most_one_known_stage() {
    // Before the list, a header wrote null under the stages not running.
    let old = header(serde_json::json!({"reflection": null, "light_field": null})).unwrap();
    assert!(old.later_state().unwrap().is_none());
    assert!(!old.holds(Stage("II")));
    let none = header(serde_json::json!({})).unwrap();
    assert!(none.later_state().unwrap().is_none());
    let lf = header(serde_json::json!({"reflection": null, "light_field": {"arrays": [["refl.means", 6]]}})).unwrap();
    let (k, v) = lf.later_state().unwrap().unwrap();
    assert_eq!(k.stage(), Stage("III"));
    assert_eq!(k.arrays(v).unwrap(), vec![("refl.means".to_string(), 6)]);
    assert!(lf.holds(Stage("III")) && !lf.holds(Stage("II")));
    let mut arrays = vec![vec![0.0f32; 3]; 6];
    let mut lf = lf;
    lf.drop_later(&mut arrays).unwrap();
    assert_eq!(arrays.len(), 5);
    assert!(lf.later_state().unwrap().is_none());
    let two = header(serde_json::json!({"reflection": {"arrays": []}, "light_field": {"arrays": []}})).unwrap();
    assert!(format!("{:#}", two.later_state().err().unwrap()).contains("two stages"));
    let unknown = header(serde_json::json!({"caustics": {"arrays": []}})).unwrap();
    assert!(format!("{:#}", unknown.later_state().err().unwrap()).contains("'caustics'"));
    // Written and read back, the map keeps only the running stage.
    let back = serde_json::to_value(&lf).unwrap();
    assert!(back.get("light_field").is_none() && back.get("reflection").is_none(), "{back}");
    let kept = serde_json::to_value(header(serde_json::json!({"light_field": {"arrays": []}})).unwrap()).unwrap();
    assert_eq!(kept["light_field"], serde_json::json!({"arrays": []}));
}

/// The settings `--resume` and `tgs eval --set` may change are gathered
/// from the stages' kinds: each lies in its stage's section and is a
/// setting the configuration has.
#[test]
fn the_settings_lists_are_built_from_the_list() {
    use tgs::train::args::{output_settings, resumable_settings};
    use tgs::train::config::flatten;
    use tgs::train::stages::kind::in_section;
    assert_eq!(resumable_settings(), ["iterations", "reflection.iterations", "reflection.reseed", "light_field.iterations", "test_interval", "checkpoint_interval"]);
    assert_eq!(output_settings(), ["reflection.normal_min_r", "reflection.residual_normal_min_r", "reflection.normal_min_alpha"]);
    let known: Vec<String> = flatten(&toml::Table::try_from(TrainConfig::quick()).unwrap()).into_iter().map(|(k, _)| k).collect();
    for k in later() {
        for key in k.resumable().iter().chain(k.output_settings()) {
            assert!(in_section(k, key), "{key} is not in the {} section", k.key());
            assert!(known.iter().any(|n| n == key), "{key} is not a setting");
        }
        for key in k.frees_earlier_settings() {
            assert!(known.iter().any(|n| n == key) && !in_section(k, key), "{key}: a setting of an earlier stage");
        }
    }
    assert!(!in_section(BUILT_IN[0], "reflectionx.iterations") && !in_section(BUILT_IN[0], "reflection"));
}
