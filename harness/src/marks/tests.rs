//! Marking's unit tests: panes and domes outlined in a few views, against their projections.

use super::*;

fn cam(eye: [f32; 3]) -> Camera {
    Camera::look_at(eye, [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.8, 64, 48)
}

/// A training view named `name` seen by `c` (a black image).
fn view(name: &str, c: Camera) -> View {
    View {
        name: name.into(),
        camera: c,
        image: crate::data::image_io::ImageF { width: c.width, height: c.height, channels: 3, data: vec![0.0; 3 * (c.width * c.height) as usize] },
        normals: None,
        mask: None,
    }
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

/// A pane marked flat (F) by its four corners in two views: a third
/// view's mask is the pane's projection (the hull of the same clicks is a
/// wedge around it); a view's corners may start anywhere round the pane,
/// either way, but not out of order.
#[test]
fn a_flat_pane_is_its_corners_polygon() {
    let corners = [[-0.5, 0.0, -0.4], [0.5, 0.0, -0.4], [0.5, 0.0, 0.4], [-0.5, 0.0, 0.4]].map(DVec3::from_array);
    let (a, b, third) = (cam([1.5, -3.0, 0.5]), cam([-1.5, -3.0, 0.2]), cam([2.5, -2.0, 1.5]));
    let (mut flat, mut hull) = (Marks::default(), Marks::default());
    flat.flat();
    for c in [&a, &b] {
        for &x in &corners {
            let (u, v) = project(c, x);
            flat.click(c, u, v);
            hull.click(c, u, v);
        }
    }
    assert!(flat.is_ready() && flat.pending().is_none());
    let q: Vec<(f64, f64)> = corners.iter().map(|&x| project(&third, x)).collect();
    let inside = |u: f64, v: f64| {
        let s: Vec<f64> = (0..4).map(|i| (q[(i + 1) % 4].0 - q[i].0) * (v - q[i].1) - (q[(i + 1) % 4].1 - q[i].1) * (u - q[i].0)).collect();
        s.iter().all(|&x| x >= 0.0) || s.iter().all(|&x| x <= 0.0)
    };
    let w = third.width as usize;
    let truth: Vec<bool> = (0..w * third.height as usize).map(|i| inside((i % w) as f64, (i / w) as f64)).collect();
    let iou = |m: &[bool]| {
        let both = m.iter().zip(&truth).filter(|(a, b)| **a && **b).count();
        both as f64 / m.iter().zip(&truth).filter(|(a, b)| **a || **b).count() as f64
    };
    let (f, h) = (iou(&flat.mask(&third)), iou(&hull.mask(&third)));
    assert!(f > 0.9 && f > h, "flat IoU {f}, hull IoU {h}");
    // The second view's corners started elsewhere, or the other way round:
    // matched to the first view's, the same pane. Two of them swapped (not
    // an order round the pane): they do not meet.
    let marked = |order: [usize; 4]| {
        let mut m = Marks::default();
        m.flat();
        for (c, order) in [(&a, [0, 1, 2, 3]), (&b, order)] {
            for k in order {
                let (u, v) = project(c, corners[k]);
                m.click(c, u, v);
            }
        }
        m
    };
    for order in [[1, 2, 3, 0], [3, 2, 1, 0], [2, 1, 0, 3]] {
        let m = marked(order);
        assert!(m.is_ready(), "{order:?}: {:?}", m.pending());
        assert_eq!(m.mask(&third), flat.mask(&third), "{order:?}");
    }
    let wrong = marked([0, 2, 1, 3]);
    assert!(!wrong.is_ready() && wrong.pending().is_some_and(|p| p.contains("do not meet")), "{:?}", wrong.pending());
    // Three corners in one view and four in the other: refused, named.
    let mut short = flat.clone();
    short.undo();
    assert!(short.pending().is_some_and(|p| p.contains("same number")), "{:?}", short.pending());
}

#[test]
fn masks_go_into_a_new_directory_only() {
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

/// A flat pane's corners go into `marks.json` for Stage II
/// (`reflection.seed_panes`), read back as they were triangulated; a
/// marking with a hull region gives none.
#[test]
fn a_flat_panes_corners_reach_stage_two() {
    use crate::train::stages::reflection::masks::marked_panes;
    let corners = [[-0.5, 0.0, -0.4], [0.5, 0.0, -0.4], [0.5, 0.0, 0.4], [-0.5, 0.0, 0.4]].map(DVec3::from_array);
    let (a, b) = (cam([1.5, -3.0, 0.5]), cam([-1.5, -3.0, 0.2]));
    let views = [view("r_0", a), view("r_1", b)];
    let dir = std::env::temp_dir().join(format!("tgs-marks-panes-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut marks = Marks::default();
    marks.flat();
    for c in [&a, &b] {
        for &x in &corners {
            let (u, v) = project(c, x);
            marks.click(c, u, v);
        }
    }
    marks.write(&views, &dir.join("flat")).unwrap();
    let panes = marked_panes(&dir.join("flat")).unwrap().expect("every region a flat pane");
    assert_eq!(panes.len(), 1);
    for (got, want) in panes[0].corners().iter().zip(&corners) {
        assert!(got.distance(*want) < 1e-4, "{got} against {want}");
    }
    assert!(panes[0].normal().dot(DVec3::Y).abs() > 1.0 - 1e-6, "{}", panes[0].normal());
    // A second piece outlined as a hull region: the masks' hull seeds.
    marks.new_region();
    for c in [&a, &b] {
        for x in [[-0.3, 1.0, -0.3], [0.3, 1.0, -0.3], [0.0, 1.0, 0.3]] {
            let (u, v) = project(c, DVec3::from_array(x));
            marks.click(c, u, v);
        }
    }
    marks.write(&views, &dir.join("mixed")).unwrap();
    assert!(marked_panes(&dir.join("mixed")).unwrap().is_none());
    std::fs::remove_dir_all(&dir).unwrap();
}
