//! NeRF-synthetic / Blender layout: transforms_{train,test}.json with
//! `camera_angle_x` (or per-file fl_x/fl_y/cx/cy/w/h), per-frame 4x4
//! camera-to-world matrices in OpenGL axes, RGBA PNGs composited on the
//! background, and this project's optional `normal_path` / `mask_path`.

use super::image_io::{read_mask, read_normals, read_rgb};
use super::{downscale_camera, downscale_mask, downscale_normals, Dataset, LoadOptions, Points, View};
use anyhow::{bail, Context as _, Result};
use serde::Deserialize;
use std::path::Path;
use tgs_pipelines::Camera;

#[derive(Deserialize)]
struct Transforms {
    camera_angle_x: Option<Num>,
    fl_x: Option<Num>,
    fl_y: Option<Num>,
    cx: Option<Num>,
    cy: Option<Num>,
    frames: Vec<Frame>,
}

#[derive(Deserialize)]
struct Frame {
    file_path: String,
    transform_matrix: Vec<Vec<Num>>,
    normal_path: Option<String>,
    mask_path: Option<String>,
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
    let train = load_split(root, "train", opts)?.context("transforms_train.json vanished")?;
    let test = load_split(root, "test", opts)?.unwrap_or_default();
    let ply = root.join("points3d.ply");
    let points = if ply.is_file() { Some(crate::export::ply::read_points(&ply)?) } else { None::<Points> };
    Ok(Dataset { root: root.to_path_buf(), format: "blender", train, test, points, background: opts.background })
}

fn resolve(root: &Path, rel: &str, default_ext: &str) -> std::path::PathBuf {
    let p = root.join(rel.trim_start_matches("./"));
    if p.extension().is_none() {
        p.with_extension(default_ext)
    } else {
        p
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

fn load_split(root: &Path, split: &str, opts: &LoadOptions) -> Result<Option<Vec<View>>> {
    let path = root.join(format!("transforms_{split}.json"));
    if !path.is_file() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path).with_context(|| format!("{}: cannot read", path.display()))?;
    let tf: Transforms = serde_json::from_str(&quote_non_finite(&text)).with_context(|| format!("{}: not a valid transforms file", path.display()))?;
    let opt = |v: &Option<Num>, name: &str| v.as_ref().map(|n| n.finite(name)).transpose().with_context(|| path.display().to_string());
    let (fl_x, fl_y, cx, cy) = (opt(&tf.fl_x, "fl_x")?, opt(&tf.fl_y, "fl_y")?, opt(&tf.cx, "cx")?, opt(&tf.cy, "cy")?);
    let angle_x = opt(&tf.camera_angle_x, "camera_angle_x")?;
    if tf.frames.is_empty() {
        bail!("{}: the {split} split has no frames", path.display());
    }
    let mut views = Vec::with_capacity(tf.frames.len());
    for (i, f) in tf.frames.iter().enumerate() {
        let what = || format!("{}: frame {i} ('{}')", path.display(), f.file_path);
        if f.transform_matrix.len() != 4 || f.transform_matrix.iter().any(|r| r.len() != 4) {
            bail!("{}: transform_matrix is not 4x4", what());
        }
        let mut m = [[0f64; 4]; 4];
        for (i, row) in f.transform_matrix.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                m[i][j] = v.finite(&format!("transform_matrix[{i}][{j}]")).with_context(what)?;
            }
        }
        check_rigid(&m).with_context(what)?;
        let img_path = resolve(root, &f.file_path, "png");
        let image = read_rgb(&img_path, opts.background).with_context(what)?;
        let (w, h) = (image.width, image.height);
        let image = image.downscale(opts.downscale).with_context(|| format!("{}: {}", what(), img_path.display()))?;
        let fx = match (fl_x, angle_x) {
            (Some(fx), _) => fx,
            (None, Some(a)) if a > 0.0 && a < std::f64::consts::PI => 0.5 * w as f64 / (0.5 * a).tan(),
            (None, Some(a)) => bail!("{}: camera_angle_x {a} is not in (0, pi)", path.display()),
            (None, None) => bail!("{}: neither camera_angle_x nor fl_x is given", path.display()),
        };
        let fy = fl_y.unwrap_or(fx);
        // Principal point in pixel-edge coordinates (centre W/2), shifted to centres at integers.
        let cx = cx.unwrap_or(0.5 * w as f64) - 0.5;
        let cy = cy.unwrap_or(0.5 * h as f64) - 0.5;
        let cam = Camera { width: w, height: h, fx: fx as f32, fy: fy as f32, cx: cx as f32, cy: cy as f32, world_to_view: gl_c2w_to_w2v(&m) };
        cam.validate().with_context(what)?;
        let normals = match &f.normal_path {
            Some(p) => {
                let np = resolve(root, p, "npy");
                let n = read_normals(&np).with_context(what)?;
                if (n.width, n.height) != (w, h) {
                    bail!("{}: normals are {}x{} but the image is {w}x{h}", np.display(), n.width, n.height);
                }
                Some(downscale_normals(&n, opts.downscale)?)
            }
            None => None,
        };
        let mask = match &f.mask_path {
            Some(p) => {
                let mp = resolve(root, p, "png");
                let (mw, mh, m) = read_mask(&mp).with_context(what)?;
                if (mw, mh) != (w, h) {
                    bail!("{}: mask is {mw}x{mh} but the image is {w}x{h}", mp.display());
                }
                Some(downscale_mask(w, h, &m, opts.downscale))
            }
            None => None,
        };
        let name = Path::new(&f.file_path).file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| format!("{split}_{i}"));
        views.push(View { name, camera: downscale_camera(&cam, opts.downscale), image, normals, mask });
    }
    Ok(Some(views))
}
