//! The light field's weights as a safetensors file (readable by the
//! `safetensors` Python package and any tool that reads the format): an
//! 8-byte little-endian header size, a JSON header, then the tensors' bytes.
//! Tensors `layers.L.weight` [fan_out, fan_in] and `layers.L.bias`
//! [fan_out], f32 little-endian, L = 0..=depth (depth: the sigmoid head);
//! `__metadata__` holds the shape (depth, width, skip, levels_x, levels_w)
//! and the normalization box (centre, half_extent), threshold and Fresnel
//! switch, so a renderer can evaluate Phi without the run's config.

use super::atomic_write_with;
use anyhow::{bail, Context as _, Result};
use std::path::Path;
use tgs_pipelines::{MlpShape, ShadeParams};

pub fn write(path: &Path, shape: &MlpShape, shade: &ShadeParams, params: &[f32]) -> Result<()> {
    if params.len() != shape.params() as usize {
        bail!("{}: {} parameters for a network of {}", path.display(), params.len(), shape.params());
    }
    let mut header = serde_json::Map::new();
    let mut data: Vec<u8> = Vec::with_capacity(4 * params.len());
    for l in 0..shape.layers() {
        let (k, j) = (shape.fan_in(l) as usize, shape.fan_out(l) as usize);
        let off = shape.offset(l) as usize;
        let rows = &params[off..off + j * (k + 1)];
        let begin = data.len();
        for r in 0..j {
            data.extend(rows[r * (k + 1)..r * (k + 1) + k].iter().flat_map(|v| v.to_le_bytes()));
        }
        header.insert(format!("layers.{l}.weight"), serde_json::json!({"dtype": "F32", "shape": [j, k], "data_offsets": [begin, data.len()]}));
        let begin = data.len();
        for r in 0..j {
            data.extend(rows[r * (k + 1) + k].to_le_bytes());
        }
        header.insert(format!("layers.{l}.bias"), serde_json::json!({"dtype": "F32", "shape": [j], "data_offsets": [begin, data.len()]}));
    }
    let meta = |v: &[f32]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>().join(",");
    header.insert(
        "__metadata__".into(),
        serde_json::json!({
            "format": "tgs light field v1",
            "depth": shape.depth.to_string(), "width": shape.width.to_string(), "skip": shape.skip.to_string(),
            "levels_x": shape.levels_x.to_string(), "levels_w": shape.levels_w.to_string(),
            "centre": meta(&shade.centre), "half_extent": meta(&shade.half_extent),
            "threshold": shade.threshold.to_string(), "fresnel": if shade.schlick { "schlick" } else { "off" },
        }),
    );
    let mut json = serde_json::to_vec(&serde_json::Value::Object(header))?;
    // The data starts 8-byte aligned (padding with spaces is allowed).
    while (8 + json.len()) % 8 != 0 {
        json.push(b' ');
    }
    atomic_write_with(path, |f| {
        f.write_all(&(json.len() as u64).to_le_bytes())?;
        f.write_all(&json)?;
        f.write_all(&data)?;
        Ok(())
    })
}

/// Read a file [`write`] wrote: the shape, the shading parameters and the
/// flat parameter vector ([`MlpShape::offset`] layout).
pub fn read(path: &Path) -> Result<(MlpShape, ShadeParams, Vec<f32>)> {
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    let bad = |why: String| anyhow::anyhow!("{}: not a tgs light-field file ({why})", path.display());
    if bytes.len() < 8 {
        return Err(bad("shorter than its header size".into()));
    }
    let hlen = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    if hlen > bytes.len() - 8 {
        return Err(bad(format!("header of {hlen} bytes in a file of {}", bytes.len())));
    }
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + hlen]).map_err(|e| bad(format!("header: {e}")))?;
    let data = &bytes[8 + hlen..];
    let meta = &header["__metadata__"];
    let num = |k: &str| -> Result<u32> { meta[k].as_str().and_then(|s| s.parse().ok()).ok_or_else(|| bad(format!("metadata '{k}'"))) };
    let vec3 = |k: &str| -> Result<[f32; 3]> {
        let v: Vec<f32> = meta[k].as_str().unwrap_or("").split(',').filter_map(|t| t.parse().ok()).collect();
        v.try_into().map_err(|_| bad(format!("metadata '{k}'")))
    };
    let shape = MlpShape { depth: num("depth")?, width: num("width")?, skip: num("skip")?, levels_x: num("levels_x")?, levels_w: num("levels_w")? };
    shape.validate().map_err(|e| bad(format!("{e:#}")))?;
    let shade = ShadeParams {
        centre: vec3("centre")?,
        half_extent: vec3("half_extent")?,
        threshold: meta["threshold"].as_str().and_then(|s| s.parse().ok()).ok_or_else(|| bad("metadata 'threshold'".into()))?,
        schlick: meta["fresnel"].as_str() == Some("schlick"),
    };
    let tensor = |name: &str, len: usize| -> Result<Vec<f32>> {
        let t = &header[name];
        let off: Vec<usize> = t["data_offsets"].as_array().map(|a| a.iter().filter_map(|v| v.as_u64().map(|x| x as usize)).collect()).unwrap_or_default();
        if t["dtype"] != "F32" || off.len() != 2 || off[1] < off[0] || off[1] > data.len() || off[1] - off[0] != 4 * len {
            return Err(bad(format!("tensor '{name}' missing or not {len} f32")));
        }
        Ok(data[off[0]..off[1]].chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect())
    };
    let mut params = vec![0.0; shape.params() as usize];
    for l in 0..shape.layers() {
        let (k, j) = (shape.fan_in(l) as usize, shape.fan_out(l) as usize);
        let off = shape.offset(l) as usize;
        let w = tensor(&format!("layers.{l}.weight"), j * k)?;
        let b = tensor(&format!("layers.{l}.bias"), j)?;
        for r in 0..j {
            params[off + r * (k + 1)..off + r * (k + 1) + k].copy_from_slice(&w[r * k..(r + 1) * k]);
            params[off + r * (k + 1) + k] = b[r];
        }
    }
    Ok((shape, shade, params))
}
