//! f64 reference of Stage II's kernels (glsl/reflection/): the cube-map
//! lookup, the per-Gaussian reflection colour and the deferred composite,
//! written from the formulas (method-notes §2.6, §3.2–3.4), not from the
//! GLSL's structure. Gradients are checked against central differences of
//! these functions.

pub type V3 = [f64; 3];

fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// Face of the OpenGL major-axis rule (ties to x, then y) and the face
/// coordinates (x, y) (method-notes §2.6 table, inverted).
pub fn cube_coords(d: V3) -> (usize, f64, f64) {
    let a = [d[0].abs(), d[1].abs(), d[2].abs()];
    let axis = if a[0] >= a[1] && a[0] >= a[2] {
        0
    } else if a[1] >= a[2] {
        1
    } else {
        2
    };
    let ma = a[axis];
    if ma <= 0.0 || !ma.is_finite() {
        return (4, 0.0, 0.0);
    }
    let face = 2 * axis + (d[axis] < 0.0) as usize;
    let (x, y) = match face {
        0 => (-d[2], -d[1]),
        1 => (d[2], -d[1]),
        2 => (d[0], d[2]),
        3 => (d[0], -d[2]),
        4 => (d[0], -d[1]),
        _ => (-d[0], -d[1]),
    };
    (face, x / ma, y / ma)
}

pub fn face_dir(face: usize, x: f64, y: f64) -> V3 {
    match face {
        0 => [1.0, -y, -x],
        1 => [-1.0, -y, x],
        2 => [x, 1.0, y],
        3 => [x, -1.0, -y],
        4 => [x, -y, 1.0],
        _ => [-x, -y, -1.0],
    }
}

/// Texel index of tap (col, row) of `face`; one off an edge: the nearest
/// texel where its extrapolated direction lands; off a corner: the face's
/// corner texel.
pub fn tap(face: usize, col: i64, row: i64, res: usize) -> usize {
    let r = res as i64;
    let (ci, ri) = ((0..r).contains(&col), (0..r).contains(&row));
    if ci == ri {
        // On the face, or off a corner (no nearest neighbour): own corner texel.
        return (face * res + row.clamp(0, r - 1) as usize) * res + col.clamp(0, r - 1) as usize;
    }
    let s = 2.0 / res as f64;
    let (f2, x, y) = cube_coords(face_dir(face, (col as f64 + 0.5) * s - 1.0, (row as f64 + 0.5) * s - 1.0));
    let c = (((x + 1.0) * 0.5 * res as f64).floor() as i64).clamp(0, r - 1) as usize;
    let rw = (((y + 1.0) * 0.5 * res as f64).floor() as i64).clamp(0, r - 1) as usize;
    (f2 * res + rw) * res + c
}

/// Bilinear taps (texel, weight) of direction `d`.
pub fn taps(d: V3, res: usize) -> [(usize, f64); 4] {
    let (face, x, y) = cube_coords(d);
    let h = 0.5 * res as f64;
    let (u, v) = ((x + 1.0) * h - 0.5, (y + 1.0) * h - 0.5);
    let (u0, v0) = (u.floor(), v.floor());
    let (fu, fv) = (u - u0, v - v0);
    let (i, j) = (u0 as i64, v0 as i64);
    [
        (tap(face, i, j, res), (1.0 - fu) * (1.0 - fv)),
        (tap(face, i + 1, j, res), fu * (1.0 - fv)),
        (tap(face, i, j + 1, res), (1.0 - fu) * fv),
        (tap(face, i + 1, j + 1, res), fu * fv),
    ]
}

/// E(d) = sigmoid(bilinear raw texels).
pub fn env_lookup(raw: &[f64], res: usize, d: V3) -> V3 {
    let mut u = [0.0; 3];
    for (t, w) in taps(d, res) {
        for c in 0..3 {
            u[c] += w * raw[3 * t + c];
        }
    }
    u.map(sigmoid)
}

/// One reflection Gaussian: position, raw quaternion (r, x, y, z), material
/// (raw f0 (3), raw r).
#[derive(Clone, Copy, Debug)]
pub struct ReflGaussian {
    pub p: V3,
    pub q: [f64; 4],
    pub material: [f64; 4],
}

/// Mirror direction of the Gaussian's camera-facing normal seen from `centre`.
pub fn mirror_dir(g: &ReflGaussian, centre: V3) -> V3 {
    let qq: f64 = g.q.iter().map(|v| v * v).sum();
    let q = if qq > 1e-30 { g.q.map(|v| v / qq.sqrt()) } else { [0.0; 4] };
    let (r, x, y, z) = (q[0], q[1], q[2], q[3]);
    let t = [2.0 * (x * z + r * y), 2.0 * (y * z - r * x), 1.0 - 2.0 * (x * x + y * y)];
    let dv = [centre[0] - g.p[0], centre[1] - g.p[1], centre[2] - g.p[2]];
    let l = dot(dv, dv).sqrt();
    let v = if l > 1e-20 { dv.map(|c| c / l) } else { [0.0, 0.0, 1.0] };
    let n = if dot(t, v) < 0.0 { t.map(|c| -c) } else { t };
    let nv = dot(n, v);
    [0, 1, 2].map(|k| 2.0 * nv * n[k] - v[k])
}

/// The lookup direction through a parallax proxy (centre c, radius R):
/// from c to the exit point of p + t w from the sphere, t > 0, solved here
/// as the larger root of |p - c + t w|^2 = R^2 in the numerically stable
/// form (not the shader's s - b); w itself without a proxy or with p on
/// or outside the sphere.
pub fn proxy_dir(p: V3, w: V3, proxy: Option<(V3, f64)>) -> V3 {
    let Some((c, r)) = proxy else { return w };
    let o = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
    let (a, b, k) = (dot(w, w), dot(o, w), dot(o, o) - r * r);
    if k >= 0.0 || r <= 0.0 {
        return w;
    }
    // a t^2 + 2 b t + k = 0 with k < 0: one positive root,
    // (-b + sq) / a = -k / (b + sq); the second form where b >= 0.
    let sq = (b * b - a * k).sqrt();
    let t = if b >= 0.0 { -k / (b + sq) } else { (sq - b) / a };
    [0, 1, 2].map(|i| o[i] + t * w[i])
}

/// Bilinear value of a one-channel cube map (`depth`, texel order) in direction `d`.
pub fn depth_lookup(depth: &[f64], res: usize, d: V3) -> f64 {
    taps(d, res).iter().map(|&(t, w)| w * depth[t]).sum()
}

/// A depth-mapped lookup (the shader's `env_dir` with a depth map): the
/// proxy's radius per direction is the depth map's value there, starting
/// from the mirror direction `w` and refined `iters` times (a step whose
/// sphere does not hold p keeps the previous direction). Returns the
/// lookup direction, the radius of the last step taken (None: none was,
/// the direction is w) and the smallest |(|o|^2 - r^2)| / r^2 met, how
/// close a step came to switching.
pub fn depth_dir(p: V3, w: V3, centre: V3, depth: &[f64], res: usize, iters: u32) -> (V3, Option<f64>, f64) {
    let o = [p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]];
    let (mut d, mut last, mut margin) = (w, None, f64::INFINITY);
    for _ in 0..iters {
        let r = depth_lookup(depth, res, d);
        let k = dot(o, o) - r * r;
        margin = margin.min(k.abs() / (r * r).max(1e-30));
        if !(k < 0.0) {
            break;
        }
        d = proxy_dir(p, w, Some((centre, r)));
        last = Some(r);
    }
    (d, last, margin)
}

/// Rasterized features: [c (3), r] plus f0 (3) with Schlick; c = f0 E or E.
pub fn color(g: &ReflGaussian, env: &[f64], res: usize, centre: V3, schlick: bool) -> Vec<f64> {
    color_with_proxy(g, env, res, centre, None, schlick)
}

/// [`color`] with the map's parallax proxy ([`proxy_dir`]).
pub fn color_with_proxy(g: &ReflGaussian, env: &[f64], res: usize, centre: V3, proxy: Option<(V3, f64)>, schlick: bool) -> Vec<f64> {
    color_along(g, env, res, proxy_dir(g.p, mirror_dir(g, centre), proxy), schlick)
}

/// [`color`] with the lookup direction `d` given.
pub fn color_along(g: &ReflGaussian, env: &[f64], res: usize, d: V3, schlick: bool) -> Vec<f64> {
    let e = env_lookup(env, res, d);
    let f0 = [0, 1, 2].map(|c| sigmoid(g.material[c]));
    let r = sigmoid(g.material[3]);
    let c = if schlick { e } else { [0, 1, 2].map(|k| f0[k] * e[k]) };
    let mut out = vec![c[0], c[1], c[2], r];
    if schlick {
        out.extend(f0);
    }
    out
}

/// Per-pixel inputs of the composite: the scattering colour and the
/// reflection render's planes at that pixel.
#[derive(Clone, Copy, Debug)]
pub struct CompositePixel {
    pub scat: V3,
    /// Blended c (A).
    pub a: V3,
    pub r: f64,
    /// Blended f0 (unnormalized).
    pub f0s: V3,
    pub alpha: f64,
    /// Blended view-space normal (unnormalized).
    pub normal: V3,
    /// Unit view direction from the surface to the camera (view space).
    pub v: V3,
}

pub fn composite(p: &CompositePixel, schlick: bool) -> V3 {
    let i_refl = if schlick {
        let f0 = p.f0s.map(|c| c / p.alpha.max(1e-6));
        let l = dot(p.normal, p.normal).sqrt();
        let cos = if l > 1e-12 { (dot(p.normal, p.v) / l).clamp(0.0, 1.0) } else { 1.0 };
        let m = (1.0 - cos).powi(5);
        [0, 1, 2].map(|k| (f0[k] + (1.0 - f0[k]) * m) * p.a[k])
    } else {
        p.a
    };
    [0, 1, 2].map(|k| (1.0 - p.r) * p.scat[k] + p.r * i_refl[k])
}

/// Unit direction from pixel (x, y)'s surface point to the camera.
pub fn pixel_view_dir(x: f64, y: f64, fx: f64, fy: f64, cx: f64, cy: f64) -> V3 {
    let d = [(x - cx) / fx, (y - cy) / fy, 1.0];
    let l = dot(d, d).sqrt();
    d.map(|c| -c / l)
}
