//! Initial Gaussians (method-notes §1.12): from dataset points (SfM or
//! points3d.ply) or uniform random points in a cube; isotropic scale from
//! the mean squared distance to the 3 nearest neighbours, random rotation,
//! opacity 0.1, SH DC from the point colour, higher SH zero.

use super::knn::knn3_mean_sq;
use crate::data::Points;
use tgs_pipelines::Rng;
use tgs_pipelines::{Camera, HostGaussians};

pub const SH_C0: f32 = 0.282_094_8;

/// `n` uniform points in [-half, half]^3 with grey-ish colours (2DGS: SH DC
/// = U(0, 1) / 255).
pub fn random_points(n: u32, half: f32, rng: &mut Rng) -> Points {
    let mut p = Points::default();
    for _ in 0..n {
        p.positions.push([0; 3].map(|_: i32| (rng.uniform() * 2.0 - 1.0) * half));
        let c = [0; 3].map(|_: i32| rng.uniform() / 255.0 * SH_C0 + 0.5);
        p.colors.push(c);
    }
    p
}

/// `n` points in the far field of the training `cameras`: beyond the cube
/// [-half, half]^3 that [`random_points`] fills and beyond the camera sphere
/// `(centre, radius)` (the training cameras' extent), each on a random
/// pixel's ray of a random view, at a view depth uniform in inverse depth
/// between where the ray leaves both and `far`, so that near and far get as
/// many points per pixel footprint. Nothing is placed among the cameras: a
/// view on a ring of cameras sees the ring's far side as background, and
/// Gaussians that paint it there sit in front of any new view taken from
/// the ring. Colours as in [`random_points`]. Deterministic in `rng`.
pub fn far_points(n: u32, cameras: &[Camera], half: f32, sphere: ([f32; 3], f32), far: f32, rng: &mut Rng) -> Points {
    let mut p = Points::default();
    if cameras.is_empty() || !(far > 0.0) {
        return p;
    }
    let mut tries = 0u64;
    while p.positions.len() < n as usize && tries < 64 * n as u64 + 64 {
        tries += 1;
        let cam = &cameras[((rng.uniform() * cameras.len() as f32) as usize).min(cameras.len() - 1)];
        let (u, v) = (rng.uniform() * cam.width as f32 - 0.5, rng.uniform() * cam.height as f32 - 0.5);
        let (o, one) = (cam.centre(), cam.unproject(u, v, 1.0));
        // Ray o + z d, z the view depth.
        let d = [one[0] - o[0], one[1] - o[1], one[2] - o[2]];
        let cube = cube_exit(o, d, half).unwrap_or_else(|| (o[0] * o[0] + o[1] * o[1] + o[2] * o[2]).sqrt());
        let near = sphere_exit(o, d, sphere).map_or(cube, |s| s.max(cube));
        let r = rng.uniform();
        if !(near > 0.0 && far > near) {
            continue;
        }
        let z = 1.0 / (1.0 / far + r * (1.0 / near - 1.0 / far));
        let x = [0, 1, 2].map(|k| o[k] + z * d[k]);
        let inside = (0..3).map(|k| (x[k] - sphere.0[k]).powi(2)).sum::<f32>() < sphere.1 * sphere.1;
        if inside || x.iter().all(|c| c.abs() <= half) || x.iter().any(|c| !c.is_finite()) {
            continue;
        }
        p.positions.push(x);
        p.colors.push([0; 3].map(|_: i32| rng.uniform() / 255.0 * SH_C0 + 0.5));
    }
    p
}

/// Where the ray o + t d (t > 0) leaves the sphere (centre, radius), if it meets it.
fn sphere_exit(o: [f32; 3], d: [f32; 3], (c, r): ([f32; 3], f32)) -> Option<f32> {
    let oc = [0, 1, 2].map(|k| (o[k] - c[k]) as f64);
    let d = d.map(|v| v as f64);
    let a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    let b = oc[0] * d[0] + oc[1] * d[1] + oc[2] * d[2];
    let q = oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2] - (r as f64) * (r as f64);
    let disc = b * b - a * q;
    if !(a > 0.0) || !(disc >= 0.0) {
        return None;
    }
    let t = (-b + disc.sqrt()) / a;
    (t > 0.0 && t.is_finite()).then_some(t as f32)
}

/// Where the ray o + t d (t > 0) leaves the cube [-half, half]^3, if it meets it.
fn cube_exit(o: [f32; 3], d: [f32; 3], half: f32) -> Option<f32> {
    let (mut t0, mut t1) = (0.0f32, f32::INFINITY);
    for k in 0..3 {
        if d[k] == 0.0 {
            if o[k].abs() > half {
                return None;
            }
            continue;
        }
        let (a, b) = ((-half - o[k]) / d[k], (half - o[k]) / d[k]);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    (t0 <= t1 && t1.is_finite()).then_some(t1)
}

pub fn gaussians_from_points(points: &Points, sh_degree: u32, rng: &mut Rng) -> HostGaussians {
    let k = (sh_degree + 1) * (sh_degree + 1);
    let mut g = HostGaussians::new(3, k);
    let d2 = knn3_mean_sq(&points.positions);
    let raw_opacity = (0.1f32 / 0.9).ln();
    for (i, (p, c)) in points.positions.iter().zip(&points.colors).enumerate() {
        let s = d2[i].max(1e-7).sqrt().ln();
        let mut feats = vec![0.0f32; (3 * k) as usize];
        for ch in 0..3 {
            feats[ch] = (c[ch] - 0.5) / SH_C0;
        }
        let q = [rng.uniform(), rng.uniform(), rng.uniform(), rng.uniform()];
        g.push(*p, [s, s], q, raw_opacity, &feats);
    }
    g
}

/// Device bytes per trained Gaussian beyond its four copies of the
/// parameters (values, gradients, two Adam moments): the densification
/// statistics and a frame's per-Gaussian projection and sort records, a
/// generous bound.
const FRAME_BYTES_PER_GAUSSIAN: u64 = 256;

/// Refuse `n` initial Gaussians at `sh_degree` before any is made when
/// they cannot fit: more than the device's memory (four copies of the
/// parameters and per-frame records) or than the host's available memory
/// (points, Gaussians, the nearest-neighbour search).
pub fn check_budget(caps: &tgs_engine::Capabilities, n: u64, sh_degree: u32, what: &str) -> anyhow::Result<()> {
    let floats = 10 + 3 * (sh_degree as u64 + 1).pow(2);
    let device = n.saturating_mul(4 * 4 * floats + FRAME_BYTES_PER_GAUSSIAN);
    let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
    if caps.device_local_bytes > 0 && device > caps.device_local_bytes {
        anyhow::bail!("{what}: {n} Gaussians need about {:.1} GiB of device memory, more than {}'s {:.1} GiB", gib(device), caps.device_name, gib(caps.device_local_bytes));
    }
    let host = n.saturating_mul(4 * (6 + floats) + 64);
    if let Some(avail) = host_available_bytes() {
        if host > avail {
            anyhow::bail!("{what}: {n} Gaussians need about {:.1} GiB of host memory to initialise, more than the {:.1} GiB available", gib(host), gib(avail));
        }
    }
    Ok(())
}

/// The host's available memory (Linux: MemAvailable), if known.
fn host_available_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    line.split_whitespace().nth(1)?.parse::<u64>().ok().map(|kib| kib * 1024)
}
