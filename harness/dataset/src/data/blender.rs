//! NeRF-synthetic / Blender layout: transforms_{train,test}.json with
//! `camera_angle_x` (or per-file fl_x/fl_y/cx/cy/w/h), per-frame 4x4
//! camera-to-world matrices in OpenGL axes, RGBA PNGs composited on the
//! background, and this project's optional `normal_path` / `mask_path`.

use super::image_io::{border_colour, read_mask, read_normals, read_rgb_alpha};
use super::{downscale_camera, downscale_mask, downscale_normals, Dataset, LoadOptions, Points, View};
use anyhow::{bail, Context as _, Result};
use serde::Deserialize;
use std::path::Path;
use tgs_pipelines::Camera;

#[derive(Deserialize)]
struct Transforms {
    camera_angle_x: Option<Num>,
    #[serde(flatten)]
    intrinsics: IntrinsicsText,
    frames: Vec<Frame>,
}

/// Intrinsics as written: the file's, or a frame's (nerfstudio's layout),
/// which override the file's.
#[derive(Deserialize)]
struct IntrinsicsText {
    fl_x: Option<Num>,
    fl_y: Option<Num>,
    cx: Option<Num>,
    cy: Option<Num>,
    w: Option<Num>,
    h: Option<Num>,
}

impl IntrinsicsText {
    /// Each given value, checked to be a finite number.
    fn finite(&self) -> Result<Intrinsics> {
        let f = |v: &Option<Num>, name: &str| v.as_ref().map(|n| n.finite(name)).transpose();
        Ok(Intrinsics { fl_x: f(&self.fl_x, "fl_x")?, fl_y: f(&self.fl_y, "fl_y")?, cx: f(&self.cx, "cx")?, cy: f(&self.cy, "cy")?, w: f(&self.w, "w")?, h: f(&self.h, "h")? })
    }
}

#[derive(Deserialize)]
struct Frame {
    file_path: String,
    transform_matrix: Vec<Vec<Num>>,
    normal_path: Option<String>,
    mask_path: Option<String>,
    #[serde(flatten)]
    intrinsics: IntrinsicsText,
}

/// A number as written in the file. Python's `json.dump` writes NaN and
/// Infinity as bare words, which JSON does not allow; they are read (see
/// [`quote_non_finite`]) so that the error can name the frame and the value.
#[derive(Deserialize, Clone, Debug)]
#[serde(untagged)]
enum Num {
    Number(f64),
    Word(String),
}

impl Num {
    /// The value, or an error naming `what` when it is not a finite number.
    fn finite(&self, what: &str) -> Result<f64> {
        match self {
            Num::Number(v) if v.is_finite() => Ok(*v),
            Num::Number(v) => bail!("{what} is {v}"),
            Num::Word(w) if ["NaN", "Infinity", "-Infinity"].contains(&w.as_str()) => bail!("{what} is {w}"),
            Num::Word(w) => bail!("{what} is '{w}', not a number"),
        }
    }
}

/// Quote the bare words NaN, Infinity and -Infinity outside strings so that
/// the JSON parser accepts them as strings.
fn quote_non_finite(text: &str) -> String {
    let mut out = String::with_capacity(text.len() + 16);
    let (mut in_string, mut escaped) = (false, false);
    let mut rest = text;
    while let Some(c) = rest.chars().next() {
        if in_string {
            if escaped {
                escaped = false;
            } else if c == '\\' {
                escaped = true;
            } else if c == '"' {
                in_string = false;
            }
        } else if c == '"' {
            in_string = true;
        } else if let Some(word) = ["NaN", "Infinity", "-Infinity"].into_iter().find(|w| rest.starts_with(w)) {
            out.push('"');
            out.push_str(word);
            out.push('"');
            rest = &rest[word.len()..];
            continue;
        }
        out.push(c);
        rest = &rest[c.len_utf8()..];
    }
    out
}

/// A camera-to-world matrix must be a rigid motion: rotation (orthonormal,
/// determinant +1) and translation, bottom row 0 0 0 1. Scale, shear or a
/// singular matrix would silently distort the scene and its extent.
fn check_rigid(m: &[[f64; 4]; 4]) -> Result<()> {
    let bottom = [0.0, 0.0, 0.0, 1.0];
    if m[3].iter().zip(bottom).any(|(a, b)| (a - b).abs() > 1e-4) {
        bail!("transform_matrix's bottom row is {:?}, not [0, 0, 0, 1]", m[3]);
    }
    let mut dev = 0.0f64;
    for i in 0..3 {
        for j in 0..3 {
            let dot: f64 = (0..3).map(|k| m[k][i] * m[k][j]).sum();
            dev = dev.max((dot - if i == j { 1.0 } else { 0.0 }).abs());
        }
    }
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if dev > 1e-3 || det < 0.0 {
        bail!("transform_matrix is not a rigid camera pose: its 3x3 rotation part has determinant {det:.4} and is off orthonormal by {dev:.3} (tgs needs a rotation and a translation, without scale, shear or mirroring)");
    }
    Ok(())
}

pub fn load(root: &Path, opts: &LoadOptions) -> Result<Dataset> {
    let (mut files, mut all_alpha) = (Vec::new(), true);
    let train = load_split(root, "train", opts, &mut files, &mut all_alpha)?.context("transforms_train.json vanished")?;
    let test = load_split(root, "test", opts, &mut files, &mut all_alpha)?;
    let mut warnings = Vec::new();
    if test.is_none() {
        warnings.push(format!("{}: no transforms_test.json: there are no test views, so no test metrics or renders", root.display()));
    }
    let test = test.unwrap_or_default();
    if !all_alpha {
        warnings.extend(backdrop_warning(&train, opts.background).map(|w| format!("{}: {w}", root.display())));
    }
    check_one_pose_per_file(root, &train, &test)?;
    let (train, test) = (train.into_iter().map(|(v, _)| v).collect(), test.into_iter().map(|(v, _)| v).collect());
    let ply = root.join("points3d.ply");
    let points = if ply.is_file() {
        files.push(ply.clone());
        let (pts, skipped) = crate::export::ply::read_points(&ply)?;
        warnings.extend(super::points_warning(&ply, pts.positions.len(), skipped));
        Some(pts)
    } else {
        None::<Points>
    };
    Ok(Dataset { root: root.to_path_buf(), format: "blender", train, test, points, background: opts.background, files, warnings })
}

/// Images without alpha whose borders are one flat colour far from the
/// background: a rendered backdrop (black, say) that the render's
/// background (white by default) cannot match. Judged by the median view.
fn backdrop_warning(views: &[(View, String)], background: [f32; 3]) -> Option<String> {
    let mut flat: Vec<([f32; 3], f32)> = views.iter().map(|(v, _)| border_colour(&v.image)).filter(|(_, spread)| *spread < 0.05).collect();
    // A photograph's border is not flat: then nothing is said.
    if flat.len() * 2 <= views.len() {
        return None;
    }
    let off = |c: &[f32; 3]| (0..3).map(|k| (c[k] - background[k]).abs()).fold(0f32, f32::max);
    flat.sort_by(|a, b| off(&a.0).total_cmp(&off(&b.0)));
    let (c, _) = flat[flat.len() / 2];
    (off(&c) > 0.25).then(|| {
        format!(
            "the images have no alpha and their borders are a flat {:.2},{:.2},{:.2}, not the background {:.2},{:.2},{:.2}: pass --background {:.2},{:.2},{:.2} (or black / white) so that empty space renders as the images show it",
            c[0], c[1], c[2], background[0], background[1], background[2], c[0], c[1], c[2]
        )
    })
}

/// An image named in both splits must have one pose (the same file seen
/// from two places is a broken dataset, not two views).
fn check_one_pose_per_file(root: &Path, train: &[(View, String)], test: &[(View, String)]) -> Result<()> {
    for (v, p) in test {
        if let Some((t, _)) = train.iter().find(|(_, q)| q == p) {
            if t.camera.world_to_view != v.camera.world_to_view {
                bail!("{}: '{p}' is a frame of both transforms_train.json and transforms_test.json with two different poses", root.display());
            }
        }
    }
    Ok(())
}

/// The path of a frame's file: `rel` under `root` (`./` allowed), with
/// `default_ext` when it has none. A path that leaves the dataset
/// directory (absolute, or through `..`) is refused: a dataset is one
/// directory, and tgs reads nothing outside it.
fn resolve(root: &Path, rel: &str, default_ext: &str) -> Result<std::path::PathBuf> {
    let mut depth = 0i32;
    if !Path::new(rel).components().any(|c| matches!(c, std::path::Component::Normal(_))) {
        bail!("file path '{rel}' names no file inside the dataset directory");
    }
    for c in Path::new(rel).components() {
        match c {
            std::path::Component::Normal(_) => depth += 1,
            std::path::Component::CurDir => {}
            std::path::Component::ParentDir => depth -= 1,
            _ => bail!("'{rel}' is an absolute path: file paths must be relative to the dataset directory"),
        }
        if depth < 0 {
            bail!("'{rel}' leaves the dataset directory (through '..'): file paths must stay inside it");
        }
    }
    let p = root.join(rel.trim_start_matches("./"));
    Ok(if p.extension().is_none() { p.with_extension(default_ext) } else { p })
}

/// Intrinsics as a transforms file gives them (each optional).
#[derive(Clone, Copy)]
struct Intrinsics {
    fl_x: Option<f64>,
    fl_y: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    w: Option<f64>,
    h: Option<f64>,
}

impl Intrinsics {
    /// These (a frame's), each falling back to `file`'s.
    fn or(self, file: &Intrinsics) -> Intrinsics {
        Intrinsics { fl_x: self.fl_x.or(file.fl_x), fl_y: self.fl_y.or(file.fl_y), cx: self.cx.or(file.cx), cy: self.cy.or(file.cy), w: self.w.or(file.w), h: self.h.or(file.h) }
    }

    /// They must describe the `w`x`h` image they come with: `w` and `h`,
    /// where given, its size; the principal point inside it. Intrinsics
    /// written for another size (a resized image folder) would train a
    /// misplaced camera without a word.
    fn check_fit(&self, w: u32, h: u32) -> Result<()> {
        if self.w.is_some_and(|v| v != w as f64) || self.h.is_some_and(|v| v != h as f64) {
            let show = |v: Option<f64>, d: u32| v.map_or(format!("{d} (not given)"), |v| format!("{v}"));
            bail!("the transforms give w = {}, h = {} but the image is {w}x{h}: intrinsics (fl_x, cx, ...) written for another image size; scale them to the image or use the images they were written for", show(self.w, w), show(self.h, h));
        }
        for (name, v, size) in [("cx", self.cx, w), ("cy", self.cy, h)] {
            if let Some(c) = v.filter(|&c| !(c > 0.0 && c < size as f64)) {
                bail!("{name} = {c} lies outside the {w}x{h} image: intrinsics written for another image size, or not in pixels");
            }
        }
        Ok(())
    }
}

/// Convert a Blender/OpenGL camera-to-world matrix to our world-to-view rows.
pub fn gl_c2w_to_w2v(m: &[[f64; 4]; 4]) -> [[f32; 4]; 3] {
    // OpenCV camera axes = OpenGL's with y and z flipped.
    let r = |i: usize, j: usize| if j == 0 { m[i][0] } else { -m[i][j] };
    let t = [m[0][3], m[1][3], m[2][3]];
    let mut rows = [[0f32; 4]; 3];
    for (j, row) in rows.iter_mut().enumerate() {
        // Row j of R^T is column j of R.
        let col = [r(0, j), r(1, j), r(2, j)];
        *row = [col[0] as f32, col[1] as f32, col[2] as f32, -(col[0] * t[0] + col[1] * t[1] + col[2] * t[2]) as f32];
    }
    rows
}

fn load_split(root: &Path, split: &str, opts: &LoadOptions, files: &mut Vec<std::path::PathBuf>, all_alpha: &mut bool) -> Result<Option<Vec<(View, String)>>> {
    let path = root.join(format!("transforms_{split}.json"));
    if !path.is_file() {
        return Ok(None);
    }
    super::image_io::regular_file(&path, "transforms file")?;
    let text = std::fs::read_to_string(&path).with_context(|| format!("{}: cannot read", path.display()))?;
    files.push(path.clone());
    // A byte-order mark (Windows editors write one) is not JSON.
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    let tf: Transforms = serde_json::from_str(&quote_non_finite(text)).with_context(|| format!("{}: not a valid transforms file", path.display()))?;
    let opt = |v: &Option<Num>, name: &str| v.as_ref().map(|n| n.finite(name)).transpose().with_context(|| path.display().to_string());
    let file_intrinsics = tf.intrinsics.finite().with_context(|| path.display().to_string())?;
    let angle_x = opt(&tf.camera_angle_x, "camera_angle_x")?;
    if tf.frames.is_empty() {
        bail!("{}: the {split} split has no frames", path.display());
    }
    let mut views = Vec::with_capacity(tf.frames.len());
    for (i, f) in tf.frames.iter().enumerate() {
        let what = || format!("{}: frame {i} ('{}')", path.display(), f.file_path);
        let m = frame_matrix(f).with_context(what)?;
        check_rigid(&m).with_context(what)?;
        if let Some(j) = tf.frames[..i].iter().position(|g| g.file_path == f.file_path) {
            bail!("{}: file_path '{}' is given twice (frames {j} and {i}): each image must be one frame", path.display(), f.file_path);
        }
        let img_path = resolve(root, &f.file_path, "png").with_context(what)?;
        files.push(img_path.clone());
        let (image, alpha) = read_rgb_alpha(&img_path, opts.background).with_context(what)?;
        *all_alpha &= alpha;
        let (w, h) = (image.width, image.height);
        let image = image.downscale(opts.downscale).with_context(|| format!("{}: {}", what(), img_path.display()))?;
        let intrinsics = f.intrinsics.finite().with_context(what)?.or(&file_intrinsics);
        intrinsics.check_fit(w, h).with_context(|| format!("{}: {}", what(), img_path.display()))?;
        let cam = frame_camera(intrinsics, angle_x, (w, h), &m).with_context(|| path.display().to_string())?;
        cam.validate().with_context(what)?;
        super::check_field_of_view(&cam).with_context(what)?;
        let (normals, mask) = frame_geometry(root, f, (w, h), opts, files).with_context(what)?;
        let name = Path::new(&f.file_path).file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| format!("{split}_{i}"));
        views.push((View { name, camera: downscale_camera(&cam, opts.downscale), image, normals, mask }, img_path.to_string_lossy().into_owned()));
    }
    Ok(Some(views))
}

/// A frame's `transform_matrix`: 4x4 and finite (naming the entry).
fn frame_matrix(f: &Frame) -> Result<[[f64; 4]; 4]> {
    if f.transform_matrix.len() != 4 || f.transform_matrix.iter().any(|r| r.len() != 4) {
        bail!("transform_matrix is not 4x4");
    }
    let mut m = [[0f64; 4]; 4];
    for (i, row) in f.transform_matrix.iter().enumerate() {
        for (j, v) in row.iter().enumerate() {
            m[i][j] = v.finite(&format!("transform_matrix[{i}][{j}]"))?;
        }
    }
    Ok(m)
}

/// A `w`x`h` frame's camera from its intrinsics (or the file's
/// `camera_angle_x`) and its camera-to-world matrix `m` (OpenGL axes).
fn frame_camera(intrinsics: Intrinsics, angle_x: Option<f64>, (w, h): (u32, u32), m: &[[f64; 4]; 4]) -> Result<Camera> {
    let Intrinsics { fl_x, fl_y, cx, cy, .. } = intrinsics;
    let fx = match (fl_x, angle_x) {
        (Some(fx), _) => fx,
        (None, Some(a)) if a > 0.0 && a < std::f64::consts::PI => 0.5 * w as f64 / (0.5 * a).tan(),
        (None, Some(a)) => bail!("camera_angle_x {a} is not in (0, pi)"),
        (None, None) => bail!("neither camera_angle_x nor fl_x is given"),
    };
    let fy = fl_y.unwrap_or(fx);
    // Principal point in pixel-edge coordinates (centre W/2), shifted to centres at integers.
    let cx = cx.unwrap_or(0.5 * w as f64) - 0.5;
    let cy = cy.unwrap_or(0.5 * h as f64) - 0.5;
    let cam = Camera { width: w, height: h, fx: fx as f32, fy: fy as f32, cx: cx as f32, cy: cy as f32, world_to_view: gl_c2w_to_w2v(m) };
    Ok(cam)
}

/// A `w`x`h` frame's ground-truth normals and glass mask, where it names
/// them (their files added to `files`), downscaled as the image is.
fn frame_geometry(
    root: &Path,
    f: &Frame,
    (w, h): (u32, u32),
    opts: &LoadOptions,
    files: &mut Vec<std::path::PathBuf>,
) -> Result<(Option<super::image_io::ImageF>, Option<Vec<bool>>)> {
    let normals = match &f.normal_path {
        Some(p) => {
            let np = resolve(root, p, "npy")?;
            files.push(np.clone());
            let n = read_normals(&np)?;
            if (n.width, n.height) != (w, h) {
                bail!("{}: normals are {}x{} but the image is {w}x{h}", np.display(), n.width, n.height);
            }
            Some(downscale_normals(&n, opts.downscale)?)
        }
        None => None,
    };
    let mask = match &f.mask_path {
        Some(p) => {
            let mp = resolve(root, p, "png")?;
            files.push(mp.clone());
            let (mw, mh, m) = read_mask(&mp)?;
            if (mw, mh) != (w, h) {
                bail!("{}: mask is {mw}x{mh} but the image is {w}x{h}", mp.display());
            }
            Some(downscale_mask(w, h, &m, opts.downscale))
        }
        None => None,
    };
    Ok((normals, mask))
}
