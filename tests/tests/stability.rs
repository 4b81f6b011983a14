//! Numerical stability across all three stages (docs/stability.md, "Numerical
//! stability" lists every hard case and the test that holds it). Here: a
//! long run of every stage on the tiny glass scene with no NaN/Inf anywhere
//! and every parameter bounded, and a light field that has no pixel to run
//! on (R never above the threshold) training without NaN and without moving
//! the network.

use std::path::Path;
use tgs::train::checkpoint;
use tgs::train::run::{train, TrainArgs};
use tgs_tests::ctx_shared;

fn args(base: &Path, out: &str, set: &[&str]) -> TrainArgs {
    let out = base.join(out);
    let _ = std::fs::remove_dir_all(&out);
    let mut set: Vec<String> = set.iter().map(|s| s.to_string()).collect();
    set.extend(["test_interval=0", "checkpoint_interval=0"].map(String::from));
    TrainArgs { dataset: Some(tgs_tests::tiny_glass_scene(&base.join("scene"))), out, preset: Some("quick".into()), set, quiet: true, ..Default::default() }
}

fn log(out: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(out.join("log.jsonl")).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect()
}

/// Largest |v| of an array.
fn max_abs(v: &[f32]) -> f32 {
    v.iter().fold(0.0f32, |m, x| m.max(x.abs()))
}

#[test]
fn long_run_of_every_stage_stays_finite_and_bounded() {
    let base = tgs_tests::TempDir::new("stability");
    let a = args(&base, "long", &["iterations=1200", "reflection.iterations=400", "light_field.iterations=400"]);
    let out = a.out.clone();
    let o = train(ctx_shared(), &a).unwrap();
    assert_eq!(o.iteration, 2000);
    let lines: Vec<serde_json::Value> = log(&out).into_iter().filter(|l| l.get("loss").is_some()).collect();
    assert_eq!(lines.len(), 2000);
    for l in &lines {
        for k in ["loss", "l1", "ssim", "psnr"] {
            let v = l[k].as_f64().unwrap_or(f64::NAN);
            assert!(v.is_finite(), "iteration {}: {k} = {v}", l["iteration"]);
        }
        if let Some(f) = l.get("phi_fraction") {
            assert!((0.0..=1.0).contains(&f.as_f64().unwrap()), "{l}");
        }
    }
    assert_eq!(lines.iter().filter(|l| l["stage"] == "III").count(), 400);
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    for s in m["stages"].as_array().unwrap() {
        let t = &s["test"];
        assert!(t["psnr"].as_f64().unwrap() > 15.0 && t["ssim"].as_f64().unwrap().is_finite() && t["normal_mae_deg"].as_f64().unwrap().is_finite(), "{s}");
    }
    // Every array of the final state (parameters and Adam moments) finite and bounded.
    let (h, arrays) = checkpoint::read(&out.join("checkpoint.bin")).unwrap();
    let names: Vec<String> = h.arrays.iter().chain(h.later_arrays().unwrap().iter()).map(|a| a.0.clone()).collect();
    assert_eq!(names.len(), arrays.len());
    for (name, v) in names.iter().zip(&arrays) {
        assert!(v.iter().all(|x| x.is_finite()), "{name}: NaN/Inf");
    }
    let get = |n: &str| &arrays[names.iter().position(|x| x == n).unwrap_or_else(|| panic!("no array {n}: {names:?}"))];
    // Bounds: positions within 10 scene extents of the origin, no splat wider
    // than the scene, colours and material logits and MLP weights moderate.
    let e = h.extent;
    for set in ["", "refl."] {
        let means = get(&format!("{set}param.means"));
        assert!(max_abs(means) < 10.0 * e, "{set}means up to {} (extent {e})", max_abs(means));
        let ls = get(&format!("{set}param.log_scales"));
        assert!(
            ls.iter().all(|&s| s < e.ln() && s > -30.0),
            "{set}log_scales in [{}, {}]",
            ls.iter().cloned().fold(f32::INFINITY, f32::min),
            ls.iter().cloned().fold(f32::NEG_INFINITY, f32::max)
        );
        assert!(max_abs(get(&format!("{set}param.opacity"))) < 50.0);
        assert!(max_abs(get(&format!("{set}param.features"))) < 50.0, "{set}features up to {}", max_abs(get(&format!("{set}param.features"))));
    }
    eprintln!(
        "extent {e}; |means| {} / {}, log_scale max {} / {}, |features| {} / {}, |mlp| {}",
        max_abs(get("param.means")),
        max_abs(get("refl.param.means")),
        get("param.log_scales").iter().cloned().fold(f32::NEG_INFINITY, f32::max),
        get("refl.param.log_scales").iter().cloned().fold(f32::NEG_INFINITY, f32::max),
        max_abs(get("param.features")),
        max_abs(get("refl.param.features")),
        max_abs(get("mlp.param"))
    );
    assert!(max_abs(get("mlp.param")) < 20.0, "MLP weights up to {}", max_abs(get("mlp.param")));
    let _ = std::fs::remove_dir_all(&base);
}

/// Stage III with a threshold no pixel passes: every iteration evaluates Φ
/// on no pixel, stays finite, and leaves the network as initialised (no
/// gradient reaches it), while the composite is the scattering colour.
#[test]
fn light_field_with_no_reflecting_pixel() {
    let base = tgs_tests::TempDir::new("stability-none");
    let a = args(&base, "none", &["iterations=150", "reflection.iterations=20", "light_field.iterations=40", "light_field.threshold=0.9999"]);
    let out = a.out.clone();
    train(ctx_shared(), &a).unwrap();
    let third: Vec<serde_json::Value> = log(&out).into_iter().filter(|l| l["stage"] == "III" && l.get("loss").is_some()).collect();
    assert_eq!(third.len(), 40);
    for l in &third {
        assert_eq!(l["phi_fraction"].as_f64(), Some(0.0), "{l}");
        assert!(l["loss"].as_f64().unwrap().is_finite());
    }
    let (h, arrays) = checkpoint::read(&out.join("checkpoint.bin")).unwrap();
    let lf: checkpoint::LightFieldHeader = h.state_of(tgs::train::Stage("III")).unwrap().expect("a Stage III state");
    let k = h.arrays.len() + lf.arrays.iter().position(|a| a.0 == "mlp.param").unwrap();
    let [depth, width, skip, levels_x, levels_w] = lf.shape;
    let shape = tgs_pipelines::MlpShape { depth, width, skip, levels_x, levels_w };
    let init = shape.init_params(h.config.seed ^ 0x4c46);
    assert!(arrays[k].iter().zip(&init).all(|(a, b)| a.to_bits() == b.to_bits()), "the network moved without a sample");
    let _ = std::fs::remove_dir_all(&base);
}
