//! Evaluation on test views: PSNR and SSIM (the 3DGS/2DGS conventions of
//! method-notes §5: renders clamped to [0, 1], 11x11 Gaussian SSIM with zero
//! padding, per-image values averaged), and where the dataset has normals
//! and transmissive masks, the mean angular error (degrees) of the rendered
//! normal on mask pixels (a mask pixel the render leaves empty counts 90°),
//! next to the error of a normal that faces each pixel's camera ray.
//! Also writes the renders: colour PNG, world normals PNG, depth EXR + PNG.

use crate::data::image_io::{depth_grey, write_exr, write_png, ImageF};
use crate::data::View;
use crate::outdir::OutDir;
use crate::train::trainer::Rendered;
use crate::train::Trainer;
use anyhow::Result;
use serde::Serialize;
use tgs_pipelines::{Camera, Plane};

/// Normal errors on the transmissive mask (degrees); None without a ground
/// truth or mask pixels, and the Stage II ones before Stage II.
#[derive(Clone, Debug, Default, Serialize)]
pub struct NormalMetrics {
    pub normal_mae_deg: Option<f64>,
    /// In Stage II: the scattering set's own normals (the field above uses
    /// the reflection set's where it covers the pixel).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub normal_mae_scattering_deg: Option<f64>,
    /// In Stage II: the fraction of mask pixels the reflection set decides
    /// (covers with alpha >= 0.5 and R >= `Trainer::normal_min_r`:
    /// `trainer::reflection_decides`), and the normal MAE on those pixels alone.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reflection_coverage: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub normal_mae_covered_deg: Option<f64>,
    /// In Stage II: of the pixels the reflection set covers, the fraction
    /// outside the transmissive mask. There its normals replace the
    /// scattering set's although no glass is there; the MAEs above, taken
    /// on the mask, do not see it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reflection_outside_mask: Option<f64>,
    /// The MAE, on the same mask pixels, of a normal facing each pixel's
    /// camera ray ([`ray_facing_normals`]): what a normal that knows
    /// nothing of the surface scores. Normals carry surface information
    /// only as far as their MAE is below this.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub normal_mae_ray_facing_deg: Option<f64>,
    /// The MAE of the output normals on the pixels outside the mask that
    /// have a ground-truth normal (datasets whose normals cover the whole
    /// image): the rest of the scene, where Stage II must not make Stage
    /// I's normals worse.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub normal_mae_outside_deg: Option<f64>,
    /// In Stage II and later: how much the reflection layer lowers the
    /// image error on the mask (and off it): the mean over those pixels of
    /// |I_gt - I_scat| - |I_gt - I|, channel-averaged, with I_scat the
    /// scattering layer alone and I the composite ([`layer_gain`]). > 0
    /// where the reflection layer explains what the scattering set misses
    /// on held-out views; it bounds the photometric evidence the reflection
    /// set's normals can learn from.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reflection_gain_mask: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reflection_gain_outside: Option<f64>,
    /// The scattering set's residual contrast: its mean image error
    /// |I_gt - I_scat| on the mask over its mean error off the mask
    /// ([`residual_contrast`]; I_scat is the render itself in Stage I).
    /// Stage II seeds the reflection set where the Stage I residual is, so
    /// this is how strongly the held-out views mark the glass for it: near
    /// 1, Stage I reproduced the glass's reflections as well as the rest
    /// of the scene (perf/RESULTS.md, forty-third entry: 0.6-1.4 on the
    /// path-traced suite at 50x50) and the residual does not say where the
    /// glass is.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub residual_contrast: Option<f64>,
}

impl NormalMetrics {
    /// Field by field, the mean over the views that have it.
    fn mean<'a>(views: impl Iterator<Item = &'a NormalMetrics> + Clone) -> NormalMetrics {
        let mean_of = |f: fn(&NormalMetrics) -> Option<f64>| -> Option<f64> {
            let v: Vec<f64> = views.clone().filter_map(f).collect();
            (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
        };
        NormalMetrics {
            normal_mae_deg: mean_of(|m| m.normal_mae_deg),
            normal_mae_scattering_deg: mean_of(|m| m.normal_mae_scattering_deg),
            reflection_coverage: mean_of(|m| m.reflection_coverage),
            normal_mae_covered_deg: mean_of(|m| m.normal_mae_covered_deg),
            reflection_outside_mask: mean_of(|m| m.reflection_outside_mask),
            normal_mae_ray_facing_deg: mean_of(|m| m.normal_mae_ray_facing_deg),
            normal_mae_outside_deg: mean_of(|m| m.normal_mae_outside_deg),
            reflection_gain_mask: mean_of(|m| m.reflection_gain_mask),
            reflection_gain_outside: mean_of(|m| m.reflection_gain_outside),
            residual_contrast: mean_of(|m| m.residual_contrast),
        }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct ViewMetrics {
    pub name: String,
    pub psnr: f64,
    pub ssim: f64,
    /// LPIPS (AlexNet v0.1, crate::lpips); None without the weights or
    /// below 31 pixels a side.
    pub lpips: Option<f64>,
    #[serde(flatten)]
    pub normals: NormalMetrics,
}

#[derive(Clone, Debug, Serialize)]
pub struct Metrics {
    pub iteration: u32,
    pub gaussians: u32,
    pub views: usize,
    pub psnr: f64,
    pub ssim: f64,
    /// The mean over the views that have one.
    pub lpips: Option<f64>,
    #[serde(flatten)]
    pub normals: NormalMetrics,
    pub per_view: Vec<ViewMetrics>,
}

pub fn psnr(a: &[f32], b: &[f32]) -> f64 {
    let mse = a.iter().zip(b).map(|(x, y)| ((x.clamp(0.0, 1.0) - y) as f64).powi(2)).sum::<f64>() / a.len().max(1) as f64;
    -10.0 * mse.max(1e-20).log10()
}

/// Mean SSIM over channels and pixels of two planar images (f64).
pub fn ssim(a: &[f32], b: &[f32], w: usize, h: usize, channels: usize) -> f64 {
    let g: Vec<f64> = {
        let raw: Vec<f64> = (-5..=5).map(|t: i32| (-(t * t) as f64 / (2.0 * 1.5 * 1.5)).exp()).collect();
        let s: f64 = raw.iter().sum();
        raw.iter().map(|v| v / s).collect()
    };
    let blur = |src: &[f64]| -> Vec<f64> {
        let mut tmp = vec![0.0; w * h];
        let mut out = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                tmp[y * w + x] = (-5i64..=5)
                    .filter_map(|t| {
                        let xx = x as i64 + t;
                        (xx >= 0 && xx < w as i64).then(|| g[(t + 5) as usize] * src[y * w + xx as usize])
                    })
                    .sum();
            }
        }
        for y in 0..h {
            for x in 0..w {
                out[y * w + x] = (-5i64..=5)
                    .filter_map(|t| {
                        let yy = y as i64 + t;
                        (yy >= 0 && yy < h as i64).then(|| g[(t + 5) as usize] * tmp[yy as usize * w + x])
                    })
                    .sum();
            }
        }
        out
    };
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let n = w * h;
    let mut total = 0.0;
    for c in 0..channels {
        let x: Vec<f64> = a[c * n..(c + 1) * n].iter().map(|v| v.clamp(0.0, 1.0) as f64).collect();
        let y: Vec<f64> = b[c * n..(c + 1) * n].iter().map(|&v| v as f64).collect();
        let prod = |p: &[f64], q: &[f64]| p.iter().zip(q).map(|(a, b)| a * b).collect::<Vec<_>>();
        let (mx, my) = (blur(&x), blur(&y));
        let (exx, eyy, exy) = (blur(&prod(&x, &x)), blur(&prod(&y, &y)), blur(&prod(&x, &y)));
        for i in 0..n {
            let (sx, sy, sxy) = (exx[i] - mx[i] * mx[i], eyy[i] - my[i] * my[i], exy[i] - mx[i] * my[i]);
            total += ((2.0 * mx[i] * my[i] + c1) * (2.0 * sxy + c2)) / ((mx[i] * mx[i] + my[i] * my[i] + c1) * (sx + sy + c2));
        }
    }
    total / (n * channels).max(1) as f64
}

/// World-space unit normals (interleaved) of a render; zero where empty.
pub fn world_normals(r: &Rendered, cam: &Camera) -> Vec<[f32; 3]> {
    world_normals_of([r.plane(Plane::Normal(0)), r.plane(Plane::Normal(1)), r.plane(Plane::Normal(2))], cam)
}

/// Unit world-space normals from three view-space normal planes (zero where empty).
pub fn world_normals_of([nx, ny, nz]: [&[f32]; 3], cam: &Camera) -> Vec<[f32; 3]> {
    let m = &cam.world_to_view;
    (0..nx.len())
        .map(|i| {
            let v = [nx[i], ny[i], nz[i]];
            // world = R^T view
            let w = [0, 1, 2].map(|j| (0..3).map(|k| m[k][j] * v[k]).sum::<f32>());
            let l = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
            if l > 1e-8 && l.is_finite() {
                w.map(|x| x / l)
            } else {
                [0.0; 3]
            }
        })
        .collect()
}

/// Unit world-space normals facing each pixel's camera ray: pixel `i`'s
/// normal points from its pixel centre's ray back to the camera.
pub fn ray_facing_normals(cam: &Camera) -> Vec<[f32; 3]> {
    // In view space the ray through pixel (u, v) is ((u - cx) / fx, (v - cy) / fy, 1).
    let (w, n) = (cam.width as usize, (cam.width * cam.height) as usize);
    let nx: Vec<f32> = (0..n).map(|i| -((i % w) as f32 - cam.cx) / cam.fx).collect();
    let ny: Vec<f32> = (0..n).map(|i| -((i / w) as f32 - cam.cy) / cam.fy).collect();
    world_normals_of([&nx, &ny, &vec![-1.0; n]], cam)
}

/// Mean angular error (degrees) on mask pixels; None without a GT or mask pixels.
pub fn normal_mae(normals: &[[f32; 3]], view: &View) -> Option<f64> {
    normal_mae_where(normals, view, |_| true)
}

/// [`normal_mae`] on the mask pixels `i` with `keep(i)`.
fn normal_mae_where(normals: &[[f32; 3]], view: &View, keep: impl Fn(usize) -> bool) -> Option<f64> {
    normal_mae_of(normals, view, true, keep)
}

/// Mean angular error (degrees) on the pixels outside the mask that have a
/// ground-truth normal; None without a GT, a mask or such pixels.
pub fn normal_mae_outside(normals: &[[f32; 3]], view: &View) -> Option<f64> {
    normal_mae_of(normals, view, false, |_| true)
}

/// The mean angular error on the pixels `i` whose mask is `on_mask` and
/// with `keep(i)`, skipping pixels without a ground-truth normal; an empty
/// output normal counts 90 degrees.
fn normal_mae_of(normals: &[[f32; 3]], view: &View, on_mask: bool, keep: impl Fn(usize) -> bool) -> Option<f64> {
    let (gt, mask) = (view.normals.as_ref()?, view.mask.as_ref()?);
    let mut sum = 0.0;
    let mut count = 0usize;
    for (i, &m) in mask.iter().enumerate() {
        if m != on_mask || !keep(i) {
            continue;
        }
        let g = &gt.data[3 * i..3 * i + 3];
        let gl = (g.iter().map(|v| (*v as f64).powi(2)).sum::<f64>()).sqrt();
        if gl < 1e-6 {
            continue;
        }
        let n = normals[i];
        let d = (0..3).map(|k| n[k] as f64 * g[k] as f64).sum::<f64>() / gl;
        let empty = n == [0.0; 3];
        sum += if empty { 90.0 } else { d.clamp(-1.0, 1.0).acos().to_degrees() };
        count += 1;
    }
    (count > 0).then(|| sum / count as f64)
}

/// The mean over the pixels `keep` selects of |gt - scat| - |gt - full|
/// (planar RGB, values clamped to [0, 1] as [`psnr`] does, channels
/// averaged): how much the composite `full` improves on its scattering
/// layer `scat` against `gt`. None where `keep` selects no pixel.
pub fn layer_gain(full: &[f32], scat: &[f32], gt: &[f32], keep: impl Fn(usize) -> bool) -> Option<f64> {
    let n = gt.len() / 3;
    let (mut sum, mut count) = (0.0f64, 0usize);
    for i in (0..n).filter(|&i| keep(i)) {
        for c in 0..3 {
            let j = c * n + i;
            let g = gt[j] as f64;
            sum += ((g - scat[j].clamp(0.0, 1.0) as f64).abs() - (g - full[j].clamp(0.0, 1.0) as f64).abs()) / 3.0;
        }
        count += 1;
    }
    (count > 0).then(|| sum / count as f64)
}

/// The mean of |gt - scat| on the pixels where `mask` is true over its
/// mean where it is false (planar RGB, values clamped to [0, 1] as
/// [`psnr`] does, channels averaged). None where either side has no pixel
/// or the error off the mask is 0.
pub fn residual_contrast(scat: &[f32], gt: &[f32], mask: &[bool]) -> Option<f64> {
    let n = gt.len() / 3;
    let mut sum = [0.0f64; 2];
    let mut count = [0usize; 2];
    for (i, &m) in mask.iter().enumerate().take(n) {
        let e: f64 = (0..3).map(|c| (gt[c * n + i] as f64 - scat[c * n + i].clamp(0.0, 1.0) as f64).abs()).sum::<f64>() / 3.0;
        sum[m as usize] += e;
        count[m as usize] += 1;
    }
    if count[0] == 0 || count[1] == 0 || sum[0] <= 0.0 {
        return None;
    }
    Some((sum[1] / count[1] as f64) / (sum[0] / count[0] as f64))
}

/// Render, measure and (with `out`) write every view.
pub fn evaluate(tr: &mut Trainer, views: &[View], mut out: Option<&mut OutDir>) -> Result<Metrics> {
    let mut per_view = Vec::new();
    let stems = crate::data::file_stems(views.iter().map(|v| v.name.as_str()));
    for (v, stem) in views.iter().zip(&stems) {
        let r = tr.render(&v.camera)?;
        let (w, h) = (r.width as usize, r.height as usize);
        let rgb = &r.planes[..3 * w * h];
        let target = v.image.planar();
        let normals = world_normals(&r, &v.camera);
        let scat_mae = r.layers.as_ref().and_then(|l| normal_mae(&world_normals(&l.0, &v.camera), v));
        let gate = tr.normal_gate();
        let covered = |i: usize| r.layers.as_ref().is_some_and(|l| crate::train::stages::reflection::reflection_decides(&l.1, i, gate));
        let coverage = match (&r.layers, &v.mask) {
            (Some(_), Some(mask)) if mask.iter().any(|&m| m) => {
                Some((0..mask.len()).filter(|&i| mask[i] && covered(i)).count() as f64 / mask.iter().filter(|&&m| m).count() as f64)
            }
            _ => None,
        };
        let outside = match (&r.layers, &v.mask) {
            (Some(_), Some(mask)) => {
                let (all, off) = (0..mask.len()).filter(|&i| covered(i)).fold((0usize, 0usize), |(a, o), i| (a + 1, o + !mask[i] as usize));
                (all > 0).then(|| off as f64 / all as f64)
            }
            _ => None,
        };
        let gain = |on_mask: bool| match (&r.layers, &v.mask) {
            (Some(l), Some(mask)) => layer_gain(rgb, &l.0.planes[..3 * w * h], &target, |i| mask[i] == on_mask),
            _ => None,
        };
        let m = ViewMetrics {
            name: v.name.clone(),
            psnr: psnr(rgb, &target),
            ssim: ssim(rgb, &target, w, h, 3),
            lpips: crate::lpips::shared().and_then(|net| net.distance(&rgb.iter().map(|v| v.clamp(0.0, 1.0)).collect::<Vec<f32>>(), &target, w, h)),
            normals: NormalMetrics {
                normal_mae_deg: normal_mae(&normals, v),
                normal_mae_scattering_deg: scat_mae,
                reflection_coverage: coverage,
                reflection_outside_mask: outside,
                normal_mae_covered_deg: r.layers.as_ref().and_then(|_| normal_mae_where(&normals, v, covered)),
                normal_mae_ray_facing_deg: v.normals.as_ref().and_then(|_| normal_mae(&ray_facing_normals(&v.camera), v)),
                normal_mae_outside_deg: normal_mae_outside(&normals, v),
                reflection_gain_mask: gain(true),
                reflection_gain_outside: gain(false),
                residual_contrast: v.mask.as_ref().and_then(|mask| residual_contrast(r.layers.as_ref().map_or(rgb, |l| &l.0.planes[..3 * w * h]), &target, mask)),
            },
        };
        if let Some(dir) = out.as_deref_mut() {
            write_outputs(dir, stem, &r, &normals, &v.camera)?;
        }
        per_view.push(m);
    }
    let k = per_view.len().max(1) as f64;
    Ok(Metrics {
        normals: NormalMetrics::mean(per_view.iter().map(|m| &m.normals)),
        iteration: tr.iteration,
        gaussians: tr.scattering.set.len() + tr.reflection().map(|r| r.set.len()).unwrap_or(0),
        views: per_view.len(),
        psnr: per_view.iter().map(|m| m.psnr).sum::<f64>() / k,
        ssim: per_view.iter().map(|m| m.ssim).sum::<f64>() / k,
        lpips: {
            let l: Vec<f64> = per_view.iter().filter_map(|m| m.lpips).collect();
            (!l.is_empty()).then(|| l.iter().sum::<f64>() / l.len() as f64)
        },
        per_view,
    })
}

/// `NAME.png` (colour), `NAME_normal.png` (world normal * 0.5 + 0.5),
/// `NAME_depth.exr` (expected depth, 0 where empty) and `NAME_depth.png`
/// (normalised to the view's depth range).
pub fn write_outputs(dir: &mut OutDir, name: &str, r: &Rendered, normals: &[[f32; 3]], cam: &Camera) -> Result<()> {
    let depth = expected_depth(r);
    write_exr(&dir.file(&format!("{name}_depth.exr"))?, &ImageF { width: r.width, height: r.height, channels: 1, data: depth.clone() })?;
    for (suffix, img) in layer_images(r, normals, &depth, cam) {
        let file = if suffix.is_empty() { format!("{name}.png") } else { format!("{name}_{suffix}.png") };
        write_png(&dir.file(&file)?, &img)?;
    }
    Ok(())
}

/// Expected depth per pixel (sum w z / alpha; 0 where nothing is hit).
pub fn expected_depth(r: &Rendered) -> Vec<f32> {
    let (a, d) = (r.plane(Plane::Alpha), r.plane(Plane::Depth));
    (0..(r.width * r.height) as usize).map(|i| if a[i] > 1e-6 { d[i] / a[i] } else { 0.0 }).collect()
}

/// The images of a render that `tgs render` writes as PNGs, by file suffix
/// ("" for the colour, then "normal", "depth" and, after Stage I, the
/// layers of [`layer_images_of`]); `tgs view` shows the same pixels.
pub fn layer_images(r: &Rendered, normals: &[[f32; 3]], depth: &[f32], cam: &Camera) -> Vec<(&'static str, ImageF)> {
    let (w, h) = (r.width, r.height);
    let n = (w * h) as usize;
    let mut out = vec![
        ("", ImageF::from_planar(w, h, 3, &r.planes[..3 * n])),
        ("normal", normal_image(w, h, normals)),
        ("depth", ImageF { width: w, height: h, channels: 1, data: depth_grey(depth, f32::INFINITY, 1.0) }),
    ];
    if let Some(l) = &r.layers {
        out.extend(layer_images_of(&l.0, &l.1, cam));
    }
    out
}

/// Stage II / III layers of a render: `scat` (I_scat), `refl` (I_refl:
/// Stage II's rasterized reflection colour, Stage III's F Phi), `R`
/// (reflectivity map), `F0` (blended F0, when the stage has it),
/// `phi_mask` (Stage III: where Phi was evaluated), `normal_scat`,
/// `normal_refl`.
fn layer_images_of(scat: &Rendered, refl: &crate::train::trainer::ReflRendered, cam: &Camera) -> Vec<(&'static str, ImageF)> {
    let (w, h) = (scat.width, scat.height);
    let n = (w * h) as usize;
    let mut out =
        vec![("scat", ImageF::from_planar(w, h, 3, &scat.planes[..3 * n])), ("refl", ImageF::from_planar(w, h, 3, refl.i_refl())), ("R", ImageF::from_planar(w, h, 1, refl.r()))];
    let alpha = refl.refl_plane(Plane::Alpha);
    if let Some(f0s) = refl.f0_sum() {
        let f0: Vec<f32> = (0..3 * n).map(|k| f0s[k] / alpha[k % n].max(1e-6)).collect();
        out.push(("F0", ImageF::from_planar(w, h, 3, &f0)));
    }
    if let Some(p) = &refl.phi {
        out.push(("phi_mask", ImageF::from_planar(w, h, 1, &p.mask)));
    }
    out.push(("normal_scat", normal_image(w, h, &world_normals(scat, cam))));
    let rn = [0, 1, 2].map(|k| refl.refl_plane(Plane::Normal(k)));
    out.push(("normal_refl", normal_image(w, h, &world_normals_of(rn, cam))));
    out
}

/// World normals as an image (n * 0.5 + 0.5; black where empty).
fn normal_image(w: u32, h: u32, normals: &[[f32; 3]]) -> ImageF {
    ImageF { width: w, height: h, channels: 3, data: normals.iter().flat_map(|v| v.map(|x| if v == &[0.0; 3] { 0.0 } else { x * 0.5 + 0.5 })).collect() }
}
