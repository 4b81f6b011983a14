//! `tgs render`: images from a run's checkpoint along the test or train
//! cameras, or an orbit around the scene (the circle through the training
//! cameras' mean height, looking at the point nearest all their optical axes).

use crate::eval::{world_normals, write_outputs};
use crate::outdir::OutDir;
use crate::train::run::open_run;
use anyhow::{bail, Result};
use glam::{DVec3, Vec3};
use std::path::Path;
use std::sync::Arc;
use tgs_engine::Context;
use tgs_pipelines::Camera;

/// `frames` cameras orbiting the training cameras (intrinsics of the first).
pub fn orbit(train: &[Camera], frames: u32) -> Result<Vec<Camera>> {
    let Some(c0) = train.first() else { bail!("no training cameras to orbit") };
    let centres = camera_centres(train);
    let n = centres.len() as f64;
    let (target, up) = look_target(train);
    // Orbit in the plane perpendicular to `up` at the cameras' mean height.
    let rel: Vec<DVec3> = centres.iter().map(|c| *c - target).collect();
    let height = rel.iter().map(|r| r.dot(up)).sum::<f64>() / n;
    let radius = rel
        .iter()
        .map(|r| {
            let h = r.dot(up);
            (r.dot(*r) - h * h).max(0.0).sqrt()
        })
        .sum::<f64>()
        / n;
    let e0 = {
        let h = rel[0].dot(up);
        let p = rel[0] - up * h;
        p / p.length().max(1e-12)
    };
    let e1 = up.cross(e0);
    let fov_y = 2.0 * ((0.5 * c0.height as f32) / c0.fy).atan();
    Ok((0..frames.max(1))
        .map(|i| {
            let t = i as f64 / frames.max(1) as f64 * std::f64::consts::TAU;
            let eye = target + up * height + (e0 * t.cos() + e1 * t.sin()) * radius;
            Camera::look_at(eye.as_vec3().to_array(), target.as_vec3().to_array(), up.as_vec3().to_array(), fov_y, c0.width, c0.height)
        })
        .collect())
}

fn camera_centres(cams: &[Camera]) -> Vec<DVec3> {
    cams.iter().map(|c| Vec3::from(c.centre()).as_dvec3()).collect()
}

/// The point the cameras look at (nearest all their optical axes; their
/// mean centre when the axes are parallel) and their mean up direction.
pub fn look_target(cams: &[Camera]) -> (DVec3, DVec3) {
    let centres = camera_centres(cams);
    let axes: Vec<DVec3> = cams.iter().map(|c| DVec3::from([0, 1, 2].map(|j| c.world_to_view[2][j] as f64))).collect();
    let ups: Vec<DVec3> = cams.iter().map(|c| DVec3::from([0, 1, 2].map(|j| -c.world_to_view[1][j] as f64))).collect();
    let mean = centres.iter().fold(DVec3::ZERO, |s, c| s + *c) / centres.len().max(1) as f64;
    let target = nearest_to_axes(&centres, &axes).unwrap_or(mean);
    let s = ups.iter().fold(DVec3::ZERO, |s, u| s + *u);
    (target, s / s.length().max(1e-12))
}

/// The point nearest all the cameras' optical axes (through `centres`
/// along `axes`): sum (I - d d^T) x = sum (I - d d^T) c by Cramer's rule;
/// None when the axes are (nearly) parallel.
fn nearest_to_axes(centres: &[DVec3], axes: &[DVec3]) -> Option<DVec3> {
    // The system's rows.
    let mut a = [DVec3::ZERO; 3];
    let mut b = DVec3::ZERO;
    for (c, d) in centres.iter().zip(axes) {
        for i in 0..3 {
            for j in 0..3 {
                let m = if i == j { 1.0 } else { 0.0 } - d[i] * d[j];
                a[i][j] += m;
                b[i] += m * c[j];
            }
        }
    }
    let det = |m: &[DVec3; 3]| m[0].dot(m[1].cross(m[2]));
    let d = det(&a);
    if !(d.abs() > 1e-9) {
        return None;
    }
    Some(DVec3::from([0, 1, 2].map(|k| {
        let mut m = a;
        for i in 0..3 {
            m[i][k] = b[i];
        }
        det(&m) / d
    })))
}

/// Render `which` (test, train or orbit) from `run` into `out`.
pub fn render(ctx: &Arc<Context>, run: &Path, which: &str, frames: u32, out: &Path) -> Result<usize> {
    let (mut tr, data) = open_run(ctx, run)?;
    let cams: Vec<(String, Camera)> = match which {
        "test" => data.test.iter().map(|v| (v.name.clone(), v.camera)).collect(),
        "train" => data.train.iter().map(|v| (v.name.clone(), v.camera)).collect(),
        "orbit" => {
            let train: Vec<Camera> = data.train.iter().map(|v| v.camera).collect();
            orbit(&train, frames)?.into_iter().enumerate().map(|(i, c)| (format!("orbit_{i:04}"), c)).collect()
        }
        _ => bail!("--cameras must be test, train or orbit, not '{which}'"),
    };
    if cams.is_empty() {
        bail!("the run's dataset has no {which} cameras");
    }
    let mut dir = OutDir::open(out, Some(&data.root))?;
    let _lock = crate::lock::lock_output(out, run, "tgs render", false)?;
    let bar = indicatif::ProgressBar::new(cams.len() as u64);
    let stems = crate::data::file_stems(cams.iter().map(|(n, _)| n.as_str()));
    for ((_, cam), name) in cams.iter().zip(&stems) {
        let r = tr.render(cam)?;
        write_outputs(&mut dir, name, &r, &world_normals(&r, cam), cam)?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(cams.len())
}
