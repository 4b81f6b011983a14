//! Checks of `tgs mesh` on a trained run, shared by the end-to-end
//! training tests (tests/tests/train_stage2.rs).

use std::path::Path;

/// `tgs mesh` on a Stage I + II run of the tiny glass scene: the scene mesh
/// near the room's true surfaces (distances in scene units; the glass
/// sphere's radius is 0.75, the room's 5), a glass mesh, a rerun
/// bit-identical, and what it refuses (an output inside `dataset`).
pub fn meshes_of_the_run(ctx: &std::sync::Arc<tgs_engine::Context>, run: &Path, dataset: &Path) {
    use tgs::mesh::{mesh, ply, MeshArgs};
    use tgs::scene::trace::Scene;
    let reports = mesh(ctx, run, &MeshArgs::default()).unwrap();
    assert_eq!(reports.iter().map(|r| r.path.file_name().unwrap().to_str().unwrap()).collect::<Vec<_>>(), ["mesh_scene.ply", "mesh_glass.ply"]);
    let truth = Scene::new();
    let stats = |d: &mut Vec<f64>| {
        d.sort_by(f64::total_cmp);
        (d.iter().sum::<f64>() / d.len() as f64, d[d.len() / 2])
    };
    let m = ply::read_mesh(&run.join("mesh_scene.ply")).unwrap();
    assert_eq!(m.positions.len(), reports[0].mesh.positions.len());
    let (mean, median) = stats(&mut m.positions.iter().map(|p| truth.surface_distance(p.map(f64::from))).collect());
    let g = ply::read_mesh(&run.join("mesh_glass.ply")).unwrap();
    let (gmean, gmedian) = stats(&mut g.positions.iter().map(|p| Scene::glass_distance(p.map(f64::from))).collect());
    eprintln!(
        "scene mesh: {} triangles, distance mean {mean:.3} median {median:.3}; glass mesh: {} triangles, distance mean {gmean:.3} median {gmedian:.3}",
        m.triangles.len(),
        g.triangles.len()
    );
    assert!(m.triangles.len() > 1000 && g.triangles.len() > 100);
    // Measured (lavapipe): mean 0.252, median 0.186 at a voxel of 0.18
    // (two pixels at the walls' depth: 48x48 views).
    assert!(mean < 0.35 && median < 0.27, "scene mesh mean {mean} median {median}");
    // The glass mesh is where the reflection set is. After this short Stage
    // I (300 iterations) the residual hull puts it in front of the cameras,
    // about 0.9 from the glass (measured): the mesh shows it, and the test
    // of the glass mesh against the true glass is in train_quality.rs.
    assert!(gmean.is_finite() && g.positions.iter().flatten().all(|v| v.is_finite()));
    // Again into the same directory (its own files): the same bytes.
    let before = std::fs::read(run.join("mesh_glass.ply")).unwrap();
    mesh(ctx, run, &MeshArgs::default()).unwrap();
    assert!(std::fs::read(run.join("mesh_glass.ply")).unwrap() == before, "a rerun of tgs mesh differs");
    // Never into the dataset, never over a file tgs did not write.
    let e = format!("{:#}", mesh(ctx, run, &MeshArgs { out: Some(dataset.join("meshes")), ..Default::default() }).unwrap_err());
    assert!(e.contains("dataset"), "{e}");
    let other = run.join("elsewhere");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::write(other.join("mesh_glass.ply"), b"mine").unwrap();
    let e = format!("{:#}", mesh(ctx, run, &MeshArgs { out: Some(other.clone()), ..Default::default() }).unwrap_err());
    assert!(e.contains("mesh_glass.ply") && e.contains("not written by tgs"), "{e}");
    assert_eq!(std::fs::read(other.join("mesh_glass.ply")).unwrap(), b"mine");
    assert!(!other.join("mesh_scene.ply").exists(), "nothing is written before the refusal");
    // A grid over the memory limit is refused with its size.
    let e = format!("{:#}", mesh(ctx, run, &MeshArgs { voxel: Some(0.001), max_bytes: 1 << 26, out: Some(run.join("fine")), ..Default::default() }).unwrap_err());
    assert!(e.contains("MiB") && e.contains("voxel"), "{e}");
    // Bad options are refused before any work, naming the option.
    for (bad, what) in [
        (MeshArgs { voxel: Some(-1.0), ..Default::default() }, "voxel size -1"),
        (MeshArgs { trunc: Some(f32::NAN), ..Default::default() }, "truncation distance NaN"),
        (MeshArgs { depth_max: Some(0.0), ..Default::default() }, "maximum depth 0"),
        (MeshArgs { resolution: 0, ..Default::default() }, "--resolution"),
    ] {
        let e = format!("{:#}", mesh(ctx, run, &MeshArgs { out: Some(run.join("bad")), ..bad }).unwrap_err());
        assert!(e.contains(what) && (what.starts_with("--") || e.contains("--voxel, --trunc, --depth-max")), "{e}");
        assert!(!run.join("bad").join("mesh_scene.ply").exists());
    }
}
