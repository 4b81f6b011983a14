//! Marking the glass (`tgs view`, key G): the user clicks around the glass
//! (a pane's corners, a dome's outline) in two or more views. Each view's
//! clicks span a convex polygon, and with the camera a cone; a piece of
//! glass is where every marked view's cone holds it (their visual hull),
//! or for a flat pane (key F) the polygon of its corners triangulated from
//! the clicks (`pane.rs`); several pieces (key B) are their union. A
//! training view's glass mask is the set of its pixels whose ray meets
//! one: exact, no sampling along the ray. The masks go into a new
//! directory (never the dataset's) for `reflection.seed_masks`.
//! Occlusion is not modelled: glass behind an opaque object is marked too.

use crate::data::image_io::write_mask;
use crate::data::View;
use crate::train::stages::reflection::masks::mask_stem;
use anyhow::{bail, Context as _, Result};
use glam::{DMat3, DVec3};
use std::path::Path;
use tgs_pipelines::Camera;

mod pane;

/// A camera's centre and the world directions of its pixels, in f64.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rays {
    pub centre: DVec3,
    /// Rows of the world-to-view rotation (the view axes in world space).
    axes: DMat3,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
}

impl Rays {
    pub fn of(cam: &Camera) -> Rays {
        let m = &cam.world_to_view;
        let row = |r: usize| DVec3::new(m[r][0] as f64, m[r][1] as f64, m[r][2] as f64);
        let axes = DMat3::from_cols(row(0), row(1), row(2));
        let t = DVec3::new(m[0][3] as f64, m[1][3] as f64, m[2][3] as f64);
        Rays { centre: -(axes * t), axes, fx: cam.fx as f64, fy: cam.fy as f64, cx: cam.cx as f64, cy: cam.cy as f64 }
    }

    /// The world direction (not unit) through pixel coordinates (u, v),
    /// pixel centres at integers: view depth 1 along it.
    pub fn dir(&self, u: f64, v: f64) -> DVec3 {
        self.axes * DVec3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
    }

    /// The camera's viewing axis in world space.
    fn forward(&self) -> DVec3 {
        self.axes.z_axis
    }

    /// The pixel coordinates of world point `x`; None behind the camera.
    pub fn project(&self, x: DVec3) -> Option<(f64, f64)> {
        let p = self.axes.transpose() * (x - self.centre);
        (p.z > 1e-9).then(|| (self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }
}

/// One view's clicks: pixel coordinates in the camera they were made on.
#[derive(Clone, Debug, PartialEq)]
pub struct Outline {
    pub camera: Camera,
    pub points: Vec<(f64, f64)>,
}

impl Outline {
    /// The half-spaces (normal, through the camera centre) whose
    /// intersection, in front of the camera, is the cone of the convex
    /// hull of the clicks; None with fewer than three points not on a line.
    fn cone(&self) -> Option<Cone> {
        let hull = convex_hull(&self.points);
        if hull.len() < 3 {
            return None;
        }
        let rays = Rays::of(&self.camera);
        let (mu, mv) = hull.iter().fold((0.0, 0.0), |(a, b), p| (a + p.0 / hull.len() as f64, b + p.1 / hull.len() as f64));
        let inside = rays.dir(mu, mv);
        let planes = (0..hull.len())
            .map(|i| {
                let (a, b) = (hull[i], hull[(i + 1) % hull.len()]);
                let n = rays.dir(a.0, a.1).cross(rays.dir(b.0, b.1));
                if n.dot(inside) < 0.0 {
                    -n
                } else {
                    n
                }
            })
            .collect();
        Some((rays, planes))
    }
}

/// A view's cone: its camera's rays and the planes bounding the outline.
type Cone = (Rays, Vec<DVec3>);

/// One piece of glass (a pane, a dome): an outline per view it was
/// clicked around in; it is where those outlines' cones meet, or, for a
/// flat pane (key F), the polygon of its corners triangulated from them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Region {
    pub outlines: Vec<Outline>,
    /// A flat pane: each outline is its corners, in order round it.
    pub flat: bool,
}

/// What a region marks: a visual hull (the views a point may miss, the
/// cones) or a pane.
enum Shape {
    Hull(usize, Vec<Cone>),
    Pane(pane::Pane),
}

impl Region {
    /// The region in `marks.json`: its outlines' clicks and cameras, and
    /// for a flat pane that meets its corners, the pane.
    fn record(&self, tolerance: usize) -> serde_json::Value {
        let mut r = serde_json::json!({"flat": self.flat, "outlines": self.outlines.iter().map(|o| serde_json::json!({
            "width": o.camera.width, "height": o.camera.height, "fx": o.camera.fx, "fy": o.camera.fy, "cx": o.camera.cx, "cy": o.camera.cy,
            "world_to_view": o.camera.world_to_view, "points": o.points,
        })).collect::<Vec<_>>()});
        if let Ok(Shape::Pane(p)) = self.shape(tolerance) {
            r["pane"] = serde_json::json!({"corners": p.0.corners().iter().map(|c| c.to_array()).collect::<Vec<_>>(), "normal": p.0.normal().to_array()});
        }
        r
    }

    /// The outlines that span a polygon (three clicks or more, not on a line).
    fn cones(&self) -> Vec<Cone> {
        self.outlines.iter().filter_map(Outline::cone).collect()
    }

    /// What the region marks once it describes glass, or why it does not yet.
    fn shape(&self, tolerance: usize) -> Result<Shape, String> {
        if self.flat {
            return pane::Pane::triangulate(&self.outlines).map(Shape::Pane);
        }
        let cones = self.cones();
        if cones.len() < 2 {
            return Err(format!("outlined in {} view(s); outline it (three clicks or more) in at least two views", cones.len()));
        }
        Ok(Shape::Hull(cones.len().saturating_sub(tolerance).max(2), cones))
    }
}

/// The clicks of a marking: one region per piece of glass (several panes
/// are several regions; each is the meeting of its own outlines' cones,
/// the glass their union), one outline per view in each.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Marks {
    pub regions: Vec<Region>,
    /// How many outlined views of a region may leave a point out and it
    /// still counts as glass (0: every one must hold it): forgives a view
    /// whose outline an occluder cut short, at the cost of a looser region.
    pub tolerance: usize,
}

impl Marks {
    /// Add a click at pixel coordinates (u, v) of `cam` to the current
    /// region: to its last outline when that was made on the same camera,
    /// else to a new one.
    pub fn click(&mut self, cam: &Camera, u: f64, v: f64) {
        let region = self.current();
        match region.outlines.last_mut() {
            Some(o) if o.camera == *cam => o.points.push((u, v)),
            _ => region.outlines.push(Outline { camera: *cam, points: vec![(u, v)] }),
        }
    }

    /// The region the next click goes to (a new one when there is none).
    fn current(&mut self) -> &mut Region {
        if self.regions.is_empty() {
            self.regions.push(Region::default());
        }
        self.regions.last_mut().expect("one was pushed")
    }

    /// Start another region (the next clicks outline another piece of
    /// glass); nothing when the current one has no clicks yet.
    pub fn new_region(&mut self) {
        if self.regions.last().is_some_and(|r| !r.outlines.is_empty()) {
            self.regions.push(Region::default());
        }
    }

    /// Take back the last click (an emptied outline and region go with it).
    pub fn undo(&mut self) {
        while self.regions.last().is_some_and(|r| r.outlines.is_empty()) {
            self.regions.pop();
        }
        if let Some(r) = self.regions.last_mut() {
            if let Some(o) = r.outlines.last_mut() {
                o.points.pop();
                if o.points.is_empty() {
                    r.outlines.pop();
                }
            }
            if r.outlines.is_empty() {
                self.regions.pop();
            }
        }
    }

    pub fn clicks(&self) -> usize {
        self.regions.iter().flat_map(|r| &r.outlines).map(|o| o.points.len()).sum()
    }

    /// Outlines over all regions (a view outlined for two panes counts twice).
    pub fn outlines(&self) -> usize {
        self.regions.iter().map(|r| r.outlines.len()).sum()
    }

    /// The current region is a flat pane: its outlines are its corners,
    /// clicked in order round it in each view (from any corner, either way).
    pub fn flat(&mut self) {
        self.current().flat = true;
    }

    /// The shape of each region that describes glass.
    fn shapes(&self) -> Vec<Shape> {
        self.regions.iter().filter_map(|r| r.shape(self.tolerance).ok()).collect()
    }

    /// Why the current region does not describe glass yet (None: it does, or it has no clicks).
    pub fn pending(&self) -> Option<String> {
        self.regions.last().filter(|r| !r.outlines.is_empty()).and_then(|r| r.shape(self.tolerance).err())
    }

    /// Whether the marking describes glass: a region with a polygon in two
    /// views, or a flat pane whose corners meet.
    pub fn is_ready(&self) -> bool {
        !self.shapes().is_empty()
    }

    /// `cam`'s glass mask (row-major): its pixels whose ray meets one of
    /// the regions: every outlined view's cone of a hull region (all but
    /// `tolerance`, and at least two) at one point in front of them, or a
    /// flat pane's polygon.
    pub fn mask(&self, cam: &Camera) -> Vec<bool> {
        mask_of(&self.shapes(), cam)
    }

    /// [`Marks::mask`] once the marking describes glass, else None (the
    /// regions' shapes made once for both).
    pub fn mask_if_ready(&self, cam: &Camera) -> Option<Vec<bool>> {
        let shapes = self.shapes();
        (!shapes.is_empty()).then(|| mask_of(&shapes, cam))
    }

    /// Every training view's mask into `dir`, a directory that must not
    /// exist yet (`VIEW.png`, VIEW the view's name without its extension,
    /// as `reflection.seed_masks` reads them), and the clicks as
    /// `marks.json`; how many masks hold glass.
    pub fn write(&self, views: &[View], dir: &Path) -> Result<usize> {
        let shapes = self.shapes();
        if shapes.is_empty() {
            let why = self
                .regions
                .iter()
                .filter_map(|r| r.shape(self.tolerance).err())
                .next_back()
                .unwrap_or_else(|| "outlined in 0 view(s); outline it (three clicks or more) in at least two views".into());
            bail!("no piece of glass is marked yet: {why}");
        }
        let stems = stems(views)?;
        if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).with_context(|| format!("{}: cannot create the directory", parent.display()))?;
        }
        std::fs::create_dir(dir).with_context(|| {
            if dir.exists() {
                format!("{}: exists; masks are written into a new directory only (never over files)", dir.display())
            } else {
                format!("{}: cannot create the directory", dir.display())
            }
        })?;
        // The views in parallel (a real capture has hundreds of megapixels).
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).min(views.len().max(1));
        let glass: Result<Vec<usize>> = std::thread::scope(|scope| {
            let jobs: Vec<_> = (0..threads)
                .map(|t| {
                    let (dir, stems, shapes) = (&dir, &stems, &shapes);
                    scope.spawn(move || -> Result<usize> {
                        let mut glass = 0;
                        for (v, stem) in views.iter().zip(stems).skip(t).step_by(threads) {
                            let m = mask_of(shapes, &v.camera);
                            glass += m.iter().any(|&b| b) as usize;
                            write_mask(&dir.join(format!("{stem}.png")), v.camera.width, v.camera.height, &m)?;
                        }
                        Ok(glass)
                    })
                })
                .collect();
            jobs.into_iter().map(|j| j.join().unwrap_or_else(|_| Err(anyhow::anyhow!("a mask thread panicked")))).collect()
        });
        let glass: usize = glass?.into_iter().sum();
        let record = serde_json::json!({
            "what": "glass marked in tgs view: per region (a piece of glass) each outline's clicks (pixel coordinates, centres at integers) on its camera; a view's mask is where its rays meet, in one region, every outline's cone but `tolerance`, or for a flat region the polygon of its corners (the i-th click of every outline), triangulated (`pane`: the corners in world space, on their plane, and its normal; Stage II seeds on them, reflection.seed_panes)",
            "tolerance": self.tolerance,
            "regions": self.regions.iter().filter(|r| !r.outlines.is_empty()).map(|r| r.record(self.tolerance)).collect::<Vec<_>>(),
        });
        let path = dir.join("marks.json");
        std::fs::write(&path, serde_json::to_vec_pretty(&record)?).with_context(|| format!("{}: cannot write", path.display()))?;
        Ok(glass)
    }
}

/// `cam`'s mask of the regions' `shapes` (see [`Marks::mask`]).
fn mask_of(shapes: &[Shape], cam: &Camera) -> Vec<bool> {
    let rays = Rays::of(cam);
    let w = cam.width as usize;
    (0..w * cam.height as usize)
        .map(|i| {
            let d = rays.dir((i % w) as f64, (i / w) as f64);
            shapes.iter().any(|s| match s {
                Shape::Hull(need, cones) => through_enough(rays.centre, d, cones, *need),
                Shape::Pane(p) => p.hit(rays.centre, d),
            })
        })
        .collect()
}

/// Each view's mask file stem (its name without extension), refused where two views would share one.
fn stems(views: &[View]) -> Result<Vec<String>> {
    let stems: Vec<String> = views.iter().map(|v| mask_stem(&v.name)).collect();
    let mut seen = std::collections::HashSet::new();
    for (s, v) in stems.iter().zip(views) {
        if !seen.insert(s) {
            bail!("training views share the mask name {s}.png (view {}): reflection.seed_masks could not tell their masks apart", v.name);
        }
    }
    Ok(stems)
}

/// Whether the ray `o + t d` (t > 0) has a point inside `need` of the
/// cones, each in front of its camera: per cone one interval of t (the
/// intersection of its planes' half-lines), then a sweep over their ends.
fn through_enough(o: DVec3, d: DVec3, cones: &[(Rays, Vec<DVec3>)], need: usize) -> bool {
    let mut ends: Vec<(f64, i32)> = Vec::with_capacity(2 * cones.len());
    let mut missed = 0;
    for (rays, planes) in cones {
        let (mut lo, mut hi) = (1e-9f64, f64::INFINITY);
        for n in std::iter::once(rays.forward()).chain(planes.iter().copied()) {
            // n . (o + t d - c) >= 0
            let (a, b) = (n.dot(o - rays.centre), n.dot(d));
            if b.abs() < 1e-15 {
                if a < 0.0 {
                    hi = -1.0;
                }
            } else if b > 0.0 {
                lo = lo.max(-a / b);
            } else {
                hi = hi.min(-a / b);
            }
        }
        if lo < hi {
            ends.extend([(lo, 1), (hi, -1)]);
        } else {
            // Most rays miss the glass: stop once too few cones are left.
            missed += 1;
            if cones.len() - missed < need {
                return false;
            }
        }
    }
    // Ends before starts at the same t: intervals that only touch do not overlap.
    ends.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut inside = 0i32;
    ends.iter().any(|&(_, e)| {
        inside += e;
        inside >= need as i32
    })
}

/// The convex hull of `p` (Andrew's monotone chain), counter-clockwise in
/// (u, v), without collinear points.
fn convex_hull(p: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut pts: Vec<(f64, f64)> = p.iter().copied().filter(|q| q.0.is_finite() && q.1.is_finite()).collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    pts.dedup();
    if pts.len() < 3 {
        return pts;
    }
    let cross = |o: (f64, f64), a: (f64, f64), b: (f64, f64)| (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0);
    let mut hull: Vec<(f64, f64)> = Vec::new();
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &(f64, f64)>> = if pass == 0 { Box::new(pts.iter()) } else { Box::new(pts.iter().rev()) };
        for &q in iter {
            while hull.len() >= start + 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0 {
                hull.pop();
            }
            hull.push(q);
        }
        hull.pop();
    }
    hull
}

#[cfg(test)]
mod tests;
