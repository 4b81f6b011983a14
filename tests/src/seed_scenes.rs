//! The synthetic scenes the seeding tests (tests/tests/seed.rs) cast their
//! residual and depth planes from: a glass sphere around an opaque ball
//! seen from a ring of cameras, and a window in a wall seen from one side;
//! with the f64 vector helpers they use.

use crate::Rng;
use tgs::train::stages::reflection::seed::{Seed, SeedNormal, SeedParams, SeedView};
use tgs_pipelines::Camera;

pub type V3 = [f64; 3];

pub fn uniform(r: &mut Rng) -> f64 {
    (r.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}
pub fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
pub fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub fn norm(a: V3) -> V3 {
    let l = dot(a, a).sqrt();
    a.map(|c| c / l)
}

pub const SPHERE_R: f64 = 0.5;
pub const BALL_R: f64 = 0.2;
pub const SIZE: u32 = 64;

/// First positive t of the ray o + t d (d unit) on the sphere of radius r at the origin.
pub fn hit(o: V3, d: V3, r: f64) -> Option<f64> {
    let b = dot(o, d);
    let c = dot(o, o) - r * r;
    let disc = b * b - c;
    if disc < 0.0 {
        return None;
    }
    let t = -b - disc.sqrt();
    (t > 0.0).then_some(t)
}

/// A ring of cameras around the origin, each view's residual (0.03 on the
/// glass sphere's silhouette, plus that on a fraction `noise` of the other
/// pixels, at random) and Stage I depth (the opaque inner ball; none
/// elsewhere).
pub fn views(noise: f64, glass: bool) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    ring(24, noise, glass)
}

/// A `SIZE`² view from `eye` towards `target` (vertical field of view
/// `fov`) and its two per-pixel planes: `pixel` maps the pixel's unit world
/// ray direction, and the length of its view ray at view depth 1 (which
/// turns a distance along the ray into view depth), to (residual, depth).
pub fn cast(eye: V3, target: [f32; 3], fov: f32, mut pixel: impl FnMut(V3, f64) -> (f32, f32)) -> (Camera, Vec<f32>, Vec<f32>) {
    let cam = Camera::look_at(eye.map(|c| c as f32), target, [0.0, 0.0, 1.0], fov, SIZE, SIZE);
    let m = cam.world_to_view;
    let n = (SIZE * SIZE) as usize;
    let (mut r, mut z) = (vec![0.0f32; n], vec![0.0f32; n]);
    for p in 0..n {
        let (u, v) = ((p as u32 % SIZE) as f64, (p as u32 / SIZE) as f64);
        let dv = [(u - cam.cx as f64) / cam.fx as f64, (v - cam.cy as f64) / cam.fy as f64, 1.0];
        // World direction R^T d_view.
        let d = norm([0, 1, 2].map(|j| (0..3).map(|k| m[k][j] as f64 * dv[k]).sum::<f64>()));
        (r[p], z[p]) = pixel(d, dot(dv, dv).sqrt());
    }
    (cam, r, z)
}

/// Camera `i` of `count` in front of a window facing +x: 3.5 away, within
/// `half` degrees of its normal, at heights 0.5 and 1.6 in turn.
fn front_eye(i: usize, count: usize, half: f64) -> V3 {
    let a = (-half + 2.0 * half * i as f64 / (count - 1) as f64).to_radians();
    [3.5 * a.cos(), 3.5 * a.sin(), if i.is_multiple_of(2) { 0.5 } else { 1.6 }]
}

/// `count` views cast from `eye(i)` towards `target` (see [`cast`]):
/// `pixel(eye, direction, length)` gives each pixel's mask and depth.
fn views_from(count: usize, eye: impl Fn(usize) -> V3, target: [f32; 3], fov: f32, pixel: impl Fn(V3, V3, f64) -> (f32, f32)) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    let (mut cams, mut masks, mut depth) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..count {
        let e = eye(i);
        let (cam, r, z) = cast(e, target, fov, |d, len| pixel(e, d, len));
        cams.push(cam);
        masks.push(r);
        depth.push(z);
    }
    (cams, masks, depth)
}

/// [`views`] from `count` cameras.
pub fn ring(count: usize, noise: f64, glass: bool) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    let mut rng = Rng(7);
    let (mut cams, mut res, mut depth) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..count {
        let a = i as f64 * std::f64::consts::TAU / count as f64;
        let h = if i % 2 == 0 { 0.4 } else { 1.0 };
        let e = [3.0 * a.cos(), 3.0 * a.sin(), h];
        let (cam, r, z) = cast(e, [0.0; 3], 0.7, |d, len| {
            let r = if (glass && hit(e, d, SPHERE_R).is_some()) || uniform(&mut rng) < noise { 0.03 } else { 0.0 };
            (r, hit(e, d, BALL_R).map_or(0.0, |t| (t / len) as f32))
        });
        cams.push(cam);
        res.push(r);
        depth.push(z);
    }
    (cams, res, depth)
}

/// Each seed's angle in degrees between its normal and the sphere's radial
/// direction at its position, sorted.
pub fn radial_error(set: &[Seed]) -> Vec<f64> {
    let mut e: Vec<f64> = set
        .iter()
        .map(|s| {
            let x = s.position.map(f64::from);
            let r = dot(x, x).sqrt();
            dot(s.normal.map(f64::from), x.map(|c| c / r)).clamp(-1.0, 1.0).acos().to_degrees()
        })
        .collect();
    e.sort_by(f64::total_cmp);
    e
}

/// A window in a wall, captured from one side (a shop window, a facade):
/// the wall is the plane x = 0, the glass fills |y| <= 1, 0.2 <= z <= 1.2
/// of it, the room's back wall is x = -2, and the cameras stand on the +x
/// side within 50 degrees of the window's normal. Each view's mask is the
/// window and its Stage I depth the wall, or the back wall through the window.
pub fn window_views(count: usize) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    front_window(count, true)
}

/// The same window standing free (no wall round it) before the wall at
/// x = -2 that is all Stage I sees: no surface meets the glass's edge.
pub fn free_window_views(count: usize) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    front_window(count, false)
}

/// `count` views of a front from within 50 degrees of +x, aimed at its
/// middle (0, 0, 0.7): [`views_from`] with those cameras.
fn front_views(count: usize, pixel: impl Fn(V3, V3, f64) -> (f32, f32)) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    views_from(count, |i| front_eye(i, count, 50.0), [0.0, 0.0, 0.7], 0.8, pixel)
}

/// [`window_views`] (`in_wall`) or [`free_window_views`].
fn front_window(count: usize, in_wall: bool) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    front_views(count, |e, d, len| {
        if d[0] >= -1e-9 {
            return (0.0, 0.0);
        }
        let t = -e[0] / d[0];
        let (y, zz) = (e[1] + t * d[1], e[2] + t * d[2]);
        let glass = y.abs() <= 1.0 && (0.2..=1.2).contains(&zz);
        let t = if glass || !in_wall { (-2.0 - e[0]) / d[0] } else { t };
        (glass as u8 as f32, (t / len) as f32)
    })
}

/// The radius of [`curved_front_views`]' front: a vertical cylinder about
/// the axis x = -R, y = 0, through the origin.
pub const FRONT_R: f64 = 1.5;

/// A curved front (a windshield, a bent shop window): the cylinder of
/// radius [`FRONT_R`] bulging towards +x is an opaque wall but for its
/// glass, |y| <= 1 and 0.2 <= z <= 1.2 on it (the glass's normals turn
/// 42 degrees from its middle to its sides), a room's back wall at x = -2
/// behind it; captured from one side as [`window_views`]. Masks of the
/// glass, depths of the wall or, through the glass, the back wall.
pub fn curved_front_views(count: usize) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    curved_front_in(count, true)
}

/// [`curved_front_views`]' glass in a band of its wall as wide as the glass
/// (|y| <= 1): past the glass's sides the back wall, so only its top and
/// bottom edges meet a surface (a windshield's roof and bonnet).
pub fn curved_band_views(count: usize) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    curved_front_in(count, false)
}

/// [`curved_front_views`] (`sides`: the wall all round the glass) or [`curved_band_views`].
fn curved_front_in(count: usize, sides: bool) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    front_views(count, move |e, d, len| {
        let back = if d[0] < -1e-9 { (-2.0 - e[0]) / d[0] } else { return (0.0, 0.0) };
        let o = [e[0] + FRONT_R, e[1]];
        let (a, b, c) = (d[0] * d[0] + d[1] * d[1], 2.0 * (o[0] * d[0] + o[1] * d[1]), o[0] * o[0] + o[1] * o[1] - FRONT_R * FRONT_R);
        let disc = b * b - 4.0 * a * c;
        let t = (disc >= 0.0).then(|| (-b - disc.sqrt()) / (2.0 * a)).filter(|&t| t > 0.0 && t < back);
        let Some(t) = t else { return (0.0, (back / len) as f32) };
        let (y, z) = (e[1] + t * d[1], e[2] + t * d[2]);
        let glass = y.abs() <= 1.0 && (0.2..=1.2).contains(&z);
        let wall = sides || y.abs() <= 1.0;
        (glass as u8 as f32, ((if glass || !wall { back } else { t }) / len) as f32)
    })
}

/// The distance of `x` from [`curved_front_views`]' cylinder and its
/// normal there.
pub fn curved_front(x: V3) -> (f64, V3) {
    let r = [x[0] + FRONT_R, x[1], 0.0];
    let len = dot(r, r).sqrt();
    ((len - FRONT_R).abs(), r.map(|c| c / len))
}

/// Two windows in a stepped front, seen together from `count` cameras in
/// front of it: window A in the wall x = 0 (y < 0), window B in the wall
/// x = 0.6 (y >= 0), the step y = 0 between them opaque; each window 1
/// wide and 1 high, a room's back wall at x = -2 behind both. As
/// [`window_views`], masks of the glass and depths of the first opaque
/// surface; a single plane through both windows' rims fits neither.
pub fn stepped_window_views(count: usize) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    let pane = |y: f64, z: f64, lo: f64| (lo..=lo + 1.0).contains(&y) && (0.2..=1.2).contains(&z);
    views_from(
        count,
        |i| front_eye(i, count, 45.0),
        [0.3, 0.0, 0.7],
        1.0,
        |e, d, len| {
            if d[0] >= -1e-9 {
                return (0.0, 0.0);
            }
            let at = |x: f64| {
                let t = (x - e[0]) / d[0];
                (t, e[1] + t * d[1], e[2] + t * d[2])
            };
            let (tb, yb, zb) = at(0.6);
            let (ta, ya, za) = at(0.0);
            let (t, glass) = if yb >= 0.0 {
                (tb, pane(yb, zb, 0.2))
            } else if ya >= 0.0 {
                // Crosses y = 0 between the walls: the step.
                (-e[1] / d[1], false)
            } else {
                (ta, pane(ya, za, -1.2))
            };
            let t = if glass { at(-2.0).0 } else { t };
            (glass as u8 as f32, (t / len) as f32)
        },
    )
}

/// The ray e + t d through the box [lo, hi]: its entry and exit distances
/// and the axis of the face it enters by; None where it misses the box or
/// starts inside it.
fn slabs(e: V3, d: V3, lo: V3, hi: V3) -> Option<(f64, f64, usize)> {
    let (mut t0, mut t1, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0);
    for k in 0..3 {
        let (a, b) = ((lo[k] - e[k]) / d[k], (hi[k] - e[k]) / d[k]);
        let (near, far) = (a.min(b), a.max(b));
        if near > t0 {
            (t0, axis) = (near, k);
        }
        t1 = t1.min(far);
    }
    (t0 <= t1 && t0 > 0.0).then_some((t0, t1, axis))
}

/// A closed box (x, y in [-0.5, 0.5], z in [0, 1]) with a window in its
/// face x = 0.5 (y in [-0.3, 0.3], z in [0.3, 0.7]), seen from `count`
/// cameras all around it: the window and its rim are hidden from the
/// cameras behind the box. Masks of the glass, depths of the first opaque
/// surface (inside the box through the window: its far wall).
pub fn window_box_views(count: usize) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    let eye = |i: usize| {
        let a = i as f64 * std::f64::consts::TAU / count as f64;
        [3.0 * a.cos(), 3.0 * a.sin(), if i.is_multiple_of(2) { 0.6 } else { 1.5 }]
    };
    views_from(count, eye, [0.0, 0.0, 0.5], 0.8, |e, d, len| {
        let Some((t0, t1, axis)) = slabs(e, d, [-0.5, -0.5, 0.0], [0.5, 0.5, 1.0]) else { return (0.0, 0.0) };
        let p = [0, 1, 2].map(|k| e[k] + t0 * d[k]);
        let glass = axis == 0 && p[0] > 0.0 && p[1].abs() <= 0.3 && (0.3..=0.7).contains(&p[2]);
        (glass as u8 as f32, ((if glass { t1 } else { t0 }) / len) as f32)
    })
}

/// A cabin (x in [-0.5, 0.5], y in [-0.4, 0.4], z in [0, 1]) whose four
/// side faces are glass between heights 0.4 and 0.8 (a vehicle's windows
/// meeting edge to edge at its corners), seen from `count` cameras all
/// around it: most views see two windows as one piece of mask that turns a
/// corner. Masks of the glass, depths of the first opaque surface (through
/// the glass: the cabin's far side).
pub fn cabin_views(count: usize) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    let eye = |i: usize| {
        let a = (i as f64 + 0.3) * std::f64::consts::TAU / count as f64;
        [3.0 * a.cos(), 3.0 * a.sin(), if i.is_multiple_of(2) { 1.4 } else { 2.0 }]
    };
    views_from(count, eye, [0.0, 0.0, 0.5], 0.8, |e, d, len| {
        let Some((t0, t1, axis)) = slabs(e, d, [-0.5, -0.4, 0.0], [0.5, 0.4, 1.0]) else { return (0.0, 0.0) };
        let glass = axis < 2 && (0.4..=0.8).contains(&(e[2] + t0 * d[2]));
        (glass as u8 as f32, ((if glass { t1 } else { t0 }) / len) as f32)
    })
}

/// The distance of `x` from the cabin's glass band ([`cabin_views`]) and
/// the normal of its nearest window.
pub fn cabin_glass(x: V3) -> (f64, V3) {
    nearest_face(x, &[(0, 0.5), (0, -0.5), (1, 0.4), (1, -0.4)], ([-0.5, -0.4, 0.4], [0.5, 0.4, 0.8]))
}

/// The normals of the box's `faces` (as [`nearest_face`] takes them) that
/// lie within `slack` of the nearest to `x`: near an edge, either face may
/// be the glass that a seed there stands for.
pub fn faces_near(x: V3, faces: &[(usize, f64)], (lo, hi): (V3, V3), slack: f64) -> Vec<V3> {
    let dist: Vec<(f64, V3)> = faces.iter().map(|&f| nearest_face(x, &[f], (lo, hi))).collect();
    let best = dist.iter().map(|d| d.0).fold(f64::INFINITY, f64::min);
    dist.into_iter().filter(|d| d.0 <= best + slack).map(|d| d.1).collect()
}

/// The glass faces of [`glass_box_views`]'s box: (axis, at) and its extent.
pub const GLASS_BOX: ([(usize, f64); 5], (V3, V3)) = ([(0, 0.5), (0, -0.5), (1, 0.5), (1, -0.5), (2, 0.8)], ([-0.5, -0.5, 0.0], [0.5, 0.5, 0.8]));

/// The distance of `x` from the nearest of a box's `faces` ((axis, at):
/// the face where coordinate `axis` is `at`, within the box `lo`..`hi`
/// on the other axes) and that face's normal along +axis.
fn nearest_face(x: V3, faces: &[(usize, f64)], (lo, hi): (V3, V3)) -> (f64, V3) {
    let mut best = (f64::INFINITY, [0.0; 3]);
    for &(k, at) in faces {
        let q: V3 = std::array::from_fn(|j| if j == k { at } else { x[j].clamp(lo[j], hi[j]) });
        let dist = dot(sub(x, q), sub(x, q)).sqrt();
        if dist < best.0 {
            let mut n = [0.0; 3];
            n[k] = 1.0;
            best = (dist, n);
        }
    }
    best
}

/// The seeding's views from per-view cameras, residuals (or masks) and
/// Stage I depths, as the scenes above return them.
pub fn seed_views<'a>(cams: &[Camera], res: &'a [Vec<f32>], depth: &'a [Vec<f32>]) -> Vec<SeedView<'a>> {
    cams.iter().zip(res.iter().zip(depth)).map(|(c, (r, z))| SeedView { camera: *c, residual: r, depth: z }).collect()
}

/// A glass box (x, y in [-0.5, 0.5], z in [0, 0.8]: its top and four
/// sides glass, as the suite's `cabinet`) standing on the floor z = 0,
/// seen from `count` cameras all around it from 20 to 50 degrees above
/// (no view sees a face edge on). Masks of the glass, depths of the floor
/// (inside the box through the glass, or around it).
pub fn glass_box_views(count: usize) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    views_from(
        count,
        |i| above_eye(i, 3.5),
        [0.0, 0.0, 0.4],
        0.8,
        |e, d, len| {
            let floor = if d[2] < 0.0 { (-e[2] / d[2] / len) as f32 } else { 0.0 };
            let glass = slabs(e, d, [-0.5, -0.5, 0.0], [0.5, 0.5, 0.8]).is_some();
            (glass as u8 as f32, floor)
        },
    )
}

/// The distance of `x` from the glass box's nearest glass face
/// ([`glass_box_views`]) and that face's normal.
pub fn glass_box_face(x: V3) -> (f64, V3) {
    nearest_face(x, &GLASS_BOX.0, GLASS_BOX.1)
}

/// The seeding's parameters for views whose residual planes are glass
/// masks (1 on the glass): a pixel is glass above 0.5, unblurred, 3,000
/// rays, seed normals by `normal`; the rest at their defaults.
pub fn mask_params(normal: SeedNormal) -> SeedParams {
    SeedParams { threshold: 0.5, blur: 0, max_rays: 3000, normal, ..SeedParams::default() }
}

/// A free-standing glass pane (x = 0, y in [-0.6, 0.6], z in [0, 0.7]: the
/// suite's `pane`) on the floor z = 0, seen from `count` cameras all around
/// it from 20 to 50 degrees above, from both sides. Masks of the glass,
/// depths of the floor.
pub fn glass_pane_views(count: usize) -> (Vec<Camera>, Vec<Vec<f32>>, Vec<Vec<f32>>) {
    views_from(
        count,
        |i| above_eye(i, 3.0),
        [0.0, 0.0, 0.35],
        0.8,
        |e, d, len| {
            let floor = if d[2] < 0.0 { (-e[2] / d[2] / len) as f32 } else { 0.0 };
            let t = -e[0] / d[0];
            let glass = t > 0.0 && (e[1] + t * d[1]).abs() <= 0.6 && (0.0..=0.7).contains(&(e[2] + t * d[2]));
            (glass as u8 as f32, floor)
        },
    )
}

/// `n` seeds uniform on the unit sphere, each with its radial normal.
pub fn unit_sphere_seeds(rng: &mut Rng, n: usize) -> Vec<Seed> {
    (0..n)
        .map(|_| {
            let (z, a) = (2.0 * uniform(rng) - 1.0, std::f64::consts::TAU * uniform(rng));
            let r = (1.0 - z * z).sqrt();
            let n = [r * a.cos(), r * a.sin(), z];
            Seed { position: n.map(|c| c as f32), normal: n.map(|c| c as f32), scale: 0.01 }
        })
        .collect()
}

/// Camera `i` of `count` all around the origin at `distance`, from 20 to 50
/// degrees above (golden-ratio azimuths): [`glass_box_views`], [`glass_pane_views`].
fn above_eye(i: usize, distance: f64) -> V3 {
    let a = (i as f64 * 0.618_034).fract() * std::f64::consts::TAU;
    let el = (20.0 + 30.0 * (i as f64 * 0.377).fract()).to_radians();
    [distance * el.cos() * a.cos(), distance * el.cos() * a.sin(), distance * el.sin()]
}
