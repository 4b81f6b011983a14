//! CPU f64 reference of the 2DGS forward (method-notes §1.3–1.5): the same
//! math as glsl/raster_*.comp in straightforward loops (every pixel walks
//! every Gaussian in depth order; a Gaussian only touches pixels of its tile
//! rectangle, which is part of the method). Gradients are taken from it by
//! central finite differences.
//!
//! Pixels where f32 rounding on the GPU could flip a discrete decision
//! (alpha at the 1/255 cut, transmittance at the 1e-4 stop or 0.5 median
//! crossing, depth at the near plane, a tile-rectangle edge) are flagged
//! `ambiguous` so tests can leave them out and count them. Pixels with an
//! ill-conditioned hit (a ray grazing a splat: the hit depth then moves far
//! under one-ulp changes of the f32 inputs) get a tolerance widened in
//! proportion to that measured sensitivity (see `sensitivity`).
//!
//! Longer than 500 lines on purpose: the forward and backward reference of
//! one kernel family, kept together so that each line of the GLSL has its
//! f64 counterpart in one file.

use tgs_pipelines::{Camera, HostGaussians};

const NEAR: f64 = 0.2;
/// The low-pass filter's size as raster/common.glsl writes it (not 1/sqrt 2
/// to the last digit: the reference takes the GPU's constant).
#[allow(clippy::approx_constant)]
const FILTER_SIZE: f64 = 0.707106;
const FAR: f64 = 100.0;
/// The tile side the reference bins with unless told the GPU frame's.
const TILE: usize = 16;

/// A Gaussian set in f64 (same layout as [`HostGaussians`]).
#[derive(Clone, Debug)]
pub struct RefScene {
    pub channels: usize,
    pub coeffs: usize,
    pub plain: bool,
    pub means: Vec<f64>,
    pub log_scales: Vec<f64>,
    pub quats: Vec<f64>,
    pub opacity: Vec<f64>,
    pub features: Vec<f64>,
}

impl RefScene {
    pub fn from_host(h: &HostGaussians, plain: bool) -> RefScene {
        let f = |v: &Vec<f32>| v.iter().map(|&x| x as f64).collect();
        RefScene {
            channels: h.channels as usize,
            coeffs: h.coeffs as usize,
            plain,
            means: f(&h.means),
            log_scales: f(&h.log_scales),
            quats: f(&h.quats),
            opacity: f(&h.opacity),
            features: f(&h.features),
        }
    }
    pub fn len(&self) -> usize {
        self.opacity.len()
    }
    pub fn is_empty(&self) -> bool {
        self.opacity.is_empty()
    }
    /// Every parameter as (group name, mutable reference), in a fixed order.
    pub fn params_mut(&mut self) -> Vec<(&'static str, &mut f64)> {
        let mut v: Vec<(&'static str, &mut f64)> = Vec::new();
        v.extend(self.means.iter_mut().map(|x| ("means", x)));
        v.extend(self.log_scales.iter_mut().map(|x| ("log_scales", x)));
        v.extend(self.quats.iter_mut().map(|x| ("quats", x)));
        v.extend(self.opacity.iter_mut().map(|x| ("opacity", x)));
        v.extend(self.features.iter_mut().map(|x| ("features", x)));
        v
    }
}

type V3 = [f64; 3];
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: V3, b: V3) -> V3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// The SH basis up to degree 3 (3DGS constants).
pub fn sh_basis(d: V3) -> [f64; 16] {
    let (x, y, z) = (d[0], d[1], d[2]);
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let c1 = 0.4886025119029199;
    let c2 = [1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396];
    let c3 = [-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658, 1.445305721320277, -0.5900435899266435];
    [
        0.28209479177387814,
        -c1 * y,
        c1 * z,
        -c1 * x,
        c2[0] * x * y,
        c2[1] * y * z,
        c2[2] * (2.0 * zz - xx - yy),
        c2[3] * x * z,
        c2[4] * (xx - yy),
        c3[0] * y * (3.0 * xx - yy),
        c3[1] * x * y * z,
        c3[2] * y * (4.0 * zz - xx - yy),
        c3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
        c3[4] * x * (4.0 * zz - xx - yy),
        c3[5] * z * (xx - yy),
        c3[6] * x * (xx - 3.0 * yy),
    ]
}

/// A projected splat.
#[derive(Clone, Debug)]
pub struct RefSplat {
    pub index: usize,
    pub tu: V3,
    pub tv: V3,
    pub tw: V3,
    pub mu: [f64; 2],
    pub n: V3,
    pub o: f64,
    pub depth: f64,
    /// Tile rectangle [x0, x1) x [y0, y1).
    pub rect: [usize; 4],
    pub feat: Vec<f64>,
    /// Union and intersection of the rectangle under rounding-sized
    /// perturbations: tiles between them are ambiguous.
    pub outer: [usize; 4],
    pub inner: [usize; 4],
    /// |cos| between the normal and the ray to the centre.
    pub cos_view: f64,
    /// Screen radius: the 3-sigma box's larger half-extent, at least the
    /// low-pass radius, rounded up (what densification sees).
    pub radius: f64,
}

struct Cam64 {
    r: [V3; 3],
    t: V3,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    centre: V3,
    w: usize,
    h: usize,
    /// Tile side in pixels.
    tile: usize,
}

impl Cam64 {
    fn new(c: &Camera) -> Cam64 {
        let m = c.world_to_view.map(|r| r.map(|x| x as f64));
        let r = [[m[0][0], m[0][1], m[0][2]], [m[1][0], m[1][1], m[1][2]], [m[2][0], m[2][1], m[2][2]]];
        let t = [m[0][3], m[1][3], m[2][3]];
        let centre = [0, 1, 2].map(|j| -(0..3).map(|i| r[i][j] * t[i]).sum::<f64>());
        Cam64 { r, t, fx: c.fx as f64, fy: c.fy as f64, cx: c.cx as f64, cy: c.cy as f64, centre, w: c.width as usize, h: c.height as usize, tile: TILE }
    }
    /// As [`Cam64::new`], binning with `tile` x `tile` tiles (the GPU frame's).
    fn tiled(c: &Camera, tile: u32) -> Cam64 {
        Cam64 { tile: tile as usize, ..Cam64::new(c) }
    }
    /// The tile grid, as the bounds rectangles are clamped to.
    fn tiles(&self) -> [f64; 3] {
        [self.w.div_ceil(self.tile) as f64, self.h.div_ceil(self.tile) as f64, self.tile as f64]
    }
    fn rot(&self, v: V3) -> V3 {
        [dot(self.r[0], v), dot(self.r[1], v), dot(self.r[2], v)]
    }
}

/// Ray-splat hit of pixel (x, y): (G with the low-pass filter, hit depth).
fn hit(tu: V3, tv: V3, tw: V3, mu: [f64; 2], x: f64, y: f64) -> Option<(f64, f64)> {
    let hx = sub(scale(tw, x), tu);
    let hy = sub(scale(tw, y), tv);
    let p = cross(hx, hy);
    if p[2] == 0.0 {
        return None;
    }
    let (u, v) = (p[0] / p[2], p[1] / p[2]);
    let rho3 = u * u + v * v;
    let (dx, dy) = (mu[0] - x, mu[1] - y);
    let rho2 = 2.0 * (dx * dx + dy * dy);
    let g = (-0.5 * rho3.min(rho2)).exp();
    Some((g, tw[0] * u + tw[1] * v + tw[2]))
}

/// How far this hit moves under f32 rounding: a ray grazing the splat plane
/// makes the hit depth ill-conditioned (one-ulp changes of the homography
/// move it far, whatever the f32 formulation). A first-order bound: each of
/// the 9 entries of T is moved by one f32 ulp on its own and the changes of
/// depth plus alpha-weighted changes are summed in absolute value, so they
/// cannot cancel (infinite when a perturbed ray misses).
fn sensitivity(sp: &RefSplat, x: f64, y: f64, g: f64, z: f64) -> f64 {
    ulp_sum(sp, x, y, |g2, z2| (z2 - z).abs() + (sp.o * (g2 - g)).abs() * (1.0 + z.abs()))
}

/// As [`sensitivity`] for alpha alone: the summed absolute change of o G.
fn alpha_sensitivity(sp: &RefSplat, x: f64, y: f64, g: f64) -> f64 {
    ulp_sum(sp, x, y, |g2, _| (sp.o * (g2 - g)).abs())
}

/// The sum over the 9 entries of T, each moved by one f32 ulp on its own,
/// of `change(G, depth)` of the perturbed hit (infinite when a perturbed
/// ray misses).
fn ulp_sum(sp: &RefSplat, x: f64, y: f64, change: impl Fn(f64, f64) -> f64) -> f64 {
    let ulp = 1.0 / (1u64 << 23) as f64;
    let mut total = 0.0f64;
    for entry in 0..9 {
        let mut rows = [sp.tu, sp.tv, sp.tw];
        rows[entry / 3][entry % 3] *= 1.0 + ulp;
        match hit(rows[0], rows[1], rows[2], sp.mu, x, y) {
            Some((g2, z2)) => total += change(g2, z2),
            None => return f64::INFINITY,
        }
    }
    total
}

/// The rows of T with each entry moved by `ulps` f32 ulps, up or down as
/// bit (3 * row + column) of `pattern` says.
fn perturb(sp: &RefSplat, pattern: u32, ulps: f64) -> (V3, V3, V3) {
    let ulp = ulps / (1u64 << 23) as f64;
    let e = |row: V3, k: usize| -> V3 { [0, 1, 2].map(|i| row[i] * (1.0 + if pattern >> (3 * k + i) & 1 == 1 { ulp } else { -ulp })) };
    (e(sp.tu, 0), e(sp.tv, 1), e(sp.tw, 2))
}

/// Centre of the 3-sigma bounding box (the low-pass filter's centre) and
/// its half-extent (at least the low-pass radius, before the ceiling: the
/// splat's screen radius); None for a singular conic.
fn bbox(tu: V3, tv: V3, tw: V3) -> Option<([f64; 2], f64)> {
    let t = [9.0, 9.0, -1.0];
    let d = t[0] * tw[0] * tw[0] + t[1] * tw[1] * tw[1] + t[2] * tw[2] * tw[2];
    if d == 0.0 {
        return None;
    }
    let f = [t[0] / d, t[1] / d, t[2] / d];
    let fdot = |a: V3, b: V3| f[0] * a[0] * b[0] + f[1] * a[1] * b[1] + f[2] * a[2] * b[2];
    let mu = [fdot(tu, tw), fdot(tv, tw)];
    let ex = (mu[0] * mu[0] - fdot(tu, tu)).max(1e-4).sqrt();
    let ey = (mu[1] * mu[1] - fdot(tv, tv)).max(1e-4).sqrt();
    Some((mu, ex.max(ey).max(3.0 * FILTER_SIZE)))
}

/// Squared cutoff k^2 = 2 ln(255 o) of the box where alpha = o G can reach
/// 1/255; None when it cannot anywhere.
fn cutoff2(o: f64) -> Option<f64> {
    let a = o * 255.0;
    (a >= 1.0).then(|| 2.0 * a.ln())
}

/// Pixel bounds [x_lo, y_lo, x_hi, y_hi] of where the splat can reach
/// alpha 1/255 at squared cutoff k2 (raster/project.glsl `pixel_bounds`):
/// the splat-plane ellipse of radius k (its screen box about its own centre)
/// joined with the low-pass disc of radius k / sqrt(2) about mu; the whole
/// plane when the ellipse reaches the camera plane (unbounded on screen).
fn pixel_bounds(tu: V3, tv: V3, tw: V3, mu: [f64; 2], k2: f64) -> [f64; 4] {
    let t = [k2, k2, -1.0];
    let d = t[0] * tw[0] * tw[0] + t[1] * tw[1] * tw[1] + t[2] * tw[2] * tw[2];
    if d < 0.0 {
        let f = [t[0] / d, t[1] / d, t[2] / d];
        let fdot = |a: V3, b: V3| f[0] * a[0] * b[0] + f[1] * a[1] * b[1] + f[2] * a[2] * b[2];
        let c = [fdot(tu, tw), fdot(tv, tw)];
        let e = [(c[0] * c[0] - fdot(tu, tu)).max(0.0).sqrt(), (c[1] * c[1] - fdot(tv, tv)).max(0.0).sqrt()];
        let r2 = (k2 / 2.0).sqrt();
        let b = [(c[0] - e[0]).min(mu[0] - r2), (c[1] - e[1]).min(mu[1] - r2), (c[0] + e[0]).max(mu[0] + r2), (c[1] + e[1]).max(mu[1] + r2)];
        if b.iter().all(|v| v.is_finite()) {
            return b;
        }
    }
    [-3.0e38, -3.0e38, 3.0e38, 3.0e38]
}

/// Tile rectangle [x0, x1) x [y0, y1) of the pixels (centres at integers)
/// inside bounds `b`, clamped to the grid; [0; 4] when no pixel is inside.
fn rect_of(b: [f64; 4], tiles: [f64; 3]) -> [usize; 4] {
    let first = [b[0].ceil(), b[1].ceil()];
    let last = [b[2].floor(), b[3].floor()];
    if first[0] > last[0] || first[1] > last[1] || b.iter().any(|v| v.is_nan()) {
        return [0; 4];
    }
    let lo = |v: f64, g: f64| (v / tiles[2]).floor().clamp(0.0, g) as usize;
    let hi = |v: f64, g: f64| ((v / tiles[2]).floor() + 1.0).clamp(0.0, g) as usize;
    [lo(first[0], tiles[0]), lo(first[1], tiles[1]), hi(last[0], tiles[0]), hi(last[1], tiles[1])]
}

fn rect_empty(r: [usize; 4]) -> bool {
    r[2] <= r[0] || r[3] <= r[1]
}

/// Every tile of rectangle `b` is in rectangle `a`.
fn rect_contains(a: [usize; 4], b: [usize; 4]) -> bool {
    rect_empty(b) || (!rect_empty(a) && a[0] <= b[0] && a[1] <= b[1] && b[2] <= a[2] && b[3] <= a[3])
}

/// The splat's tile rectangle (raster/project.glsl `tile_rect`).
fn rect_at(tu: V3, tv: V3, tw: V3, mu: [f64; 2], o: f64, tiles: [f64; 3]) -> [usize; 4] {
    match cutoff2(o) {
        Some(k2) => rect_of(pixel_bounds(tu, tv, tw, mu, k2), tiles),
        None => [0; 4],
    }
}

/// The splat's tile rectangle, and the smallest and largest rectangles that
/// f32 rounding of its inputs (opacity, the bounds) could give: (rect,
/// inner, outer).
fn rects(tu: V3, tv: V3, tw: V3, mu: [f64; 2], o: f64, tiles: [f64; 3]) -> ([usize; 4], [usize; 4], [usize; 4]) {
    let rect = rect_at(tu, tv, tw, mu, o, tiles);
    let dl = 1e-5 * (1.0 + mu[0].abs().max(mu[1].abs()));
    let (mut lo, mut hi) = ([f64::INFINITY; 4], [f64::NEG_INFINITY; 4]);
    let mut maybe_culled = false;
    for dk in [-1.0, 0.0, 1.0] {
        let Some(k2) = cutoff2(o * (1.0 + dk * 1e-6)) else {
            maybe_culled = true;
            continue;
        };
        let k2 = (k2 + dk * (2e-6 + 1e-6 * k2)).max(0.0);
        let b = pixel_bounds(tu, tv, tw, mu, k2);
        let e = dl + 1e-6 * (b[2] - b[0]).abs().max((b[3] - b[1]).abs());
        for i in 0..4 {
            lo[i] = lo[i].min(b[i] - e);
            hi[i] = hi[i].max(b[i] + e);
        }
    }
    // outer: the lowest lower and highest upper bounds; inner: the reverse.
    let outer = rect_of([lo[0], lo[1], hi[2], hi[3]], tiles);
    let inner = if maybe_culled { [0; 4] } else { rect_of([hi[0], hi[1], lo[2], lo[3]], tiles) };
    (rect, inner, outer)
}

fn project(s: &RefScene, g: usize, cam: &Cam64, degree: u32) -> Option<RefSplat> {
    let p = [s.means[3 * g], s.means[3 * g + 1], s.means[3 * g + 2]];
    let q = &s.quats[4 * g..4 * g + 4];
    let qq: f64 = q.iter().map(|v| v * v).sum();
    if !(qq > 1e-30) || !qq.is_finite() {
        return None;
    }
    let l = qq.sqrt();
    let (r, x, y, z) = (q[0] / l, q[1] / l, q[2] / l, q[3] / l);
    let tu_w = [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + r * z), 2.0 * (x * z - r * y)];
    let tv_w = [2.0 * (x * y - r * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + r * x)];
    let tw_w = [2.0 * (x * z + r * y), 2.0 * (y * z - r * x), 1.0 - 2.0 * (x * x + y * y)];
    let su = s.log_scales[2 * g].exp();
    let sv = s.log_scales[2 * g + 1].exp();
    let pv = {
        let a = cam.rot(p);
        [a[0] + cam.t[0], a[1] + cam.t[1], a[2] + cam.t[2]]
    };
    if !(pv[2] > NEAR) {
        return None;
    }
    let au = cam.rot(scale(tu_w, su));
    let av = cam.rot(scale(tv_w, sv));
    let tu = [cam.fx * au[0] + cam.cx * au[2], cam.fx * av[0] + cam.cx * av[2], cam.fx * pv[0] + cam.cx * pv[2]];
    let tv = [cam.fy * au[1] + cam.cy * au[2], cam.fy * av[1] + cam.cy * av[2], cam.fy * pv[1] + cam.cy * pv[2]];
    let tw = [au[2], av[2], pv[2]];
    let nv = cam.rot(tw_w);
    let cosv = -dot(pv, nv);
    if cosv == 0.0 || cosv.is_nan() {
        return None;
    }
    let n = if cosv < 0.0 { scale(nv, -1.0) } else { nv };
    let (mu, radius_raw) = bbox(tu, tv, tw)?;
    let radius = radius_raw.ceil();
    let all = tu.iter().chain(&tv).chain(&tw).chain(&mu).chain(&n).chain(std::iter::once(&radius));
    if !all.into_iter().all(|v| v.is_finite()) {
        return None;
    }
    let o = 1.0 / (1.0 + (-s.opacity[g]).exp());
    let (rect, inner, outer) = rects(tu, tv, tw, mu, o, cam.tiles());
    if rect_empty(outer) {
        return None;
    }
    let ch = s.channels;
    let fb = g * s.coeffs * ch;
    let feat = if s.plain {
        s.features[fb..fb + ch].to_vec()
    } else {
        let dir = sub(p, cam.centre);
        let len = dot(dir, dir).sqrt();
        let dir = if len > 0.0 { scale(dir, 1.0 / len) } else { [0.0, 0.0, 1.0] };
        let y = sh_basis(dir);
        let dg = degree.min(3) as usize;
        let nk = ((dg + 1) * (dg + 1)).min(s.coeffs);
        (0..ch).map(|c| (0.5 + (0..nk).map(|k| y[k] * s.features[fb + k * ch + c]).sum::<f64>()).max(0.0)).collect()
    };
    Some(RefSplat { index: g, tu, tv, tw, mu, n, o, depth: pv[2], rect, outer, inner, cos_view: cosv.abs() / dot(pv, pv).sqrt(), feat, radius })
}

/// The reference render: planes in the GPU layout (CH features, alpha,
/// depth numerator, normal ×3, median, distortion), each w*h.
pub struct RefRender {
    pub planes: Vec<f64>,
    pub ambiguous: Vec<bool>,
    /// Per-pixel max abs error allowed: 1e-4, widened in proportion to the
    /// measured rounding sensitivity of ill-conditioned hits.
    pub tolerance: Vec<f64>,
    pub splats: Vec<RefSplat>,
}

/// Tolerances above this mark a pixel as ill-conditioned (a grazing hit),
/// as the forward comparison reports them.
pub const ILL_CONDITIONED: f64 = 2e-4;

/// Tolerances above this (a one-ulp sensitivity above 2e-4) make a pixel's
/// f32 gradient too inexact for a 1e-2 gradient check. Measured on a failing
/// seed: with no exclusion the error was 1.0e-2; excluding pixels above any
/// threshold from 2e-4 to 3e-2 gave 1e-6 to 3e-6.
pub const GRADIENT_ILL_CONDITIONED: f64 = 1e-2;

impl RefRender {
    /// Not ambiguous, and not so ill-conditioned that an f32 gradient
    /// cannot be held to 1e-2 relative error there.
    pub fn gradient_checkable(&self, pixel: usize) -> bool {
        !self.ambiguous[pixel] && self.tolerance[pixel] <= GRADIENT_ILL_CONDITIONED
    }
}

pub fn render(s: &RefScene, cam: &Camera, background: &[f64], degree: u32) -> RefRender {
    render_with_rects(s, cam, background, degree, None)
}

/// As [`render`], with the tile rectangles taken from the GPU (the binning
/// decision), so rounding at rectangle edges cannot make the two differ.
/// Check the GPU's rectangles with [`rects_agree`].
pub fn render_with_rects(s: &RefScene, cam: &Camera, background: &[f64], degree: u32, rects: Option<(&[[u32; 4]], u32)>) -> RefRender {
    let c = match rects {
        Some((_, tile)) => Cam64::tiled(cam, tile),
        None => Cam64::new(cam),
    };
    let rects = rects.map(|(r, _)| r);
    let (w, h) = (c.w, c.h);
    let ch = s.channels;
    let mut splats: Vec<RefSplat> = (0..s.len()).filter_map(|g| project(s, g, &c, degree)).collect();
    if let Some(r) = rects {
        for sp in &mut splats {
            let g = r[sp.index].map(|v| v as usize);
            sp.rect = g;
            sp.inner = g;
            sp.outer = g;
        }
        splats.retain(|sp| sp.rect[2] > sp.rect[0] && sp.rect[3] > sp.rect[1]);
    }
    // Depth order; the GPU's radix sort is stable, so ties keep index order.
    // The GPU sorts the f32 depth, so compare that.
    splats.sort_by(|a, b| (a.depth as f32).partial_cmp(&(b.depth as f32)).unwrap().then(a.index.cmp(&b.index)));
    let np = w * h;
    let mut planes = vec![0.0; (ch + 7) * np];
    let mut ambiguous = vec![false; np];
    let mut tolerance = vec![1e-4; np];
    for py in 0..h {
        for px in 0..w {
            let i = py * w + px;
            let (tx, ty) = (px / c.tile, py / c.tile);
            let (xf, yf) = (px as f64, py as f64);
            let mut acc = vec![0.0; ch];
            let (mut t, mut dsum, mut m1, mut m2, mut dist, mut med) = (1.0f64, 0.0, 0.0, 0.0, 0.0, 0.0);
            let mut nsum = [0.0; 3];
            let mut amb = false;
            let mut tol = 1e-4f64;
            for sp in &splats {
                let inside = |r: [usize; 4]| tx >= r[0] && tx < r[2] && ty >= r[1] && ty < r[3];
                amb |= inside(sp.outer) && !inside(sp.inner);
                if !inside(sp.rect) {
                    continue;
                }
                let Some((g, z)) = hit(sp.tu, sp.tv, sp.tw, sp.mu, xf, yf) else {
                    continue;
                };
                // (Alpha does not depend on z: test it first so that hits
                // rejected at the near plane are probed too.)
                let alpha = (sp.o * g).min(0.99);
                // The cut flips under rounding if alpha is within rounding of
                // it, and a grazing hit's G moves far under one-ulp changes
                // (measured: alpha 1.1e-6 below the cut with a first-order
                // f32 sensitivity of 8.9e-6, and the GPU kept the splat).
                amb |= (alpha * 255.0 - 1.0).abs() < 2e-5 || ((alpha * 255.0 - 1.0).abs() < 1e-2 && (alpha - 1.0 / 255.0).abs() <= 8.0 * alpha_sensitivity(sp, xf, yf, g));
                if alpha < 1.0 / 255.0 {
                    continue;
                }
                let sens = sensitivity(sp, xf, yf, g, z);
                // The near-plane decision flips if rounding can carry z across
                // it (a splat seen edge-on has a hit depth of pure rounding).
                // Measured: a flip at 0.15x the sensitivity, none beyond 14x.
                amb |= sens.is_infinite() || (z - NEAR).abs() <= 1e-5 * (1.0 + z.abs()) + 8.0 * sens;
                if !(z >= NEAR) || z.is_infinite() {
                    continue;
                }
                tol = tol.max(1e-4 + 50.0 * sens);
                let tn = t * (1.0 - alpha);
                amb |= (tn / 1e-4 - 1.0).abs() < 1e-4;
                if tn < 1e-4 {
                    break;
                }
                let wgt = alpha * t;
                for (a, f) in acc.iter_mut().zip(&sp.feat) {
                    *a += wgt * f;
                }
                dsum += wgt * z;
                for k in 0..3 {
                    nsum[k] += wgt * sp.n[k];
                }
                let m = FAR / (FAR - NEAR) * (1.0 - NEAR / z);
                dist += wgt * (m * m * (1.0 - t) + m2 - 2.0 * m * m1);
                m1 += wgt * m;
                m2 += wgt * m * m;
                amb |= (t - 0.5).abs() < 1e-4;
                if t > 0.5 {
                    med = z;
                }
                t = tn;
            }
            for c in 0..ch {
                planes[c * np + i] = acc[c] + t * background[c];
            }
            planes[ch * np + i] = 1.0 - t;
            planes[(ch + 1) * np + i] = dsum;
            for k in 0..3 {
                planes[(ch + 2 + k) * np + i] = nsum[k];
            }
            planes[(ch + 5) * np + i] = med;
            planes[(ch + 6) * np + i] = dist;
            ambiguous[i] = amb;
            tolerance[i] = tol;
        }
    }
    RefRender { planes, ambiguous, tolerance, splats }
}

/// Where a splat reaches on screen (see [`splat_reach`]).
pub struct SplatReach {
    /// Bounding box [x_lo, y_lo, x_hi, y_hi] of the image's pixel centres
    /// where the splat reaches alpha 1/255 with a hit past the near plane
    /// (those within 1e-6 of the cut left out); None when there are none.
    pub pixels: Option<[f64; 4]>,
    /// Whether its cutoff ellipse misses the camera plane (bounded on screen).
    pub bounded: bool,
    /// The GPU's pixel box in f64 (raster/project.glsl `pixel_box`: the
    /// pixel bounds widened by one pixel) where the splat is bounded and
    /// its bounding conic is well conditioned.
    pub pixel_box: Option<[f64; 4]>,
    /// Every pixel centre (x, y) in `pixels`' sense: the splat reaches
    /// alpha 1/255 there with a hit past the near plane.
    pub reached: Vec<(u32, u32)>,
}

/// Where splat `g` reaches on screen; None when it is culled (not
/// projected, or too faint ever to reach alpha 1/255).
pub fn splat_reach(s: &RefScene, cam: &Camera, degree: u32, g: usize) -> Option<SplatReach> {
    let c = Cam64::new(cam);
    let sp = project(s, g, &c, degree)?;
    let k2 = cutoff2(sp.o)?;
    let tw = sp.tw;
    let bounded = k2 * (tw[0] * tw[0] + tw[1] * tw[1]) - tw[2] * tw[2] < 0.0;
    let mut b = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
    let mut reached = Vec::new();
    for py in 0..c.h {
        for px in 0..c.w {
            let (x, y) = (px as f64, py as f64);
            let Some((gv, z)) = hit(sp.tu, sp.tv, sp.tw, sp.mu, x, y) else { continue };
            let alpha = (sp.o * gv).min(0.99);
            if alpha * 255.0 < 1.0 + 1e-6 || !(z >= NEAR) || z.is_infinite() {
                continue;
            }
            b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
            reached.push((px as u32, py as u32));
        }
    }
    let pixel_box = (bounded && !bbox_ill_conditioned(&sp, c.tiles())).then(|| {
        let p = pixel_bounds(sp.tu, sp.tv, sp.tw, sp.mu, k2);
        [p[0] - 1.0, p[1] - 1.0, p[2] + 1.0, p[3] + 1.0]
    });
    Some(SplatReach { pixels: b[0].is_finite().then_some(b), bounded, pixel_box, reached })
}

/// Tiles the splats of `s` that can reach alpha 1/255 would cover with a
/// square box of their screen radius about mu (the 3-sigma binning 2DGS
/// uses), summed: what the opacity-aware per-axis boxes are measured against.
pub fn square_box_tiles(s: &RefScene, cam: &Camera, degree: u32, tile: u32) -> usize {
    let c = Cam64::tiled(cam, tile);
    (0..s.len())
        .filter_map(|g| project(s, g, &c, degree))
        .map(|sp| {
            let r = rect_of([sp.mu[0] - sp.radius, sp.mu[1] - sp.radius, sp.mu[0] + sp.radius, sp.mu[1] + sp.radius], c.tiles());
            if rect_empty(r) {
                0
            } else {
                (r[2] - r[0]) * (r[3] - r[1])
            }
        })
        .sum()
}

/// Gaussians whose GPU tile rectangle is not between the reference's inner
/// and outer rectangles (or that one side culls and the other does not, with
/// a rectangle that cannot be empty). Returns their indices.
pub fn rects_agree(s: &RefScene, cam: &Camera, degree: u32, gpu: &[[u32; 4]], tile: u32) -> Vec<usize> {
    let c = Cam64::tiled(cam, tile);
    let mut bad = Vec::new();
    for (g, r) in gpu.iter().enumerate() {
        let r = r.map(|v| v as usize);
        let empty = r[2] <= r[0] || r[3] <= r[1];
        match project(s, g, &c, degree) {
            None => {
                if !empty {
                    bad.push(g);
                }
            }
            Some(sp) if bbox_ill_conditioned(&sp, c.tiles()) => {}
            // A centre within rounding of the near plane: the GPU's f32
            // depth may sit on it and cull the splat.
            Some(sp) if empty && (sp.depth - NEAR).abs() <= 1e-6 * NEAR => {}
            Some(sp) => {
                if !(rect_contains(sp.outer, r) && rect_contains(r, sp.inner)) {
                    bad.push(g);
                }
            }
        }
    }
    bad
}

/// The 3-sigma box of a nearly edge-on splat is ill-conditioned (its conic
/// is close to degenerate): does its tile rectangle change when the entries
/// of T move by one f32 ulp?
fn bbox_ill_conditioned(sp: &RefSplat, tiles: [f64; 3]) -> bool {
    if sp.cos_view < 1e-3 {
        return true; // seen edge-on: the bounding conic is degenerate
    }
    let w = sp.tw;
    let near_zero = |k2: f64| (k2 * (w[0] * w[0] + w[1] * w[1]) - w[2] * w[2]).abs() < 1e-3 * (k2 * (w[0] * w[0] + w[1] * w[1]) + w[2] * w[2]);
    if near_zero(9.0) || cutoff2(sp.o).is_some_and(near_zero) {
        return true;
    }
    [0b101_010_101u32, 0b110_011_001, 0b011_100_110].iter().any(|&pattern| {
        let (tu, tv, tw) = perturb(sp, pattern, 2.0);
        match bbox(tu, tv, tw) {
            Some((mu, r)) => !r.is_finite() || rect_at(tu, tv, tw, mu, sp.o, tiles) != sp.rect,
            None => true,
        }
    })
}
