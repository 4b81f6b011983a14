//! Seeds on panes marked in `tgs view` by their corners
//! (`reflection.seed_panes`;
//! harness/train/src/train/stages/reflection/seed/panes.rs), on the CPU:
//! the seeds lie on the marked pane with its normal, whatever the masks'
//! hull says; `marks.json`'s panes are read only where every region is flat
//! (a flat region whose corners did not meet has none, and no mask).

use glam::DVec3;
use tgs::train::stages::reflection::masks::marked_panes;
use tgs::train::stages::reflection::seed::{pane_seeds, PanePolygon, SeedNormal, SeedParams};
use tgs_tests::seed_scenes::*;

/// The suite's free-standing pane (`glass_pane_views`), turned `deg` about z.
fn pane_corners(deg: f64) -> Vec<DVec3> {
    let (s, c) = deg.to_radians().sin_cos();
    [[0.0, -0.6, 0.0], [0.0, 0.6, 0.0], [0.0, 0.6, 0.7], [0.0, -0.6, 0.7]].iter().map(|p| DVec3::new(-s * p[1], c * p[1], p[2])).collect()
}

#[test]
fn seeds_lie_on_the_marked_pane_with_its_normal() {
    let (cams, masks, depth) = glass_pane_views(40);
    let sv = seed_views(&cams, &masks, &depth);
    // The marked pane a little off the glass the masks show (4 degrees):
    // the seeds follow the marks.
    let pane = PanePolygon::from_corners(&pane_corners(4.0)).unwrap();
    let p = mask_params(SeedNormal::Consensus);
    let seeds = pane_seeds(&sv, std::slice::from_ref(&pane), &p);
    let (n, c) = (pane.normal(), pane.corners()[0]);
    eprintln!("marked pane: {} seeds", seeds.len());
    assert!(seeds.len() > 1000, "{} seeds", seeds.len());
    for s in &seeds {
        let (x, sn) = (DVec3::from(s.position.map(f64::from)), DVec3::from(s.normal.map(f64::from)));
        assert!((x - c).dot(n).abs() < 1e-5, "{x} off the pane by {}", (x - c).dot(n));
        assert!(sn.dot(n).abs() > 1.0 - 1e-6, "{sn} against {n}");
        assert!(s.scale > 0.0 && s.scale < 0.1, "{}", s.scale);
    }
    // Seeds on both sides' views face them: both signs appear.
    assert!(seeds.iter().any(|s| s.normal[0] > 0.5) && seeds.iter().any(|s| s.normal[0] < -0.5));
    assert_eq!(pane_seeds(&sv, std::slice::from_ref(&pane), &SeedParams { threads: 1, ..p }), seeds, "the same at one thread");
    // Stage I's surface in front of the pane in every view (something
    // opaque the marks do not know of): hidden, no seeds.
    let near: Vec<Vec<f32>> = depth.iter().map(|d| vec![0.5; d.len()]).collect();
    assert!(pane_seeds(&seed_views(&cams, &masks, &near), std::slice::from_ref(&pane), &p).is_empty());
    // A pane no masked ray meets, or none at all: no seeds.
    let far = PanePolygon::from_corners(&pane_corners(0.0).iter().map(|x| *x + DVec3::new(0.0, 0.0, 50.0)).collect::<Vec<_>>()).unwrap();
    assert!(pane_seeds(&sv, &[far], &p).is_empty());
    assert!(pane_seeds(&sv, &[], &p).is_empty());
}

#[test]
fn a_pane_polygon_is_flat_and_hit_inside_only() {
    assert!(PanePolygon::from_corners(&[DVec3::ZERO, DVec3::X]).unwrap_err().contains("three corners"));
    assert!(PanePolygon::from_corners(&[DVec3::ZERO, DVec3::X, 2.0 * DVec3::X]).unwrap_err().contains("line"));
    assert!(PanePolygon::from_corners(&[DVec3::ZERO, DVec3::X, DVec3::ONE, DVec3::new(0.0, 1.0, -1.0)]).unwrap_err().contains("plane"));
    assert!(PanePolygon::from_corners(&[DVec3::ZERO, DVec3::X, DVec3::new(f64::NAN, 0.0, 0.0)]).is_err());
    // An L-shaped pane in z = 0: not convex, its notch not glass.
    let l = [[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0], [1.0, 2.0], [0.0, 2.0]].map(|[x, y]| DVec3::new(x, y, 0.0));
    let pane = PanePolygon::from_corners(&l).unwrap();
    let down = |x: f64, y: f64| pane.hit(DVec3::new(x, y, 3.0), DVec3::NEG_Z);
    assert_eq!(down(0.5, 0.5), Some(3.0));
    assert_eq!(down(1.5, 0.5), Some(3.0));
    assert_eq!(down(1.5, 1.5), None, "the notch");
    assert_eq!(down(2.5, 0.5), None);
    assert_eq!(pane.hit(DVec3::new(0.5, 0.5, 3.0), DVec3::Z), None, "behind the ray's origin");
    assert_eq!(pane.hit(DVec3::new(0.5, 0.5, 3.0), DVec3::X), None, "parallel");
    for (got, want) in pane.corners().iter().zip(&l) {
        assert!(got.distance(*want) < 1e-12);
    }
}

#[test]
fn marks_json_gives_panes_only_when_every_region_is_flat() {
    let dir = tgs_tests::TempDir::new("seed-panes-marks");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    assert!(marked_panes(&dir).unwrap().is_none(), "no marks.json: exact masks");
    let pane = r#"{"flat": true, "outlines": [], "pane": {"corners": [[0, -0.6, 0], [0, 0.6, 0], [0, 0.6, 0.7], [0, -0.6, 0.7]]}}"#;
    for (text, count) in [
        (format!(r#"{{"regions": [{pane}]}}"#), Some(1)),
        (format!(r#"{{"regions": [{pane}, {pane}]}}"#), Some(2)),
        (format!(r#"{{"regions": [{pane}, {{"flat": false, "outlines": []}}]}}"#), None),
        (format!(r#"{{"regions": [{pane}, {{"flat": true, "outlines": []}}]}}"#), Some(1)),
        (r#"{"regions": [{"flat": true, "outlines": []}]}"#.to_string(), None),
        (r#"{"regions": []}"#.to_string(), None),
        ("not json".to_string(), None),
    ] {
        std::fs::write(dir.join("marks.json"), &text).unwrap();
        assert_eq!(marked_panes(&dir).unwrap().map(|p| p.len()), count, "{text}");
    }
    std::fs::write(dir.join("marks.json"), r#"{"regions": [{"flat": true, "pane": {"corners": [[0, 0, 0], [1, 0, 0], [2, 0, 0]]}}]}"#).unwrap();
    let e = format!("{:#}", marked_panes(&dir).unwrap_err());
    assert!(e.contains("marks.json") && e.contains("region 1") && e.contains("line"), "{e}");
}
