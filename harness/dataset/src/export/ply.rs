//! PLY files: the standard 3DGS/2DGS splat layout that splat viewers open
//! (x y z, nx ny nz, f_dc_0..2, f_rest_* channel-major, opacity (raw),
//! scale_0..2 (log; scale_2 is a thin third axis for 3DGS viewers, 2DGS
//! readers ignore it), rot_0..3 (w x y z)), and point clouds (x y z with
//! optional uchar red green blue) for initialisation.

use anyhow::{bail, Context as _, Result};
use std::path::Path;
use tgs_pipelines::HostGaussians;

/// Initial points with colours in [0, 1] (SfM points, points3d.ply).
#[derive(Clone, Debug, Default)]
pub struct Points {
    pub positions: Vec<[f32; 3]>,
    pub colors: Vec<[f32; 3]>,
}

/// Log of the third (normal) axis written for viewers that expect 3 scales.
pub const THIN_LOG_SCALE: f32 = -13.8;

pub fn write_splats(path: &Path, g: &HostGaussians) -> Result<()> {
    write_splats_with(path, g, &[])
}

/// [`write_splats`] with extra per-splat float properties appended (name, one value per splat).
pub fn write_splats_with(path: &Path, g: &HostGaussians, extra: &[(&str, Vec<f32>)]) -> Result<()> {
    g.validate()?;
    if let Some((name, v)) = extra.iter().find(|(_, v)| v.len() != g.len()) {
        bail!("PLY property '{name}' has {} values for {} splats", v.len(), g.len());
    }
    let c = g.channels as usize;
    let k = g.coeffs as usize;
    if c != 3 {
        bail!("splat PLY needs 3 colour channels, the set has {c}");
    }
    let rest = (k - 1) * 3;
    let mut header = String::from("ply\nformat binary_little_endian 1.0\n");
    header += &format!("element vertex {}\n", g.len());
    for p in ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] {
        header += &format!("property float {p}\n");
    }
    for i in 0..rest {
        header += &format!("property float f_rest_{i}\n");
    }
    for p in ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"] {
        header += &format!("property float {p}\n");
    }
    for (p, _) in extra {
        header += &format!("property float {p}\n");
    }
    header += "end_header\n";
    let mut out = Vec::with_capacity(header.len() + g.len() * (17 + rest + extra.len()) * 4);
    out.extend_from_slice(header.as_bytes());
    let mut put = |v: f32| out.extend_from_slice(&v.to_le_bytes());
    for i in 0..g.len() {
        let f = &g.features[i * k * c..(i + 1) * k * c];
        (0..3).for_each(|j| put(g.means[3 * i + j]));
        (0..3).for_each(|_| put(0.0));
        (0..3).for_each(|ch| put(f[ch]));
        for ch in 0..3 {
            for kk in 1..k {
                put(f[kk * c + ch]);
            }
        }
        put(g.opacity[i]);
        put(g.log_scales[2 * i]);
        put(g.log_scales[2 * i + 1]);
        put(THIN_LOG_SCALE);
        (0..4).for_each(|j| put(g.quats[4 * i + j]));
        extra.iter().for_each(|(_, v)| put(v[i]));
    }
    super::atomic_write(path, &out)
}

/// Read a splat PLY written by [`write_splats`] (or 3DGS/2DGS) back.
pub fn read_splats(path: &Path) -> Result<HostGaussians> {
    let (names, n, body) = read_binary(path)?;
    let idx = |name: &str| names.iter().position(|p| p == name).with_context(|| format!("{}: no property '{name}'", path.display()));
    let rest = names.iter().filter(|p| p.starts_with("f_rest_")).count();
    if rest % 3 != 0 {
        bail!("{}: {rest} f_rest properties is not a multiple of 3", path.display());
    }
    let k = rest / 3 + 1;
    let mut g = HostGaussians::new(3, k as u32);
    let stride = names.len();
    let (ix, idc, irest, iop, is0, is1, ir) = (idx("x")?, idx("f_dc_0")?, idx("f_rest_0").unwrap_or(0), idx("opacity")?, idx("scale_0")?, idx("scale_1")?, idx("rot_0")?);
    for i in 0..n {
        let row = &body[i * stride..(i + 1) * stride];
        let mut feats = vec![0.0; 3 * k];
        for ch in 0..3 {
            feats[ch] = row[idc + ch];
            for kk in 1..k {
                feats[kk * 3 + ch] = row[irest + ch * (k - 1) + kk - 1];
            }
        }
        g.push([row[ix], row[ix + 1], row[ix + 2]], [row[is0], row[is1]], [row[ir], row[ir + 1], row[ir + 2], row[ir + 3]], row[iop], &feats);
    }
    Ok(g)
}

/// A vertex property: name, type and byte size.
struct Property {
    name: String,
    ty: String,
    size: usize,
}

/// The vertex properties, vertex count, file bytes and the offset of the
/// body of a binary little-endian PLY (the body holds at least count x
/// stride bytes).
fn read_vertices(path: &Path) -> Result<(Vec<Property>, usize, Vec<u8>, usize)> {
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let end = bytes.windows(11).position(|w| w == b"end_header\n").with_context(|| format!("{}: not a PLY (no end_header)", path.display()))?;
    let header = std::str::from_utf8(&bytes[..end]).with_context(|| format!("{}: header is not text", path.display()))?;
    if !header.contains("format binary_little_endian") {
        bail!("{}: only binary little-endian PLY is read", path.display());
    }
    let mut n = 0usize;
    let mut props = Vec::new();
    let mut in_vertex = false;
    for l in header.lines() {
        let t: Vec<&str> = l.split_whitespace().collect();
        match t.as_slice() {
            ["element", name, c] => {
                in_vertex = *name == "vertex";
                if in_vertex {
                    n = c.parse().with_context(|| format!("{}: bad vertex count", path.display()))?;
                }
            }
            ["property", ty, name] if in_vertex => {
                let size = match *ty {
                    "float" | "float32" | "int" | "uint" | "int32" | "uint32" => 4,
                    "double" | "float64" => 8,
                    "uchar" | "uint8" | "char" | "int8" => 1,
                    "short" | "ushort" | "int16" | "uint16" => 2,
                    _ => bail!("{}: property type {ty} not supported", path.display()),
                };
                props.push(Property { name: name.to_string(), ty: ty.to_string(), size });
            }
            _ => {}
        }
    }
    let stride: usize = props.iter().map(|p| p.size).sum();
    if stride == 0 {
        bail!("{}: the vertex element has no properties", path.display());
    }
    let body = bytes.len() - (end + 11);
    // The count comes from the file: a huge one must not wrap the product.
    if n.checked_mul(stride).is_none_or(|need| body < need) {
        bail!("{}: truncated or corrupt header ({body} bytes of data for {n} vertices of {stride} bytes)", path.display());
    }
    Ok((props, n, bytes, end + 11))
}

/// Float properties of a PLY whose vertex properties are all `float`.
fn read_binary(path: &Path) -> Result<(Vec<String>, usize, Vec<f32>)> {
    let (props, n, bytes, start) = read_vertices(path)?;
    let body = &bytes[start..];
    if let Some(p) = props.iter().find(|p| p.ty != "float") {
        bail!("{}: property type {} not supported here", path.display(), p.ty);
    }
    let vals = body[..n * props.len() * 4].chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    Ok((props.into_iter().map(|p| p.name).collect(), n, vals))
}

/// Write a point cloud (x y z float, red green blue uchar).
pub fn write_points(path: &Path, pts: &Points) -> Result<()> {
    let mut out = format!("ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n", pts.positions.len()).into_bytes();
    for (p, c) in pts.positions.iter().zip(&pts.colors) {
        p.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
        c.iter().for_each(|v| out.push((v.clamp(0.0, 1.0) * 255.0).round() as u8));
    }
    super::atomic_write(path, &out)
}

/// Read x, y, z and (if present) red, green, blue from a binary PLY point
/// cloud (float or double positions, uchar colours, other properties skipped).
/// Points from a PLY (x, y, z and optional red, green, blue); points with a
/// NaN or infinite coordinate are skipped, and the second value says how
/// many (a file of nothing else is an error).
pub fn read_points(path: &Path) -> Result<(Points, usize)> {
    let (props, n, bytes, start) = read_vertices(path)?;
    let body = &bytes[start..];
    let stride: usize = props.iter().map(|p| p.size).sum();
    let find = |name: &str| -> Option<(usize, &str)> {
        let mut off = 0;
        for p in &props {
            if p.name == name {
                return Some((off, p.ty.as_str()));
            }
            off += p.size;
        }
        None
    };
    let xyz: Vec<(usize, &str)> = ["x", "y", "z"].iter().map(|a| find(a).with_context(|| format!("{}: no '{a}' property", path.display()))).collect::<Result<_>>()?;
    let rgb: Option<Vec<(usize, &str)>> = ["red", "green", "blue"].iter().map(|a| find(a)).collect();
    let mut pts = Points::default();
    let mut skipped = 0usize;
    for i in 0..n {
        let row = &body[i * stride..(i + 1) * stride];
        let read = |(off, ty): (usize, &str)| -> f32 {
            match ty {
                "double" | "float64" => f64::from_le_bytes(row[off..off + 8].try_into().unwrap()) as f32,
                "uchar" | "uint8" => row[off] as f32 / 255.0,
                _ => f32::from_le_bytes(row[off..off + 4].try_into().unwrap()),
            }
        };
        let p = [read(xyz[0]), read(xyz[1]), read(xyz[2])];
        if !p.iter().all(|v| v.is_finite()) {
            skipped += 1;
            continue;
        }
        pts.positions.push(p);
        pts.colors.push(match &rgb {
            Some(c) => [read(c[0]), read(c[1]), read(c[2])],
            None => [0.5; 3],
        });
    }
    if skipped > 0 && pts.positions.is_empty() {
        bail!("{}: all {n} points have NaN or infinite coordinates", path.display());
    }
    Ok((pts, skipped))
}

/// The reflection set as a splat PLY: colour = f0 (as SH DC, so viewers show
/// it), plus `f0_0..2` and `reflectivity` (activated, in [0, 1]).
pub fn write_reflection_splats(path: &Path, g: &HostGaussians) -> Result<()> {
    g.validate()?;
    if g.channels != 4 || g.coeffs != 1 {
        bail!("a reflection set has 4 material values per splat, not {} x {}", g.channels, g.coeffs);
    }
    let sig = |x: f32| 1.0 / (1.0 + (-x).exp());
    let n = g.len();
    let m = |c: usize| (0..n).map(|i| sig(g.features[4 * i + c])).collect::<Vec<f32>>();
    let (f0, r) = ([m(0), m(1), m(2)], m(3));
    const SH_C0: f32 = 0.282_094_8;
    let features = (0..n).flat_map(|i| [0, 1, 2].map(|c| (f0[c][i] - 0.5) / SH_C0)).collect();
    let base = HostGaussians { channels: 3, coeffs: 1, features, ..g.clone() };
    let [a, b, c] = f0;
    write_splats_with(path, &base, &[("f0_0", a), ("f0_1", b), ("f0_2", c), ("reflectivity", r)])
}
