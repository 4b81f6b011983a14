//! End to end, the method's result: on the built-in glass scene (the
//! quick preset with its Stage I schedule halved: 1,500 iterations, then
//! 200 of Stage II and 100 of Stage III), Stage II's residual-hull
//! reflection set (`reflection.dataset_masks` off) lowers the glass-mask
//! normal MAE below Stage I's and keeps the test PSNR; Stage III raises the
//! PSNR; the meshes lie near the true surfaces. The output normals are the
//! set's only where its R reaches `reflection.residual_normal_min_r`
//! (0.07); ungated (0, as `tgs eval --set` gives it) the set covers the
//! glass with far better normals, and far worse ones beside it.
//! Measured on lavapipe (perf/journal/2026-12-04-fifty-seventh.md):
//! Stage I 59.04 degrees, PSNR 28.376, beside the glass 17.65; Stage II
//! 51.03 degrees, PSNR 28.294, coverage 0.386, beside the glass 25.56;
//! ungated 44.25 degrees, coverage 0.907, beside the glass 43.39; Stage III
//! 54.46 degrees (R moves with the reflectivity it trains; ungated the
//! normals are Stage II's), PSNR 28.495, beside the glass 19.94; scene mesh
//! distance mean 0.326, median 0.232; glass mesh 0.369, 0.412. The
//! same test with each of three broken Stage II/III settings failed
//! (thirty-third entry): the paper's copy start in place of the seeds, a
//! light field that does not learn, and a residual hull cast with 64 rays.
//! scripts/test.sh runs it once, not again at subgroup size 4 (it tests
//! the method, not a kernel).
//! Then the same Stage I seeded from the scene's training masks
//! (`reflection.dataset_masks`, the default where a dataset has them):
//! Stage II 5.10 degrees (0.086x Stage I's), 18.76 beside the glass,
//! Stage III PSNR 28.513; the whole test 276 s beside other work.

use tgs::train::run::{train, TrainArgs};
use tgs_tests::{check_validation, ctx_shared};

#[test]
fn method_on_glass() {
    let ctx = ctx_shared();
    let out = tgs_tests::TempDir::new("quality");
    let _ = std::fs::remove_dir_all(&out);
    // The quick preset's Stage I schedule at half its length (every
    // iteration-counted setting halved).
    let stage1 = [
        "iterations=1500",
        "sh_interval=250",
        "normal_from=750",
        "dist_from=500",
        "densify_from=150",
        "densify_until=1000",
        "opacity_reset_interval=500",
        "opacity_reset_min_after=150",
    ];
    // The residual's seeds (the path of a dataset without training masks).
    let set = stage1
        .iter()
        .chain(&["reflection.iterations=200", "light_field.iterations=100", "test_interval=0", "checkpoint_interval=0", "reflection.dataset_masks=false"])
        .map(|s| s.to_string())
        .collect();
    // No dataset: the built-in glass scene, written to OUT/scene.
    let o = train(ctx, &TrainArgs { out: out.to_path_buf(), preset: Some("quick".into()), set, quiet: true, ..Default::default() }).unwrap();
    assert_eq!(o.iteration, 1800);
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    let s = &m["stages"];
    let get = |i: usize, k: &str| s[i]["test"][k].as_f64().unwrap_or_else(|| panic!("stage {i} {k}: {s}"));
    let (mae1, mae2) = (get(0, "normal_mae_deg"), get(1, "normal_mae_deg"));
    eprintln!("Stage I: MAE {mae1:.2} PSNR {:.3}; Stage II: MAE {mae2:.2} PSNR {:.3} coverage {:.3}", get(0, "psnr"), get(1, "psnr"), get(1, "reflection_coverage"));
    eprintln!("beside the glass: Stage I {:.2}, Stage II {:.2}", get(0, "normal_mae_outside_deg"), get(1, "normal_mae_outside_deg"));
    // Gated by reflection.residual_normal_min_r: better on the glass.
    assert!(mae2 < 0.95 * mae1, "Stage II glass normal MAE {mae2:.2} vs Stage I {mae1:.2}");
    assert!(get(1, "psnr") > get(0, "psnr") - 0.3, "Stage II PSNR {} vs Stage I {}", get(1, "psnr"), get(0, "psnr"));
    assert!(get(1, "reflection_coverage") > 0.2, "coverage {}", get(1, "reflection_coverage"));
    // The set itself, ungated (residual_normal_min_r = 0, as `tgs eval
    // --set` gives it), after Stage II and after Stage III: it covers the
    // glass and its normals there are far better than Stage I's; the gate
    // keeps them off most of what it covers beside the glass.
    let (_, data) = tgs::train::run::open_run(ctx, &out).unwrap();
    let ungated = |file: &str| {
        let path = out.join(file);
        let mut tr = tgs::train::checkpoint::restore(ctx, &path, tgs::train::checkpoint::read(&path).unwrap(), &data).unwrap();
        tgs::train::run::set_output_settings(&mut tr, &["reflection.residual_normal_min_r=0".into()]).unwrap();
        let m = tgs::eval::evaluate(&mut tr, &data.test, None).unwrap();
        (m.normals.normal_mae_deg.unwrap(), m.normals.reflection_coverage.unwrap(), m.normals.normal_mae_outside_deg.unwrap())
    };
    let (mae0, cov0, beside0) = ungated("checkpoint-stage2.bin");
    eprintln!("Stage II ungated: MAE {mae0:.2} coverage {cov0:.3}, beside the glass {beside0:.2}");
    assert!(mae0 < 0.85 * mae1 && cov0 > 0.8, "ungated: MAE {mae0:.2} vs Stage I {mae1:.2}, coverage {cov0:.3}");
    let beside2 = get(1, "normal_mae_outside_deg");
    assert!(beside2 < beside0 - 5.0, "beside the glass: gated {beside2:.2}, ungated {beside0:.2}");
    // The scattering set is frozen in Stage II: its own MAE is Stage I's.
    assert!((get(1, "normal_mae_scattering_deg") - mae1).abs() < 1e-9);
    // Stage III: the reflection geometry frozen (ungated, the same
    // normals; gated, R moves with the reflectivity it trains), the PSNR raised.
    let mae3 = get(2, "normal_mae_deg");
    eprintln!("Stage III: MAE {mae3:.2} PSNR {:.3}, beside the glass {:.2}", get(2, "psnr"), get(2, "normal_mae_outside_deg"));
    assert_eq!(ungated("checkpoint.bin").0, mae0, "Stage III moved the reflection set's normals");
    assert!(mae3 < 0.95 * mae1, "Stage III glass normal MAE {mae3:.2} vs Stage I {mae1:.2}");
    assert!(get(2, "psnr") > get(1, "psnr") + 0.1, "Stage III PSNR {} vs Stage II {}", get(2, "psnr"), get(1, "psnr"));
    // `tgs mesh`: the scene mesh near the room's true surfaces, the glass
    // mesh near the glass sphere (radius 0.75), in scene units.
    use tgs::scene::trace::Scene;
    let reports = tgs::mesh::mesh(ctx, &out, &tgs::mesh::MeshArgs::default()).unwrap();
    assert_eq!(reports.len(), 2);
    let truth = Scene::new();
    let stats = |d: Vec<f64>| {
        let mut d = d;
        d.sort_by(f64::total_cmp);
        (d.iter().sum::<f64>() / d.len() as f64, d[d.len() / 2])
    };
    let (mean, median) = stats(reports[0].mesh.positions.iter().map(|p| truth.surface_distance(p.map(f64::from))).collect());
    let (gmean, gmedian) = stats(reports[1].mesh.positions.iter().map(|p| Scene::glass_distance(p.map(f64::from))).collect());
    eprintln!(
        "meshes: scene {} triangles, distance mean {mean:.3} median {median:.3}; glass {} triangles, distance mean {gmean:.3} median {gmedian:.3}",
        reports[0].mesh.triangles.len(),
        reports[1].mesh.triangles.len()
    );
    // Measured (lavapipe, thirtieth session, 1,500 Stage I iterations):
    // scene mean 0.292, median 0.209 (voxel 0.14: two pixels at the walls'
    // depth; 0.246 and 0.189 after 3,000); glass mean 0.422, median 0.453.
    // The glass mesh is the reflection set's surface, which
    // here is a shell around the sphere larger than it (the residual hull):
    // on the glass mask its median depth lies 0.06 from the glass, but it
    // also covers pixels beside the glass (`reflection_outside_mask`).
    assert!(mean < 0.35 && median < 0.25, "scene mesh: mean {mean} median {median}");
    assert!(gmean < 0.5 && gmedian < 0.5, "glass mesh: mean {gmean} median {gmedian}");

    // The same Stage I, then Stages II and III seeded from the scene's own
    // training masks (reflection.dataset_masks, the default where a
    // dataset has them): issue 42's end-to-end aim, the glass normal MAE
    // within 0.6x Stage I's, far below the residual seeds', and the
    // normals beside the glass near Stage I's.
    let masked = tgs_tests::TempDir::new("quality-masks");
    let _ = std::fs::remove_dir_all(&masked);
    let am = TrainArgs {
        out: masked.to_path_buf(),
        from: Some(out.to_path_buf()),
        stages: Some("II,III".into()),
        set: vec!["reflection.dataset_masks=true".into()],
        quiet: true,
        ..Default::default()
    };
    assert_eq!(train(ctx, &am).unwrap().iteration, 1800);
    let mm: serde_json::Value = serde_json::from_slice(&std::fs::read(masked.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(mm["reflection"]["seed_mask_source"], "dataset");
    let ms = &mm["stages"];
    let mget = |i: usize, k: &str| ms[i]["test"][k].as_f64().unwrap_or_else(|| panic!("masked stage {i} {k}: {ms}"));
    let (mae_m, out1, out_m) = (mget(1, "normal_mae_deg"), get(0, "normal_mae_outside_deg"), mget(1, "normal_mae_outside_deg"));
    eprintln!(
        "masks: Stage II MAE {mae_m:.2} ({:.3}x Stage I), beside the glass {out_m:.2} (Stage I {out1:.2}); PSNR II {:.3} III {:.3}",
        mae_m / mae1,
        mget(1, "psnr"),
        mget(2, "psnr")
    );
    assert!(mae_m < 0.6 * mae1 && mae_m < 0.5 * mae2, "masked Stage II glass normal MAE {mae_m:.2} vs Stage I {mae1:.2}, residual seeds {mae2:.2}");
    assert!(out_m < out1 + 5.0, "masked Stage II normals beside the glass {out_m:.2} vs Stage I {out1:.2}");
    assert!(mget(2, "psnr") > get(0, "psnr"), "masked Stage III PSNR {} vs Stage I {}", mget(2, "psnr"), get(0, "psnr"));
    let _ = std::fs::remove_dir_all(&masked);
    let _ = std::fs::remove_dir_all(&out);
    check_validation(ctx);
}
