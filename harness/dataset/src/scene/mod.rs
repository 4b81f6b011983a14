//! The built-in procedural transmissive scene, rendered on the CPU and
//! written in the dataset format of docs/dataset-format.md (Blender layout,
//! per-frame normals `.npy` and transmissive masks), plus a `points3d.ply`
//! of visible surface points (what SfM would give) for initialisation.

pub mod spheres;
pub mod trace;

use crate::data::image_io::{write_mask, write_npy, write_png, ImageF};
use crate::data::Points;
use crate::export::ply::write_points;
use anyhow::{bail, Context as _, Result};
use serde_json::json;
use std::path::Path;
use trace::{Material, Scene, V3};

/// A named size of the built-in scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneSpec {
    pub name: &'static str,
    pub size: u32,
    pub train: u32,
    pub test: u32,
    pub points: u32,
    /// The glass sphere (false: the same room without it, a diffuse scene).
    pub glass: bool,
}

pub const SCENES: [SceneSpec; 3] = [
    SceneSpec { name: "glass", size: 64, train: 32, test: 8, points: 4000, glass: true },
    SceneSpec { name: "glass-tiny", size: 48, train: 16, test: 4, points: 2000, glass: true },
    SceneSpec { name: "diffuse", size: 64, train: 32, test: 8, points: 4000, glass: false },
];

pub fn spec(name: &str) -> Result<SceneSpec> {
    match SCENES.iter().find(|s| s.name == name) {
        Some(s) => Ok(*s),
        None => {
            bail!("unknown scene '{name}' (built-in: {}, {})", SCENES.iter().map(|s| s.name).collect::<Vec<_>>().join(", "), spheres::SpheresSpec::NAMED.map(|s| s.0).join(", "))
        }
    }
}

const FOV_X: f64 = 0.9;
const TARGET: V3 = V3::new(0.0, 0.0, 0.55);

/// Camera `i` of `n` on the ring (test views sit between train views).
fn eye(i: u32, n: u32, test: bool) -> V3 {
    let a = (i as f64 + if test { 0.5 } else { 0.0 }) * std::f64::consts::TAU / n as f64;
    let h = if i.is_multiple_of(2) { 1.15 } else { 1.65 };
    let r = if test { 2.5 } else { 2.7 };
    V3::new(r * a.cos(), r * a.sin(), h)
}

/// Camera basis at `e` looking at TARGET, z up: (forward, right, up).
fn basis(e: V3) -> (V3, V3, V3) {
    let f = (TARGET - e).normalize();
    let r = f.cross(V3::Z).normalize();
    (f, r, r.cross(f))
}

struct View {
    rgb: ImageF,
    normals: ImageF,
    mask: Vec<bool>,
    c2w: [[f64; 4]; 4],
}

/// Render one view: 2x2 samples per pixel for colour; normals at the pixel
/// centre (world, facing the camera; 0 on background); mask where all four
/// samples first hit glass.
fn render(scene: &Scene, e: V3, size: u32) -> View {
    let (f, r, u) = basis(e);
    let focal = 0.5 * size as f64 / (0.5 * FOV_X).tan();
    let c = 0.5 * size as f64;
    let dir = |x: f64, y: f64| (r * ((x - c) / focal) + u * (-(y - c) / focal) + f).normalize();
    let mut rgb = ImageF::new(size, size, 3);
    let mut normals = ImageF::new(size, size, 3);
    let mut mask = vec![false; (size * size) as usize];
    for y in 0..size {
        for x in 0..size {
            let i = (y * size + x) as usize;
            let mut acc = V3::ZERO;
            let mut all_glass = true;
            for s in 0..4 {
                let d = dir(x as f64 + 0.25 + 0.5 * (s % 2) as f64, y as f64 + 0.25 + 0.5 * (s / 2) as f64);
                acc += scene.radiance(e, d, 6);
                all_glass &= scene.intersect(e, d, f64::INFINITY, true).is_some_and(|h| h.mat == Material::Glass);
            }
            for k in 0..3 {
                rgb.data[3 * i + k] = (acc[k] / 4.0) as f32;
            }
            let d = dir(x as f64 + 0.5, y as f64 + 0.5);
            if let Some(h) = scene.intersect(e, d, f64::INFINITY, true) {
                let n = if h.n.dot(d) > 0.0 { -h.n } else { h.n };
                for k in 0..3 {
                    normals.data[3 * i + k] = n[k] as f32;
                }
            }
            mask[i] = all_glass;
        }
    }
    let c2w = [[r[0], u[0], -f[0], e[0]], [r[1], u[1], -f[1], e[1]], [r[2], u[2], -f[2], e[2]], [0.0, 0.0, 0.0, 1.0]];
    View { rgb, normals, mask, c2w }
}

/// Visible surface points with their colours, from rays through random
/// pixels of the training cameras (deterministic).
fn surface_points(scene: &Scene, spec: &SceneSpec) -> Points {
    let mut pts = Points::default();
    let mut state = 0x1234_5678_9ABC_DEF0u64;
    let mut next = || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for k in 0..spec.points {
        let e = eye(k % spec.train, spec.train, false);
        let (f, r, u) = basis(e);
        let t = (0.5 * FOV_X).tan();
        let d = (r * ((2.0 * next() - 1.0) * t) + u * ((2.0 * next() - 1.0) * t) + f).normalize();
        if let Some(h) = scene.intersect(e, d, f64::INFINITY, true) {
            let c = scene.radiance(e, d, 6);
            pts.positions.push(h.p.as_vec3().to_array());
            pts.colors.push(c.as_vec3().to_array());
        }
    }
    pts
}

/// Write the scene `spec` as a dataset into `dir` (see [`write_new_dir`]).
pub fn make(spec: &SceneSpec, dir: &Path, progress: impl FnMut(u32, u32)) -> Result<()> {
    write_new_dir(dir, |partial| write_dataset(spec, partial, progress))
}

/// Fill a new directory `dir`, which must not exist or be empty (files in it
/// are never overwritten). `fill` writes into a sibling `DIR.tgs-partial`
/// directory that is renamed to `dir` when complete, so an interrupted run
/// never leaves a half-written dataset.
pub fn write_new_dir(dir: &Path, fill: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    if dir.exists() {
        let mut entries = std::fs::read_dir(dir).with_context(|| format!("{}: exists and is not a readable directory", dir.display()))?;
        if entries.next().is_some() {
            bail!("{}: the directory is not empty; choose a new or empty one (tgs never overwrites a dataset)", dir.display());
        }
    }
    let name = dir.file_name().with_context(|| format!("{}: not a directory path", dir.display()))?;
    let mut partial = name.to_os_string();
    partial.push(".tgs-partial");
    let partial = dir.with_file_name(partial);
    if partial.exists() {
        std::fs::remove_dir_all(&partial).with_context(|| format!("{}: cannot remove a previous partial write", partial.display()))?;
    }
    std::fs::create_dir_all(&partial).with_context(|| format!("{}: cannot create", partial.display()))?;
    fill(&partial)?;
    if dir.exists() {
        std::fs::remove_dir(dir).with_context(|| format!("{}: cannot replace the empty directory", dir.display()))?;
    }
    std::fs::rename(&partial, dir).with_context(|| format!("{}: cannot move {} into place", dir.display(), partial.display()))?;
    crate::export::sync_dir(dir)
}

/// Write the built-in scene called `name` (`glass`, `glass-tiny`, `diffuse`,
/// `spheres-128`, `spheres-256`) into the new directory `dir`.
pub fn make_named(name: &str, dir: &Path, progress: impl FnMut(u32, u32)) -> Result<()> {
    match spheres::SpheresSpec::named(name) {
        Some(s) => write_new_dir(dir, |p| spheres::write(&s, p, progress)),
        None => make(&spec(name)?, dir, progress),
    }
}

/// One line per built-in scene: name, size, views.
pub fn list() -> Vec<String> {
    let mut out: Vec<String> = SCENES
        .iter()
        .map(|s| {
            format!(
                "{:12} {}x{} px, {} train + {} test views, {}",
                s.name,
                s.size,
                s.size,
                s.train,
                s.test,
                if s.glass { "glass sphere in a room" } else { "the same room without the glass (diffuse only)" }
            )
        })
        .collect();
    for (name, s) in spheres::SpheresSpec::NAMED {
        out.push(format!("{name:12} {}x{} px, {} train + {} test views, {} initial points (Brush's workload)", s.width, s.height, s.train, s.test, s.points));
    }
    out
}

fn write_dataset(spec: &SceneSpec, dir: &Path, mut progress: impl FnMut(u32, u32)) -> Result<()> {
    let mut scene = Scene::new();
    scene.glass = spec.glass;
    let total = spec.train + spec.test;
    let mut done = 0;
    for (split, n, test) in [("train", spec.train, false), ("test", spec.test, true)] {
        std::fs::create_dir_all(dir.join(split)).with_context(|| format!("{}: cannot create", dir.join(split).display()))?;
        let mut frames = Vec::new();
        for i in 0..n {
            let v = render(&scene, eye(i, n, test), spec.size);
            let stem = format!("{split}/r_{i}");
            write_png(&dir.join(format!("{stem}.png")), &v.rgb)?;
            write_npy(&dir.join(format!("{stem}_normal.npy")), &v.normals)?;
            write_mask(&dir.join(format!("{stem}_mask.png")), spec.size, spec.size, &v.mask)?;
            frames.push(json!({
                "file_path": format!("./{stem}"),
                "transform_matrix": v.c2w,
                "normal_path": format!("./{stem}_normal.npy"),
                "mask_path": format!("./{stem}_mask.png"),
            }));
            done += 1;
            progress(done, total);
        }
        let doc = json!({ "camera_angle_x": FOV_X, "frames": frames });
        let path = dir.join(format!("transforms_{split}.json"));
        std::fs::write(&path, serde_json::to_string_pretty(&doc)?).with_context(|| format!("{}: cannot write", path.display()))?;
    }
    write_points(&dir.join("points3d.ply"), &surface_points(&scene, spec))?;
    Ok(())
}
