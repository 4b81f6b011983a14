//! Reading and writing the image files a dataset and a run use: 8-bit PNG
//! (RGB, RGBA composited on a background, grey masks), float EXR, float32
//! `.npy` arrays, with errors that name the file.

use anyhow::{bail, Context as _, Result};
use std::path::Path;

/// An image as interleaved f32 values, `channels` per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageF {
    pub width: u32,
    pub height: u32,
    pub channels: u32,
    pub data: Vec<f32>,
}

impl ImageF {
    pub fn new(width: u32, height: u32, channels: u32) -> ImageF {
        ImageF { width, height, channels, data: vec![0.0; (width * height * channels) as usize] }
    }
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
    /// Planar copy (channel-major), the layout of the GPU targets.
    pub fn planar(&self) -> Vec<f32> {
        let (n, c) = (self.pixels(), self.channels as usize);
        let mut out = vec![0.0; n * c];
        for p in 0..n {
            for k in 0..c {
                out[k * n + p] = self.data[p * c + k];
            }
        }
        out
    }
    pub fn from_planar(width: u32, height: u32, channels: u32, planes: &[f32]) -> ImageF {
        let n = (width * height) as usize;
        let c = channels as usize;
        let mut data = vec![0.0; n * c];
        for p in 0..n {
            for k in 0..c {
                data[p * c + k] = planes[k * n + p];
            }
        }
        ImageF { width, height, channels, data }
    }

    /// Box-filter downscale by an integer factor (the size is floored).
    pub fn downscale(&self, factor: u32) -> Result<ImageF> {
        if factor <= 1 {
            return Ok(self.clone());
        }
        let (w, h) = (self.width / factor, self.height / factor);
        if w == 0 || h == 0 {
            bail!("--downscale {factor} leaves nothing of a {}x{} image", self.width, self.height);
        }
        let c = self.channels as usize;
        let mut out = ImageF::new(w, h, self.channels);
        let inv = 1.0 / (factor * factor) as f32;
        for y in 0..h as usize {
            for x in 0..w as usize {
                for k in 0..c {
                    let mut s = 0.0;
                    for dy in 0..factor as usize {
                        for dx in 0..factor as usize {
                            let (sx, sy) = (x * factor as usize + dx, y * factor as usize + dy);
                            s += self.data[(sy * self.width as usize + sx) * c + k];
                        }
                    }
                    out.data[(y * w as usize + x) * c + k] = s * inv;
                }
            }
        }
        Ok(out)
    }
}

/// An 8-bit PNG as RGB in [0, 1]; RGBA is composited on `background`.
pub fn read_rgb(path: &Path, background: [f32; 3]) -> Result<ImageF> {
    Ok(read_rgb_alpha(path, background)?.0)
}

/// [`read_rgb`], and whether the file had an alpha channel.
pub fn read_rgb_alpha(path: &Path, background: [f32; 3]) -> Result<(ImageF, bool)> {
    let img = open_image(path, "image")?;
    let rgba = img.to_rgba32f();
    let has_alpha = img.color().has_alpha();
    let (w, h) = rgba.dimensions();
    if w == 0 || h == 0 {
        bail!("{}: the image is empty ({w}x{h})", path.display());
    }
    let mut out = ImageF::new(w, h, 3);
    for (i, px) in rgba.pixels().enumerate() {
        let a = if has_alpha { px.0[3] } else { 1.0 };
        for k in 0..3 {
            out.data[3 * i + k] = px.0[k] * a + background[k] * (1.0 - a);
        }
    }
    Ok((out, has_alpha))
}

/// The mean colour of an image's one-pixel border and the largest
/// deviation of a border pixel from it (any channel).
pub fn border_colour(img: &ImageF) -> ([f32; 3], f32) {
    let (w, h, c) = (img.width as usize, img.height as usize, img.channels as usize);
    let idx: Vec<usize> = (0..h).flat_map(|y| (0..w).filter(move |&x| y == 0 || y + 1 == h || x == 0 || x + 1 == w).map(move |x| y * w + x)).collect();
    let mut mean = [0f32; 3];
    for &i in &idx {
        for k in 0..3 {
            mean[k] += img.data[c * i + k.min(c - 1)] / idx.len() as f32;
        }
    }
    let spread = idx.iter().flat_map(|&i| (0..3).map(move |k| (i, k))).map(|(i, k)| (img.data[c * i + k.min(c - 1)] - mean[k]).abs()).fold(0f32, f32::max);
    (mean, spread)
}

/// An 8-bit mask (grey or the first channel): true where the value is >= 128.
pub fn read_mask(path: &Path) -> Result<(u32, u32, Vec<bool>)> {
    Ok(mask_of(&open_mask(path)?))
}

/// [`read_mask`] for a mask a user names by hand (`reflection.seed_masks`):
/// a colour image is refused, so that a folder of the views' images
/// (named as their masks would be) is not taken for their masks. Grey
/// stored as RGB (R = G = B) passes.
pub fn read_grey_mask(path: &Path) -> Result<(u32, u32, Vec<bool>)> {
    let img = open_mask(path)?;
    if img.color().has_color() && img.to_rgb8().pixels().any(|p| p.0[0] != p.0[1] || p.0[1] != p.0[2]) {
        bail!("{}: a colour image, not a glass mask (8-bit grey, white on the glass); is this the views' image folder?", path.display());
    }
    Ok(mask_of(&img))
}

fn open_mask(path: &Path) -> Result<image::DynamicImage> {
    open_image(path, "mask")
}

/// An image file decoded (`what`: "image", "mask" for the messages): a
/// regular file only (a FIFO would block and a device never end), its
/// format read from its first bytes, a JPEG only when whole
/// ([`jpeg_complete`]: the decoder fills a truncated one with grey rows
/// and says nothing). The decoder's message is said once (its error's
/// source repeats it).
pub fn open_image(path: &Path, what: &str) -> Result<image::DynamicImage> {
    regular_file(path, what)?;
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read the {what}", path.display()))?;
    if bytes.starts_with(&[0xFF, 0xD8]) {
        if let Err(e) = jpeg_complete(&bytes) {
            bail!("{}: cannot read the {what}: a truncated or damaged JPEG ({e})", path.display());
        }
    }
    let reader = image::ImageReader::new(std::io::Cursor::new(bytes)).with_guessed_format().with_context(|| format!("{}: cannot read the {what}", path.display()))?;
    reader.decode().map_err(|e| anyhow::anyhow!("{}: cannot read the {what}: {e}", path.display()))
}

/// Refuse a path that is not a regular file (a FIFO blocks a reader and a
/// device never ends), naming it.
pub fn regular_file(path: &Path, what: &str) -> Result<()> {
    let meta = std::fs::metadata(path).with_context(|| format!("{}: cannot read the {what}", path.display()))?;
    if !meta.is_file() {
        bail!("{}: not a regular file (a directory, FIFO or device); the {what} must be a file", path.display());
    }
    Ok(())
}

/// Whether a JPEG's bytes run whole to its end-of-image marker: the
/// segments walked by their lengths, each scan's entropy-coded data to
/// the next marker (0xFF followed by neither 0x00, a restart marker nor
/// fill), until EOI. Bytes after EOI (camera trailers) are allowed.
pub fn jpeg_complete(b: &[u8]) -> std::result::Result<(), String> {
    if !b.starts_with(&[0xFF, 0xD8]) {
        return Err("no start-of-image marker".into());
    }
    let mut i = 2;
    loop {
        // Fill bytes before a marker.
        while b.get(i) == Some(&0xFF) && b.get(i + 1) == Some(&0xFF) {
            i += 1;
        }
        match (b.get(i), b.get(i + 1)) {
            (Some(0xFF), Some(&m)) => {
                i += 2;
                match m {
                    0xD9 => return Ok(()),
                    0x01 | 0xD0..=0xD7 => continue,
                    _ => {}
                }
                let len = match (b.get(i), b.get(i + 1)) {
                    (Some(&h), Some(&l)) => u16::from_be_bytes([h, l]) as usize,
                    _ => return Err(format!("it ends inside marker 0xFF{m:02X}")),
                };
                if len < 2 || i + len > b.len() {
                    return Err(format!("segment 0xFF{m:02X} runs past the end of the file"));
                }
                i += len;
                if m == 0xDA {
                    // Entropy-coded data: to the next real marker.
                    loop {
                        match (b.get(i), b.get(i + 1)) {
                            (Some(0xFF), Some(0x00 | 0xD0..=0xD7)) => i += 2,
                            (Some(0xFF), Some(0xFF)) => i += 1,
                            (Some(0xFF), Some(_)) => break,
                            (Some(_), _) => i += 1,
                            (None, _) => return Err("it ends inside the image data, before its end-of-image marker".into()),
                        }
                    }
                }
            }
            (None, _) | (Some(0xFF), None) => return Err("it ends before its end-of-image marker".into()),
            (Some(&x), _) => return Err(format!("byte 0x{x:02X} at offset {i} where a marker belongs")),
        }
    }
}

/// The mask's size and its pixels at or above 128 in grey.
fn mask_of(img: &image::DynamicImage) -> (u32, u32, Vec<bool>) {
    let g = img.to_luma8();
    let (w, h) = g.dimensions();
    (w, h, g.pixels().map(|p| p.0[0] >= 128).collect())
}

/// Per-pixel unit normals (HxWx3) from `.npy` (float32/float64), `.exr`
/// (RGB) or a Shiny-Blender `_normal.png` (n = rgb * 2 / 255 - 1).
pub fn read_normals(path: &Path) -> Result<ImageF> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    let img = match ext.as_str() {
        "npy" => read_npy(path)?,
        "exr" => read_exr(path)?,
        "png" => {
            let rgb = read_rgb(path, [0.0; 3])?;
            ImageF { data: rgb.data.iter().map(|v| v * 2.0 - 1.0).collect(), ..rgb }
        }
        _ => bail!("{}: normals must be .npy, .exr or .png", path.display()),
    };
    if img.channels != 3 {
        bail!("{}: normals need 3 channels, the file has {}", path.display(), img.channels);
    }
    if img.data.iter().any(|v| !v.is_finite()) {
        bail!("{}: normals contain NaN or infinite values", path.display());
    }
    Ok(img)
}

/// A float32 or float64 `.npy` array of shape (H, W) or (H, W, C), C order.
pub fn read_npy(path: &Path) -> Result<ImageF> {
    regular_file(path, "array")?;
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    parse_npy(&bytes).with_context(|| format!("{}: not a valid .npy array", path.display()))
}

pub fn parse_npy(bytes: &[u8]) -> Result<ImageF> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        bail!("missing the NUMPY magic");
    }
    let major = bytes[6];
    let (hlen, start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                bail!("truncated header");
            }
            (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12)
        }
        v => bail!("unsupported .npy version {v}"),
    };
    let header = bytes.get(start..start + hlen).context("truncated header")?;
    let header = std::str::from_utf8(header).context("header is not text")?;
    let field = |key: &str| -> Result<&str> {
        let i = header.find(&format!("'{key}'")).with_context(|| format!("header has no '{key}'"))?;
        Ok(header[i + key.len() + 2..].trim_start().trim_start_matches(':').trim_start())
    };
    let descr = field("descr")?;
    let elem = if descr.starts_with("'<f4'") {
        4
    } else if descr.starts_with("'<f8'") {
        8
    } else {
        bail!("dtype {} is not little-endian float32/float64", descr.split(',').next().unwrap_or(""));
    };
    if field("fortran_order")?.starts_with("True") {
        bail!("Fortran-order arrays are not supported");
    }
    let shape = field("shape")?;
    let inner = shape.trim_start_matches('(').split(')').next().unwrap_or("");
    let dims: Vec<usize> = inner.split(',').map(str::trim).filter(|s| !s.is_empty()).map(|s| s.parse::<usize>()).collect::<Result<_, _>>().context("bad shape")?;
    let (h, w, c) = match dims.as_slice() {
        [h, w] => (*h, *w, 1),
        [h, w, c] => (*h, *w, *c),
        _ => bail!("shape {dims:?} is not (H, W) or (H, W, C)"),
    };
    // The shape comes from the file: check the products instead of wrapping.
    let count = h.checked_mul(w).and_then(|v| v.checked_mul(c));
    let need = count.and_then(|n| n.checked_mul(elem));
    let data = &bytes[start + hlen..];
    let (Some(count), Some(need)) = (count, need) else { bail!("shape {dims:?} is too large") };
    if u32::try_from(h).is_err() || u32::try_from(w).is_err() || u32::try_from(c).is_err() {
        bail!("shape {dims:?} is too large");
    }
    if data.len() < need {
        bail!("holds {} bytes of data; shape {dims:?} needs {need}", data.len());
    }
    let values: Vec<f32> = if elem == 4 {
        data[..count * 4].chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
    } else {
        data[..count * 8].chunks_exact(8).map(|b| f64::from_le_bytes(b.try_into().unwrap()) as f32).collect()
    };
    Ok(ImageF { width: w as u32, height: h as u32, channels: c as u32, data: values })
}

/// Write a float32 `.npy` of shape (H, W, C).
pub fn write_npy(path: &Path, img: &ImageF) -> Result<()> {
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({}, {}, {}), }}", img.height, img.width, img.channels);
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + img.data.len() * 4);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in &img.data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(path, out).with_context(|| format!("{}: cannot write", path.display()))
}

/// RGB(A) channels of an EXR file.
pub fn read_exr(path: &Path) -> Result<ImageF> {
    regular_file(path, "EXR")?;
    let img = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |res, _| ImageF::new(res.width() as u32, res.height() as u32, 3),
        |img: &mut ImageF, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            let i = 3 * (pos.y() * img.width as usize + pos.x());
            img.data[i] = r;
            img.data[i + 1] = g;
            img.data[i + 2] = b;
        },
    )
    .with_context(|| format!("{}: cannot read the EXR", path.display()))?;
    Ok(img.layer_data.channel_data.pixels)
}

/// Write 1 (as Y) or 3 (RGB) float channels to EXR.
pub fn write_exr(path: &Path, img: &ImageF) -> Result<()> {
    let (w, h, c) = (img.width as usize, img.height as usize, img.channels as usize);
    let res = match c {
        1 => exr::prelude::write_rgb_file(path, w, h, |x, y| {
            let v = img.data[y * w + x];
            (v, v, v)
        }),
        3 => exr::prelude::write_rgb_file(path, w, h, |x, y| {
            let i = 3 * (y * w + x);
            (img.data[i], img.data[i + 1], img.data[i + 2])
        }),
        _ => bail!("EXR output takes 1 or 3 channels, not {c}"),
    };
    res.with_context(|| format!("{}: cannot write the EXR", path.display()))
}

/// Write an 8-bit PNG (values clamped to [0, 1] and rounded); 1 or 3 channels.
pub fn write_png(path: &Path, img: &ImageF) -> Result<()> {
    let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    let bytes: Vec<u8> = img.data.iter().map(|&v| q(if v.is_finite() { v } else { 0.0 })).collect();
    let color = match img.channels {
        1 => image::ExtendedColorType::L8,
        3 => image::ExtendedColorType::Rgb8,
        4 => image::ExtendedColorType::Rgba8,
        c => bail!("PNG output takes 1, 3 or 4 channels, not {c}"),
    };
    image::save_buffer(path, &bytes, img.width, img.height, color).with_context(|| format!("{}: cannot write the PNG", path.display()))
}

/// Write a grey 8-bit mask.
pub fn write_mask(path: &Path, width: u32, height: u32, mask: &[bool]) -> Result<()> {
    let bytes: Vec<u8> = mask.iter().map(|&m| if m { 255 } else { 0 }).collect();
    image::save_buffer(path, &bytes, width, height, image::ExtendedColorType::L8).with_context(|| format!("{}: cannot write the PNG", path.display()))
}

/// A depth image as grey levels for a PNG: the depths in (0, `far`)
/// mapped linearly from 1 (the nearest) to 1 - `span` (the farthest), and
/// 0 elsewhere (no surface).
pub fn depth_grey(depth: &[f32], far: f32, span: f32) -> Vec<f32> {
    let keep = |v: f32| v > 0.0 && v < far;
    let (lo, hi) = depth.iter().copied().filter(|&v| keep(v)).fold((f32::INFINITY, 0.0f32), |(l, hh), v| (l.min(v), hh.max(v)));
    depth.iter().map(|&v| if keep(v) && hi > lo { 1.0 - span * (v - lo) / (hi - lo) } else { 0.0 }).collect()
}
