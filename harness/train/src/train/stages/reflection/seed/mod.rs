//! Residual-guided seeding of the reflection set (Stage II).
//!
//! Stage I leaves transmissive surfaces unoccupied: its Gaussians sit on the
//! content seen through the glass, and the residual |I_gt - I_scat| marks
//! where the glass is in every training view. A point on the transmissive
//! surface projects onto residual in (nearly) every view that sees it in
//! front of the Stage I surface; a point in open air in front of a diffuse
//! surface does not. So the residual's multi-view intersection (a visual
//! hull of the residual, carved only where a view sees the point in front of
//! its Stage I depth) encloses the transmissive surface, and the first hull
//! point along a residual pixel's ray lies on its front, provided the ray
//! met carved space first: where glass fills every view, the residual has no
//! silhouette, nothing near the cameras is carved, and a ray that is inside
//! the hull from its start says nothing about where the surface is. Nor does
//! a point whose agreement chance explains: where noise and texture put
//! residual on most pixels, a point near the cameras that few views see
//! lands on residual in 90% of them by chance, so a hull point also needs a
//! binomial tail at the masks' coverage below [`SeedParams::significance`]
//! ([`min_hits`]); where no point can pass it, Stage II's [`hull_seeding`]
//! takes the hull without it, found in the same march, each ray's seed the
//! point of it that the most views agree on. Seeds are the first hull points
//! of rays that crossed carved space; their normals are by default
//! ([`SeedNormal::Halfway`]) the bisector of the direction to the camera
//! that found them ([`SeedNormal::View`]) and the silhouette cones' normal
//! from the gradient of the views' blurred masks ([`SeedNormal::Gradient`]);
//! or, with [`SeedNormal::Plane`], the local plane of neighbouring seeds
//! (PCA), or with [`SeedNormal::Consensus`] (masks' default) the plane most
//! of its wider neighbourhood lies on; all turned to that camera. Their size
//! is the seed spacing. Stage II then refines them by the reflection it has
//! to explain.
//!
//! Why not the plane: on an ideal hull the seeds lie on the surface and
//! their plane is its tangent plane (the synthetic sphere in
//! `tests/tests/seed.rs`: median error under 10 degrees), but the hull of a
//! real Stage I residual places seeds with a depth noise comparable to
//! their spacing, and the plane through 16 of them is then close to a
//! random direction (perf/RESULTS.md, fifteenth session: glass normal MAE
//! after Stage II 45.1 / 60.7 / 65.8 degrees on the built-in glass /
//! `lantern` / `pane` with plane normals, 40.2 / 47.7 / 46.4 facing the
//! camera). The mask gradient is smooth where the plane is not (it is a
//! property of the field, not of where the march stopped), and right where
//! the residual's hull is the glass's: on closed glass objects seen from
//! around them. Where the glass is a flat pane inside a blob of residual,
//! or an open tube whose hull has a lid, it is the normal of the wrong
//! surface; halfway keeps most of its gain on the first and about halves
//! its loss on the second (perf/RESULTS.md, thirty-third session: nine
//! path-traced scenes, two seeds, glass normal MAE after Stage II 41.8 /
//! 37.8 / 36.8 degrees with view / gradient / halfway).
//!
//! Silhouettes cannot place a front of glass that every view sees from one
//! side: its hull is a wedge in front of it. With given glass masks
//! ([`SeedParams::rim`]), a view whose glass is ringed by a frame or wall
//! that Stage I reconstructed seeds its rays on the plane of that rim
//! instead (the `rim` module). And where a view's hull points over one
//! piece of its mask lie on a plane, or on two meeting at a corner (a
//! cabin's windows), those seeds move onto it and take its normal
//! ([`SeedParams::planes`], the `planes` module). With masks the seeds'
//! normals are then smoothed over their neighbours ([`SeedParams::smooth`])
//! and, where flat faces of the glass show among them, take their face's
//! ([`SeedParams::faces`]). Panes a user marked by their corners in `tgs
//! view` are the glass's planes themselves: their seeds lie on them
//! ([`pane_seeds`], the `panes` module).

mod chance;
mod curved;
mod faces;
mod geometry;
mod membrane;
mod normals;
mod panes;
mod planes;
mod rim;
mod smooth;

pub use chance::min_hits;

pub use faces::flat_faces;
pub use geometry::pixel_of;
pub(crate) use geometry::unproject_pixel;
use geometry::{box_blur, image_point, image_xy, in_parallel, nearest, normalize, unproject_xy, V3};
pub use normals::{consensus_normal, jacobi_eigen, quat_for_normal, SeedNormal, GRADIENT_MIN};
use normals::{gradient_pixels, least_squares_plane, surfels};
pub use panes::{pane_seeds, PanePolygon};
pub use rim::fit_plane;
pub use smooth::smooth_normals;
use tgs_pipelines::Camera;

/// One training view as the seeding sees it.
pub struct SeedView<'a> {
    pub camera: Camera,
    /// Per-pixel residual magnitude mean_c |I_gt - I_scat| (row-major).
    pub residual: &'a [f32],
    /// Per-pixel Stage I surface depth (view z; 0 or non-finite where no surface).
    pub depth: &'a [f32],
}

#[derive(Clone, Copy, Debug)]
pub struct SeedParams {
    /// A pixel has residual when its box-blurred magnitude exceeds this.
    pub threshold: f32,
    /// Box-blur radius in pixels (the mask is then eroded by half of it).
    pub blur: u32,
    /// Fraction of the views that see a point in front of their Stage I
    /// surface whose residual it must project onto.
    pub agree: f32,
    /// At most this many rays are cast (spread evenly over the views'
    /// residual pixels); each gives at most one seed.
    pub max_rays: u32,
    /// Samples along a ray, uniform in depth from `near` x the far end.
    pub steps: u32,
    /// How a seed's normal is chosen.
    pub normal: SeedNormal,
    /// A point is in the hull only if its hits would be this unlikely
    /// from masks placed at random (one-sided binomial tail at the views'
    /// mean mask coverage; 1: no test). See [`min_hits`].
    pub significance: f64,
    /// Looser levels tried in order where no hull point beats
    /// `significance`, before the fallback of [`hull_seeding`]: the first
    /// that some point beats is used. Stage II gives them for glass masks
    /// (few masked views cannot beat 1e-6), none for the residual.
    pub relax: &'static [f64],
    /// Depth from the glass's rim (see the `rim` module): where a view's
    /// mask is ringed by Stage I surface that the other views see at their
    /// masks' edges, its rays' seeds lie on the plane of that rim if the
    /// hull holds it. Stage II sets it for given glass masks only
    /// (`reflection.seed_rim`): the residual's masks are not the glass's
    /// outline on the path-traced suite (perf/RESULTS.md, forty-third
    /// entry), so their edges do not trace a rim.
    pub rim: bool,
    /// With `rim`: glass in an object seen from every side (a house's
    /// windows): the rim counts only the views that see it, and a piece's
    /// plane must be ringed by the points on it
    /// (`reflection.seed_rim_all_around`; rim::membranes).
    pub rim_all_around: bool,
    /// With `rim`: the first hull points of the rays at the masks' edges
    /// are rim candidates too (`reflection.seed_rim_hull`; rim::membranes).
    pub rim_hull: bool,
    /// With `rim`: a view whose rim lies off its plane as a bent front's
    /// does seeds on a curved membrane (`curved`; `seed_rim_curved`).
    pub rim_curved: bool,
    /// With given glass masks: each view's mask pieces whose hull points lie
    /// on a plane, or two at a corner, seeded on it (the `planes` module).
    pub planes: bool,
    /// Bilateral smoothing of the seeds' normals (the `smooth` module).
    pub smooth: bool,
    /// With given glass masks: the seeds over a flat face of the glass take
    /// its normal (the `faces` module; after `smooth`).
    pub faces: bool,
    /// Threads for the march and the normals (0: every core the process
    /// may use). The seeds are the same, bit for bit, at any count: the
    /// rays and seeds are split into contiguous runs whose results are
    /// joined in order.
    pub threads: usize,
}

impl Default for SeedParams {
    fn default() -> Self {
        SeedParams {
            threshold: 0.007,
            blur: 2,
            agree: 0.9,
            max_rays: 8192,
            steps: 128,
            normal: SeedNormal::Halfway,
            significance: 1e-6,
            relax: &[],
            rim: false,
            rim_all_around: false,
            rim_hull: false,
            rim_curved: false,
            planes: false,
            smooth: false,
            faces: false,
            threads: 0,
        }
    }
}

/// A seed surfel: position, unit normal (facing its camera), isotropic scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Seed {
    pub position: [f32; 3],
    pub normal: [f32; 3],
    pub scale: f32,
}

/// A view prepared for hull tests: its residual mask and depths.
struct Prepared {
    cam: Camera,
    mask: Vec<bool>,
    /// With [`SeedNormal::Gradient`] or [`SeedNormal::Halfway`]: `mask` as 0/1 box-blurred by
    /// [`gradient_pixels`], the field whose 3D gradient gives the normal.
    soft: Vec<f32>,
    /// Stage I depth with "no surface" as infinity.
    depth: Vec<f32>,
}

impl Prepared {
    fn new(v: &SeedView, p: &SeedParams) -> Prepared {
        let (w, h) = (v.camera.width as usize, v.camera.height as usize);
        // Blur then threshold fills the gaps of a spotty residual but grows
        // its region, by about half the blur radius at a residual a few
        // times the threshold; eroding by that much brings the boundary back.
        let blurred = box_blur(v.residual, w, h, p.blur as usize);
        let grown: Vec<f32> = blurred.iter().map(|&b| (b > p.threshold) as u8 as f32).collect();
        let r = p.blur as usize / 2;
        let mask: Vec<bool> = if r == 0 { grown.iter().map(|&g| g > 0.5).collect() } else { box_blur(&grown, w, h, r).iter().map(|&m| m > 1.0 - 1e-4).collect() };
        let depth = v.depth.iter().map(|&d| if d.is_finite() && d > 0.0 { d } else { f32::INFINITY }).collect();
        let soft = if p.normal.uses_field() { box_blur(&mask.iter().map(|&m| m as u8 as f32).collect::<Vec<f32>>(), w, h, gradient_pixels(w)) } else { Vec::new() };
        Prepared { cam: v.camera, mask, soft, depth }
    }

    /// `soft` sampled bilinearly at the projection of `x` (0 outside the
    /// image or behind the camera).
    fn soft_at(&self, x: V3) -> f64 {
        let Some((u, v, _)) = image_point(&self.cam, x) else {
            return 0.0;
        };
        let (w, h) = (self.cam.width as usize, self.cam.height as usize);
        if !(u > -1.0 && v > -1.0 && u < w as f64 && v < h as f64) {
            return 0.0;
        }
        let at = |x: i64, y: i64| if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 { 0.0 } else { self.soft[y as usize * w + x as usize] as f64 };
        let (u0, v0) = (u.floor(), v.floor());
        let (fu, fv) = (u - u0, v - v0);
        let (x0, y0) = (u0 as i64, v0 as i64);
        (at(x0, y0) * (1.0 - fu) + at(x0 + 1, y0) * fu) * (1.0 - fv) + (at(x0, y0 + 1) * (1.0 - fu) + at(x0 + 1, y0 + 1) * fu) * fv
    }

    fn pixel(&self, x: V3) -> Option<(usize, f64)> {
        pixel_of(&self.cam, x)
    }

    /// The pixel `x` projects to, if this view sees it in front of its
    /// Stage I surface (the views that take part in the hull test).
    fn in_front(&self, x: V3) -> Option<usize> {
        self.pixel(x).and_then(|(i, z)| (z < self.depth[i] as f64 * 0.98).then_some(i))
    }

    fn unproject(&self, i: usize, z: f64) -> V3 {
        unproject_pixel(&self.cam, i, z)
    }

    /// The span of pixel `i`'s ray the hull march walks, (near, far): from
    /// 5% of its far end to its Stage I depth, or to `far` where it has none.
    fn ray_span(&self, i: usize, far: f64) -> (f64, f64) {
        let z_far = if self.depth[i].is_finite() { self.depth[i] as f64 } else { far };
        (0.05 * z_far, z_far)
    }
}

/// The depths the hull march samples in `span`: the midpoints of `steps`
/// equal steps, near to far.
fn span_depths((z_near, z_far): (f64, f64), steps: u32) -> impl Iterator<Item = f64> {
    (0..steps).map(move |s| z_near + (z_far - z_near) * (s as f64 + 0.5) / steps as f64)
}

/// What the views that see a point in front of their Stage I surface say of it.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Verdict {
    /// Fewer than 3 views see it so.
    Unseen,
    /// Fewer than `agree` of them see residual there: carved.
    Carved,
    /// Enough agree (`hits` of the views that see it); `significant`: also
    /// more than chance explains (`min_hits`, indexed by the views that see it).
    Agrees { significant: bool, hits: u32 },
}

fn hull_test(views: &[Prepared], x: V3, agree: f32, min_hits: &[u32]) -> Verdict {
    let (seen, hit) = hull_votes(views, x);
    if seen < 3 {
        Verdict::Unseen
    } else if (hit as f64) < agree as f64 * seen as f64 {
        Verdict::Carved
    } else {
        Verdict::Agrees { significant: hit >= min_hits[seen as usize], hits: hit }
    }
}

/// Of the views that see `x` in front of their Stage I surface: how many,
/// and how many hold it in their mask.
fn hull_votes(views: &[Prepared], x: V3) -> (u32, u32) {
    let (mut seen, mut hit) = (0u32, 0u32);
    for v in views {
        if let Some(i) = v.in_front(x) {
            seen += 1;
            hit += v.mask[i] as u32;
        }
    }
    (seen, hit)
}

/// Whether `x` is in the hull: at least 3 views see it in front of their
/// Stage I surface and `agree` of them hold it ([`hull_test`]'s
/// [`Verdict::Agrees`], without the significance it grades).
fn in_hull(views: &[Prepared], x: V3, agree: f32) -> bool {
    let (seen, hit) = hull_votes(views, x);
    seen >= 3 && hit as f64 >= agree as f64 * seen as f64
}

/// The far end of a ray with no Stage I surface: the largest finite depth
/// any view saw.
fn far_depth(views: &[Prepared]) -> f64 {
    views.iter().flat_map(|v| v.depth.iter()).filter(|d| d.is_finite()).fold(0.0f32, |a, &b| a.max(b)) as f64
}

/// Seeds of the reflection set from the views' residuals and Stage I depths
/// (see the module documentation). Deterministic; empty when no pixel has
/// residual, fewer than 3 views agree anywhere, no point beats chance
/// ([`SeedParams::significance`]), or no ray crosses carved space before
/// the hull.
pub fn residual_hull_seeds(views: &[SeedView], p: &SeedParams) -> Vec<Seed> {
    let prepared: Vec<Prepared> = views.iter().map(|v| Prepared::new(v, p)).collect();
    let found = march(&prepared, p, &membranes(&prepared, p));
    surfels(&found.significant, &found.rim_normals, &prepared, p.normal, p.threads)
}

/// The reflection set's seeds as Stage II takes them.
#[derive(Clone, Debug, PartialEq)]
pub struct HullSeeding {
    pub seeds: Vec<Seed>,
    /// Views whose rim gave them a membrane ([`SeedParams::rim`]).
    pub rim_views: usize,
    /// Of those, the views with a curved membrane ([`SeedParams::rim_curved`]).
    pub rim_curved: usize,
    /// Seeds placed on a membrane.
    pub rim_seeds: usize,
    /// Mask pieces whose hull points gave a plane ([`SeedParams::planes`]).
    pub plane_pieces: usize,
    /// Seeds moved onto those planes.
    pub plane_seeds: usize,
    /// Flat faces of the glass found ([`SeedParams::faces`]), and the seeds that took their normal.
    pub faces: [usize; 2],
    /// No hull point beat chance, so the seeds are the hull's without the
    /// significance test.
    pub significance_dropped: bool,
    /// The level of [`SeedParams::relax`] the seeds beat, where none beat
    /// [`SeedParams::significance`].
    pub significance_relaxed: Option<f64>,
}

/// [`residual_hull_seeds`], except where no point can beat chance (with
/// 16 views whose masks cover 80% of the pixels not even all of them
/// agreeing can): there the seeds of the hull without the test, not none,
/// each the point of its ray that the most views agree on, facing the
/// camera that found it ([`SeedNormal::without_outline`]). The first
/// agreeing point, which seeding took before, lies where the fewest views
/// see it, among the cameras: with residual on nearly every pixel a point
/// that three views see agrees as readily as the glass does (measured on
/// the path-traced room fronts, masks on 89% of the pixels: the first
/// agreeing points 2 to 2.5 units in front of the glass, seen by a median
/// of 5 of 60 views; perf/RESULTS.md, thirty-third entry). One march finds
/// both. Before that fallback, the levels of [`SeedParams::relax`], each a
/// march over the same prepared views and membranes.
pub fn hull_seeding(views: &[SeedView], p: &SeedParams) -> HullSeeding {
    let prepared: Vec<Prepared> = views.iter().map(|v| Prepared::new(v, p)).collect();
    let membranes = membranes(&prepared, p);
    let mut found = march(&prepared, p, &membranes);
    let mut relaxed = None;
    if found.significant.is_empty() && !found.agreeing.is_empty() {
        for &alpha in p.relax.iter().filter(|&&a| a > p.significance) {
            let f = march(&prepared, &SeedParams { significance: alpha, ..*p }, &membranes);
            if !f.significant.is_empty() {
                (found, relaxed) = (f, Some(alpha));
                break;
            }
        }
    }
    let dropped = found.significant.is_empty() && !found.agreeing.is_empty() && p.significance < 1.0;
    let fixed = |f: &Found| if dropped { 0 } else { f.rim_normals.iter().filter(|n| n.is_some()).count() };
    let rim_seeds = fixed(&found);
    let plane_pieces = if p.planes && !dropped { planes::snap(&mut found, &prepared) } else { 0 };
    let plane_seeds = fixed(&found) - rim_seeds;
    let (chosen, fixed, normal) = if dropped { (&found.agreeing, &[][..], p.normal.without_outline()) } else { (&found.significant, &found.rim_normals[..], p.normal) };
    let mut seeds = surfels(chosen, fixed, &prepared, normal, p.threads);
    if p.smooth && !dropped {
        smooth::smooth_normals(&mut seeds, p.threads);
    }
    let faces = if p.faces && !dropped { faces::flat_faces(&mut seeds, faces::face_band(chosen, &prepared)) } else { (0, 0) };
    HullSeeding {
        seeds,
        rim_views: found.rim_views,
        rim_curved: membranes.iter().filter(|m| m.curved()).count(),
        rim_seeds,
        plane_pieces,
        plane_seeds,
        faces: [faces.0, faces.1],
        significance_dropped: dropped,
        significance_relaxed: relaxed,
    }
}

/// Each view's membranes where [`SeedParams::rim`] asks for them.
fn membranes(prepared: &[Prepared], p: &SeedParams) -> Vec<rim::ViewMembranes> {
    if p.rim {
        rim::membranes(prepared, p)
    } else {
        vec![rim::ViewMembranes::default(); prepared.len()]
    }
}

/// Per ray: the first hull point after carved space with the significance
/// test, and without it the hull point after carved space with the most
/// agreeing views (the first of them on a tie). Each with the view whose
/// ray found it.
struct Found {
    significant: Vec<(V3, usize)>,
    /// Per `significant` point: its membrane's normal, where it lies on one.
    rim_normals: Vec<Option<V3>>,
    agreeing: Vec<(V3, usize)>,
    rim_views: usize,
}

fn march(prepared: &[Prepared], p: &SeedParams, membranes: &[rim::ViewMembranes]) -> Found {
    let mut found = Found { significant: Vec::new(), rim_normals: Vec::new(), agreeing: Vec::new(), rim_views: 0 };
    let far = far_depth(prepared);
    let total: usize = prepared.iter().map(|v| v.mask.iter().filter(|&&m| m).count()).sum();
    if total == 0 || far <= 0.0 || p.steps == 0 {
        return found;
    }
    let pixels: usize = prepared.iter().map(|v| v.mask.len()).sum();
    let min_hits = min_hits(prepared.len(), total as f64 / pixels.max(1) as f64, p.significance);
    let rays = strided_rays(prepared, total, p.max_rays);
    found.rim_views = membranes.iter().filter(|m| m.any()).count();
    for part in in_parallel(&rays, p.threads, |chunk| march_rays(prepared, p, chunk, far, &min_hits, membranes)) {
        found.significant.extend(part.significant);
        found.rim_normals.extend(part.rim_normals);
        found.agreeing.extend(part.agreeing);
    }
    found
}

/// The rays the seeding casts, (view, pixel): every `stride`-th of the
/// `total` masked pixels over the views, in view order, at most `max_rays`.
fn strided_rays(prepared: &[Prepared], total: usize, max_rays: u32) -> Vec<(usize, usize)> {
    let stride = total.div_ceil(max_rays.max(1) as usize).max(1);
    prepared.iter().enumerate().flat_map(|(vi, v)| (0..v.mask.len()).filter(|&i| v.mask[i]).map(move |i| (vi, i))).skip(stride - 1).step_by(stride).collect()
}

/// [`march`] along `rays` (view, pixel), in order.
fn march_rays(prepared: &[Prepared], p: &SeedParams, rays: &[(usize, usize)], far: f64, min_hits: &[u32], membranes: &[rim::ViewMembranes]) -> Found {
    let mut found = Found { significant: Vec::new(), rim_normals: Vec::new(), agreeing: Vec::new(), rim_views: 0 };
    for &(vi, i) in rays {
        let v = &prepared[vi];
        let (z_near, z_far) = v.ray_span(i, far);
        // A view with a membrane seeds on it where the hull holds it. Where
        // the hull does not, the ray's first hull point is kept unless it
        // lies in front of the membrane by more than [`rim::RIM_FRONT`]:
        // there it is in the wedge, and one such seed, isolated, grows into
        // a large surfel with a random plane that hides the glass behind it
        // (`facade`, seed 1: glass normal MAE 26.8 degrees with them, 5.3
        // without); behind the membrane it is where a curved front bends
        // away from the rim's plane (`windshield`'s sides, where these
        // seeds lie a median 0.02 from the glass). perf/RESULTS.md,
        // forty-fifth entry.
        let membrane = membranes[vi].at(i);
        let z_rim = membrane.and_then(|m| m.depth(v, i));
        let on_rim = z_rim.filter(|&z| z > z_near && z < z_far * 0.98).map(|z| v.unproject(i, z));
        let on_rim = on_rim.filter(|&x| matches!(hull_test(prepared, x, p.agree, min_hits), Verdict::Agrees { significant: true, .. }));
        // A ray that starts inside the hull has no evidence of where
        // the surface begins (the residual covers what every view sees
        // there): it seeds only after some of it was carved. A point
        // that agrees by chance alone is neither hull nor carved: the
        // test's march goes on through it, and the plain one keeps, of
        // the agreeing points, the one the most views agree on (if the
        // first of them came after carved space: `after_carved`, set there).
        let mut carved = false;
        let mut after_carved: Option<bool> = None;
        let mut best: Option<(u32, V3)> = None;
        for z in span_depths((z_near, z_far), p.steps) {
            let x = v.unproject(i, z);
            match hull_test(prepared, x, p.agree, min_hits) {
                Verdict::Agrees { significant, hits } => {
                    if *after_carved.get_or_insert(carved) && best.is_none_or(|(h, _)| hits > h) {
                        best = Some((hits, x));
                    }
                    if significant {
                        let keep = membrane.is_none() || (on_rim.is_none() && z_rim.is_none_or(|zm| z >= zm * (1.0 - rim::RIM_FRONT)));
                        if carved && keep {
                            found.significant.push((x, vi));
                            found.rim_normals.push(None);
                        }
                        break;
                    }
                }
                Verdict::Carved => carved = true,
                Verdict::Unseen => {}
            }
        }
        if let (Some(x), Some(m)) = (on_rim, membrane) {
            found.significant.push((x, vi));
            found.rim_normals.push(Some(m.normal(v, i)));
        }
        if let Some((_, x)) = best {
            found.agreeing.push((x, vi));
        }
    }
    found
}
