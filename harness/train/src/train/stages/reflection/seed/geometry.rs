//! The seeding's geometry and plumbing: world points and pixels of a
//! camera in f64, a box blur, and a deterministic split of work over
//! threads.

use glam::DVec3;
use tgs_pipelines::Camera;

pub(super) type V3 = [f64; 3];

/// `a` over its length (divided, as the seeds were always made); +z where
/// it has none (zero, or not finite).
pub(super) fn normalize(a: V3) -> V3 {
    let v = DVec3::from(a);
    let l = v.length();
    if l > 0.0 && l.is_finite() {
        (v / l).to_array()
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// The pixel (row-major index) world point `x` projects to in `cam`, and
/// its view depth, if it is in front of the camera and inside the image.
pub fn pixel_of(cam: &Camera, x: V3) -> Option<(usize, f64)> {
    let (u, v, z) = image_point(cam, x)?;
    let (u, v) = (u.round(), v.round());
    if !(u >= 0.0 && v >= 0.0 && u < cam.width as f64 && v < cam.height as f64) {
        return None;
    }
    Some((v as usize * cam.width as usize + u as usize, z))
}

/// The unrounded pixel coordinates (pixel centres at integers) and view
/// depth of world point `x` in `cam`, if it is in front of the camera; in f64.
pub(super) fn image_point(cam: &Camera, x: V3) -> Option<(f64, f64, f64)> {
    let m = &cam.world_to_view;
    let p: V3 = [0, 1, 2].map(|r| m[r][0] as f64 * x[0] + m[r][1] as f64 * x[1] + m[r][2] as f64 * x[2] + m[r][3] as f64);
    if !(p[2] > 1e-6) {
        return None;
    }
    Some((cam.fx as f64 * p[0] / p[2] + cam.cx as f64, cam.fy as f64 * p[1] / p[2] + cam.cy as f64, p[2]))
}

/// The world point at pixel `i` (row-major) of `cam`, view depth `z`:
/// R^T (p_view - t), in f64.
pub(crate) fn unproject_pixel(cam: &Camera, i: usize, z: f64) -> V3 {
    let (x, y) = image_xy(cam, (i % cam.width as usize) as f64, (i / cam.width as usize) as f64);
    unproject_xy(cam, x, y, z)
}

/// The normalised image coordinates ((u - cx) / fx, (v - cy) / fy) of
/// pixel position (u, v) in `cam`.
pub(super) fn image_xy(cam: &Camera, u: f64, v: f64) -> (f64, f64) {
    ((u - cam.cx as f64) / cam.fx as f64, (v - cam.cy as f64) / cam.fy as f64)
}

/// The world point at normalised image point (x, y) of `cam`, view depth
/// `z`: R^T (p_view - t), in f64.
pub(super) fn unproject_xy(cam: &Camera, x: f64, y: f64, z: f64) -> V3 {
    let m = &cam.world_to_view;
    let d = [x * z - m[0][3] as f64, y * z - m[1][3] as f64, z - m[2][3] as f64];
    [0, 1, 2].map(|j| (0..3).map(|r| m[r][j] as f64 * d[r]).sum())
}

/// Box blur of radius `r` (mean over the window clipped to the image).
pub(super) fn box_blur(img: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    // Integral image in f64.
    let mut s = vec![0.0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0.0;
        for x in 0..w {
            let v = img.get(y * w + x).copied().unwrap_or(0.0);
            row += if v.is_finite() { v as f64 } else { 0.0 };
            s[(y + 1) * (w + 1) + x + 1] = s[y * (w + 1) + x + 1] + row;
        }
    }
    let mut out = vec![0.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let (x0, x1, y0, y1) = (x.saturating_sub(r), (x + r + 1).min(w), y.saturating_sub(r), (y + r + 1).min(h));
            let sum = s[y1 * (w + 1) + x1] - s[y0 * (w + 1) + x1] - s[y1 * (w + 1) + x0] + s[y0 * (w + 1) + x0];
            out[y * w + x] = (sum / ((x1 - x0) * (y1 - y0)) as f64) as f32;
        }
    }
    out
}

/// The `k` points of `pts` nearest `x` (all of them if fewer), as
/// (squared distance, index), nearest first; the point at index `skip`
/// left out. Deterministic: the same points in the same order every run.
pub(super) fn nearest(x: DVec3, pts: impl Iterator<Item = DVec3>, skip: Option<usize>, k: usize) -> Vec<(f64, usize)> {
    let mut near: Vec<(f64, usize)> = pts.enumerate().filter(|&(j, _)| Some(j) != skip).map(|(j, p)| (x.distance_squared(p), j)).collect();
    let k = k.min(near.len());
    if k > 0 {
        near.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0));
        near.truncate(k);
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    near
}

/// `f` over contiguous runs of `items` on up to `threads` scoped threads
/// (0: the available parallelism), the results in the runs' order: the
/// same as `f(items)` split at the run boundaries, whatever the count.
pub(super) fn in_parallel<T: Sync, R: Send>(items: &[T], threads: usize, f: impl Fn(&[T]) -> R + Sync) -> Vec<R> {
    let threads = if threads == 0 { std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1) } else { threads };
    let runs = threads.clamp(1, items.len().max(1));
    if runs == 1 {
        return vec![f(items)];
    }
    let size = items.len().div_ceil(runs);
    std::thread::scope(|scope| {
        let handles: Vec<_> = items.chunks(size).map(|c| scope.spawn(|| f(c))).collect();
        handles.into_iter().map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e))).collect()
    })
}

/// 1 / z = row(x, y) · coef through `pts` ([x, y, 1 / z]) by iteratively
/// reweighted least squares (10 rounds; rows weighted 1 within twice the
/// residuals' robust spread, s / r beyond it), each round's normal
/// equations solved by `solve`. None where `solve` finds them singular.
pub(super) fn reweighted_fit<const N: usize>(
    pts: &[[f64; 3]],
    row: impl Fn(&[f64; 3]) -> [f64; N],
    solve: impl Fn([[f64; N]; N], [f64; N]) -> Option<[f64; N]>,
) -> Option<[f64; N]> {
    let mut wts = vec![1.0f64; pts.len()];
    let mut coef = None;
    for _ in 0..10 {
        let (mut a, mut b) = ([[0.0f64; N]; N], [0.0f64; N]);
        for (p, &wt) in pts.iter().zip(&wts) {
            let row = row(p);
            for r in 0..N {
                for c in 0..N {
                    a[r][c] += wt * wt * row[r] * row[c];
                }
                b[r] += wt * wt * row[r] * p[2];
            }
        }
        let c = solve(a, b)?;
        let res: Vec<f64> = pts.iter().map(|p| (row(p).iter().zip(&c).map(|(r, c)| c * r).sum::<f64>() - p[2]).abs()).collect();
        let mut sorted = res.clone();
        sorted.sort_by(f64::total_cmp);
        let s = 2.0 * 1.4826 * sorted[sorted.len() / 2] + 1e-12;
        wts = res.iter().map(|&r| if r < s { 1.0 } else { s / r }).collect();
        coef = Some(c);
    }
    coef
}

/// `a` x = `b` by Gaussian elimination with partial pivoting; None where
/// `a` is (nearly) singular.
pub(super) fn solve<const N: usize>(mut a: [[f64; N]; N], mut b: [f64; N]) -> Option<[f64; N]> {
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    for col in 0..N {
        let piv = (col..N).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if !(a[piv][col].abs() > 1e-12 * scale) {
            return None;
        }
        a.swap(col, piv);
        b.swap(col, piv);
        for r in col + 1..N {
            let f = a[r][col] / a[col][col];
            for c in col..N {
                a[r][c] -= f * a[col][c];
            }
            b[r] -= f * b[col];
        }
    }
    let mut x = [0.0f64; N];
    for r in (0..N).rev() {
        x[r] = (b[r] - (r + 1..N).map(|c| a[r][c] * x[c]).sum::<f64>()) / a[r][r];
    }
    Some(x)
}
