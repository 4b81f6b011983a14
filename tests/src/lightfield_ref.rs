//! f64 reference of Stage III's deferred kernels (pipelines/src/lightfield):
//! a pixel's light-field sample and the composite with its gradients.

pub type V3 = [f64; 3];

fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn norm(a: V3) -> V3 {
    let l = dot(a, a).sqrt();
    a.map(|v| v / l)
}

/// A camera as the kernels see it: world_to_view rows [R | t], intrinsics.
#[derive(Clone, Copy)]
pub struct Cam {
    pub rot: [[f64; 4]; 3],
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Cam {
    fn ray(&self, x: f64, y: f64) -> V3 {
        [(x - self.cx) / self.fx, (y - self.cy) / self.fy, 1.0]
    }
    fn to_world_dir(self, v: V3) -> V3 {
        let r = &self.rot;
        [0, 1, 2].map(|j| r[0][j] * v[0] + r[1][j] * v[1] + r[2][j] * v[2])
    }
}

/// One pixel of the reflection render: [F0 sum (3), R], alpha, depth (sum w z), normal.
#[derive(Clone, Copy, Debug)]
pub struct ReflPixel {
    pub f0s: V3,
    pub r: f64,
    pub alpha: f64,
    pub depth: f64,
    pub normal: V3,
}

/// The sample of pixel (x, y): (x_refl normalized, w_r).
pub fn sample(cam: &Cam, x: f64, y: f64, p: &ReflPixel, centre: V3, half: V3) -> [f64; 6] {
    let ray = cam.ray(x, y);
    let z = p.depth / p.alpha.max(1e-6);
    let xv = ray.map(|v| v * z);
    let t = [cam.rot[0][3], cam.rot[1][3], cam.rot[2][3]];
    let xw = cam.to_world_dir([xv[0] - t[0], xv[1] - t[1], xv[2] - t[2]]);
    let d = norm(ray);
    let len = dot(p.normal, p.normal).sqrt();
    let r = if len > 1e-12 {
        let n = p.normal.map(|v| v / len);
        let k = 2.0 * dot(d, n);
        [d[0] - k * n[0], d[1] - k * n[1], d[2] - k * n[2]]
    } else {
        d.map(|v| -v)
    };
    let w = norm(cam.to_world_dir(r));
    [(xw[0] - centre[0]) / half[0], (xw[1] - centre[1]) / half[1], (xw[2] - centre[2]) / half[2], w[0], w[1], w[2]]
}

/// Schlick's m = (1 - clamp(n.v, 0, 1))^5 at a pixel (0 with Schlick off).
pub fn schlick_m(cam: &Cam, x: f64, y: f64, p: &ReflPixel, schlick: bool) -> f64 {
    if !schlick {
        return 0.0;
    }
    let v = norm(cam.ray(x, y)).map(|c| -c);
    let len = dot(p.normal, p.normal).sqrt();
    let c = if len > 1e-12 { dot(p.normal.map(|a| a / len), v) } else { 1.0 };
    (1.0 - c.clamp(0.0, 1.0)).powi(5)
}

/// I = (1 - R) S + R F Phi with F = F0 + (1 - F0) m, F0 = F0 sum /
/// max(alpha, 1e-6) where Phi was evaluated; I = S elsewhere.
pub fn composite_at(p: &ReflPixel, m: f64, scat: V3, phi: Option<V3>) -> V3 {
    match phi {
        Some(phi) => composite(p, m, scat, phi),
        None => scat,
    }
}

/// Gradients of g . I where Phi was not evaluated: only dS = g.
pub fn composite_grad_at(p: &ReflPixel, m: f64, scat: V3, phi: Option<V3>, g: V3) -> (V3, V3, f64, V3) {
    match phi {
        Some(phi) => composite_grad(p, m, scat, phi, g),
        None => ([0.0; 3], [0.0; 3], 0.0, g),
    }
}

/// I = (1 - R) S + R F Phi with F = F0 + (1 - F0) m, F0 = F0 sum / max(alpha, 1e-6).
pub fn composite(p: &ReflPixel, m: f64, scat: V3, phi: V3) -> V3 {
    let ae = p.alpha.max(1e-6);
    [0, 1, 2].map(|c| {
        let f0 = p.f0s[c] / ae;
        let f = f0 + (1.0 - f0) * m;
        (1.0 - p.r) * scat[c] + p.r * f * phi[c]
    })
}

/// Gradients of g . I: (dPhi, dF0 sum, dR, dS).
pub fn composite_grad(p: &ReflPixel, m: f64, scat: V3, phi: V3, g: V3) -> (V3, V3, f64, V3) {
    let ae = p.alpha.max(1e-6);
    let f = [0, 1, 2].map(|c| {
        let f0 = p.f0s[c] / ae;
        f0 + (1.0 - f0) * m
    });
    let dphi = [0, 1, 2].map(|c| g[c] * p.r * f[c]);
    let df0s = [0, 1, 2].map(|c| g[c] * p.r * phi[c] * (1.0 - m) / ae);
    let dr = (0..3).map(|c| g[c] * (f[c] * phi[c] - scat[c])).sum();
    let ds = [0, 1, 2].map(|c| g[c] * (1.0 - p.r));
    (dphi, df0s, dr, ds)
}
