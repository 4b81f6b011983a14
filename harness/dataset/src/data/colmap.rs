//! COLMAP sparse models (text and binary): PINHOLE and SIMPLE_PINHOLE
//! cameras (other models are rejected by name), images with world-to-camera
//! quaternion + translation (OpenCV axes), points3D with colours. Images
//! come from `images/` (or `images_N/` when downscaling by N and it exists);
//! the test split is every `holdout`-th image after sorting by name.

use super::image_io::read_rgb;
use super::{downscale_camera, Dataset, LoadOptions, Points, View};
use anyhow::{bail, Context as _, Result};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use tgs_pipelines::Camera;

#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    pub id: u32,
    pub model: String,
    pub width: u32,
    pub height: u32,
    pub params: Vec<f64>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    pub id: u32,
    /// World-to-camera rotation (w, x, y, z) and translation.
    pub qvec: [f64; 4],
    pub tvec: [f64; 3],
    pub camera_id: u32,
    pub name: String,
}

/// (name, parameter count) of COLMAP's camera model ids.
const MODELS: [(&str, usize); 11] = [
    ("SIMPLE_PINHOLE", 3),
    ("PINHOLE", 4),
    ("SIMPLE_RADIAL", 4),
    ("RADIAL", 5),
    ("OPENCV", 8),
    ("OPENCV_FISHEYE", 8),
    ("FULL_OPENCV", 12),
    ("FOV", 5),
    ("SIMPLE_RADIAL_FISHEYE", 4),
    ("RADIAL_FISHEYE", 5),
    ("THIN_PRISM_FISHEYE", 12),
];

/// The sparse model directory: sparse/0 or sparse.
pub fn find_model(root: &Path) -> Option<PathBuf> {
    [root.join("sparse/0"), root.join("sparse")].into_iter().find(|d| d.join("cameras.bin").is_file() || d.join("cameras.txt").is_file())
}

pub fn load(root: &Path, opts: &LoadOptions) -> Result<Dataset> {
    let dir = find_model(root).context("no COLMAP model (sparse/0 or sparse/ with cameras.bin or cameras.txt)")?;
    let (cameras, images, points) = read_model(&dir)?;
    let cams: HashMap<u32, ColmapCamera> = cameras.into_iter().map(|c| (c.id, c)).collect();
    let mut images = images;
    images.sort_by(|a, b| a.name.cmp(&b.name));
    if images.is_empty() {
        bail!("{}: the model has no images", dir.display());
    }
    if let Some(w) = images.windows(2).find(|w| w[0].name == w[1].name) {
        bail!("{}: image '{}' is in the model twice (image ids {} and {}): each image must have one pose", dir.display(), w[0].name, w[0].id, w[1].id);
    }
    let ext = if dir.join("cameras.bin").is_file() { "bin" } else { "txt" };
    let mut files: Vec<std::path::PathBuf> = ["cameras", "images", "points3D"].iter().map(|n| dir.join(format!("{n}.{ext}"))).filter(|p| p.is_file()).collect();
    let scaled_dir = root.join(format!("images_{}", opts.downscale));
    let (img_dir, prescaled) = if opts.downscale > 1 && scaled_dir.is_dir() { (scaled_dir, true) } else { (root.join("images"), false) };
    let mut train = Vec::new();
    let mut test = Vec::new();
    for (i, im) in images.iter().enumerate() {
        let cc = cams.get(&im.camera_id).with_context(|| format!("{}: image '{}' refers to camera {} which is not in the model", dir.display(), im.name, im.camera_id))?;
        let cam = to_camera(cc, im).with_context(|| format!("{}: image '{}'", dir.display(), im.name))?;
        super::check_field_of_view(&cam).with_context(|| format!("{}: image '{}' (camera {})", dir.display(), im.name, cc.id))?;
        let path = img_dir.join(&im.name);
        let image = read_rgb(&path, opts.background)?;
        files.push(path.clone());
        let (image, cam) = if prescaled {
            let want = downscale_camera(&cam, opts.downscale);
            if (image.width, image.height) != (want.width, want.height) {
                bail!("{}: image is {}x{} but camera {} at 1/{} is {}x{}", path.display(), image.width, image.height, cc.id, opts.downscale, want.width, want.height);
            }
            (image, want)
        } else {
            if (image.width, image.height) != (cam.width, cam.height) {
                bail!("{}: image is {}x{} but camera {} says {}x{}", path.display(), image.width, image.height, cc.id, cam.width, cam.height);
            }
            (image.downscale(opts.downscale).with_context(|| path.display().to_string())?, downscale_camera(&cam, opts.downscale))
        };
        let view = View { name: im.name.clone(), camera: cam, image, normals: None, mask: None };
        if opts.holdout > 0 && i % opts.holdout as usize == 0 {
            test.push(view);
        } else {
            train.push(view);
        }
    }
    let mut warnings = Vec::new();
    if let Some((pts, skipped)) = &points {
        warnings.extend(super::points_warning(&dir.join(format!("points3D.{ext}")), pts.positions.len(), *skipped));
    }
    let points = points.map(|(p, _)| p);
    Ok(Dataset { root: root.to_path_buf(), format: "colmap", train, test, points, background: opts.background, files, warnings })
}

/// Our camera from a COLMAP camera and image pose.
pub fn to_camera(c: &ColmapCamera, im: &ColmapImage) -> Result<Camera> {
    let (fx, fy, cx, cy) = match (c.model.as_str(), c.params.as_slice()) {
        ("PINHOLE", [fx, fy, cx, cy]) => (*fx, *fy, *cx, *cy),
        ("SIMPLE_PINHOLE", [f, cx, cy]) => (*f, *f, *cx, *cy),
        ("PINHOLE" | "SIMPLE_PINHOLE", p) => bail!("camera {} ({}) has {} parameters", c.id, c.model, p.len()),
        (m, _) => bail!("camera {} uses the {m} model; tgs takes PINHOLE or SIMPLE_PINHOLE (undistort the images first, e.g. `colmap image_undistorter`)", c.id),
    };
    let [w, x, y, z] = im.qvec;
    let norm = (w * w + x * x + y * y + z * z).sqrt();
    if !(norm > 1e-12) || im.tvec.iter().chain(im.qvec.iter()).any(|v| !v.is_finite()) {
        bail!("pose has a non-finite or zero quaternion/translation (q {:?}, t {:?})", im.qvec, im.tvec);
    }
    let (w, x, y, z) = (w / norm, x / norm, y / norm, z / norm);
    let r = [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ];
    let mut rows = [[0f32; 4]; 3];
    for i in 0..3 {
        rows[i] = [r[i][0] as f32, r[i][1] as f32, r[i][2] as f32, im.tvec[i] as f32];
    }
    // COLMAP puts the centre of the top-left pixel at (0.5, 0.5).
    let cam = Camera { width: c.width, height: c.height, fx: fx as f32, fy: fy as f32, cx: (cx - 0.5) as f32, cy: (cy - 0.5) as f32, world_to_view: rows };
    cam.validate()?;
    Ok(cam)
}

/// A model as read: cameras, images, and the points with the number
/// skipped for non-finite coordinates (None without a points3D file).
pub type Model = (Vec<ColmapCamera>, Vec<ColmapImage>, Option<(Points, usize)>);

/// Read cameras, images and points from a model directory (binary preferred).
pub fn read_model(dir: &Path) -> Result<Model> {
    if dir.join("cameras.bin").is_file() {
        let (cams, ims) = (parse_file(dir, "cameras.bin", parse_cameras_bin)?, parse_file(dir, "images.bin", parse_images_bin)?);
        Ok((cams, ims, optional(dir, "points3D.bin", parse_points_bin)?))
    } else {
        let (cams, ims) = (parse_file(dir, "cameras.txt", text(parse_cameras_txt))?, parse_file(dir, "images.txt", text(parse_images_txt))?);
        Ok((cams, ims, optional(dir, "points3D.txt", text(parse_points_txt))?))
    }
}

/// Parse `dir/name`; the errors name the file.
fn parse_file<T>(dir: &Path, name: &str, parse: impl FnOnce(&[u8]) -> Result<T>) -> Result<T> {
    let p = dir.join(name);
    let b = std::fs::read(&p).with_context(|| format!("{}: cannot read", p.display()))?;
    parse(&b).with_context(|| format!("{}: corrupt", p.display()))
}

/// [`parse_file`] of a file a model may lack (None where it is absent).
fn optional<T>(dir: &Path, name: &str, parse: impl FnOnce(&[u8]) -> Result<T>) -> Result<Option<T>> {
    dir.join(name).exists().then(|| parse_file(dir, name, parse)).transpose()
}

/// A text parser as a parser of the file's bytes (UTF-8).
fn text<T>(parse: impl FnOnce(&str) -> Result<T>) -> impl FnOnce(&[u8]) -> Result<T> {
    move |b| parse(std::str::from_utf8(b).context("not UTF-8 text")?)
}

fn content_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().map(|(i, l)| (i + 1, l.trim())).filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

fn num<T: std::str::FromStr>(tok: Option<&str>, line: usize, what: &str) -> Result<T> {
    let t = tok.with_context(|| format!("line {line}: missing {what}"))?;
    t.parse::<T>().map_err(|_| anyhow::anyhow!("line {line}: {what} '{t}' is not a number"))
}

pub fn parse_cameras_txt(text: &str) -> Result<Vec<ColmapCamera>> {
    let mut out = Vec::new();
    for (ln, l) in content_lines(text) {
        let mut it = l.split_whitespace();
        let id = num(it.next(), ln, "camera id")?;
        let model = it.next().with_context(|| format!("line {ln}: missing model"))?.to_string();
        let width = num(it.next(), ln, "width")?;
        let height = num(it.next(), ln, "height")?;
        let params = it.map(|t| t.parse::<f64>().map_err(|_| anyhow::anyhow!("line {ln}: parameter '{t}' is not a number"))).collect::<Result<Vec<_>>>()?;
        out.push(ColmapCamera { id, model, width, height, params });
    }
    Ok(out)
}

pub fn parse_images_txt(text: &str) -> Result<Vec<ColmapImage>> {
    // Two lines per image; the second (2-D points) may be empty, so walk raw lines.
    let mut out = Vec::new();
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim_start().starts_with('#'));
    while let Some((i, l)) = lines.next() {
        let ln = i + 1;
        if l.trim().is_empty() {
            continue;
        }
        let mut it = l.split_whitespace();
        let id = num(it.next(), ln, "image id")?;
        let mut q = [0f64; 4];
        for (k, v) in q.iter_mut().enumerate() {
            *v = num(it.next(), ln, &format!("q{k}"))?;
        }
        let mut t = [0f64; 3];
        for (k, v) in t.iter_mut().enumerate() {
            *v = num(it.next(), ln, &format!("t{k}"))?;
        }
        let camera_id = num(it.next(), ln, "camera id")?;
        let name = it.collect::<Vec<_>>().join(" ");
        if name.is_empty() {
            bail!("line {ln}: missing image name");
        }
        out.push(ColmapImage { id, qvec: q, tvec: t, camera_id, name });
        // The 2-D points line (possibly empty). COLMAP always writes it; a
        // file without it would otherwise lose every second image silently.
        if let Some((j, pl)) = lines.next() {
            if !is_points2d_line(pl) {
                bail!(
                    "line {}: expected the 2-D points of image {id} (X Y POINT3D_ID triples, or an empty line), found '{}'; images.txt has two lines per image and the second may be empty but not missing",
                    j + 1,
                    pl.chars().take(60).collect::<String>()
                );
            }
        }
    }
    Ok(out)
}

/// Whether a line is an images.txt 2-D points line: X Y POINT3D_ID triples
/// (the id an integer, -1 for none).
fn is_points2d_line(l: &str) -> bool {
    let t: Vec<&str> = l.split_whitespace().collect();
    t.len().is_multiple_of(3) && t.chunks(3).all(|p| p[0].parse::<f64>().is_ok() && p[1].parse::<f64>().is_ok() && p[2].parse::<i64>().is_ok())
}

/// The points and how many were skipped for NaN or infinite coordinates
/// (an f64 past f32's range counts as infinite).
pub fn parse_points_txt(text: &str) -> Result<(Points, usize)> {
    let (mut pts, mut skipped) = (Points::default(), 0);
    for (ln, l) in content_lines(text) {
        let mut it = l.split_whitespace();
        let _id: u64 = num(it.next(), ln, "point id")?;
        let p: [f32; 3] = [num(it.next(), ln, "x")?, num(it.next(), ln, "y")?, num(it.next(), ln, "z")?];
        let c: [f32; 3] = [num::<u8>(it.next(), ln, "r")? as f32 / 255.0, num::<u8>(it.next(), ln, "g")? as f32 / 255.0, num::<u8>(it.next(), ln, "b")? as f32 / 255.0];
        if p.iter().all(|v| v.is_finite()) {
            pts.positions.push(p);
            pts.colors.push(c);
        } else {
            skipped += 1;
        }
    }
    Ok((pts, skipped))
}

struct Cursor<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8]> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.b.len()).with_context(|| format!("truncated at byte {} (wanted {n} more)", self.at))?;
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u64(&mut self) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    fn i32(&mut self) -> Result<i32> {
        Ok(i32::from_le_bytes(self.take(4)?.try_into().unwrap()))
    }
    fn f64(&mut self) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    fn count(&mut self, each: usize) -> Result<usize> {
        let n = self.u64()?;
        let left = (self.b.len() - self.at) as u64;
        if n.saturating_mul(each as u64) > left {
            bail!("truncated: count {n} at byte {} exceeds the file", self.at - 8);
        }
        Ok(n as usize)
    }
}

pub fn parse_cameras_bin(b: &[u8]) -> Result<Vec<ColmapCamera>> {
    let mut c = Cursor { b, at: 0 };
    let n = c.count(24)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = c.i32()? as u32;
        let model_id = c.i32()?;
        let &(model, np) = MODELS.get(model_id as usize).with_context(|| format!("camera {id}: unknown model id {model_id}"))?;
        let width = u32::try_from(c.u64()?).with_context(|| format!("camera {id}: width out of range"))?;
        let height = u32::try_from(c.u64()?).with_context(|| format!("camera {id}: height out of range"))?;
        let params = (0..np).map(|_| c.f64()).collect::<Result<Vec<_>>>()?;
        out.push(ColmapCamera { id, model: model.into(), width, height, params });
    }
    Ok(out)
}

pub fn parse_images_bin(b: &[u8]) -> Result<Vec<ColmapImage>> {
    let mut c = Cursor { b, at: 0 };
    let n = c.count(64)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = c.i32()? as u32;
        let qvec = [c.f64()?, c.f64()?, c.f64()?, c.f64()?];
        let tvec = [c.f64()?, c.f64()?, c.f64()?];
        let camera_id = c.i32()? as u32;
        let mut name = Vec::new();
        loop {
            let ch = c.take(1)?[0];
            if ch == 0 {
                break;
            }
            name.push(ch);
        }
        let name = String::from_utf8(name).context("image name is not UTF-8")?;
        let np = c.count(24)?;
        c.take(np * 24)?;
        out.push(ColmapImage { id, qvec, tvec, camera_id, name });
    }
    Ok(out)
}

/// As [`parse_points_txt`], from points3D.bin.
pub fn parse_points_bin(b: &[u8]) -> Result<(Points, usize)> {
    let mut c = Cursor { b, at: 0 };
    let n = c.count(43)?;
    let (mut pts, mut skipped) = (Points::default(), 0);
    for _ in 0..n {
        c.u64()?;
        let p = [c.f64()? as f32, c.f64()? as f32, c.f64()? as f32];
        let rgb = c.take(3)?;
        c.f64()?;
        let tl = c.count(8)?;
        c.take(tl * 8)?;
        if p.iter().all(|v| v.is_finite()) {
            pts.positions.push(p);
            pts.colors.push([rgb[0] as f32 / 255.0, rgb[1] as f32 / 255.0, rgb[2] as f32 / 255.0]);
        } else {
            skipped += 1;
        }
    }
    Ok((pts, skipped))
}
