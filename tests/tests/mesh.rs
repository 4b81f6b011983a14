//! TSDF fusion and mesh extraction (`tgs mesh`): the GPU fusion against its
//! f64 reference on exact depth maps of a sphere, bit-identical reruns, a
//! closed, outward-facing mesh near the true sphere, the PLY round trip, and
//! the hard cases (nothing seen, a 1x1 view, a camera facing away, depths
//! past the limit, a grid of one voxel, grids too large or malformed).
//! End to end on a trained run: tests/tests/train_stage2.rs.

use std::collections::HashMap;
use tgs::mesh::{extract, ply, Mesh};
use tgs_engine::{Buffer, Recorder};
use tgs_pipelines::{Camera, HostTsdf, TsdfFusion, TsdfGrid};
use tgs_tests::tsdf_ref::{compare, fuse as fuse_ref, RefView};
use tgs_tests::{check_validation, ctx_shared};

const CENTRE: [f64; 3] = [0.1, -0.2, 0.3];
const RADIUS: f64 = 0.5;

/// Views from `n` directions spread over the sphere (a Fibonacci lattice),
/// 2.2 from the centre, looking at it.
fn cameras(n: usize, size: u32) -> Vec<Camera> {
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let a = i as f64 * 2.399_963_229_728_653;
            let s = (1.0 - z * z).sqrt();
            let dir = [s * a.cos(), s * a.sin(), z];
            let eye = [0, 1, 2].map(|k| (CENTRE[k] + 2.2 * dir[k]) as f32);
            let up = if z.abs() > 0.9 { [0.0, 1.0, 0.0] } else { [0.0, 0.0, 1.0] };
            Camera::look_at(eye, CENTRE.map(|v| v as f32), up, 0.8, size, size)
        })
        .collect()
}

/// Exact view depth of the sphere at each pixel centre (0 on a miss), a
/// weight of 1 where it is hit, and the hit normal as colour.
fn sphere_view(cam: &Camera) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let m = cam.world_to_view.map(|r| r.map(f64::from));
    let e = cam.centre().map(f64::from);
    let (mut depth, mut weight, mut colour) = (vec![0f32; w * h], vec![0f32; w * h], vec![0f32; 3 * w * h]);
    for i in 0..w * h {
        let dv = [((i % w) as f64 - cam.cx as f64) / cam.fx as f64, ((i / w) as f64 - cam.cy as f64) / cam.fy as f64, 1.0];
        let d: [f64; 3] = std::array::from_fn(|j| (0..3).map(|k| m[k][j] * dv[k]).sum());
        let oc: [f64; 3] = std::array::from_fn(|k| e[k] - CENTRE[k]);
        let (a, b, c) = (d.iter().map(|v| v * v).sum::<f64>(), d.iter().zip(&oc).map(|(x, y)| x * y).sum::<f64>(), oc.iter().map(|v| v * v).sum::<f64>() - RADIUS * RADIUS);
        let disc = b * b - a * c;
        if disc < 0.0 {
            continue;
        }
        let t = (-b - disc.sqrt()) / a;
        depth[i] = t as f32;
        weight[i] = 1.0;
        for k in 0..3 {
            colour[k * w * h + i] = (0.5 + 0.5 * (oc[k] + t * d[k]) / RADIUS) as f32;
        }
    }
    (depth, weight, colour)
}

fn sphere_grid(dims: u32) -> TsdfGrid {
    let side = 1.5f32;
    let voxel = side / dims as f32;
    TsdfGrid { origin: CENTRE.map(|c| c as f32 - 0.5 * side), voxel, dims: [dims; 3], trunc: 3.0 * voxel, depth_max: f32::INFINITY }
}

/// A view to fuse: its camera, depth, weight and colour planes.
type DepthView = (Camera, Vec<f32>, Vec<f32>, Vec<f32>);

/// Fuse `views` on the GPU.
fn fuse_gpu(grid: TsdfGrid, views: &[DepthView]) -> HostTsdf {
    let ctx = ctx_shared();
    let fusion = TsdfFusion::new(ctx).unwrap();
    let vol = fusion.volume(grid, 1 << 30).unwrap();
    for (cam, d, w, c) in views {
        let (d, w, c) = (Buffer::from_slice(ctx, "d", d).unwrap(), Buffer::from_slice(ctx, "w", w).unwrap(), Buffer::from_slice(ctx, "c", c).unwrap());
        let mut rec = Recorder::new(ctx).unwrap();
        fusion.record(&mut rec, &vol, cam, &d, &w, &c).unwrap();
        rec.submit_and_wait().unwrap();
    }
    vol.download().unwrap()
}

fn sphere_views(n: usize, size: u32) -> Vec<DepthView> {
    cameras(n, size)
        .into_iter()
        .map(|c| {
            let (d, w, col) = sphere_view(&c);
            (c, d, w, col)
        })
        .collect()
}

fn bits(v: &HostTsdf) -> Vec<u32> {
    v.tsdf.iter().chain(&v.weight).chain(v.rgb.iter().flatten()).map(|x| x.to_bits()).collect()
}

fn distance(p: [f32; 3]) -> f64 {
    ((0..3).map(|k| (p[k] as f64 - CENTRE[k]).powi(2)).sum::<f64>().sqrt() - RADIUS).abs()
}

/// Every undirected edge in exactly two triangles, once in each direction.
fn closed_and_consistent(m: &Mesh) -> Result<(), String> {
    let mut uses: HashMap<(u32, u32), i32> = HashMap::new();
    for t in &m.triangles {
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            *uses.entry((a.min(b), a.max(b))).or_default() += if a < b { 1 } else { -1 };
        }
    }
    let mut count: HashMap<(u32, u32), u32> = HashMap::new();
    for t in &m.triangles {
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let open = count.values().filter(|&&c| c != 2).count();
    let flipped = uses.values().filter(|&&s| s != 0).count();
    if open > 0 || flipped > 0 {
        return Err(format!("{open} edges not in exactly two triangles, {flipped} used twice in one direction, of {}", count.len()));
    }
    Ok(())
}

#[test]
fn fusion_matches_the_f64_reference_and_meshes_the_sphere() {
    let grid = sphere_grid(30);
    let views = sphere_views(20, 40);
    let gpu = fuse_gpu(grid, &views);
    assert!(gpu.tsdf.iter().chain(&gpu.weight).chain(gpu.rgb.iter().flatten()).all(|v| v.is_finite()));
    let refs: Vec<RefView> = views.iter().map(|(c, d, w, col)| RefView { camera: *c, depth: d, weight: w, colour: col }).collect();
    let r = fuse_ref(&grid, &refs);
    let (dt, dw, dc, compared) = compare(&gpu, &r);
    let n = r.tsdf.len();
    eprintln!("compared {compared} of {n} voxels: max |dT| {dt:.2e}, |dW| {dw:.2e}, |dC| {dc:.2e}");
    assert!(compared as f64 > 0.98 * n as f64, "only {compared} of {n} voxels unambiguous");
    assert!(dt < 1e-5 && dw == 0.0 && dc < 1e-5, "GPU fusion differs from the f64 reference: {dt:.2e} {dw:.2e} {dc:.2e}");
    assert!(r.weight.iter().filter(|&&w| w > 0.0).count() > n / 4, "the views should observe much of the grid");
    // Bit-identical on a rerun.
    assert_eq!(bits(&fuse_gpu(grid, &views)), bits(&gpu));

    let mesh = extract(&gpu, grid.origin, grid.voxel, 0.0);
    assert!(mesh.triangles.len() > 1000, "{} triangles", mesh.triangles.len());
    let d: Vec<f64> = mesh.positions.iter().map(|&p| distance(p)).collect();
    let (mean, max) = (d.iter().sum::<f64>() / d.len() as f64, d.iter().cloned().fold(0.0, f64::max));
    eprintln!(
        "sphere mesh: {} vertices, {} triangles; distance to the sphere mean {:.4} max {:.4} (voxel {:.4})",
        mesh.positions.len(),
        mesh.triangles.len(),
        mean,
        max,
        grid.voxel
    );
    // Measured: mean 0.13, max 0.56 voxels (the projective distance, the
    // nearest pixel's depth and linear interpolation on the edges).
    assert!(mean < 0.2 * grid.voxel as f64 && max < 0.75 * grid.voxel as f64, "mean {mean} max {max}");
    closed_and_consistent(&mesh).unwrap();
    // Outward: every face's normal points away from the centre.
    for t in &mesh.triangles {
        let p = t.map(|i| mesh.positions[i as usize].map(f64::from));
        let (u, v) = ([0, 1, 2].map(|k| p[1][k] - p[0][k]), [0, 1, 2].map(|k| p[2][k] - p[0][k]));
        let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        let c = [0, 1, 2].map(|k| (p[0][k] + p[1][k] + p[2][k]) / 3.0 - CENTRE[k]);
        assert!(n[0] * c[0] + n[1] * c[1] + n[2] * c[2] > 0.0, "a face points inwards");
    }
    // Colours are the fused normals' colours: close to the vertex's own.
    let worst = mesh
        .positions
        .iter()
        .zip(&mesh.colors)
        .map(|(p, c)| {
            let l = (0..3).map(|k| (p[k] as f64 - CENTRE[k]).powi(2)).sum::<f64>().sqrt();
            (0..3).map(|k| (c[k] as f64 - (0.5 + 0.5 * (p[k] as f64 - CENTRE[k]) / l)).abs()).fold(0.0, f64::max)
        })
        .fold(0.0, f64::max);
    assert!(worst < 0.15, "vertex colour off by {worst}");
    // The extraction is a function of the grid.
    assert_eq!(extract(&gpu, grid.origin, grid.voxel, 0.0), mesh);

    // PLY round trip (colours to 8 bits).
    let dir = tgs_tests::TempDir::new("mesh-ply");
    std::fs::create_dir_all(&*dir).unwrap();
    let path = dir.join("m.ply");
    ply::write_mesh(&path, &mesh).unwrap();
    let back = ply::read_mesh(&path).unwrap();
    assert_eq!((back.positions.clone(), back.triangles.clone()), (mesh.positions.clone(), mesh.triangles.clone()));
    assert!(back.colors.iter().zip(&mesh.colors).all(|(a, b)| (0..3).all(|k| (a[k] - b[k]).abs() <= 0.5 / 255.0 + 1e-6)));
    // A torn file is refused, naming it.
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() - 5]).unwrap();
    let e = format!("{:#}", ply::read_mesh(&path).unwrap_err());
    assert!(e.contains("m.ply") && e.contains("expected"), "{e}");
    check_validation(ctx_shared());
}

#[test]
fn hard_cases_leave_the_grid_finite_and_are_refused_with_their_sizes() {
    let ctx = ctx_shared();
    let grid = sphere_grid(12);
    let cams = cameras(4, 16);
    // A view that sees nothing: the grid stays empty, the mesh too.
    let empty = (cams[0], vec![0f32; 256], vec![0f32; 256], vec![0f32; 768]);
    let g = fuse_gpu(grid, std::slice::from_ref(&empty));
    assert!(g.weight.iter().all(|&w| w == 0.0) && g.tsdf.iter().all(|&t| t == 0.0));
    assert!(extract(&g, grid.origin, grid.voxel, 0.0).triangles.is_empty());
    // Weight but no depth (0), NaN and infinite depths: nothing fused, nothing NaN.
    let bad = (cams[1], (0..256).map(|i| [0.0, f32::NAN, f32::INFINITY, -1.0][i % 4]).collect(), vec![1f32; 256], vec![0.5f32; 768]);
    let g = fuse_gpu(grid, &[bad]);
    assert!(g.weight.iter().all(|&w| w == 0.0) && g.tsdf.iter().all(|t| t.is_finite()));
    // A 1x1 view with the sphere's depth at its centre.
    let one = Camera { width: 1, height: 1, fx: 1.0, fy: 1.0, cx: 0.0, cy: 0.0, ..cams[2] };
    let (d, w, c) = sphere_view(&one);
    assert!(w[0] == 1.0);
    let g = fuse_gpu(grid, &[(one, d.clone(), w.clone(), c.clone())]);
    assert!(g.weight.iter().any(|&w| w > 0.0) && g.tsdf.iter().chain(&g.rgb[0]).all(|v| v.is_finite()));
    let r = fuse_ref(&grid, &[RefView { camera: one, depth: &d, weight: &w, colour: &c }]);
    let (dt, dw, _, _) = compare(&g, &r);
    assert!(dt < 1e-5 && dw == 0.0);
    // A camera turned away from the grid (the sphere behind it): no update.
    // Flip the view axis through the same centre: z' = -z.
    let mut away = cams[3];
    let c = away.centre();
    let row = &mut away.world_to_view[2];
    for v in row.iter_mut().take(3) {
        *v = -*v;
    }
    row[3] = -(row[0] * c[0] + row[1] * c[1] + row[2] * c[2]);
    let g = fuse_gpu(grid, &[(away, vec![1.0; 256], vec![1.0; 256], vec![0.5; 768])]);
    assert!(g.weight.iter().all(|&w| w == 0.0));
    // Depths past depth_max are not fused.
    let (d, w, c) = sphere_view(&cams[0]);
    let g = fuse_gpu(TsdfGrid { depth_max: 1.0, ..grid }, &[(cams[0], d, w, c)]);
    assert!(g.weight.iter().all(|&w| w == 0.0), "the sphere is 1.7 away: past depth_max 1");
    // A grid of one voxel (and of one row) fuses and meshes to nothing.
    let tiny = TsdfGrid { dims: [1, 1, 1], ..grid };
    let (d, w, c) = sphere_view(&cams[0]);
    let g = fuse_gpu(tiny, &[(cams[0], d, w, c)]);
    assert_eq!(g.tsdf.len(), 1);
    assert!(extract(&g, tiny.origin, tiny.voxel, 0.0).triangles.is_empty());
    // Refusals name the sizes.
    let fusion = TsdfFusion::new(ctx).unwrap();
    let e = format!("{:#}", fusion.volume(TsdfGrid { dims: [1024, 1024, 1024], ..grid }, 2 << 30).err().unwrap());
    assert!(e.contains("1024x1024x1024") && e.contains("MiB") && e.contains("voxel"), "{e}");
    let e = format!("{:#}", fusion.volume(TsdfGrid { dims: [100, 100, 100], ..grid }, 1 << 20).err().unwrap());
    assert!(e.contains("100x100x100") && e.contains("19.1 MiB"), "{e}");
    for bad in [
        TsdfGrid { dims: [0, 4, 4], ..grid },
        TsdfGrid { voxel: 0.0, ..grid },
        TsdfGrid { voxel: f32::NAN, ..grid },
        TsdfGrid { trunc: -1.0, ..grid },
        TsdfGrid { dims: [1 << 16, 1 << 16, 2], ..grid },
    ] {
        assert!(fusion.volume(bad, u64::MAX).is_err(), "{bad:?} accepted");
    }
    // Wrong image sizes are refused.
    let vol = fusion.volume(grid, 1 << 30).unwrap();
    let small = Buffer::from_slice(ctx, "d", &[0f32; 10]).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    assert!(fusion.record(&mut rec, &vol, &cams[0], &small, &small, &small).is_err());
    check_validation(ctx);
}
