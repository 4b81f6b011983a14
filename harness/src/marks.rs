//! Marking the glass (`tgs view`, key G): the user clicks around the glass
//! (a pane's corners, a dome's outline) in two or more views. Each view's
//! clicks span a convex polygon, and with the camera a cone; the glass is
//! where every marked view's cone holds it (their visual hull). A training
//! view's glass mask is the set of its pixels whose ray passes through
//! that hull: exact, no sampling along the ray. The masks go into a new
//! directory (never the dataset's) for `reflection.seed_masks`.
//! Occlusion is not modelled: glass behind an opaque object is marked too.

use crate::data::image_io::write_mask;
use crate::data::View;
use crate::train::stages::reflection::masks::mask_stem;
use anyhow::{bail, Context as _, Result};
use glam::{DMat3, DVec3};
use std::path::Path;
use tgs_pipelines::Camera;

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
    fn cone(&self) -> Option<(Rays, Vec<DVec3>)> {
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
/// clicked around in; it is where those outlines' cones meet.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Region {
    pub outlines: Vec<Outline>,
}

impl Region {
    /// The outlines that span a polygon (three clicks or more, not on a line).
    fn cones(&self) -> Vec<(Rays, Vec<DVec3>)> {
        self.outlines.iter().filter_map(Outline::cone).collect()
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
        if self.regions.is_empty() {
            self.regions.push(Region::default());
        }
        let region = self.regions.last_mut().expect("one was pushed");
        match region.outlines.last_mut() {
            Some(o) if o.camera == *cam => o.points.push((u, v)),
            _ => region.outlines.push(Outline { camera: *cam, points: vec![(u, v)] }),
        }
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

    /// Each region that describes glass (a polygon in two views or more), as its cones.
    fn ready_regions(&self) -> Vec<Vec<Cone>> {
        self.regions.iter().map(Region::cones).filter(|c| c.len() >= 2).collect()
    }

    /// Whether the marking describes glass: a region with a polygon in two views.
    pub fn is_ready(&self) -> bool {
        !self.ready_regions().is_empty()
    }

    /// `cam`'s glass mask (row-major): its pixels whose ray meets, in one
    /// of the regions, every outlined view's cone (all but `tolerance`,
    /// and at least two) at one point in front of them.
    pub fn mask(&self, cam: &Camera) -> Vec<bool> {
        let regions: Vec<(usize, Vec<Cone>)> = self.ready_regions().into_iter().map(|c| (c.len().saturating_sub(self.tolerance).max(2), c)).collect();
        let rays = Rays::of(cam);
        let (w, h) = (cam.width as usize, cam.height as usize);
        let mut out = vec![false; w * h];
        for (i, m) in out.iter_mut().enumerate() {
            let d = rays.dir((i % w) as f64, (i / w) as f64);
            *m = regions.iter().any(|(need, cones)| through_enough(rays.centre, d, cones, *need));
        }
        out
    }

    /// Every training view's mask into `dir`, a directory that must not
    /// exist yet (`VIEW.png`, VIEW the view's name without its extension,
    /// as `reflection.seed_masks` reads them), and the clicks as
    /// `marks.json`; how many masks hold glass.
    pub fn write(&self, views: &[View], dir: &Path) -> Result<usize> {
        if !self.is_ready() {
            let most = self.regions.iter().map(|r| r.cones().len()).max().unwrap_or(0);
            bail!("the glass is marked in {most} view(s); outline it (three clicks or more) in at least two views");
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
                    let (dir, stems) = (&dir, &stems);
                    scope.spawn(move || -> Result<usize> {
                        let mut glass = 0;
                        for (v, stem) in views.iter().zip(stems).skip(t).step_by(threads) {
                            let m = self.mask(&v.camera);
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
            "what": "glass marked in tgs view: per region (a piece of glass) each outline's clicks (pixel coordinates, centres at integers) on its camera; a view's mask is where its rays meet, in one region, every outline's cone but `tolerance`",
            "tolerance": self.tolerance,
            "regions": self.regions.iter().filter(|r| !r.outlines.is_empty()).map(|r| serde_json::json!({"outlines": r.outlines.iter().map(|o| serde_json::json!({
                "width": o.camera.width, "height": o.camera.height, "fx": o.camera.fx, "fy": o.camera.fy, "cx": o.camera.cx, "cy": o.camera.cy,
                "world_to_view": o.camera.world_to_view, "points": o.points,
            })).collect::<Vec<_>>()})).collect::<Vec<_>>(),
        });
        let path = dir.join("marks.json");
        std::fs::write(&path, serde_json::to_vec_pretty(&record)?).with_context(|| format!("{}: cannot write", path.display()))?;
        Ok(glass)
    }
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
mod tests {
    use super::*;

    fn cam(eye: [f32; 3]) -> Camera {
        Camera::look_at(eye, [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.8, 64, 48)
    }

    /// The pixel coordinates of world point `x` in `c`.
    fn project(c: &Camera, x: DVec3) -> (f64, f64) {
        let r = Rays::of(c);
        let p = r.axes.transpose() * (x - r.centre);
        (r.fx * p.x / p.z + r.cx, r.fy * p.y / p.z + r.cy)
    }

    #[test]
    fn hull_drops_inner_and_collinear_points() {
        let h = convex_hull(&[(0.0, 0.0), (2.0, 0.0), (1.0, 0.0), (2.0, 2.0), (0.0, 2.0), (1.0, 1.0), (0.0, 2.0)]);
        assert_eq!(h.len(), 4, "{h:?}");
        assert!(convex_hull(&[(0.0, 0.0), (1.0, 1.0), (2.0, 2.0)]).len() < 3);
    }

    #[test]
    fn rays_invert_the_projection() {
        let c = cam([3.0, -2.0, 1.5]);
        let x = DVec3::new(0.2, -0.1, 0.3);
        let (u, v) = project(&c, x);
        let r = Rays::of(&c);
        let d = r.dir(u, v);
        let t = (x - r.centre).dot(d) / d.length_squared();
        assert!((r.centre + t * d - x).length() < 1e-6);
        let [ex, ey, ez] = c.centre();
        assert!((r.centre - DVec3::new(ex as f64, ey as f64, ez as f64)).length() < 1e-5);
    }

    /// A square pane outlined by its corners in two views: a third view's
    /// mask holds the pane's projection and little else; one view is not enough.
    #[test]
    fn a_pane_outlined_in_two_views_masks_a_third() {
        let corners = [[-0.5, 0.0, -0.4], [0.5, 0.0, -0.4], [0.5, 0.0, 0.4], [-0.5, 0.0, 0.4]].map(DVec3::from_array);
        let (a, b, third) = (cam([1.5, -3.0, 0.5]), cam([-1.5, -3.0, 0.2]), cam([0.3, -3.2, 1.0]));
        let mut marks = Marks::default();
        for c in [&a, &b] {
            for &x in &corners {
                let (u, v) = project(c, x);
                marks.click(c, u, v);
            }
        }
        assert_eq!((marks.outlines(), marks.clicks()), (2, 8));
        let m = marks.mask(&third);
        // The pane's own projection in the third view, by point-in-quad.
        let q: Vec<(f64, f64)> = corners.iter().map(|&x| project(&third, x)).collect();
        let inside = |u: f64, v: f64| {
            (0..4).all(|i| {
                let (p0, p1) = (q[i], q[(i + 1) % 4]);
                (p1.0 - p0.0) * (v - p0.1) - (p1.1 - p0.1) * (u - p0.0) >= 0.0
            }) || (0..4).all(|i| {
                let (p0, p1) = (q[i], q[(i + 1) % 4]);
                (p1.0 - p0.0) * (v - p0.1) - (p1.1 - p0.1) * (u - p0.0) <= 0.0
            })
        };
        let w = third.width as usize;
        let truth: Vec<bool> = (0..m.len()).map(|i| inside((i % w) as f64, (i / w) as f64)).collect();
        let both = m.iter().zip(&truth).filter(|(a, b)| **a && **b).count();
        let either = m.iter().zip(&truth).filter(|(a, b)| **a || **b).count();
        let missed = truth.iter().zip(&m).filter(|(t, m)| **t && !**m).count();
        assert!(truth.iter().filter(|&&t| t).count() > 100);
        assert_eq!(missed, 0, "the hull holds the pane");
        assert!(both as f64 / either as f64 > 0.7, "IoU {}", both as f64 / either as f64);
        // A third outline cut short (an occluder hid half the pane there):
        // every view must hold a point, so the pane's far half is lost;
        // forgiving one view brings it back.
        let mut cut = marks.clone();
        let cut_cam = cam([0.0, -3.4, -0.6]);
        for x in [corners[0], (corners[0] + corners[1]) / 2.0, (corners[2] + corners[3]) / 2.0, corners[3]] {
            let (u, v) = project(&cut_cam, x);
            cut.click(&cut_cam, u, v);
        }
        let lost = |m: &[bool]| truth.iter().zip(m).filter(|(t, m)| **t && !**m).count();
        assert!(lost(&cut.mask(&third)) > 50, "{}", lost(&cut.mask(&third)));
        cut.tolerance = 1;
        assert_eq!(lost(&cut.mask(&third)), 0);
        // One outline is no region; undo takes clicks back one by one.
        let mut one = marks.clone();
        for _ in 0..4 {
            one.undo();
        }
        assert_eq!(one.outlines(), 1);
        assert!(!one.is_ready() && one.mask(&third).iter().all(|&b| !b));
        // Behind every camera nothing is marked: a view looking away.
        let away = Camera::look_at([0.0, -3.0, 0.0], [0.0, -6.0, 0.0], [0.0, 0.0, 1.0], 0.8, 16, 12);
        assert!(marks.mask(&away).iter().all(|&b| !b));
    }

    /// Two panes side by side with a gap: outlined as one region the
    /// views' convex outlines span the gap too; as two regions (B between
    /// them) the gap stays unmarked and both panes are held.
    #[test]
    fn two_panes_are_two_regions() {
        let pane = |x0: f64| [[x0, 0.0, -0.3], [x0 + 0.4, 0.0, -0.3], [x0 + 0.4, 0.0, 0.3], [x0, 0.0, 0.3]].map(DVec3::from_array);
        let (left, right) = (pane(-0.8), pane(0.4));
        let (a, b, third) = (cam([1.5, -3.0, 0.5]), cam([-1.5, -3.0, 0.2]), cam([0.3, -3.2, 1.0]));
        let (mut one, mut two) = (Marks::default(), Marks::default());
        // One region: each view's clicks go around both panes.
        for c in [&a, &b] {
            for &x in left.iter().chain(&right) {
                let (u, v) = project(c, x);
                one.click(c, u, v);
            }
        }
        // Two regions: a pane outlined in both views, then B, then the other.
        for corners in [left, right] {
            for c in [&a, &b] {
                for &x in &corners {
                    let (u, v) = project(c, x);
                    two.click(c, u, v);
                }
            }
            two.new_region();
            two.new_region(); // a second press on an empty region adds none
        }
        assert_eq!((one.regions.len(), two.regions.len(), two.outlines(), two.clicks()), (1, 3, 4, 16));
        let gap = project(&third, DVec3::new(0.0, 0.0, 0.0));
        let at = |m: &[bool], p: (f64, f64)| m[p.1.round() as usize * third.width as usize + p.0.round() as usize];
        let (m1, m2) = (one.mask(&third), two.mask(&third));
        assert!(at(&m1, gap) && !at(&m2, gap), "the gap between the panes");
        for x in [DVec3::new(-0.6, 0.0, 0.0), DVec3::new(0.6, 0.0, 0.0)] {
            assert!(at(&m2, project(&third, x)), "a pane's centre");
        }
        // Undo empties the second region and then takes clicks from the first.
        let mut u = two.clone();
        for _ in 0..8 {
            u.undo();
        }
        assert_eq!((u.regions.len(), u.clicks()), (1, 8));
        assert!(u.is_ready() && !at(&u.mask(&third), project(&third, DVec3::new(0.6, 0.0, 0.0))));
    }

    #[test]
    fn masks_go_into_a_new_directory_only() {
        let view = |name: &str, c: Camera| View {
            name: name.into(),
            camera: c,
            image: crate::data::image_io::ImageF { width: c.width, height: c.height, channels: 3, data: vec![0.0; 3 * (c.width * c.height) as usize] },
            normals: None,
            mask: None,
        };
        let (a, b) = (cam([1.5, -3.0, 0.5]), cam([-1.5, -3.0, 0.2]));
        let views = [view("train/r_0.png", a), view("train/r_1", b)];
        let dir = std::env::temp_dir().join(format!("tgs-marks-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut marks = Marks::default();
        let e = format!("{:#}", marks.write(&views, &dir.join("m")).unwrap_err());
        assert!(e.contains("in 0 view(s)") && !dir.join("m").exists(), "{e}");
        for c in [&a, &b] {
            for x in [[-0.3, 0.0, -0.3], [0.3, 0.0, -0.3], [0.0, 0.0, 0.3]] {
                let (u, v) = project(c, DVec3::from_array(x));
                marks.click(c, u, v);
            }
        }
        assert_eq!(marks.write(&views, &dir.join("m")).unwrap(), 2);
        let m = crate::data::image_io::read_grey_mask(&dir.join("m/r_0.png")).unwrap();
        assert_eq!(m.2, marks.mask(&a));
        assert!(dir.join("m/r_1.png").is_file() && dir.join("m/marks.json").is_file());
        let e = format!("{:#}", marks.write(&views, &dir.join("m")).unwrap_err());
        assert!(e.contains("exists"), "{e}");
        let e = format!("{:#}", marks.write(&[view("a/r_0", a), view("b/r_0.jpg", b)], &dir.join("n")).unwrap_err());
        assert!(e.contains("r_0.png") && !dir.join("n").exists(), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
