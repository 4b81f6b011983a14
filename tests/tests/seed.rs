//! Residual-guided seeding of the reflection set (harness/train/src/train/stages/reflection/seed/),
//! on the CPU: the geometry helpers against closed forms, and the residual
//! hull on a synthetic glass sphere whose residual is exactly its
//! silhouette (plus scattered noise), seen from a ring of cameras around
//! an opaque ball inside it: the seeds must lie on the sphere's front with
//! radial normals; no residual gives no seeds, and neither does residual
//! over every view (glass that fills the frame: nothing is carved).

use tgs::train::stages::reflection::seed::{
    consensus_normal, hull_seeding, jacobi_eigen, min_hits, pixel_of, quat_for_normal, residual_hull_seeds, HullSeeding, Seed, SeedNormal, SeedParams, SeedView,
};
use tgs_pipelines::Camera;
use tgs_tests::raster_util::splat_normal;
use tgs_tests::seed_scenes::*;
use tgs_tests::{seed, Rng};

#[test]
fn quaternion_for_a_normal_has_that_normal() {
    let mut rng = Rng(seed("quaternion_for_a_normal_has_that_normal"));
    let mut normals: Vec<V3> = vec![[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [1e-9, 0.0, -1.0]];
    for _ in 0..200 {
        normals.push(norm([uniform(&mut rng) - 0.5, uniform(&mut rng) - 0.5, uniform(&mut rng) - 0.5]));
    }
    for n in normals {
        let q = quat_for_normal(n.map(|c| c as f32));
        assert!(q.iter().all(|v| v.is_finite()), "{n:?} -> {q:?}");
        let got = splat_normal(q);
        let err = (0..3).map(|k| (got[k] - norm(n)[k]).abs()).fold(0.0, f64::max);
        assert!(err < 1e-5, "normal {n:?}: quaternion {q:?} has t_w {got:?}");
    }
}

#[test]
fn jacobi_eigenpairs_of_symmetric_matrices() {
    let mut rng = Rng(seed("jacobi_eigenpairs_of_symmetric_matrices"));
    let mut cases = vec![[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], [[0.0; 3]; 3], [[2.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 0.0, 0.0]]];
    for _ in 0..100 {
        let mut a = [[0.0; 3]; 3];
        for r in 0..3 {
            for c in r..3 {
                a[r][c] = uniform(&mut rng) * 2.0 - 1.0;
                a[c][r] = a[r][c];
            }
        }
        cases.push(a);
    }
    for a in cases {
        let (vals, vecs) = jacobi_eigen(a);
        for k in 0..3 {
            let v = [vecs[0][k], vecs[1][k], vecs[2][k]];
            assert!((dot(v, v) - 1.0).abs() < 1e-9, "{a:?}: eigenvector {k} not unit");
            for r in 0..3 {
                let av = dot(a[r], v);
                assert!((av - vals[k] * v[r]).abs() < 1e-9, "{a:?}: A v != lambda v for {k}");
            }
        }
    }
}

#[test]
fn residual_hull_seeds_lie_on_the_glass_with_radial_normals() {
    let (cams, res, depth) = views(0.05, true);
    let sv = seed_views(&cams, &res, &depth);
    // On this ideal hull the seeds' plane is the sphere's tangent plane.
    let p = SeedParams { max_rays: 3000, normal: SeedNormal::Plane, ..SeedParams::default() };
    let seeds = residual_hull_seeds(&sv, &p);
    assert!(seeds.len() > 1000, "{} seeds from 3000 rays", seeds.len());
    let mut off = Vec::new();
    for s in &seeds {
        let x = s.position.map(f64::from);
        off.push(dot(x, x).sqrt() - SPHERE_R);
        let n = s.normal.map(f64::from);
        assert!((dot(n, n) - 1.0).abs() < 1e-4 && s.scale > 0.0 && s.scale.is_finite(), "{s:?}");
    }
    off.sort_by(f64::total_cmp);
    let radial = radial_error(&seeds);
    let pct = |v: &[f64], q: f64| v[((v.len() - 1) as f64 * q) as usize];
    eprintln!(
        "distance to the sphere: 5% {:.3} median {:.3} 95% {:.3}; normal error median {:.1} 90% {:.1} deg",
        pct(&off, 0.05),
        pct(&off, 0.5),
        pct(&off, 0.95),
        pct(&radial, 0.5),
        pct(&radial, 0.9)
    );
    // A visual hull encloses the surface: seeds are on or just outside it
    // (never inside by more than the march step), mostly within 10% of its radius.
    assert!(pct(&off, 0.01) > -0.03, "seeds inside the glass: {:.3}", pct(&off, 0.01));
    assert!(pct(&off, 0.9) < 0.05, "90% of seeds within 0.05 of the glass: {:.3}", pct(&off, 0.9));
    assert!(pct(&radial, 0.5) < 10.0 && pct(&radial, 0.9) < 25.0, "normals: median {:.1}, 90% {:.1} deg", pct(&radial, 0.5), pct(&radial, 0.9));
    // Deterministic.
    assert_eq!(seeds, residual_hull_seeds(&sv, &p));

    // The default normal faces the camera whose ray found the seed: the
    // same seeds, each normal the unit direction to one of the cameras
    // (and not to the same one for all).
    let pv = SeedParams { normal: SeedNormal::View, ..p };
    let view = residual_hull_seeds(&sv, &pv);
    assert_eq!(view.len(), seeds.len());
    let mut used = std::collections::BTreeSet::new();
    for (v, s) in view.iter().zip(&seeds) {
        assert_eq!((v.position, v.scale), (s.position, s.scale));
        let n = v.normal.map(f64::from);
        let x = v.position.map(f64::from);
        let best = cams
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let d = sub(c.centre().map(f64::from), x);
                (dot(n, d) / dot(d, d).sqrt(), i)
            })
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .unwrap();
        assert!(best.0 > 1.0 - 1e-5, "seed normal {n:?} faces no camera (best cosine {})", best.0);
        used.insert(best.1);
    }
    assert!(used.len() > 1, "every seed faces one camera");
    assert_eq!(view, residual_hull_seeds(&sv, &pv));

    // "gradient": against the gradient of the views' blurred masks summed
    // at the seed's projections, the silhouette cones' normal. The same
    // seeds; on the sphere far closer to radial than the camera direction
    // (measured: median 11.6 / 45.6 degrees, 90% 16.4 / 72.0).
    let pg = SeedParams { normal: SeedNormal::Gradient, ..p };
    let grad = residual_hull_seeds(&sv, &pg);
    assert_eq!(grad.len(), seeds.len());
    let (eg, ev) = (radial_error(&grad), radial_error(&view));
    for (g, s) in grad.iter().zip(&seeds) {
        assert_eq!((g.position, g.scale), (s.position, s.scale));
        let n = g.normal.map(f64::from);
        assert!((dot(n, n) - 1.0).abs() < 1e-4, "{g:?}");
    }
    assert!(pct(&eg, 0.5) < 20.0 && pct(&eg, 0.9) < 30.0, "gradient normals: median {:.1}, 90% {:.1} deg", pct(&eg, 0.5), pct(&eg, 0.9));
    assert!(pct(&eg, 0.5) + 20.0 < pct(&ev, 0.5), "gradient median {:.1} against view {:.1} deg", pct(&eg, 0.5), pct(&ev, 0.5));
    assert_eq!(grad, residual_hull_seeds(&sv, &pg));

    // "halfway": the unit bisector of the two, seed by seed (the camera
    // direction where the field is flat: there the gradient's normal is
    // the camera's too); on the sphere between them.
    let ph = SeedParams { normal: SeedNormal::Halfway, ..p };
    let half = residual_hull_seeds(&sv, &ph);
    assert_eq!(half.len(), seeds.len());
    for ((h, g), v) in half.iter().zip(&grad).zip(&view) {
        assert_eq!((h.position, h.scale), (g.position, g.scale));
        let (nh, ng, nv) = (h.normal.map(f64::from), g.normal.map(f64::from), v.normal.map(f64::from));
        let b = [ng[0] + nv[0], ng[1] + nv[1], ng[2] + nv[2]];
        let bl = dot(b, b).sqrt();
        assert!(bl > 1.0, "gradient {ng:?} and view {nv:?} normals not in one hemisphere");
        let cos = dot(nh, b) / bl;
        assert!(cos > 1.0 - 1e-5 && (dot(nh, nh) - 1.0).abs() < 1e-4, "halfway {nh:?} against the bisector of {ng:?} and {nv:?}");
    }
    let eh = radial_error(&half);
    assert!(
        pct(&eh, 0.5) < pct(&ev, 0.5) - 10.0 && pct(&eh, 0.5) > pct(&eg, 0.5),
        "halfway median {:.1} against gradient {:.1} and view {:.1} deg",
        pct(&eh, 0.5),
        pct(&eg, 0.5),
        pct(&ev, 0.5)
    );
    assert_eq!(half, residual_hull_seeds(&sv, &ph));
}

#[test]
fn no_residual_no_seeds() {
    let (cams, res, depth) = views(0.05, false);
    let sv = seed_views(&cams, &res, &depth);
    // Only scattered noise: blurred below the threshold everywhere.
    assert!(residual_hull_seeds(&sv, &SeedParams::default()).is_empty());
    // Nothing at all, one view, empty and 1-pixel images: no seeds, no panic.
    let zero = vec![0.0f32; (SIZE * SIZE) as usize];
    let sv0: Vec<SeedView> = cams.iter().map(|c| SeedView { camera: *c, residual: &zero, depth: &zero }).collect();
    assert!(residual_hull_seeds(&sv0, &SeedParams::default()).is_empty());
    let one = [1.0f32];
    let tiny = Camera::look_at([3.0, 0.0, 0.0], [0.0; 3], [0.0, 0.0, 1.0], 0.7, 1, 1);
    let sv1 = [SeedView { camera: tiny, residual: &one, depth: &one }];
    assert!(residual_hull_seeds(&sv1, &SeedParams::default()).is_empty());
    assert!(residual_hull_seeds(&[], &SeedParams::default()).is_empty());
    // Residual everywhere, no Stage I surface anywhere: rays run to the
    // largest depth seen (none: no seeds) without NaN.
    let all = vec![1.0f32; (SIZE * SIZE) as usize];
    let sv2: Vec<SeedView> = cams.iter().map(|c| SeedView { camera: *c, residual: &all, depth: &zero }).collect();
    assert!(residual_hull_seeds(&sv2, &SeedParams::default()).is_empty());
}

/// Glass that fills every view (`lantern`): residual on every pixel, the
/// opaque ball behind it. Every point between the cameras and the ball
/// projects onto residual everywhere, so nothing is carved and no ray has
/// evidence of where a surface starts: no seeds, rather than seeds at the
/// near end of every ray.
#[test]
fn residual_over_every_view_seeds_nothing() {
    let (cams, _, depth) = views(0.0, false);
    let all = vec![0.03f32; (SIZE * SIZE) as usize];
    let sv: Vec<SeedView> = cams.iter().zip(&depth).map(|(c, z)| SeedView { camera: *c, residual: &all, depth: z }).collect();
    // Without the significance test, which alone would empty this hull
    // (masks that cover every pixel make no agreement significant): the
    // carving is what is tested here.
    let p = SeedParams { max_rays: 2000, significance: 1.0, ..SeedParams::default() };
    assert!(residual_hull_seeds(&sv, &p).is_empty());
    // The silhouette case still seeds (its rays cross carved air first).
    let (cams, res, depth) = views(0.0, true);
    let sv = seed_views(&cams, &res, &depth);
    assert!(residual_hull_seeds(&sv, &p).len() > 500);
}

/// `min_hits` against the binomial tail summed term by term in f64 from
/// the factorials: k is the fewest hits whose tail is within alpha, and
/// one fewer is not.
#[test]
fn min_hits_is_the_binomial_tail_quantile() {
    fn tail(n: usize, k: usize, p: f64) -> f64 {
        let choose = |n: usize, j: usize| (0..j).fold(1.0f64, |c, i| c * (n - i) as f64 / (i + 1) as f64);
        (k..=n).map(|j| choose(n, j) * p.powi(j as i32) * (1.0 - p).powi((n - j) as i32)).sum()
    }
    for &(p, alpha) in &[(0.3, 1e-3), (0.6, 1e-6), (0.65, 1e-10), (0.05, 0.05), (0.9, 1e-3)] {
        let k = min_hits(120, p, alpha);
        assert_eq!(k.len(), 121);
        assert_eq!(k[0], 1, "no view: never significant");
        for n in 0..=120usize {
            let kn = k[n] as usize;
            assert!(kn <= n + 1, "n {n}: k {kn}");
            if kn <= n {
                let t = tail(n, kn, p);
                assert!(t <= alpha * (1.0 + 1e-9), "p {p} alpha {alpha} n {n}: tail at k {kn} is {t}");
            }
            if kn > 0 {
                let t = tail(n, kn - 1, p);
                assert!(t > alpha * (1.0 - 1e-9), "p {p} alpha {alpha} n {n}: k {kn} is not the fewest (tail at {} is {t})", kn - 1);
            }
            if n > 0 {
                assert!(k[n] >= k[n - 1] && k[n] <= k[n - 1] + 1, "p {p} alpha {alpha}: k jumps at n {n}: {} -> {}", k[n - 1], k[n]);
            }
        }
        // Enough views always suffice.
        assert!(k[120] <= 120, "p {p} alpha {alpha}: 120 agreeing views not significant");
    }
    // No test, masks that cover nothing or everything.
    assert!(min_hits(10, 0.5, 1.0).iter().all(|&k| k == 0));
    assert!(min_hits(10, 0.0, 1e-6).iter().all(|&k| k == 0));
    assert!(min_hits(10, 1.0, 1e-6).iter().enumerate().all(|(n, &k)| k == n as u32 + 1));
    assert!(min_hits(0, 0.5, 1e-6) == vec![1]);
}

/// Residual over a large share of every view (path-tracing noise, a
/// textured floor) besides the glass: a point near the cameras, seen by a
/// few views, lands on residual in 90% of them by chance, and it lies in
/// front of everything else on its ray. Without the significance test the
/// seeds float in front of the glass; the stricter the test, the more of
/// them are back on it (measured, 48 views, 30% noise pixels: 7.8% of the
/// seeds within 0.05 of the glass without it, 36.7% at 1e-6, 84.7% at 1e-8).
#[test]
fn seeds_on_the_glass_through_dense_residual_noise() {
    let (cams, res, depth) = ring(48, 0.3, true);
    let sv = seed_views(&cams, &res, &depth);
    let near = |set: &[Seed]| {
        set.iter()
            .filter(|s| {
                let x = s.position.map(f64::from);
                (dot(x, x).sqrt() - SPHERE_R).abs() < 0.05
            })
            .count() as f64
            / set.len().max(1) as f64
    };
    let base = SeedParams { max_rays: 3000, ..SeedParams::default() };
    let at = |a: f64| residual_hull_seeds(&sv, &SeedParams { significance: a, ..base });
    let (loose, default, tight) = (at(1.0), at(base.significance), at(1e-8));
    eprintln!(
        "within 0.05 of the glass: {:.1}% of {} seeds without the test, {:.1}% of {} at {:e}, {:.1}% of {} at 1e-8",
        100.0 * near(&loose),
        loose.len(),
        100.0 * near(&default),
        default.len(),
        base.significance,
        100.0 * near(&tight),
        tight.len()
    );
    assert!(near(&loose) < 0.2, "without the test: {:.2} on the glass", near(&loose));
    assert!(near(&default) > 2.0 * near(&loose), "default {:.2} against {:.2} without", near(&default), near(&loose));
    assert!(tight.len() > 300 && near(&tight) > 0.75, "at 1e-8: {} seeds, {:.2} on the glass", tight.len(), near(&tight));
    assert_eq!(tight, at(1e-8));
    // Stage II's seeding (one march for both hulls): the test's seeds where
    // any point beats chance; where none can (1e-300 needs more than 48
    // views), the hull's without the test, and it says so: on each ray the
    // agreeing point the most views agree on instead of the first (which
    // few views see, near the cameras), so as many seeds, more on the glass.
    let seeding = |a: f64| hull_seeding(&sv, &SeedParams { significance: a, ..base });
    let plain = HullSeeding {
        seeds: tight.clone(),
        rim_views: 0,
        rim_curved: 0,
        rim_seeds: 0,
        plane_pieces: 0,
        plane_seeds: 0,
        faces: [0, 0],
        significance_dropped: false,
        significance_relaxed: None,
    };
    assert_eq!(seeding(1e-8), plain);
    assert_eq!(seeding(1.0), HullSeeding { seeds: loose.clone(), ..plain.clone() });
    assert!(at(1e-300).is_empty(), "1e-300 is beaten by chance with 48 views");
    let dropped = seeding(1e-300);
    assert!(dropped.significance_dropped);
    assert_eq!(dropped.seeds.len(), loose.len());
    // Views whose image the seed projects into.
    let seen_by = |s: &Seed| cams.iter().filter(|c| pixel_of(c, s.position.map(f64::from)).is_some()).count();
    let mean_seen = |set: &[Seed]| set.iter().map(seen_by).sum::<usize>() as f64 / set.len().max(1) as f64;
    eprintln!(
        "without the test, first agreeing / most agreeing point: {:.1}% / {:.1}% within 0.05 of the glass, seen by {:.1} / {:.1} views",
        100.0 * near(&loose),
        100.0 * near(&dropped.seeds),
        mean_seen(&loose),
        mean_seen(&dropped.seeds)
    );
    assert!(near(&dropped.seeds) > near(&loose) + 0.1, "most agreeing {:.2} against first agreeing {:.2} on the glass", near(&dropped.seeds), near(&loose));
    assert!(mean_seen(&dropped.seeds) > mean_seen(&loose));
    // There the masks have no outline to take a normal from: the seeds
    // face the camera that found them, whatever `normal` asks for.
    assert_eq!(base.normal, SeedNormal::Halfway);
    for sd in &dropped.seeds {
        let (n, x) = (sd.normal.map(f64::from), sd.position.map(f64::from));
        let best = cams
            .iter()
            .map(|c| {
                let d = sub(c.centre().map(f64::from), x);
                dot(n, d) / dot(d, d).sqrt()
            })
            .fold(-1.0f64, f64::max);
        assert!(best > 1.0 - 1e-5, "fallback seed normal {n:?} faces no camera (best cosine {best})");
    }
    assert_eq!(seeding(1e-300), dropped);
    assert_eq!(hull_seeding(&sv, &SeedParams { significance: 1e-300, normal: SeedNormal::View, ..base }), dropped);
    // Looser levels before that fallback (`relax`; Stage II's with masks): the first that some point beats, not one below the test's.
    assert_eq!(hull_seeding(&sv, &SeedParams { significance: 1e-300, relax: &[1e-301, 1e-8, 1.0], ..base }), HullSeeding { significance_relaxed: Some(1e-8), ..plain });
}

/// The march and the normals run on threads, each on a contiguous run of
/// rays or seeds: the seeds must be the same, bit for bit and in order, at
/// any thread count, for every kind of normal (the gradient and the plane
/// read every view and every other seed).
#[test]
fn seeds_are_the_same_at_any_thread_count() {
    let (cams, res, depth) = ring(24, 0.1, true);
    let sv = seed_views(&cams, &res, &depth);
    for normal in [SeedNormal::View, SeedNormal::Plane, SeedNormal::Consensus, SeedNormal::Gradient, SeedNormal::Halfway] {
        let at = |threads: usize| hull_seeding(&sv, &SeedParams { max_rays: 1500, normal, threads, ..SeedParams::default() });
        let one = at(1);
        assert!(one.seeds.len() > 200, "{normal:?}: {} seeds", one.seeds.len());
        for threads in [2, 3, 7, 0] {
            assert_eq!(at(threads), one, "{normal:?}: {threads} threads against 1");
        }
    }
}

/// A uniform draw in [-1, 1).
fn signed(r: &mut Rng) -> f64 {
    r.next_u32() as f64 / 2f64.powi(31) - 1.0
}

/// The angle in degrees between `n` and the line along `want` (sign free).
fn off_axis(n: [f64; 3], want: [f64; 3]) -> f64 {
    dot(n, want).abs().min(1.0).acos().to_degrees()
}

/// The smallest-eigenvalue direction of the points' covariance: the
/// 16-neighbour plane [`SeedNormal::Plane`] takes, computed here anew.
fn pca_normal(pts: &[[f64; 3]]) -> [f64; 3] {
    let n = pts.len() as f64;
    let m = [0, 1, 2].map(|k| pts.iter().map(|p| p[k]).sum::<f64>() / n);
    let c = [0, 1, 2].map(|r| [0, 1, 2].map(|s| pts.iter().map(|p| (p[r] - m[r]) * (p[s] - m[s])).sum::<f64>()));
    let (vals, vecs) = jacobi_eigen(c);
    let k = (0..3).min_by(|&a, &b| vals[a].total_cmp(&vals[b])).unwrap();
    [vecs[0][k], vecs[1][k], vecs[2][k]]
}

/// The `k` points of `cloud` nearest `x` (itself excluded), nearest first.
fn nearest(cloud: &[[f64; 3]], x: [f64; 3], k: usize) -> Vec<[f64; 3]> {
    let mut d: Vec<(f64, [f64; 3])> = cloud.iter().filter(|p| **p != x).map(|p| (dot(sub(*p, x), sub(*p, x)), *p)).collect();
    d.sort_by(|a, b| a.0.total_cmp(&b.0));
    d.into_iter().take(k).map(|a| a.1).collect()
}

/// A mask hull's points scatter about a pane by as much as their spacing
/// (`pane` at 50²): the plane of 16 neighbours is then tilted far off, the
/// plane most of 128 lie on is not. Where two panes meet, a point on one
/// takes that one's normal rather than a blend of the two.
#[test]
fn consensus_normal_finds_a_scattered_pane_and_one_side_of_a_corner() {
    let mut r = Rng(seed("consensus_normal"));
    // A 2 x 2 pane z = 0, 1,600 points, spacing 0.05, scattered +-0.05.
    let pane: Vec<[f64; 3]> = (0..1600).map(|_| [signed(&mut r), signed(&mut r), 0.05 * signed(&mut r)]).collect();
    let (mut ours, mut sixteen) = (0.0, 0.0);
    let inner: Vec<[f64; 3]> = pane.iter().filter(|p| p[0].abs() < 0.6 && p[1].abs() < 0.6).copied().collect();
    for (i, &x) in inner.iter().enumerate() {
        let n = consensus_normal(x, &nearest(&pane, x, 128), 0.08, i as u64).expect("a plane");
        ours += off_axis(n, [0.0, 0.0, 1.0]) / inner.len() as f64;
        let mut local = nearest(&pane, x, 16);
        local.push(x);
        sixteen += off_axis(pca_normal(&local), [0.0, 0.0, 1.0]) / inner.len() as f64;
    }
    eprintln!("pane: mean normal error {ours:.1} deg (the 16 nearest's plane: {sixteen:.1})");
    assert!(ours < 4.0 && sixteen > 2.0 * ours, "consensus {ours:.1} deg, 16-point plane {sixteen:.1}");
    // The same seed and points give the same normal.
    let x = inner[0];
    assert_eq!(consensus_normal(x, &nearest(&pane, x, 128), 0.08, 7), consensus_normal(x, &nearest(&pane, x, 128), 0.08, 7));
    // A corner: the pane z = 0 (x < 0) meets the pane x = 0 (z < 0);
    // points on the first, 0.05 to 0.2 from the edge, keep its normal.
    let mut corner: Vec<[f64; 3]> = pane.iter().map(|p| [-0.5 * (p[0] + 1.0), p[1], 0.3 * p[2]]).collect();
    corner.extend(pane.iter().map(|p| [0.3 * p[2], p[1], -0.5 * (p[0] + 1.0)]));
    let near_edge: Vec<[f64; 3]> = corner.iter().filter(|p| (-0.2..-0.05).contains(&p[0]) && p[1].abs() < 0.5 && p[2].abs() < 0.05).copied().collect();
    assert!(near_edge.len() > 20, "{} points near the edge", near_edge.len());
    // A point at the edge of the scatter, within 0.07 of the corner, may
    // find more of its neighbours on a plane across the corner than on
    // one parallel to its own pane, 10-70 degrees off (15 of 36,325
    // points over 300 runs; 13 runs had one or two): up to 5% are allowed.
    let (mut blend, mut mean, mut off) = (0.0, 0.0, 0usize);
    for (i, &x) in near_edge.iter().enumerate() {
        let n = consensus_normal(x, &nearest(&corner, x, 128), 0.02, i as u64).expect("a plane");
        let e = off_axis(n, [0.0, 0.0, 1.0]);
        (mean, off) = (mean + e / near_edge.len() as f64, off + (e > 10.0) as usize);
        blend += off_axis(pca_normal(&nearest(&corner, x, 128)), [0.0, 0.0, 1.0]) / near_edge.len() as f64;
    }
    eprintln!("corner: mean normal error {mean:.1} deg, {off} of {} over 10 (the 128 nearest's plane: {blend:.1})", near_edge.len());
    assert!(mean < 4.0 && off * 20 <= near_edge.len() && blend > 10.0, "consensus {mean:.1} deg, {off} over 10; 128-point plane {blend:.1}");
    // Too few points, or all on one line: no plane.
    assert_eq!(consensus_normal([0.0; 3], &[[1.0, 0.0, 0.0], [2.0, 0.0, 0.0]], 0.1, 0), None);
    assert_eq!(consensus_normal([0.0; 3], &[[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [-1.0, 0.0, 0.0]], 0.1, 0), None);
}
