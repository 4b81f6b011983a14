//! Datasets: the NeRF-synthetic/Blender layout (with the optional per-frame
//! normals and transmissive masks of this project) and COLMAP sparse models.
//! Every camera convention is converted at load time to the rasterizer's
//! (OpenCV axes, pixel centres at integers, per-image fx, fy, cx, cy).

pub mod blender;
pub mod colmap;
pub mod fingerprint;
pub mod image_io;

use anyhow::{bail, Result};
use image_io::ImageF;
use std::path::{Path, PathBuf};
use tgs_pipelines::Camera;

pub use crate::export::ply::Points;

/// One image with its camera and optional geometry ground truth.
#[derive(Clone, Debug)]
pub struct View {
    pub name: String,
    pub camera: Camera,
    /// RGB in [0, 1], interleaved.
    pub image: ImageF,
    /// World-space unit normals facing the camera (HxWx3), if given.
    pub normals: Option<ImageF>,
    /// True where the first hit is transmissive, if given.
    pub mask: Option<Vec<bool>>,
}

#[derive(Clone, Debug)]
pub struct Dataset {
    pub root: PathBuf,
    pub format: &'static str,
    pub train: Vec<View>,
    pub test: Vec<View>,
    pub points: Option<Points>,
    pub background: [f32; 3],
    /// Every file the load read (its [`fingerprint::Fingerprint`]'s list).
    pub files: Vec<PathBuf>,
    /// What the load found suspicious but not wrong (a backdrop that is
    /// not the background, skipped points), for the commands to show.
    pub warnings: Vec<String>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoadOptions {
    /// Integer image downscale factor (1 = full size).
    pub downscale: u32,
    /// Background RGBA images are composited on (and the render's background).
    pub background: [f32; 3],
    /// COLMAP: every `holdout`-th image (sorted by name) is a test image; 0 = none.
    pub holdout: u32,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions { downscale: 1, background: [1.0; 3], holdout: 8 }
    }
}

impl Dataset {
    /// Load a Blender-layout (transforms_train.json) or COLMAP (sparse/) dataset.
    pub fn load(root: &Path, opts: &LoadOptions) -> Result<Dataset> {
        if opts.downscale == 0 {
            bail!("--downscale must be at least 1");
        }
        if !root.is_dir() {
            bail!("{}: dataset directory does not exist", root.display());
        }
        let ds = if root.join("transforms_train.json").is_file() {
            blender::load(root, opts)?
        } else if colmap::find_model(root).is_some() {
            colmap::load(root, opts)?
        } else if let Some(d) = [root.join("sparse/0"), root.join("sparse")].into_iter().find(|d| d.is_dir()) {
            bail!("{}: a COLMAP model directory without cameras.txt or cameras.bin (it needs cameras, images and optionally points3D, as .txt or .bin)", d.display());
        } else {
            bail!("{}: neither transforms_train.json (Blender layout) nor sparse/0 or sparse/ (COLMAP) found", root.display());
        };
        if ds.train.is_empty() {
            bail!("{}: the training split is empty", root.display());
        }
        if let Some(o) = camera_outlier(ds.train.iter().chain(&ds.test), CAMERA_OUTLIER_FACTOR) {
            bail!("{}: {o}: a pose in other units or a corrupt transform; fix or remove that view", root.display());
        }
        Ok(ds)
    }

    /// The fingerprint of the files the load read.
    pub fn fingerprint(&self) -> Result<fingerprint::Fingerprint> {
        fingerprint::Fingerprint::of(&self.root, &self.files)
    }

    /// Scene extent (method-notes §1.12): 1.1 x the largest distance of a
    /// training camera from their mean, and that mean.
    pub fn extent(&self) -> (f32, [f32; 3]) {
        let centres: Vec<[f32; 3]> = self.train.iter().map(|v| v.camera.centre()).collect();
        let n = centres.len().max(1) as f32;
        let mut mean = [0.0f32; 3];
        for c in &centres {
            for k in 0..3 {
                mean[k] += c[k] / n;
            }
        }
        let far = centres.iter().map(|c| (0..3).map(|k| (c[k] - mean[k]).powi(2)).sum::<f32>().sqrt()).fold(0.0f32, f32::max);
        (1.1 * far.max(1e-6), mean)
    }
}

/// Fewer initial points than this are warned about: the Gaussians start
/// from them alone.
pub const FEW_POINTS: usize = 100;

/// What to say of a dataset's initial points (`path`): those skipped for
/// NaN or infinite coordinates, none left (random points instead), or
/// few left.
/// The image extensions a view's name may end in (COLMAP names views by
/// their image file, `0000.jpg`).
const IMAGE_EXTENSIONS: [&str; 6] = ["png", "jpg", "jpeg", "exr", "tif", "tiff"];

/// The names the files written per view take (renders, residual maps):
/// each view's name without its image extension (`0000.jpg` → `0000`), or
/// the whole name where two views would otherwise share one.
pub fn file_stems<'a>(names: impl IntoIterator<Item = &'a str>) -> Vec<String> {
    let names: Vec<&str> = names.into_iter().collect();
    let strip = |n: &str| -> String {
        match n.rsplit_once('.') {
            Some((stem, ext)) if !stem.is_empty() && !stem.ends_with('/') && IMAGE_EXTENSIONS.contains(&ext.to_ascii_lowercase().as_str()) => stem.to_string(),
            _ => n.to_string(),
        }
    };
    let stems: Vec<String> = names.iter().map(|n| strip(n)).collect();
    let mut count = std::collections::HashMap::new();
    for s in &stems {
        *count.entry(s.as_str()).or_insert(0) += 1;
    }
    names.iter().zip(&stems).map(|(n, s)| if count[s.as_str()] > 1 { n.to_string() } else { s.clone() }).collect()
}

pub fn points_warning(path: &Path, kept: usize, skipped: usize) -> Option<String> {
    let skipped_note = if skipped > 0 { format!("{skipped} of {} points have NaN or infinite coordinates and are skipped; ", skipped + kept) } else { String::new() };
    let what = if kept == 0 {
        "it holds no usable point: the Gaussians start from init_points random points instead".to_string()
    } else if kept < FEW_POINTS {
        format!(
            "only {kept} usable point(s): training starts from {kept} Gaussian(s) and densification must grow the rest (delete the file to start from init_points random points)"
        )
    } else if skipped > 0 {
        return Some(format!("{}: {}", path.display(), skipped_note.trim_end_matches("; ")));
    } else {
        return None;
    };
    Some(format!("{}: {skipped_note}{what}", path.display()))
}

/// A camera this many times farther from the cameras' median point than
/// their median distance from it is refused at load time.
pub const CAMERA_OUTLIER_FACTOR: f64 = 1e4;

/// The camera farthest from the views' median centre (per axis), when it
/// lies more than `factor` times the median distance from there, said by
/// name and distance. None with fewer than three views or all cameras at
/// one point.
pub fn camera_outlier<'a>(views: impl IntoIterator<Item = &'a View>, factor: f64) -> Option<String> {
    let views: Vec<&View> = views.into_iter().collect();
    if views.len() < 3 {
        return None;
    }
    let centres: Vec<[f64; 3]> = views.iter().map(|v| v.camera.centre().map(f64::from)).collect();
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let mid: [f64; 3] = std::array::from_fn(|k| median(centres.iter().map(|c| c[k]).collect()));
    let dist: Vec<f64> = centres.iter().map(|c| (0..3).map(|k| (c[k] - mid[k]).powi(2)).sum::<f64>().sqrt()).collect();
    let typical = median(dist.clone());
    let (i, far) = dist.iter().copied().enumerate().max_by(|a, b| a.1.total_cmp(&b.1))?;
    (typical > 0.0 && far > factor * typical)
        .then(|| format!("view '{}': its camera lies {far:.3e} from the cameras' median point, {:.1e} times their median distance ({typical:.3})", views[i].name, far / typical))
}

/// The narrowest field of view a dataset camera may have: focal lengths
/// up to 10^4 times the image size (0.0057°; a 2,000 mm lens on a full
/// frame sensor is 1.2°). A larger one is a unit or parse error (degrees
/// for radians, a focal length in mm for one in pixels), and would train
/// on a scene squeezed into a line of sight.
pub const MAX_FOCAL_PER_PIXEL: f32 = 1e4;

/// Refuse a camera whose field of view is implausibly narrow.
pub fn check_field_of_view(cam: &Camera) -> Result<()> {
    let (rx, ry) = (cam.fx / cam.width as f32, cam.fy / cam.height as f32);
    if rx > MAX_FOCAL_PER_PIXEL || ry > MAX_FOCAL_PER_PIXEL {
        bail!(
            "focal length {} x {} px on a {}x{} image: a field of view under {:.4}°, implausibly narrow (check camera_angle_x / fl_x units: radians and pixels)",
            cam.fx,
            cam.fy,
            cam.width,
            cam.height,
            2.0 * (0.5 / MAX_FOCAL_PER_PIXEL).atan().to_degrees()
        );
    }
    Ok(())
}

/// Scale a camera's intrinsics for an image downscaled by `factor` (pixel
/// centres at integers: x' = (x + 0.5) / f - 0.5).
pub fn downscale_camera(cam: &Camera, factor: u32) -> Camera {
    if factor <= 1 {
        return *cam;
    }
    let f = factor as f32;
    Camera { width: cam.width / factor, height: cam.height / factor, fx: cam.fx / f, fy: cam.fy / f, cx: (cam.cx + 0.5) / f - 0.5, cy: (cam.cy + 0.5) / f - 0.5, ..*cam }
}

/// Downscale a mask: a pixel stays set only when all its sub-pixels are.
pub fn downscale_mask(w: u32, h: u32, mask: &[bool], factor: u32) -> Vec<bool> {
    if factor <= 1 {
        return mask.to_vec();
    }
    let (nw, nh) = (w / factor, h / factor);
    let mut out = vec![false; (nw * nh) as usize];
    for y in 0..nh {
        for x in 0..nw {
            let mut all = true;
            for dy in 0..factor {
                for dx in 0..factor {
                    all &= mask[((y * factor + dy) * w + x * factor + dx) as usize];
                }
            }
            out[(y * nw + x) as usize] = all;
        }
    }
    out
}

/// Downscale normals: average, then renormalise.
pub fn downscale_normals(n: &ImageF, factor: u32) -> Result<ImageF> {
    let mut d = n.downscale(factor)?;
    for p in d.data.chunks_mut(3) {
        let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        if l > 1e-12 {
            p.iter_mut().for_each(|v| *v /= l);
        }
    }
    Ok(d)
}
