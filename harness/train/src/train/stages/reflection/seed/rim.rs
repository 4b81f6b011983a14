//! Depth from the glass's rim ([`SeedParams::rim`]): where a front of glass
//! is captured from one side only (a shop window, a facade), the masks'
//! hull is a wedge whose tip reaches far in front of the glass, and the
//! first hull point along a ray lies in that wedge (perf/RESULTS.md,
//! forty-fourth entry: `facade`'s seeds a median 0.45 in front). What
//! places such a front is its rim: a pane set in a frame or a wall meets
//! opaque surfaces that Stage I reconstructed, right at the masks' edges.
//!
//! The rim points are the Stage I surface points of the pixels just outside
//! each view's mask that project onto (or next to) a mask edge in at least
//! [`RIM_AGREE`] of the views whose image holds them: a frame flush with
//! the glass does, in every view; the background seen past a closed
//! object's silhouette, or past an open pane's free edge, does not (it lies
//! elsewhere in the other views). A view whose mask has rim points all
//! around it ([`RIM_SECTORS`] of 12 directions from the mask's centre)
//! gets a membrane: the plane through them, fitted as inverse depth affine
//! in the normalised image coordinates (exact for a plane) by iteratively
//! reweighted least squares. Its rays' seeds are then the membrane's point,
//! with the membrane's normal, where the hull holds it (it agrees, beats
//! chance and lies in front of Stage I's surface); elsewhere the first hull
//! point, unless that lies more than [`RIM_FRONT`] in front of the
//! membrane (the wedge).
//!
//! Measured on the path-traced suite with exact masks (perf/RESULTS.md,
//! forty-fifth entry): `facade`'s seeds lie 99.1% within 0.1 of the glass
//! (13.5% without the rim) and its glass normal MAE after Stage II falls
//! from 37.8 to 3.3 degrees, `windshield`'s from 23.3 to 13.5 (its plane
//! is the curved glass's chord); on `globe`, `globe_far`, `dome`,
//! `cabinet` and `cylinder` no rim point agrees (their rims are
//! silhouettes) and the seeds are unchanged, and `pane`'s (its foot on the
//! floor) ring at most 4 of 60 views, moving it by 0.1 degrees.

use super::curved::{curved, median_off};
use super::geometry::reweighted_fit;
use super::membrane::{off_plane, Corner, Membrane};
use super::{far_depth, image_point, image_xy, in_hull, in_parallel, pixel_of, span_depths, Prepared, SeedParams, V3};
use glam::DVec3;

/// The share of the views holding a rim point in their image that must see
/// it at a mask edge.
pub const RIM_AGREE: f64 = 0.9;
/// Of 12 directions around a view's mask centre, how many must hold rim
/// points for the view to get a membrane.
pub const RIM_SECTORS: usize = 9;
/// A first hull point of a view with a membrane, on a ray whose membrane
/// point the hull does not hold, is taken for the wedge in front of the
/// glass, and dropped, when its depth is less than (1 - this) times the
/// membrane's. Measured on the suite's fronts (exact masks): on `facade`
/// such points lie a median 5% of the depth in front of the membrane
/// (0.09 in front of the glass, a tenth of them 0.96), on `windshield` a
/// median 3.5% behind it (0.02 from the glass).
pub const RIM_FRONT: f64 = 0.02;
/// With `all_around` ([`membranes`]): how far behind a view's own Stage I
/// surface a rim point may lie and still count as seen by it (a share of
/// that depth).
pub const RIM_VISIBLE: f64 = 0.05;
/// With `all_around`: how far from a piece's fitted plane (a share of the
/// depth) its rim points may lie and count as on it.
pub const RIM_PLANAR: f64 = 0.05;
/// The share of a piece's points a corner's two planes ([`Membrane`])
/// must hold, within the fit's tolerance ([`RIM_PLANAR`] for the rim).
pub const RIM_CORNER: f64 = 0.8;
/// The fewest rim points a membrane is fitted to.
const RIM_MIN_POINTS: usize = 12;

/// The pixels of a `w` x `h` image within `r` of pixel `i` (the
/// (2r + 1)² square around it, row by row; `i` included, nothing beyond
/// the image).
fn square(i: usize, w: usize, h: usize, r: i64) -> impl Iterator<Item = usize> {
    let (x, y) = ((i % w) as i64, (i / w) as i64);
    (-r..=r)
        .flat_map(move |dy| (-r..=r).map(move |dx| (x + dx, y + dy)))
        .filter(move |&(a, b)| a >= 0 && b >= 0 && (a as usize) < w && (b as usize) < h)
        .map(move |(a, b)| b as usize * w + a as usize)
}

/// `img` grown by one pixel (3 x 3; nothing beyond the image).
fn dilate(img: &[bool], w: usize, h: usize) -> Vec<bool> {
    (0..w * h).map(|i| square(i, w, h, 1).any(|j| img[j])).collect()
}

/// A view's mask edge as the rim reads it.
struct Edge {
    /// Pixels outside the mask with a mask pixel among their 3 x 3 neighbours.
    ring: Vec<bool>,
    /// Pixels within one pixel (3 x 3) of the edge: of the ring, or of the
    /// mask pixels with a neighbour outside it (or beyond the image).
    near: Vec<bool>,
    /// Mask pixels with a neighbour outside the mask (in the image).
    inner: Vec<bool>,
}

impl Edge {
    fn new(mask: &[bool], w: usize, h: usize) -> Edge {
        let ring: Vec<bool> = dilate(mask, w, h).iter().zip(mask).map(|(&g, &m)| g && !m).collect();
        let outside: Vec<bool> = mask.iter().map(|&m| !m).collect();
        let open = dilate(&outside, w, h);
        let border = |i: usize| i.is_multiple_of(w) || i % w == w - 1 || i / w == 0 || i / w == h - 1;
        let inner: Vec<bool> = mask.iter().zip(&open).map(|(&m, &o)| m && o).collect();
        let band: Vec<bool> = (0..w * h).map(|i| ring[i] || inner[i] || (mask[i] && border(i))).collect();
        Edge { near: dilate(&band, w, h), ring, inner }
    }
}

/// The rim points of all views, in view and pixel order: Stage I surface
/// points on a mask's ring (and with `p.rim_hull` the [`hull_edge_points`])
/// that enough views see at a mask edge.
fn rim_points(views: &[Prepared], edges: &[Edge], p: &SeedParams) -> Vec<V3> {
    let mut candidates: Vec<V3> = Vec::new();
    for (v, e) in views.iter().zip(edges) {
        candidates.extend((0..e.ring.len()).filter(|&i| e.ring[i] && v.depth[i].is_finite()).map(|i| v.unproject(i, v.depth[i] as f64)));
    }
    if p.rim_hull {
        candidates.extend(hull_edge_points(views, edges, p));
    }
    let mut out = Vec::new();
    for x in candidates {
        let (mut seen, mut hit) = (0u32, 0u32);
        for (u, f) in views.iter().zip(edges) {
            // All around: a view counts where it sees the point, not
            // behind its own Stage I surface there (an object seen all
            // around hides its front's rim from the views behind it).
            if let Some((j, _)) = pixel_of(&u.cam, x).filter(|&(j, z)| !p.rim_all_around || z <= u.depth[j] as f64 * (1.0 + RIM_VISIBLE)) {
                seen += 1;
                hit += f.near[j] as u32;
            }
        }
        if seen >= 3 && hit as f64 >= RIM_AGREE * seen as f64 {
            out.push(x);
        }
    }
    out
}

/// The first hull point (where `p.agree` of the views that see it in
/// front of their Stage I surface hold it in their masks) along the ray of
/// each mask pixel at a view's mask edge, in view and pixel order: the
/// glass's outline as the masks alone place it, where no surface meets it.
/// Near the glass's edge the hull is thin, so these lie on the outline
/// where it is real (a free pane's edge, a window's top under a roof seen
/// edge-on) and the rim test keeps them; on a silhouette they are where
/// the other views do not see an edge, and it drops them.
fn hull_edge_points(views: &[Prepared], edges: &[Edge], p: &SeedParams) -> Vec<V3> {
    let far = far_depth(views);
    let rays: Vec<(usize, usize)> = edges.iter().enumerate().flat_map(|(vi, e)| (0..e.inner.len()).filter(|&i| e.inner[i]).map(move |i| (vi, i))).collect();
    let first = |&(vi, i): &(usize, usize)| -> Option<V3> {
        let v = &views[vi];
        span_depths(v.ray_span(i, far), p.steps.max(1)).map(|z| v.unproject(i, z)).find(|&x| in_hull(views, x, p.agree))
    };
    in_parallel(&rays, p.threads, |run| run.iter().filter_map(first).collect::<Vec<V3>>()).into_iter().flatten().collect()
}

/// A view's membranes: one for each piece of its mask (8-connected: a
/// vehicle's windows, seen two or three at a time, are pieces apart) whose
/// rim points ring it.
#[derive(Clone, Debug, Default)]
pub(super) struct ViewMembranes {
    /// Per pixel: its piece of the mask ([`NO_PIECE`] off it); empty without membranes.
    piece: Vec<u32>,
    planes: Vec<Option<Membrane>>,
}

/// A pixel off the mask.
pub(super) const NO_PIECE: u32 = u32::MAX;

impl ViewMembranes {
    /// The membrane of the mask piece pixel `i` lies in, if it has one.
    pub(super) fn at(&self, i: usize) -> Option<Membrane> {
        self.piece.get(i).and_then(|&k| self.planes.get(k as usize)).copied().flatten()
    }
    /// Whether any piece has a membrane.
    pub(super) fn any(&self) -> bool {
        self.planes.iter().any(Option::is_some)
    }
    /// Whether any piece's membrane is curved.
    pub(super) fn curved(&self) -> bool {
        self.planes.iter().flatten().any(|m| m.bend != [0.0; 3])
    }
}

/// Each view's membranes, one per piece of its mask that rim points ring.
/// `p.rim_all_around` (`reflection.seed_rim_all_around`, for glass in an
/// object seen from every side): only the views that see a rim point count
/// for or against it, and a piece's membrane needs the points on its plane
/// to ring it too. `p.rim_hull` (`reflection.seed_rim_hull`): the first
/// hull points at the masks' edges are candidates beside the Stage I
/// surface's ([`hull_edge_points`]).
pub(super) fn membranes(views: &[Prepared], p: &SeedParams) -> Vec<ViewMembranes> {
    let edges: Vec<Edge> = views.iter().map(|v| Edge::new(&v.mask, v.cam.width as usize, v.cam.height as usize)).collect();
    let rim = rim_points(views, &edges, p);
    views.iter().zip(&edges).map(|(v, e)| view_membranes(v, &e.near, &rim, p)).collect()
}

/// `mask`'s 8-connected pieces, numbered in pixel order: each pixel's piece
/// ([`NO_PIECE`] off the mask) and their count.
pub(super) fn pieces(mask: &[bool], w: usize, h: usize) -> (Vec<u32>, u32) {
    let mut piece = vec![NO_PIECE; mask.len()];
    let mut n = 0u32;
    let mut stack = Vec::new();
    for start in 0..mask.len() {
        if !mask[start] || piece[start] != NO_PIECE {
            continue;
        }
        piece[start] = n;
        stack.push(start);
        while let Some(i) = stack.pop() {
            for j in square(i, w, h, 1) {
                if mask[j] && piece[j] == NO_PIECE {
                    piece[j] = n;
                    stack.push(j);
                }
            }
        }
        n += 1;
    }
    (piece, n)
}

/// [`membranes`] for one view: the rim points at its mask edge (`edge`),
/// each given to the pieces within two pixels of it (a pillar between two
/// windows rims both), and a membrane for each piece they ring.
fn view_membranes(v: &Prepared, edge: &[bool], rim: &[V3], p: &SeedParams) -> ViewMembranes {
    let (w, h) = (v.cam.width as usize, v.cam.height as usize);
    let (piece, n) = pieces(&v.mask, w, h);
    let mut centre = vec![(0usize, 0.0f64, 0.0f64); n as usize];
    for (i, &k) in piece.iter().enumerate().filter(|(_, &k)| k != NO_PIECE) {
        let c = &mut centre[k as usize];
        *c = (c.0 + 1, c.1 + (i % w) as f64, c.2 + (i / w) as f64);
    }
    // Per piece: (u, v) and (x, y, 1 / z) of its rim points, in rim order.
    let mut pts: Vec<Vec<([f64; 2], [f64; 3])>> = vec![Vec::new(); n as usize];
    let mut near = Vec::new();
    for &r in rim {
        let Some((i, _)) = pixel_of(&v.cam, r) else { continue };
        let Some((u, vv, z)) = image_point(&v.cam, r) else { continue };
        if !edge[i] {
            continue;
        }
        near.clear();
        for k in square(i, w, h, 2).map(|j| piece[j]) {
            if k != NO_PIECE && !near.contains(&k) {
                near.push(k);
            }
        }
        for &k in &near {
            let (x, y) = image_xy(&v.cam, u, vv);
            pts[k as usize].push(([u, vv], [x, y, 1.0 / z]));
        }
    }
    let planes: Vec<Option<Membrane>> = centre.iter().zip(&pts).map(|(&(m, su, sv), pts)| membrane(pts, [su / m as f64, sv / m as f64], p)).collect();
    if planes.iter().all(Option::is_none) {
        return ViewMembranes::default();
    }
    ViewMembranes { piece, planes }
}

/// A piece's membrane from its rim points (image position, plane
/// coordinates), where they lie all around its centre `c` (with
/// `p.rim_all_around`, those on the fitted membrane too); curved where
/// `p.rim_curved` and the points call for it.
fn membrane(pts: &[([f64; 2], [f64; 3])], c: [f64; 2], p: &SeedParams) -> Option<Membrane> {
    let rings = |pts: &mut dyn Iterator<Item = [f64; 2]>| {
        let mut sectors = [false; 12];
        let mut n = 0;
        for uv in pts {
            let a = (uv[1] - c[1]).atan2(uv[0] - c[0]);
            sectors[(((a + std::f64::consts::PI) / std::f64::consts::TAU * 12.0) as usize).min(11)] = true;
            n += 1;
        }
        n >= RIM_MIN_POINTS && sectors.iter().filter(|&&s| s).count() >= RIM_SECTORS
    };
    if !rings(&mut pts.iter().map(|p| p.0)) {
        return None;
    }
    let plane: Vec<[f64; 3]> = pts.iter().map(|p| p.1).collect();
    let one = Membrane::flat(fit_plane(&plane)?);
    // Two planes at a corner, or a curve: whichever the points lie nearer.
    let bent = if p.rim_curved { curved(&plane, &one) } else { None };
    let m = match (corner(&plane, one, RIM_PLANAR), bent) {
        (Some(k), Some(b)) => {
            if median_off(&plane, &b).total_cmp(&median_off(&plane, &k)).is_lt() {
                b
            } else {
                k
            }
        }
        (k, b) => k.or(b).unwrap_or(one),
    };
    // The points on the membrane (within RIM_PLANAR of their depth) must
    // ring the piece too: where a piece's rim lies on planes the fit does
    // not explain, it fits none of them.
    (!p.rim_all_around || rings(&mut pts.iter().filter(|q| m.off(&q.1) <= RIM_PLANAR).map(|q| q.0))).then_some(m)
}

/// Two planes for points ([x, y, 1 / z]) that `one` plane leaves off (a
/// piece of mask across two windows that meet at a corner: the points of
/// each lie on its own plane): the [`consensus`] plane of all of them, then
/// of those it leaves, both refitted to the points nearer each, and the
/// corner convex or concave as more points lie on it (within `tol` of their
/// depth). None unless [`RIM_CORNER`] of the points lie on it and at most
/// half as many as on `one` lie off it.
pub(super) fn corner(pts: &[[f64; 3]], one: Membrane, tol: f64) -> Option<Membrane> {
    let within = |m: &Membrane| pts.iter().filter(|p| m.off(p) <= tol).count();
    let on_one = within(&one);
    if pts.len() - on_one < RIM_MIN_POINTS {
        return None;
    }
    let mut a = consensus(pts, tol)?;
    let rest: Vec<[f64; 3]> = pts.iter().filter(|p| off_plane(&a, p) > tol).copied().collect();
    let mut b = consensus(&rest, tol)?;
    for _ in 0..3 {
        let (sa, sb): (Vec<[f64; 3]>, Vec<[f64; 3]>) = pts.iter().filter(|p| off_plane(&a, p).min(off_plane(&b, p)) <= tol).partition(|p| off_plane(&a, p) <= off_plane(&b, p));
        if sa.len() < RIM_MIN_POINTS || sb.len() < RIM_MIN_POINTS {
            return None;
        }
        (a, b) = (fit_plane(&sa)?, fit_plane(&sb)?);
    }
    let two = [false, true].map(|convex| Membrane { coef: a, corner: Some(Corner { coef: b, convex }), bend: [0.0; 3] });
    let (n, m) = two.iter().map(|m| (within(m), *m)).max_by_key(|&(n, _)| n)?;
    (n as f64 >= RIM_CORNER * pts.len() as f64 && 2 * (pts.len() - n) <= pts.len() - on_one).then_some(m)
}

/// The plane through three of `pts` ([x, y, 1 / z]) that the most of them
/// lie on within `tol` of their depth (of [`CONSENSUS_TRIES`] triples
/// drawn by a fixed sequence: the same every run), refitted to those.
/// None with fewer than [`RIM_MIN_POINTS`] on it.
pub(super) fn consensus(pts: &[[f64; 3]], tol: f64) -> Option<[f64; 3]> {
    if pts.len() < RIM_MIN_POINTS {
        return None;
    }
    let on = |c: &[f64; 3], p: &&[f64; 3]| off_plane(c, p) <= tol;
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state % pts.len() as u64) as usize
    };
    let mut best: Option<(usize, [f64; 3])> = None;
    for _ in 0..CONSENSUS_TRIES {
        let t = [next(), next(), next()].map(|k| pts[k]);
        let Some(c) = solve3(t.map(|p| [p[0], p[1], 1.0]), t.map(|p| p[2])) else { continue };
        let n = pts.iter().filter(|p| on(&c, p)).count();
        if best.is_none_or(|(m, _)| n > m) {
            best = Some((n, c));
        }
    }
    let (n, c) = best?;
    if n < RIM_MIN_POINTS {
        return None;
    }
    fit_plane(&pts.iter().filter(|p| on(&c, p)).copied().collect::<Vec<_>>())
}

/// Triples [`consensus`] tries.
const CONSENSUS_TRIES: usize = 256;

/// 1 / z = a x + b y + c through `pts` ([x, y, 1 / z]) by iteratively
/// reweighted least squares (rows weighted 1 within twice the residuals'
/// robust spread, s / r beyond it): a frame's stray points (the sky past a
/// pane's top edge) do not tilt the plane. None where the points are
/// collinear.
pub fn fit_plane(pts: &[[f64; 3]]) -> Option<[f64; 3]> {
    reweighted_fit(pts, |p| [p[0], p[1], 1.0], solve3)
}

/// The solution of the 3 x 3 system `a` x = `b` (Cramer's rule), None
/// where `a` is singular.
fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    // Row 0 against the cross product of rows 1 and 2 (the expansion along row 0).
    let det = |m: [[f64; 3]; 3]| DVec3::from(m[0]).dot(DVec3::from(m[1]).cross(DVec3::from(m[2])));
    let d = det(a);
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    if !(d.abs() > 1e-12 * scale.powi(3)) {
        return None;
    }
    Some(std::array::from_fn(|k| {
        let mut m = a;
        for r in 0..3 {
            m[r][k] = b[r];
        }
        det(m) / d
    }))
}
