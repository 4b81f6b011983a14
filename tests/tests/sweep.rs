//! `tgs sweep`: grid files (modes, duplicates of the base, refusals naming
//! the problem), the Pareto front, and a small sweep on the tiny glass
//! scene: one CSV row per run with every stage's metrics, the plots, and a
//! half-finished sweep resumed (finished runs kept, the missing one trained).

use tgs::sweep::{pareto, sweep, Grid, Row, SweepArgs};
use tgs_tests::ctx_shared;

#[test]
fn grids_expand_and_bad_grids_are_refused() {
    let g = Grid::parse("[base]\niterations = 100\n[knobs]\niterations = [50, 100, 200]\nsh_degree = [1, 3]\n", "g").unwrap();
    let names: Vec<String> = g.runs(true).unwrap().into_iter().map(|r| r.0).collect();
    // The base has iterations = 100 and the quick preset's sh_degree 3: those values are the base run.
    assert_eq!(names, ["base", "iterations=50", "iterations=200", "sh_degree=1"]);
    let p = Grid::parse("mode = \"product\"\n[knobs]\niterations = [50, 100]\n[knobs.light_field]\npreset = [\"small\", \"paper\"]\n", "p").unwrap();
    let names: Vec<String> = p.runs(true).unwrap().into_iter().map(|r| r.0).collect();
    assert_eq!(names.len(), 4, "{names:?}");
    assert!(names.contains(&"iterations=100,light_field.preset=paper".to_string()), "{names:?}");
    for (text, says) in [
        ("[knobs]\n", "no [knobs]"),
        ("mode = \"grid\"\n[knobs]\niterations = [1]\n", "mode"),
        ("[knobs]\niterations = 5\n", "non-empty list"),
        ("colour = 1\n[knobs]\niterations = [1]\n", "unknown entry 'colour'"),
        ("[knobs]\n\"reflection.env_res\" = [16, 100000]\n", "reflection.env_res=100000"),
        ("[knobs]\nno_such_key = [1]\n", "no_such_key"),
        ("[knobs\n", "not valid TOML"),
    ] {
        let e = Grid::parse(text, "grid.toml").and_then(|g| g.runs(true)).err().unwrap_or_else(|| panic!("accepted: {text}"));
        assert!(format!("{e:#}").contains(says), "{text}: {e:#}");
    }
}

#[test]
fn pareto_front_keeps_the_undominated_runs() {
    let row = |name: &str, wall_s: f64, psnr: f64| Row { name: name.into(), wall_s, psnr, ..Default::default() };
    let rows = vec![row("a", 10.0, 20.0), row("b", 20.0, 25.0), row("c", 30.0, 24.0), row("d", 5.0, 20.0), row("e", 40.0, f64::NAN), row("f", 20.0, 25.0)];
    // c is slower and worse than b; a is as good as d but slower; e has no score; b and f tie (neither dominates).
    assert_eq!(pareto(&rows, |r| r.psnr), vec![3, 1, 5]);
    assert_eq!(pareto(&[], |r| r.psnr), Vec::<usize>::new());
}

#[test]
fn sweep_tabulates_plots_and_resumes() {
    let base = tgs_tests::TempDir::new("sweep");
    let scene = tgs_tests::tiny_glass_scene(&base.join("scene"));
    let grid = base.join("grid.toml");
    std::fs::write(
        &grid,
        "[base]\niterations = 60\n\"reflection.iterations\" = 10\n\"light_field.iterations\" = 10\ntest_interval = 0\ncheckpoint_interval = 0\n[knobs]\niterations = [40, 60]\n\"light_field.threshold\" = [0.01, 0.05]\n",
    )
    .unwrap();
    let out = base.join("sweep");
    let a = SweepArgs { dataset: Some(scene), out: out.clone(), grid: Some(grid), quiet: true };
    let o = sweep(ctx_shared(), &a).unwrap();
    assert!(!o.interrupted);
    assert_eq!(o.trained, 3);
    let names: Vec<&str> = o.rows.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(names, ["base", "iterations=40", "light_field.threshold=0.05"]);
    for r in &o.rows {
        assert_eq!(r.stages.keys().map(String::as_str).collect::<Vec<_>>(), ["I", "II", "III"], "{}", r.name);
        assert!(r.wall_s > 0.0 && r.gpu_ms_per_iteration > 0.0 && r.psnr.is_finite() && r.normal_mae_deg.is_finite(), "{r:?}");
        assert_eq!(r.psnr, r.stages["III"].0[0]);
        // LPIPS (the weights scripts/setup.sh converts) for the run and each stage.
        assert!(r.lpips.is_finite() && r.lpips > 0.0 && r.lpips == r.stages["III"].0[3], "{r:?}");
        assert!(r.stages.values().all(|s| s.0[3].is_finite()), "{r:?}");
    }
    assert_eq!(o.rows[1].iterations, 60, "40 + 10 + 10 iterations");
    assert_eq!(o.rows[1].settings["iterations"], "40");
    let csv = std::fs::read_to_string(out.join("sweep.csv")).unwrap();
    assert_eq!(csv.lines().count(), 4);
    assert!(csv.starts_with("run,key,iterations,light_field.threshold,wall_s,gpu_ms_per_iteration,total_iterations,psnr,"), "{csv}");
    assert!(csv.lines().next().unwrap().contains(",normal_mae_deg,lpips,I_psnr,I_ssim,I_normal_mae_deg,I_lpips,I_wall_s,"), "{csv}");
    for p in ["psnr_vs_time.png", "normal_mae_vs_time.png", "lpips_vs_time.png"] {
        let img = image::open(out.join(p)).unwrap_or_else(|e| panic!("{p}: {e}"));
        assert_eq!((img.width(), img.height()), (960, 640));
    }

    // Again: nothing to train, the same rows.
    let again = sweep(ctx_shared(), &a).unwrap();
    assert_eq!((again.trained, &again.rows), (0, &o.rows));
    // Half finished: the last row lost (its run directory left behind), trained again.
    let kept: Vec<&str> = csv.lines().take(3).collect();
    std::fs::write(out.join("sweep.csv"), kept.join("\n") + "\n").unwrap();
    let resumed = sweep(ctx_shared(), &a).unwrap();
    assert_eq!(resumed.trained, 1);
    assert_eq!(resumed.rows[..2], o.rows[..2]);
    assert_eq!(resumed.rows[2].name, "light_field.threshold=0.05");
    // A CSV of another grid is refused, not mixed in.
    std::fs::write(out.join("sweep.csv"), "run,x\n").unwrap();
    assert!(format!("{:#}", sweep(ctx_shared(), &a).err().unwrap()).contains("another grid"));
    let _ = std::fs::remove_dir_all(&base);
}
