//! The coloured-spheres scene of the Brush timings in DEVELOPERS.md, ported
//! from `../shared/bench/gen_spheres.py`: five Lambert-shaded spheres with
//! stripes on black, cameras on the upper hemisphere at radius 4 looking at
//! the origin (field of view 0.69 rad), and initial points on the spheres
//! (count by area, colour x 200/255). It is the workload of the training
//! benchmark: `spheres-128` (10k points, 128²) and `spheres-256` (50k, 256²),
//! 20 training views each. Random draws use this crate's generator, not
//! numpy's, so positions differ from the Python script's; the workload
//! (sizes, counts, coverage) is the same.

use super::trace::{hit_sphere, V3};
use crate::data::blender::gl_c2w_to_w2v;
use crate::data::image_io::{write_png, ImageF};
use crate::data::{Dataset, Points, View};
use crate::export::ply::write_points;
use anyhow::{bail, Context as _, Result};
use serde_json::json;
use std::path::Path;
use tgs_pipelines::Camera;
use tgs_pipelines::Rng;

/// (centre, radius, colour) of each sphere.
const SPHERES: [([f64; 3], f64, [f64; 3]); 5] = [
    ([0.0, 0.0, 0.0], 0.55, [0.9, 0.2, 0.2]),
    ([0.9, 0.3, 0.1], 0.35, [0.2, 0.8, 0.3]),
    ([-0.8, 0.2, 0.4], 0.40, [0.2, 0.3, 0.9]),
    ([0.2, -0.7, 0.6], 0.30, [0.9, 0.8, 0.1]),
    ([-0.3, 0.6, -0.7], 0.30, [0.8, 0.3, 0.9]),
];

/// Image size, view counts, initial points and horizontal field of view.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpheresSpec {
    pub width: u32,
    pub height: u32,
    pub train: u32,
    pub test: u32,
    pub points: u32,
    pub fov_x: f64,
}

impl SpheresSpec {
    /// Brush's two workloads.
    pub const NAMED: [(&'static str, SpheresSpec); 2] = [
        ("spheres-128", SpheresSpec { width: 128, height: 128, train: 20, test: 4, points: 10_000, fov_x: 0.69 }),
        ("spheres-256", SpheresSpec { width: 256, height: 256, train: 20, test: 4, points: 50_000, fov_x: 0.69 }),
    ];

    pub fn named(name: &str) -> Option<SpheresSpec> {
        Self::NAMED.iter().find(|(n, _)| *n == name).map(|(_, s)| *s)
    }

    fn validate(&self) -> Result<()> {
        if self.width == 0 || self.height == 0 || self.train == 0 || self.points == 0 {
            bail!(
                "spheres scene: width, height, training views and points must be at least 1 (width {}, height {}, {} training views, {} points)",
                self.width,
                self.height,
                self.train,
                self.points
            );
        }
        // The images are rendered in host memory (f32 RGB) before anything
        // else: refuse sizes that cannot fit rather than abort mid-way.
        let bytes = 12 * self.width as u64 * self.height as u64 * (self.train as u64 + self.test as u64) + 24 * self.points as u64;
        if self.width > 16384 || self.height > 16384 || bytes > 16 << 30 {
            bail!(
                "spheres scene: {}x{} with {} views and {} points needs {:.1} GiB of host memory (at most 16384 pixels a side and 16 GiB)",
                self.width,
                self.height,
                self.train + self.test,
                self.points,
                bytes as f64 / (1u64 << 30) as f64
            );
        }
        if !(self.fov_x > 0.0 && self.fov_x < std::f64::consts::PI) {
            bail!("spheres scene: field of view {} is not in (0, pi)", self.fov_x);
        }
        Ok(())
    }
}

/// Camera positions: a jittered Fibonacci spiral over the upper hemisphere.
fn positions(n: u32, radius: f64, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|k| {
            let phi = k as f64 * 2.399963 + (rng.uniform() as f64 * 0.2 - 0.1);
            let zf = 0.1 + 0.8 * (k as f64 + 0.5) / n as f64;
            let rr = (1.0 - zf * zf).sqrt();
            [radius * rr * phi.cos(), radius * rr * phi.sin(), radius * zf]
        })
        .collect()
}

/// Blender/OpenGL camera-to-world looking at the origin, z up.
fn look_at_c2w(pos: [f64; 3]) -> [[f64; 4]; 4] {
    let z = V3::from(pos).normalize(); // the camera looks down -z, at the origin
    let up = if V3::Z.dot(z).abs() > 0.99 { V3::Y } else { V3::Z };
    let x = up.cross(z).normalize();
    let y = z.cross(x);
    [[x[0], y[0], z[0], pos[0]], [x[1], y[1], z[1], pos[1]], [x[2], y[2], z[2], pos[2]], [0.0, 0.0, 0.0, 1.0]]
}

/// Render one view (one ray through each pixel centre, RGB on black).
fn render(c2w: &[[f64; 4]; 4], width: u32, height: u32, fov_x: f64) -> ImageF {
    let f = 0.5 * width as f64 / (0.5 * fov_x).tan();
    let light = V3::new(0.5, 0.8, 0.6).normalize();
    let o = V3::new(c2w[0][3], c2w[1][3], c2w[2][3]);
    let mut img = ImageF::new(width, height, 3);
    let (half_w, half_h) = (width as f64 / 2.0, height as f64 / 2.0);
    for i in 0..height {
        for j in 0..width {
            let dc = V3::new((j as f64 + 0.5 - half_w) / f, -(i as f64 + 0.5 - half_h) / f, -1.0);
            let d = V3::from([0, 1, 2].map(|r| V3::new(c2w[r][0], c2w[r][1], c2w[r][2]).dot(dc))).normalize();
            let mut best = f64::INFINITY;
            let mut col = [0.0; 3];
            for (c, r, rgb) in SPHERES {
                // The camera is outside every sphere: the nearer hit is the entry.
                let Some(&t) = hit_sphere(V3::from(c), r, o, d).first() else { continue };
                if t >= best {
                    continue;
                }
                best = t;
                let n = V3::from([0, 1, 2].map(|k| (o[k] + d[k] * t - c[k]) / r));
                let shade = 0.25 + 0.75 * n.dot(light).clamp(0.0, 1.0);
                let stripes = 0.85 + 0.15 * (12.0 * n[2]).sin().signum();
                col = rgb.map(|v| v * shade * stripes);
            }
            let p = (i as usize * width as usize + j as usize) * 3;
            for k in 0..3 {
                img.data[p + k] = col[k].clamp(0.0, 1.0) as f32;
            }
        }
    }
    img
}

/// `n` points on the spheres' surfaces, each sphere drawn by its area.
fn points(n: u32, seed: u64) -> Points {
    let mut rng = Rng::new(seed);
    let areas: Vec<f64> = SPHERES.iter().map(|s| s.1 * s.1).collect();
    let total: f64 = areas.iter().sum();
    let mut pts = Points::default();
    for _ in 0..n {
        let mut u = rng.uniform() as f64 * total;
        let s = areas.iter().position(|&a| {
            u -= a;
            u < 0.0
        });
        let (c, r, rgb) = SPHERES[s.unwrap_or(SPHERES.len() - 1)];
        // Uniform on the unit sphere: z uniform in [-1, 1], angle uniform.
        let z = rng.uniform() as f64 * 2.0 - 1.0;
        let a = rng.uniform() as f64 * std::f64::consts::TAU;
        let rr = (1.0 - z * z).max(0.0).sqrt();
        let v = [rr * a.cos(), rr * a.sin(), z];
        pts.positions.push([0, 1, 2].map(|k| (c[k] + r * v[k]) as f32));
        // The script stores uint8(rgb * 200).
        pts.colors.push(rgb.map(|x| (x * 200.0).floor() as f32 / 255.0));
    }
    pts
}

/// The views of one split: (file stem, camera-to-world, image).
fn split(spec: &SpheresSpec, test: bool) -> Vec<(String, [[f64; 4]; 4], ImageF)> {
    let (n, seed, name) = if test { (spec.test, 2, "test") } else { (spec.train, 1, "train") };
    positions(n, 4.0, seed)
        .into_iter()
        .enumerate()
        .map(|(k, pos)| {
            let c2w = look_at_c2w(pos);
            (format!("{name}/r_{k}"), c2w, render(&c2w, spec.width, spec.height, spec.fov_x))
        })
        .collect()
}

fn camera(spec: &SpheresSpec, c2w: &[[f64; 4]; 4]) -> Camera {
    let f = (0.5 * spec.width as f64 / (0.5 * spec.fov_x).tan()) as f32;
    let (cx, cy) = (spec.width as f32 * 0.5 - 0.5, spec.height as f32 * 0.5 - 0.5);
    Camera { width: spec.width, height: spec.height, fx: f, fy: f, cx, cy, world_to_view: gl_c2w_to_w2v(c2w) }
}

/// The scene as an in-memory dataset (black background), without files.
pub fn dataset(spec: &SpheresSpec) -> Result<Dataset> {
    spec.validate()?;
    let views = |test: bool| -> Vec<View> {
        split(spec, test)
            .into_iter()
            .map(|(stem, c2w, image)| View { name: stem.rsplit('/').next().unwrap_or(&stem).to_string(), camera: camera(spec, &c2w), image, normals: None, mask: None })
            .collect()
    };
    Ok(Dataset {
        root: "spheres (in memory)".into(),
        format: "spheres",
        train: views(false),
        test: views(true),
        points: Some(points(spec.points, 3)),
        background: [0.0; 3],
        files: Vec::new(),
        warnings: Vec::new(),
    })
}

/// Write the scene in the Blender layout (RGB PNGs on black, transforms,
/// points3d.ply) into `dir`.
pub fn write(spec: &SpheresSpec, dir: &Path, mut progress: impl FnMut(u32, u32)) -> Result<()> {
    spec.validate()?;
    let total = spec.train + spec.test;
    let mut done = 0;
    for (name, test) in [("train", false), ("test", true)] {
        std::fs::create_dir_all(dir.join(name)).with_context(|| format!("{}: cannot create", dir.join(name).display()))?;
        let mut frames = Vec::new();
        for (stem, c2w, image) in split(spec, test) {
            write_png(&dir.join(format!("{stem}.png")), &image)?;
            frames.push(json!({ "file_path": format!("./{stem}"), "transform_matrix": c2w }));
            done += 1;
            progress(done, total);
        }
        let path = dir.join(format!("transforms_{name}.json"));
        crate::export::atomic_write(&path, serde_json::to_string_pretty(&json!({ "camera_angle_x": spec.fov_x, "frames": frames }))?.as_bytes())?;
    }
    write_points(&dir.join("points3d.ply"), &points(spec.points, 3))
}
