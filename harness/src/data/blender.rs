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
    camera_angle_x: Option<f64>,
    fl_x: Option<f64>,
    fl_y: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    frames: Vec<Frame>,
}

#[derive(Deserialize)]
struct Frame {
    file_path: String,
    transform_matrix: Vec<Vec<f64>>,
    normal_path: Option<String>,
    mask_path: Option<String>,
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
    let tf: Transforms = serde_json::from_str(&text).with_context(|| format!("{}: not a valid transforms file", path.display()))?;
    if tf.frames.is_empty() {
        bail!("{}: the {split} split has no frames", path.display());
    }
    let mut views = Vec::with_capacity(tf.frames.len());
    for (i, f) in tf.frames.iter().enumerate() {
        let what = || format!("{}: frame {i} ('{}')", path.display(), f.file_path);
        let rows: Vec<[f64; 4]> = f.transform_matrix.iter().map(|r| <[f64; 4]>::try_from(r.as_slice())).collect::<Result<_, _>>().map_err(|_| anyhow::anyhow!("{}: transform_matrix is not 4x4", what()))?;
        let m: [[f64; 4]; 4] = rows.try_into().map_err(|_| anyhow::anyhow!("{}: transform_matrix is not 4x4", what()))?;
        if m.iter().flatten().any(|v| !v.is_finite()) {
            bail!("{}: transform_matrix has a non-finite value", what());
        }
        let img_path = resolve(root, &f.file_path, "png");
        let image = read_rgb(&img_path, opts.background).with_context(what)?;
        let (w, h) = (image.width, image.height);
        let fx = match (tf.fl_x, tf.camera_angle_x) {
            (Some(fx), _) => fx,
            (None, Some(a)) if a > 0.0 && a < std::f64::consts::PI => 0.5 * w as f64 / (0.5 * a).tan(),
            (None, Some(a)) => bail!("{}: camera_angle_x {a} is not in (0, pi)", path.display()),
            (None, None) => bail!("{}: neither camera_angle_x nor fl_x is given", path.display()),
        };
        let fy = tf.fl_y.unwrap_or(fx);
        // Principal point in pixel-edge coordinates (centre W/2), shifted to centres at integers.
        let cx = tf.cx.unwrap_or(0.5 * w as f64) - 0.5;
        let cy = tf.cy.unwrap_or(0.5 * h as f64) - 0.5;
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
        let image = image.downscale(opts.downscale).with_context(what)?;
        let name = Path::new(&f.file_path).file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| format!("{split}_{i}"));
        views.push(View { name, camera: downscale_camera(&cam, opts.downscale), image, normals, mask });
    }
    Ok(Some(views))
}
