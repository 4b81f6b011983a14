//! Triangle meshes as binary PLY (vertex position, 8-bit colour; faces as
//! vertex index lists), the format MeshLab, Blender and Open3D read.

use super::Mesh;
use crate::export::atomic_write_with;
use anyhow::{bail, Result};
use std::path::Path;

/// Write `mesh` to `path` (crash-safe: the old file or the new one).
pub fn write_mesh(path: &Path, mesh: &Mesh) -> Result<()> {
    if mesh.colors.len() != mesh.positions.len() {
        bail!("{}: a mesh with {} vertices and {} colours", path.display(), mesh.positions.len(), mesh.colors.len());
    }
    if let Some(t) = mesh.triangles.iter().find(|t| t.iter().any(|&i| i as usize >= mesh.positions.len())) {
        bail!("{}: triangle {t:?} indexes past the {} vertices", path.display(), mesh.positions.len());
    }
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by tgs mesh\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nelement face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        mesh.positions.len(),
        mesh.triangles.len()
    );
    atomic_write_with(path, |w| {
        w.write_all(header.as_bytes())?;
        let mut buf = Vec::with_capacity(15 * mesh.positions.len());
        for (p, c) in mesh.positions.iter().zip(&mesh.colors) {
            for v in p {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            buf.extend(c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8));
        }
        w.write_all(&buf)?;
        buf.clear();
        for t in &mesh.triangles {
            buf.push(3);
            for i in t {
                buf.extend_from_slice(&i.to_le_bytes());
            }
        }
        w.write_all(&buf)?;
        Ok(())
    })
}

/// Read a mesh written by [`write_mesh`] (for tests and tools).
pub fn read_mesh(path: &Path) -> Result<Mesh> {
    use anyhow::Context as _;
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let end = bytes.windows(11).position(|w| w == b"end_header\n").with_context(|| format!("{}: no PLY header", path.display()))? + 11;
    let header = std::str::from_utf8(&bytes[..end]).with_context(|| format!("{}: header is not text", path.display()))?;
    let count = |el: &str| -> Result<usize> {
        header
            .lines()
            .find_map(|l| l.strip_prefix(&format!("element {el} ")))
            .with_context(|| format!("{}: no element {el}", path.display()))?
            .trim()
            .parse()
            .with_context(|| format!("{}: element {el} count", path.display()))
    };
    if !header.contains("property list uchar uint vertex_indices") || !header.contains("property uchar blue") {
        bail!("{}: not a mesh in tgs's PLY layout", path.display());
    }
    let (nv, nf) = (count("vertex")?, count("face")?);
    let need = end as u64 + 15 * nv as u64 + 13 * nf as u64;
    if bytes.len() as u64 != need {
        bail!("{}: {} bytes, expected {need} for {nv} vertices and {nf} faces", path.display(), bytes.len());
    }
    let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    let mut m = Mesh::default();
    for v in 0..nv {
        let o = end + 15 * v;
        m.positions.push([f32_at(o), f32_at(o + 4), f32_at(o + 8)]);
        m.colors.push([0, 1, 2].map(|c| bytes[o + 12 + c] as f32 / 255.0));
    }
    let base = end + 15 * nv;
    for f in 0..nf {
        let o = base + 13 * f;
        if bytes[o] != 3 {
            bail!("{}: face {f} has {} vertices (tgs writes triangles)", path.display(), bytes[o]);
        }
        m.triangles.push([0, 1, 2].map(|k| u32::from_le_bytes(bytes[o + 1 + 4 * k..o + 5 + 4 * k].try_into().unwrap())));
    }
    Ok(m)
}
