//! `tgs render`: images from a run's checkpoint along the test or train
//! cameras, or an orbit around the scene (the circle through the training
//! cameras' mean height, looking at the point nearest all their optical axes).

use crate::eval::{world_normals, write_outputs};
use crate::outdir::OutDir;
use crate::scene::trace::{cross, dot, sub};
use crate::train::run::open_run;
use anyhow::{bail, Result};
use std::path::Path;
use std::sync::Arc;
use tgs_engine::Context;
use tgs_pipelines::Camera;

/// `frames` cameras orbiting the training cameras (intrinsics of the first).
pub fn orbit(train: &[Camera], frames: u32) -> Result<Vec<Camera>> {
    let Some(c0) = train.first() else { bail!("no training cameras to orbit") };
    let centres: Vec<[f64; 3]> = train.iter().map(|c| c.centre().map(f64::from)).collect();
    let axes: Vec<[f64; 3]> = train.iter().map(|c| [0, 1, 2].map(|j| c.world_to_view[2][j] as f64)).collect();
    let ups: Vec<[f64; 3]> = train.iter().map(|c| [0, 1, 2].map(|j| -c.world_to_view[1][j] as f64)).collect();
    // Point nearest all axes: sum (I - d d^T) x = sum (I - d d^T) c.
    let mut a = [[0f64; 3]; 3];
    let mut b = [0f64; 3];
    for (c, d) in centres.iter().zip(&axes) {
        for i in 0..3 {
            for j in 0..3 {
                let m = if i == j { 1.0 } else { 0.0 } - d[i] * d[j];
                a[i][j] += m;
                b[i] += m * c[j];
            }
        }
    }
    let det = |m: &[[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(&a);
    let n = centres.len() as f64;
    let mean = [0, 1, 2].map(|k| centres.iter().map(|c| c[k]).sum::<f64>() / n);
    let target = if d.abs() > 1e-9 {
        [0, 1, 2].map(|k| {
            let mut m = a;
            for i in 0..3 {
                m[i][k] = b[i];
            }
            det(&m) / d
        })
    } else {
        mean
    };
    let up = {
        let s = [0, 1, 2].map(|k| ups.iter().map(|u| u[k]).sum::<f64>());
        let l = dot(s, s).sqrt().max(1e-12);
        s.map(|v| v / l)
    };
    // Orbit in the plane perpendicular to `up` at the cameras' mean height.
    let rel: Vec<[f64; 3]> = centres.iter().map(|c| sub(*c, target)).collect();
    let height = rel.iter().map(|r| dot(*r, up)).sum::<f64>() / n;
    let radius = rel
        .iter()
        .map(|r| {
            let h = dot(*r, up);
            (dot(*r, *r) - h * h).max(0.0).sqrt()
        })
        .sum::<f64>()
        / n;
    let e0 = {
        let r = rel[0];
        let h = dot(r, up);
        let p = sub(r, up.map(|u| u * h));
        let l = dot(p, p).sqrt().max(1e-12);
        p.map(|v| v / l)
    };
    let e1 = cross(up, e0);
    let fov_y = 2.0 * ((0.5 * c0.height as f32) / c0.fy).atan();
    Ok((0..frames.max(1))
        .map(|i| {
            let t = i as f64 / frames.max(1) as f64 * std::f64::consts::TAU;
            let eye = [0, 1, 2].map(|k| (target[k] + up[k] * height + radius * (t.cos() * e0[k] + t.sin() * e1[k])) as f32);
            Camera::look_at(eye, target.map(|v| v as f32), up.map(|v| v as f32), fov_y, c0.width, c0.height)
        })
        .collect())
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
