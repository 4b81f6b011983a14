//! CPU f64 reference of the training image loss (pipelines/src/train/loss.rs):
//! (1 - λ) L1 + λ (1 - SSIM) (11x11 Gaussian σ 1.5, zero padding, mean over
//! pixels and channels) + λ_n mean(1 - α_det N·s) + λ_d mean(distortion).
//! `alpha_det` is the detached alpha weighting the normal term (held fixed
//! under finite differences, as in 2DGS).

pub struct LossInput {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub ssim: f64,
    pub normal: f64,
    pub dist: f64,
    pub target: Vec<f64>,
}

const MIN_ALPHA: f64 = 1e-6;

fn blur(src: &[f64], w: usize, h: usize) -> Vec<f64> {
    let raw: Vec<f64> = (-5i64..=5).map(|t| (-((t * t) as f64) / (2.0 * 1.5 * 1.5)).exp()).collect();
    let s: f64 = raw.iter().sum();
    let g: Vec<f64> = raw.iter().map(|v| v / s).collect();
    blur_pass(&blur_pass(src, w, h, &g, true), w, h, &g, false)
}

/// One 11-tap pass of the separable blur `g`, along x (`along_x`) or y;
/// taps past the image's edge are left out.
fn blur_pass(src: &[f64], w: usize, h: usize, g: &[f64], along_x: bool) -> Vec<f64> {
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            for t in -5i64..=5 {
                let (xx, yy) = if along_x { (x as i64 + t, y as i64) } else { (x as i64, y as i64 + t) };
                if xx >= 0 && xx < w as i64 && yy >= 0 && yy < h as i64 {
                    out[y * w + x] += g[(t + 5) as usize] * src[yy as usize * w + xx as usize];
                }
            }
        }
    }
    out
}

/// Mean SSIM over pixels and channels.
pub fn ssim(x: &[f64], y: &[f64], w: usize, h: usize, c: usize) -> f64 {
    let n = w * h;
    let (c1, c2) = (1e-4, 9e-4);
    let mut total = 0.0;
    for ch in 0..c {
        let a = &x[ch * n..(ch + 1) * n];
        let b = &y[ch * n..(ch + 1) * n];
        let p = |u: &[f64], v: &[f64]| u.iter().zip(v).map(|(s, t)| s * t).collect::<Vec<_>>();
        let (mx, my, exx, eyy, exy) = (blur(a, w, h), blur(b, w, h), blur(&p(a, a), w, h), blur(&p(b, b), w, h), blur(&p(a, b), w, h));
        for i in 0..n {
            let (sx, sy, sxy) = (exx[i] - mx[i] * mx[i], eyy[i] - my[i] * my[i], exy[i] - mx[i] * my[i]);
            total += ((2.0 * mx[i] * my[i] + c1) * (2.0 * sxy + c2)) / ((mx[i] * mx[i] + my[i] * my[i] + c1) * (sx + sy + c2));
        }
    }
    total / (n * c) as f64
}

/// Per-pixel normal-consistency terms (1 - α_det N·s); 1 where undefined.
pub fn normal_terms(inp: &LossInput, planes: &[f64], alpha_det: &[f64]) -> Vec<f64> {
    let (w, h, c) = (inp.width, inp.height, inp.channels);
    let n = w * h;
    let plane = |k: usize| &planes[k * n..(k + 1) * n];
    let (alpha, depth) = (plane(c), plane(c + 1));
    let point = |x: usize, y: usize| -> [f64; 3] {
        let i = y * w + x;
        let z = if alpha[i] > MIN_ALPHA { depth[i] / alpha[i] } else { 0.0 };
        [z * (x as f64 - inp.cx) / inp.fx, z * (y as f64 - inp.cy) / inp.fy, z]
    };
    let mut out = vec![1.0; n];
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            let i = y * w + x;
            let (a, b, p, q) = (point(x, y + 1), point(x, y - 1), point(x + 1, y), point(x - 1, y));
            let dy = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
            let dx = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
            let cr = [dy[1] * dx[2] - dy[2] * dx[1], dy[2] * dx[0] - dy[0] * dx[2], dy[0] * dx[1] - dy[1] * dx[0]];
            let len = (cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]).sqrt();
            if len > 1e-20 && alpha_det[i] > 0.0 {
                let nrm = [plane(c + 2)[i], plane(c + 3)[i], plane(c + 4)[i]];
                out[i] = 1.0 - alpha_det[i] * (nrm[0] * cr[0] + nrm[1] * cr[1] + nrm[2] * cr[2]) / len;
            }
        }
    }
    out
}

/// The total loss and its parts (l1, mse, ssim, normal mean).
pub fn loss(inp: &LossInput, planes: &[f64], alpha_det: &[f64]) -> (f64, [f64; 4]) {
    let (w, h, c) = (inp.width, inp.height, inp.channels);
    let n = w * h;
    let col = &planes[..c * n];
    let l1 = col.iter().zip(&inp.target).map(|(a, b)| (a - b).abs()).sum::<f64>() / (n * c) as f64;
    let mse = col.iter().zip(&inp.target).map(|(a, b)| (a - b) * (a - b)).sum::<f64>() / (n * c) as f64;
    let s = ssim(col, &inp.target, w, h, c);
    let nt = normal_terms(inp, planes, alpha_det).iter().sum::<f64>() / n as f64;
    let dist = planes[(c + 6) * n..(c + 7) * n].iter().sum::<f64>() / n as f64;
    let total = (1.0 - inp.ssim) * l1 + inp.ssim * (1.0 - s) + inp.normal * nt + inp.dist * dist;
    (total, [l1, mse, s, nt])
}

/// The high-frequency loss (method-notes §3.6) in f64: per pixel e = mean_c
/// |x - y| (x, y planar RGB; selected on 3 e = sum_c |x - y|, summed in f32
/// as the kernel does so that ties stay ties); tau = the ascending 3 e of
/// rank floor(pct (n - 1)); returns (3 tau, count of e >= tau, their mean
/// e, d mean / d x).
pub fn hf_loss(x: &[f32], y: &[f32], n: usize, pct: f64) -> (f32, usize, f64, Vec<f64>) {
    let e: Vec<f32> = (0..n).map(|i| (x[i] - y[i]).abs() + (x[n + i] - y[n + i]).abs() + (x[2 * n + i] - y[2 * n + i]).abs()).collect();
    let mut sorted = e.clone();
    sorted.sort_by(f32::total_cmp);
    let tau = sorted[(pct * (n - 1) as f64).floor() as usize];
    let sel: Vec<usize> = (0..n).filter(|&i| e[i] >= tau).collect();
    let mean = sel.iter().map(|&i| e[i] as f64).sum::<f64>() / (3.0 * sel.len() as f64);
    let mut g = vec![0.0; 3 * n];
    for &i in &sel {
        for c in 0..3 {
            let d = x[c * n + i] as f64 - y[c * n + i] as f64;
            g[c * n + i] = d.signum() * if d == 0.0 { 0.0 } else { 1.0 } / (3.0 * sel.len() as f64);
        }
    }
    (tau, sel.len(), mean, g)
}
