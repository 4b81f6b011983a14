//! Flat faces of the glass among the mask hull's seeds
//! (`reflection.seed_faces`;
//! harness/train/src/train/stages/reflection/seed/faces.rs), on the CPU:
//! a glass box's pillowed faces and a free-standing pane's ridge take
//! their face's normal; a sphere offers no face and keeps its normals.

use tgs::train::stages::reflection::seed::{flat_faces, hull_seeding, HullSeeding, Seed, SeedNormal, SeedParams};
use tgs_tests::seed_scenes::*;
use tgs_tests::{seed, Rng};

/// Mean angle (degrees) between each seed's normal and `truth`'s at its position, either way round.
fn tilt(h: &HullSeeding, truth: impl Fn([f64; 3]) -> [f64; 3]) -> f64 {
    let t: f64 = h.seeds.iter().map(|s| dot(s.normal.map(f64::from), truth(s.position.map(f64::from))).abs().clamp(0.0, 1.0).acos().to_degrees()).sum();
    t / h.seeds.len() as f64
}

#[test]
fn a_glass_boxs_seeds_take_its_faces_normals() {
    let (cams, masks, depth) = glass_box_views(40);
    let sv = seed_views(&cams, &masks, &depth);
    let smoothed = SeedParams { planes: true, smooth: true, ..mask_params(SeedNormal::Consensus) };
    let (before, after) = (hull_seeding(&sv, &smoothed), hull_seeding(&sv, &SeedParams { faces: true, ..smoothed }));
    // Off the nearest face, or within 0.05 of an edge the better of its two.
    let face = |h: &HullSeeding| {
        let off = |s: &Seed| {
            let x = s.position.map(f64::from);
            faces_near(x, &GLASS_BOX.0, GLASS_BOX.1, 0.05).iter().map(|&f| dot(s.normal.map(f64::from), f).abs().clamp(0.0, 1.0).acos().to_degrees()).fold(90.0, f64::min)
        };
        h.seeds.iter().map(off).sum::<f64>() / h.seeds.len() as f64
    };
    let (b, a) = (face(&before), face(&after));
    eprintln!("glass box: {} seeds, {:?} faces / seeds taken; normals {b:.2} deg off its faces smoothed, {a:.2} with the faces", after.seeds.len(), after.faces);
    assert_eq!(before.faces, [0, 0]);
    assert!((4..=6).contains(&after.faces[0]), "{:?} faces for a box's five", after.faces);
    assert!(after.faces[1] as f64 >= 0.8 * after.seeds.len() as f64, "{:?}", after.faces);
    assert!(a < 0.6 * b, "{a} deg with the faces, {b} without");
    // Only normals change, each on its side; the same at one thread.
    for (a, b) in after.seeds.iter().zip(&before.seeds) {
        assert_eq!((a.position, a.scale), (b.position, b.scale));
        assert!(dot(a.normal.map(f64::from), b.normal.map(f64::from)) > 0.0 && a.normal.iter().all(|v| v.is_finite()));
    }
    assert_eq!(hull_seeding(&sv, &SeedParams { faces: true, threads: 1, ..smoothed }), after, "the same at one thread");
}

#[test]
fn a_panes_ridge_takes_the_panes_normal() {
    let (cams, masks, depth) = glass_pane_views(40);
    let sv = seed_views(&cams, &masks, &depth);
    let smoothed = SeedParams { planes: true, smooth: true, ..mask_params(SeedNormal::Consensus) };
    let (before, after) = (hull_seeding(&sv, &smoothed), hull_seeding(&sv, &SeedParams { faces: true, ..smoothed }));
    let x = |_| [1.0, 0.0, 0.0];
    let worst = |h: &HullSeeding| h.seeds.iter().filter(|s| dot(s.normal.map(f64::from), [1.0, 0.0, 0.0]).abs() < 20f64.to_radians().cos()).count();
    eprintln!(
        "glass pane: {} seeds, {:?} faces / seeds taken; normals {:.2} deg off it smoothed ({} over 20), {:.2} with the faces ({})",
        after.seeds.len(),
        after.faces,
        tilt(&before, x),
        worst(&before),
        tilt(&after, x),
        worst(&after)
    );
    assert_eq!(after.faces[0], 1, "{:?}", after.faces);
    assert!(tilt(&after, x) < 0.6 * tilt(&before, x) && worst(&after) < worst(&before) / 2, "{} deg with the face, {} without", tilt(&after, x), tilt(&before, x));
}

#[test]
fn a_sphere_offers_no_face() {
    let seeds = unit_sphere_seeds(&mut Rng(seed("seed-faces-sphere")), 3000);
    // A band of 0.05 (a pixel and a half at 50² and the suite's distance, for a unit sphere).
    let mut s = seeds.clone();
    assert_eq!(flat_faces(&mut s, 0.05), (0, 0));
    assert_eq!(s, seeds);
    // The glass sphere's hull seeds: none either.
    let (cams, res, depth) = views(0.0, true);
    let sv = seed_views(&cams, &res, &depth);
    let p = SeedParams { threshold: 0.01, blur: 0, max_rays: 1500, normal: SeedNormal::Consensus, smooth: true, ..SeedParams::default() };
    let (a, b) = (hull_seeding(&sv, &p), hull_seeding(&sv, &SeedParams { faces: true, ..p }));
    let mean = |h: &HullSeeding| radial_error(&h.seeds).iter().sum::<f64>() / h.seeds.len() as f64;
    eprintln!("glass sphere: {:?} faces / seeds taken; normals {:.2} deg off radial, {:.2} with the faces", b.faces, mean(&a), mean(&b));
    assert_eq!((b.faces, &b.seeds), ([0, 0], &a.seeds));
    // Degenerate input: nothing, one seed, a zero or non-finite band.
    for (n, band) in [(0, 0.05), (1, 0.05), (100, 0.0), (100, f64::NAN)] {
        let mut s = seeds[..n].to_vec();
        assert_eq!(flat_faces(&mut s, band), (0, 0));
        assert_eq!(s, seeds[..n]);
    }
}

#[test]
fn regions_marked_in_the_viewer_are_recognised() {
    use tgs::train::stages::reflection::masks::marked_regions;
    let dir = tgs_tests::TempDir::new("seed-faces-marks");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    assert!(!marked_regions(&dir), "no marks.json: exact masks");
    for (text, marked) in [
        (r#"{"regions": [{"flat": true, "outlines": []}]}"#, false),
        (r#"{"regions": [{"flat": true}, {"flat": false}]}"#, true),
        (r#"{"regions": []}"#, false),
        ("not json", false),
    ] {
        std::fs::write(dir.join("marks.json"), text).unwrap();
        assert_eq!(marked_regions(&dir), marked, "{text}");
    }
}
