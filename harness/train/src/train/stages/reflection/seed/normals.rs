//! The seeds' surfels: each found hull point's normal (facing the camera
//! that found it, or the local plane of its neighbours, or the gradient of
//! the views' blurred residual masks, or halfway between the first and the
//! last; see the parent module for which and
//! why) and its size (the spacing of its nearest seeds), and the
//! quaternion that turns a surfel's normal axis onto a normal.

use super::{in_parallel, nearest, normalize, Prepared, Seed, V3};
use glam::DVec3;

crate::train::settings::name_enum!(
    /// A seed's normal (see the seed module's documentation; `reflection.seed_normal`).
    SeedNormal, "reflection.seed_normal", {
        /// The unit direction from the seed to the centre of the camera whose
        /// ray found it.
        View = "view",
        /// The least-squares plane of the seed and its 16 nearest seeds,
        /// turned to face that camera (the camera direction with fewer than 3
        /// neighbours).
        Plane = "plane",
        /// The plane through the seed that most of its 128 nearest seeds lie
        /// on within 2% of its depth (the best of 128 through the seed and two
        /// of them, a fixed sequence), refitted by least squares to those:
        /// a mask's hull points scatter about the glass by as much as their
        /// spacing, which tilts `Plane`'s 16-point fit (docs/stage2.md).
        Consensus = "consensus",
        /// Against the gradient of the hull's agreement field: the sum, over
        /// the views that see the seed, of their residual masks blurred by a
        /// tenth of the image width and sampled at its projections,
        /// differentiated in 3D by central differences over that width. A view
        /// whose mask edge passes near the seed adds the normal of its
        /// silhouette cone there; a view that sees it deep inside or outside
        /// its mask adds nothing. Where the field changes by less than
        /// [`GRADIENT_MIN`] over the step, the camera direction (as `View`).
        Gradient = "gradient",
        /// The unit bisector of `View` and `Gradient`'s normals (the camera
        /// direction where the field is flat). The hull's outward normal is
        /// right where the residual's hull is the glass's (closed objects)
        /// and wrong where it is not (a flat pane or an open tube inside a
        /// blob of residual); halfway keeps most of its gain on the first
        /// and most of the camera direction on the second (perf/RESULTS.md,
        /// thirty-third session).
        Halfway = "halfway",
        /// `Consensus` when the hull comes from given glass masks
        /// (`reflection.seed_masks`), `Halfway` when it comes from the
        /// residual ([`SeedNormal::for_source`]): an exact mask's hull puts
        /// the seeds on the glass, and their neighbours' plane is then its
        /// tangent plane (perf/RESULTS.md, forty-fourth entry; the consensus
        /// over `Plane`: perf/journal/2026-12-05-sixty-first.md).
        Auto = "auto",
    }
);

impl SeedNormal {
    /// [`SeedNormal::Auto`] resolved for a hull from given glass masks
    /// (`masks`) or from the residual; any other choice as it is.
    pub fn for_source(self, masks: bool) -> SeedNormal {
        match self {
            SeedNormal::Auto if masks => SeedNormal::Consensus,
            SeedNormal::Auto => SeedNormal::Halfway,
            n => n,
        }
    }

    /// Whether the normal reads the views' blurred masks' gradient.
    pub(super) fn uses_field(self) -> bool {
        matches!(self.for_source(false), SeedNormal::Gradient | SeedNormal::Halfway)
    }

    /// The normal where no hull point beat chance ([`super::hull_seeding`]'s
    /// fallback): the masks then cover most of every image, so their sum
    /// has no outline to take a normal from, and the normals that read it
    /// ([`SeedNormal::Gradient`], [`SeedNormal::Halfway`]) face the camera
    /// instead. Measured on the path-traced room fronts and `lantern`
    /// (perf/RESULTS.md, thirty-third entry), glass normal MAE after Stage
    /// II with the fallback's most-agreeing seeds, halfway against the
    /// camera direction: `facade` 16.9 / 17.7 against 18.6 / 16.6 degrees
    /// (seeds 0 / 1), `windshield` 18.6 / 19.0 against 20.9 / 18.9,
    /// `lantern` 50.8 against 47.5 (seed 0; its Stage I 47.7), and beside
    /// the glass 5 to 7 degrees worse on the rooms.
    pub fn without_outline(self) -> SeedNormal {
        if self.uses_field() {
            SeedNormal::View
        } else {
            self
        }
    }
}

/// Normals (`normal`, facing the finding camera) and scales (root mean
/// squared distance to the 3 nearest) of the found points.
/// A point with a `fixed` normal (its membrane's, seed/rim.rs; `fixed`
/// is empty or one per point) takes that one, turned to face its camera.
pub(super) fn surfels(found: &[(V3, usize)], fixed: &[Option<V3>], views: &[Prepared], normal: SeedNormal, threads: usize) -> Vec<Seed> {
    let index: Vec<usize> = (0..found.len()).collect();
    in_parallel(&index, threads, |run| run.iter().map(|&i| surfel(found, i, fixed.get(i).copied().flatten(), views, normal)).collect::<Vec<Seed>>()).concat()
}

/// [`surfels`] for `found[i]`.
fn surfel(found: &[(V3, usize)], i: usize, fixed: Option<V3>, views: &[Prepared], normal: SeedNormal) -> Seed {
    const K: usize = 16;
    let (x, vi) = found[i];
    let wide = fixed.is_none() && normal.for_source(false) == SeedNormal::Consensus;
    let near = nearest(DVec3::from(x), found.iter().map(|&(y, _)| DVec3::from(y)), Some(i), if wide { CONSENSUS_NEIGHBOURS } else { K });
    let k = near.len();
    let cam = views[vi].cam.centre().map(f64::from);
    let to_cam = normalize((DVec3::from(cam) - DVec3::from(x)).to_array());
    let mut n = if let Some(f) = fixed {
        f
    } else {
        match normal.for_source(false) {
            SeedNormal::Plane if k >= 3 => plane_normal(x, near.iter().map(|&(_, j)| found[j].0)),
            SeedNormal::Consensus => {
                let pts: Vec<V3> = near.iter().map(|&(_, j)| found[j].0).collect();
                consensus_normal(x, &pts, CONSENSUS_TOL * (DVec3::from(cam) - DVec3::from(x)).length(), i as u64).unwrap_or(to_cam)
            }
            SeedNormal::Gradient => field_normal(x, views, &views[vi]).unwrap_or(to_cam),
            SeedNormal::Halfway => field_normal(x, views, &views[vi]).map_or(to_cam, |g| {
                let g = if DVec3::from(g).dot(DVec3::from(to_cam)) < 0.0 { g.map(|c| -c) } else { g };
                normalize((DVec3::from(g) + DVec3::from(to_cam)).to_array())
            }),
            _ => to_cam,
        }
    };
    if DVec3::from(n).dot(DVec3::from(to_cam)) < 0.0 {
        n = n.map(|c| -c);
    }
    let m = near.len().min(3);
    let scale = if m > 0 { (near[..m].iter().map(|a| a.0).sum::<f64>() / m as f64).sqrt() } else { 0.0 };
    Seed { position: x.map(|c| c as f32), normal: n.map(|c| c as f32), scale: scale.max(1e-4) as f32 }
}

/// The nearest seeds [`SeedNormal::Consensus`] looks for a plane among.
/// Measured with exact masks at 50² (perf/journal/2026-12-05-sixty-first.md):
/// 128 against 256 and 512, the nine scenes' mean the same and the worst
/// (`cabinet`, whose hull bevels its edges) least hurt.
pub const CONSENSUS_NEIGHBOURS: usize = 128;
/// How far from a candidate plane (a share of the seed's depth) a
/// neighbour may lie and count as on it: the mask hull's scatter about a
/// pane (`pane`: a median 0.05 off at a depth near 4).
pub const CONSENSUS_TOL: f64 = 0.02;
/// Candidate planes [`consensus_normal`] tries.
const CONSENSUS_TRIES: usize = 128;

/// The unit normal of the plane through `x` and two of `pts` (a fixed
/// xorshift sequence from `seed`, [`CONSENSUS_TRIES`] pairs) that the most
/// of `pts` lie within `tol` of, refitted by least squares to those (and
/// `x`); None with fewer than 3 points or no pair that spans a plane.
pub fn consensus_normal(x: V3, pts: &[V3], tol: f64, seed: u64) -> Option<V3> {
    if pts.len() < 3 {
        return None;
    }
    let xc = DVec3::from(x);
    let on = |n: DVec3| move |p: &&V3| n.dot(DVec3::from(**p) - xc).abs() <= tol;
    let mut state = 0x9e37_79b9_7f4a_7c15u64 ^ seed.wrapping_mul(0x2545_f491_4f6c_dd1d);
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        DVec3::from(pts[(state % pts.len() as u64) as usize])
    };
    let mut best: Option<(usize, DVec3)> = None;
    for _ in 0..CONSENSUS_TRIES {
        let n = (next() - xc).cross(next() - xc);
        if n.length_squared() < 1e-24 {
            continue;
        }
        let n = n.normalize();
        let count = pts.iter().filter(on(n)).count();
        if best.is_none_or(|(m, _)| count > m) {
            best = Some((count, n));
        }
    }
    let (_, n) = best?;
    Some(plane_normal(x, pts.iter().filter(on(n)).copied()))
}

/// [`SeedNormal::Gradient`]'s blur radius and half-step, in pixels: a
/// tenth of the image width. Measured on the built-in glass (64 px): the
/// seeds' normal error fell from 49 to 27 degrees (median) as this grew
/// from 2 to 10 pixels.
pub(super) fn gradient_pixels(width: usize) -> usize {
    ((width as f64 * 0.1).round() as usize).max(1)
}

/// The least change of the agreement field (in views' masks) over a
/// half-step for [`SeedNormal::Gradient`] to trust its gradient: weaker
/// slopes come from stray residual pixels, not from a silhouette that
/// several views share. Measured on the built-in glass: rendered normal
/// MAE 36.9 / 35.3 / 31.4 / 30.3 degrees at thresholds 0.1 / 2 / 3 / 4
/// before Stage II trains (`lantern`, at 6 pixels: 54.0 / 49.1 / 50.4 / 50.6).
pub const GRADIENT_MIN: f64 = 3.0;

/// The unit normal against the agreement field's gradient at `x` (central
/// differences over [`gradient_pixels`] of `finder` at `x`), over the
/// views that see `x` in front of their Stage I surface; None where the
/// field is flat (see [`GRADIENT_MIN`]).
fn field_normal(x: V3, views: &[Prepared], finder: &Prepared) -> Option<V3> {
    let seeing: Vec<&Prepared> = views.iter().filter(|v| v.in_front(x).is_some()).collect();
    let z = finder.pixel(x)?.1;
    let h = gradient_pixels(finder.cam.width as usize) as f64 * z / finder.cam.fx as f64;
    let field = |p: V3| seeing.iter().map(|v| v.soft_at(p)).sum::<f64>();
    let g: V3 = [0, 1, 2].map(|k| {
        let (mut a, mut b) = (x, x);
        a[k] += h;
        b[k] -= h;
        (field(a) - field(b)) / (2.0 * h)
    });
    let len = DVec3::from(g).length();
    (len * h > GRADIENT_MIN).then(|| g.map(|c| -c / len))
}

/// Unit normal of the least-squares plane through `x` and `pts`.
fn plane_normal(x: V3, pts: impl Iterator<Item = V3>) -> V3 {
    let all: Vec<DVec3> = std::iter::once(x).chain(pts).map(DVec3::from).collect();
    normalize(least_squares_plane(&all).1.to_array())
}

/// The least-squares plane of `pts` (at least one): their mean, and the
/// eigenvector (as the Jacobi rotations leave it, near unit length) of the
/// smallest eigenvalue of their covariance, its normal.
pub(super) fn least_squares_plane(pts: &[DVec3]) -> (DVec3, DVec3) {
    let mean = pts.iter().copied().sum::<DVec3>() / pts.len() as f64;
    let mut c = [[0.0f64; 3]; 3];
    for p in pts {
        let d = *p - mean;
        for r in 0..3 {
            for s in 0..3 {
                c[r][s] += d[r] * d[s];
            }
        }
    }
    let (vals, vecs) = jacobi_eigen(c);
    let k = (0..3).min_by(|&a, &b| vals[a].total_cmp(&vals[b])).unwrap_or(2);
    (mean, DVec3::new(vecs[0][k], vecs[1][k], vecs[2][k]))
}

/// Eigenvalues and eigenvectors (columns) of a symmetric 3x3 matrix by
/// cyclic Jacobi rotations.
pub fn jacobi_eigen(mut a: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..32 {
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        if off <= 1e-30 * (a[0][0].abs() + a[1][1].abs() + a[2][2].abs()).max(1e-300) {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q].abs() < 1e-300 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            // A <- J^T A J with J the rotation in the (p, q) plane.
            for k in 0..3 {
                let (akp, akq) = (a[k][p], a[k][q]);
                a[k][p] = c * akp - s * akq;
                a[k][q] = s * akp + c * akq;
            }
            for k in 0..3 {
                let (apk, aqk) = (a[p][k], a[q][k]);
                a[p][k] = c * apk - s * aqk;
                a[q][k] = s * apk + c * aqk;
            }
            for row in v.iter_mut() {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    ([a[0][0], a[1][1], a[2][2]], v)
}

/// The quaternion (r, x, y, z) of the shortest rotation taking +z to the
/// unit vector `n`: a splat with it has normal t_w = n.
pub fn quat_for_normal(n: [f32; 3]) -> [f32; 4] {
    let n = normalize(n.map(f64::from));
    if n[2] < -1.0 + 1e-9 {
        return [0.0, 1.0, 0.0, 0.0];
    }
    // q = (1 + z.n, z x n) normalised, z x n = (-n_y, n_x, 0).
    let q = [1.0 + n[2], -n[1], n[0], 0.0];
    let l = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    q.map(|v| (v / l) as f32)
}
