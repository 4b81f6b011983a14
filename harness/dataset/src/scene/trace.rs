//! A small CPU ray tracer for the built-in transmissive scene: a thin glass
//! sphere (Schlick Fresnel reflection, straight transmission) around two
//! diffuse objects on a checkered floor, ringed by striped blocks and a
//! painted wall (near-field surroundings to be reflected), lit by a sun
//! with shadows and ambient light.

pub use glam::DVec3 as V3;

/// Glass: centre, radius, Fresnel F0.
pub const GLASS_C: V3 = V3::new(0.0, 0.0, 0.8);
pub const GLASS_R: f64 = 0.75;
pub const GLASS_F0: f64 = 0.04;
const WALL_R: f64 = 5.0;
const WALL_H: f64 = 3.5;
const SUN: V3 = V3::new(0.48, 0.3, 0.82);

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Material {
    Glass,
    Diffuse(V3),
}

#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f64,
    pub p: V3,
    pub n: V3,
    pub mat: Material,
}

struct Box3 {
    lo: V3,
    hi: V3,
    color: V3,
}

pub struct Scene {
    blocks: Vec<Box3>,
    inner_box: Box3,
    ball: (V3, f64),
    /// Whether the glass sphere is there (without it: a diffuse scene).
    pub glass: bool,
}

impl Default for Scene {
    fn default() -> Self {
        Self::new()
    }
}

fn hue(h: f64) -> V3 {
    let f = |n: f64| {
        let k = (n + h * 6.0) % 6.0;
        0.85 - 0.65 * (k.min(4.0 - k).clamp(0.0, 1.0))
    };
    V3::new(f(5.0), f(3.0), f(1.0))
}

impl Scene {
    pub fn new() -> Scene {
        let mut blocks = Vec::new();
        for i in 0..8 {
            let a = i as f64 * std::f64::consts::TAU / 8.0 + 0.2;
            let c = [3.3 * a.cos(), 3.3 * a.sin()];
            let h = 0.7 + 0.35 * ((i * 5) % 3) as f64;
            blocks.push(Box3 { lo: V3::new(c[0] - 0.35, c[1] - 0.35, 0.0), hi: V3::new(c[0] + 0.35, c[1] + 0.35, h), color: hue(i as f64 / 8.0) });
        }
        Scene {
            blocks,
            inner_box: Box3 { lo: V3::new(-0.38, -0.3, 0.05), hi: V3::new(-0.04, 0.04, 0.39), color: V3::new(0.15, 0.6, 0.55) },
            ball: (V3::new(0.18, 0.15, 0.33), 0.26),
            glass: true,
        }
    }

    /// Nearest hit with t in (eps, tmax).
    pub fn intersect(&self, o: V3, d: V3, tmax: f64, glass: bool) -> Option<Hit> {
        let eps = 1e-6;
        let mut best: Option<Hit> = None;
        let mut take = |h: Hit| {
            if h.t > eps && h.t < tmax && best.as_ref().is_none_or(|b| h.t < b.t) {
                best = Some(h);
            }
        };
        // Floor disc.
        if d[2].abs() > 1e-12 {
            let t = -o[2] / d[2];
            let p = o + d * t;
            if p[0] * p[0] + p[1] * p[1] < WALL_R * WALL_R {
                let check = ((p[0] * 2.0).floor() + (p[1] * 2.0).floor()) as i64 & 1;
                let c = if check == 0 { V3::new(0.78, 0.74, 0.66) } else { V3::new(0.32, 0.3, 0.34) };
                take(Hit { t, p, n: V3::Z, mat: Material::Diffuse(c) });
            }
        }
        // Wall: inside of a vertical cylinder.
        let (a, b, c) = (d[0] * d[0] + d[1] * d[1], o[0] * d[0] + o[1] * d[1], o[0] * o[0] + o[1] * o[1] - WALL_R * WALL_R);
        if a > 1e-12 {
            let disc = b * b - a * c;
            if disc >= 0.0 {
                let t = (-b + disc.sqrt()) / a;
                let p = o + d * t;
                if p[2] >= 0.0 && p[2] <= WALL_H {
                    let ang = p[1].atan2(p[0]);
                    let stripe = ((ang * 12.0 / std::f64::consts::PI).floor() as i64 & 1) as f64;
                    let base = hue((ang / std::f64::consts::TAU + 1.0) % 1.0);
                    let k = 0.55 + 0.3 * stripe + 0.15 * (p[2] / WALL_H);
                    take(Hit { t, p, n: V3::new(-p[0], -p[1], 0.0).normalize(), mat: Material::Diffuse(base * k) });
                }
            }
        }
        for bx in self.blocks.iter().chain(std::iter::once(&self.inner_box)) {
            if let Some((t, n)) = hit_box(bx, o, d) {
                let p = o + d * t;
                let stripe = (((p[2] * 6.0).floor() as i64) & 1) as f64;
                take(Hit { t, p, n, mat: Material::Diffuse(bx.color * (0.75 + 0.25 * stripe)) });
            }
        }
        // The ball is opaque: only its nearest hit counts.
        if let Some(&t) = hit_sphere(self.ball.0, self.ball.1, o, d).first() {
            let p = o + d * t;
            let n = (p - self.ball.0).normalize();
            let band = (((n[2] * 4.0).floor() as i64) & 1) as f64;
            take(Hit { t, p, n, mat: Material::Diffuse(V3::new(0.9, 0.45 + 0.25 * band, 0.15)) });
        }
        if glass && self.glass {
            for t in hit_sphere(GLASS_C, GLASS_R, o, d) {
                let p = o + d * t;
                take(Hit { t, p, n: (p - GLASS_C).normalize(), mat: Material::Glass });
            }
        }
        best
    }

    /// Distance from `p` to the nearest opaque surface (floor disc, wall,
    /// blocks, the box and ball inside the glass): the truth a scene mesh
    /// is measured against.
    pub fn surface_distance(&self, p: impl Into<V3>) -> f64 {
        let p = p.into();
        let box_dist = |b: &Box3| {
            let q: [f64; 3] = std::array::from_fn(|k| (p[k] - 0.5 * (b.lo[k] + b.hi[k])).abs() - 0.5 * (b.hi[k] - b.lo[k]));
            let outside = q.iter().map(|v| v.max(0.0).powi(2)).sum::<f64>().sqrt();
            (outside + q[0].max(q[1]).max(q[2]).min(0.0)).abs()
        };
        let r = p[0].hypot(p[1]);
        let floor = if r < WALL_R { p[2].abs() } else { (r - WALL_R).hypot(p[2]) };
        let wall = (r - WALL_R).hypot(p[2] - p[2].clamp(0.0, WALL_H));
        let ball = ((p - self.ball.0).length() - self.ball.1).abs();
        self.blocks.iter().chain(std::iter::once(&self.inner_box)).map(box_dist).fold(floor.min(wall).min(ball), f64::min)
    }

    /// Distance from `p` to the glass sphere's surface.
    pub fn glass_distance(p: impl Into<V3>) -> f64 {
        let p = p.into();
        ((p - GLASS_C).length() - GLASS_R).abs()
    }

    /// Radiance along a ray (thin glass: reflect F, transmit 1 - F unbent).
    pub fn radiance(&self, o: V3, d: V3, depth: u32) -> V3 {
        let Some(h) = self.intersect(o, d, f64::INFINITY, true) else {
            return V3::new(0.9, 0.93, 1.0);
        };
        let n = if h.n.dot(d) > 0.0 { -h.n } else { h.n };
        match h.mat {
            Material::Diffuse(albedo) => {
                let l = SUN.normalize();
                let lit = n.dot(l).max(0.0);
                let shadow = if lit > 0.0 && self.intersect(h.p + n * 1e-5, l, f64::INFINITY, false).is_some_and(|s| s.p[0].hypot(s.p[1]) < WALL_R - 1e-3) { 0.0 } else { 1.0 };
                albedo * (0.35 + 0.65 * lit * shadow)
            }
            Material::Glass => {
                if depth == 0 {
                    return V3::splat(0.5);
                }
                let cos = (-n.dot(d)).clamp(0.0, 1.0);
                let f = GLASS_F0 + (1.0 - GLASS_F0) * (1.0 - cos).powi(5);
                let r = d - n * (2.0 * n.dot(d));
                let refl = self.radiance(h.p + n * 1e-6, r, depth - 1);
                let trans = self.radiance(h.p + d * 1e-6, d, depth - 1);
                refl * f + trans * (1.0 - f)
            }
        }
    }
}

/// Ray parameters t > 0 where the ray meets the sphere, nearest first.
pub(crate) fn hit_sphere(c: V3, r: f64, o: V3, d: V3) -> Vec<f64> {
    let oc = o - c;
    let b = oc.dot(d);
    let cc = oc.dot(oc) - r * r;
    let disc = b * b - cc;
    if disc < 0.0 {
        return Vec::new();
    }
    let s = disc.sqrt();
    [-b - s, -b + s].into_iter().filter(|&t| t > 1e-6).collect()
}

fn hit_box(b: &Box3, o: V3, d: V3) -> Option<(f64, V3)> {
    let mut t0 = f64::NEG_INFINITY;
    let mut t1 = f64::INFINITY;
    let mut axis = 0;
    for k in 0..3 {
        if d[k].abs() < 1e-15 {
            if o[k] < b.lo[k] || o[k] > b.hi[k] {
                return None;
            }
            continue;
        }
        let (mut a, mut c) = ((b.lo[k] - o[k]) / d[k], (b.hi[k] - o[k]) / d[k]);
        if a > c {
            std::mem::swap(&mut a, &mut c);
        }
        if a > t0 {
            t0 = a;
            axis = k;
        }
        t1 = t1.min(c);
    }
    if t0 > t1 || t0 <= 1e-6 {
        return None;
    }
    let mut n = V3::ZERO;
    n[axis] = -d[axis].signum();
    Some((t0, n))
}
