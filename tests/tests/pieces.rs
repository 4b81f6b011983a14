//! The reflection set's pieces and their verdict on the validation views
//! (issue 77, `stages/reflection/pieces.rs`): the partition against a
//! brute-force reference, the per-piece errors and their spread over tiles
//! against an f64 reference, and the keep/drop rule on pieces whose answer
//! is known. CPU only.

use tgs::train::stages::reflection::pieces::{count, partition, verdicts, PieceErrors, BLOCK, MAX_PIECES};
use tgs_tests::Rng;

fn uniform(r: &mut Rng) -> f32 {
    r.next_u32() as f32 / u32::MAX as f32
}

/// Points of `blobs` (centre, count, radius) in a shuffled order.
fn blobs(r: &mut Rng, blobs: &[([f32; 3], usize, f32)]) -> Vec<[f32; 3]> {
    let mut pts = Vec::new();
    for &(c, n, rad) in blobs {
        for _ in 0..n {
            pts.push(std::array::from_fn(|k| c[k] + rad * (2.0 * uniform(r) - 1.0)));
        }
    }
    for i in (1..pts.len()).rev() {
        pts.swap(i, r.below(i as u32 + 1) as usize);
    }
    pts
}

/// Whether two labellings put the same points together.
fn same_grouping(a: &[u32], b: &[u32]) -> bool {
    (0..a.len()).all(|i| (0..a.len()).all(|j| (a[i] == a[j]) == (b[i] == b[j])))
}

/// The brute-force partition for one cell: points within `link` of each
/// other joined, transitively (O(n²) flood fill).
fn reference_components(pts: &[[f32; 3]], link: f64) -> Vec<u32> {
    let mut label = vec![u32::MAX; pts.len()];
    let mut next = 0;
    for s in 0..pts.len() {
        if label[s] != u32::MAX {
            continue;
        }
        let mut stack = vec![s];
        label[s] = next;
        while let Some(i) = stack.pop() {
            for j in 0..pts.len() {
                let d2: f64 = (0..3).map(|k| (pts[i][k] as f64 - pts[j][k] as f64).powi(2)).sum();
                if label[j] == u32::MAX && d2 <= link * link {
                    label[j] = next;
                    stack.push(j);
                }
            }
        }
        next += 1;
    }
    label
}

#[test]
fn partition_matches_a_brute_force_reference() {
    let seed = tgs_tests::seed("partition_matches_a_brute_force_reference");
    let mut r = Rng(seed);
    // Three blobs 1 apart inside a set 2.2 long: one cell along it links at 1.1.
    let pts = blobs(&mut r, &[([0.0; 3], 200, 0.1), ([1.0, 0.0, 0.0], 120, 0.1), ([2.0, 0.0, 0.0], 60, 0.1)]);
    let means: Vec<f32> = pts.iter().flatten().copied().collect();
    let one = partition(&means, 1);
    assert_eq!(count(&one), 1, "blobs a link apart are one piece");
    // Three cells (edges near 0.63 and 1.35): the link (half a cell, ~0.36)
    // separates the blobs, the cells cut none of them apart.
    let three = partition(&means, 3);
    assert_eq!(count(&three), 3, "seed {seed}");
    assert!(same_grouping(&three, &reference_components(&pts, 0.3)), "seed {seed}: not the blobs");
    // Largest first.
    let size = |l: u32| three.iter().filter(|&&x| x == l).count();
    assert_eq!((size(0), size(1), size(2)), (200, 120, 60));
    // The labels do not depend on the order the Gaussians come in.
    let rev: Vec<f32> = pts.iter().rev().flatten().copied().collect();
    let back: Vec<u32> = partition(&rev, 3).into_iter().rev().collect();
    assert_eq!(back, three, "seed {seed}: order changed the labels");
    // Cells (~0.27) about a blob's size cut some: no piece spans more than a cell.
    let fine = partition(&means, 8);
    assert!(count(&fine) > 3);
    for l in 0..count(&fine) as u32 {
        let xs: Vec<f32> = pts.iter().zip(&fine).filter(|(_, &f)| f == l).map(|(p, _)| p[0]).collect();
        let span = xs.iter().cloned().fold(f32::MIN, f32::max) - xs.iter().cloned().fold(f32::MAX, f32::min);
        assert!(span <= 0.3, "piece {l} spans {span} along x, over a cell");
    }
    // Many separate strays: at most MAX_PIECES labels, the rest sharing the last.
    let strays: Vec<f32> = (0..200).flat_map(|i| [i as f32, 0.0, 0.0]).collect();
    assert_eq!(count(&partition(&strays, 64)), MAX_PIECES);
    assert!(partition(&[], 4).is_empty());
    // Non-finite means do not panic and get a piece.
    assert_eq!(partition(&[f32::NAN, 0.0, 0.0, 1.0, 1.0, 1.0], 2).len(), 2);
}

/// One view of a piece: width, height, the render with it, without it, the target.
type PieceView = (usize, usize, Vec<f32>, Vec<f32>, Vec<f32>);

/// f64 reference of a piece's errors over views: pixels, the two error sums, z.
fn reference_errors(views: &[PieceView]) -> (u64, f64, f64, f64) {
    let (mut pixels, mut sw, mut swo) = (0u64, 0.0, 0.0);
    let mut tiles: Vec<f64> = Vec::new();
    for (w, h, with, without, target) in views {
        let n = w * h;
        for ty in (0..*h).step_by(BLOCK) {
            for tx in (0..*w).step_by(BLOCK) {
                let mut tile = None;
                for y in ty..(ty + BLOCK).min(*h) {
                    for x in tx..(tx + BLOCK).min(*w) {
                        let i = y * w + x;
                        if !(0..3).any(|c| (with[c * n + i] - without[c * n + i]).abs() > 1e-5) {
                            continue;
                        }
                        pixels += 1;
                        let e = |img: &[f32]| (0..3).map(|c| (img[c * n + i] as f64 - target[c * n + i] as f64).powi(2)).sum::<f64>();
                        sw += e(with);
                        swo += e(without);
                        tile = Some(tile.unwrap_or(0.0) + e(without) - e(with));
                    }
                }
                tiles.extend(tile);
            }
        }
    }
    let b = tiles.len() as f64;
    let mean = tiles.iter().sum::<f64>() / b;
    let se = (tiles.iter().map(|t| (t - mean).powi(2)).sum::<f64>() / (b - 1.0) * b).sqrt();
    (pixels, sw, swo, (swo - sw) / se)
}

#[test]
fn piece_errors_match_an_f64_reference() {
    let seed = tgs_tests::seed("piece_errors_match_an_f64_reference");
    let mut r = Rng(seed);
    let mut views = Vec::new();
    let mut e = PieceErrors::default();
    // Sizes not multiples of the tile, a 1-pixel view, a view the piece does not touch.
    for (w, h) in [(37, 21), (1, 1), (16, 9), (5, 5)] {
        let n = w * h;
        let target: Vec<f32> = (0..3 * n).map(|_| uniform(&mut r)).collect();
        let with: Vec<f32> = (0..3 * n).map(|_| uniform(&mut r)).collect();
        let touched = (w, h) != (5, 5);
        let without: Vec<f32> = with.iter().map(|&v| if touched && uniform(&mut r) < 0.6 { v + 0.3 * (uniform(&mut r) - 0.4) } else { v }).collect();
        e.add(&with, &without, &target, w, h);
        views.push((w, h, with, without, target));
    }
    let (pixels, sw, swo, z) = reference_errors(&views);
    assert_eq!(e.pixels, pixels, "seed {seed}");
    assert!((e.sse_with - sw).abs() < 1e-9 * sw.max(1.0) && (e.sse_without - swo).abs() < 1e-9 * swo.max(1.0), "seed {seed}");
    assert!((e.z() - z).abs() < 1e-9 * z.abs().max(1.0), "seed {seed}: z {} against {z}", e.z());
    assert!((e.gain_db() - 10.0 * (swo / sw).log10()).abs() < 1e-9);
    // Two standard errors off the removed error, in dB.
    let se = (swo - sw) / z;
    assert!((e.gain_db_at(2.0) - 10.0 * ((swo - 2.0 * se) / sw).log10()).abs() < 1e-9);
    assert!(e.gain_db_at(2.0) < e.gain_db() && e.gain_db() < e.gain_db_at(-2.0));
}

/// A piece over `tiles` views of one 8×8 tile each, whose removal changes
/// every pixel: squared error `a` a channel with it, `b` plus `noise`
/// (uniform, zero mean, one draw a tile) without it.
fn piece(tiles: usize, a: f32, b: f32, noise: f32, r: &mut Rng) -> PieceErrors {
    let mut e = PieceErrors::default();
    let n = BLOCK * BLOCK;
    for _ in 0..tiles {
        let without = (b + noise * (2.0 * uniform(r) - 1.0)).max(0.0).sqrt();
        e.add(&vec![0.5 + a.sqrt(); 3 * n], &vec![0.5 + without; 3 * n], &vec![0.5; 3 * n], BLOCK, BLOCK);
    }
    e
}

#[test]
fn the_rule_keeps_what_lowers_the_error_and_drops_the_rest() {
    let mut r = Rng(7);
    let labels = [0u32, 1, 2, 3];
    let means = [0.0f32; 12];
    let helps = piece(40, 0.0025, 0.04, 0.002, &mut r);
    let harms = piece(40, 0.04, 0.0025, 0.002, &mut r);
    // No gain on average: the error without swings either side of the error with.
    let noise = piece(40, 0.01, 0.01, 0.008, &mut r);
    let nothing = PieceErrors::default();
    assert!(helps.z() > 10.0 && harms.z() < -10.0 && noise.z().abs() < 2.0, "{} {} {}", helps.z(), harms.z(), noise.z());
    let errors = [helps, harms, noise, nothing];
    let kept = |z: f64, margin: f64| verdicts(&labels, &means, &errors, margin, z).iter().map(|v| v.kept).collect::<Vec<_>>();
    // Benefit of the doubt (z = -2): the noise stays; harm and a piece that changes nothing go.
    assert_eq!(kept(-2.0, 0.0), [true, false, true, false]);
    // Sure of the gain (z = 2): the noise goes too.
    assert_eq!(kept(2.0, 0.0), [true, false, false, false]);
    // A margin no piece clears drops them all.
    assert_eq!(kept(-2.0, 100.0), [false; 4]);
    let v = verdicts(&labels, &means, &errors, 0.0, -2.0);
    assert_eq!((v[0].gaussians, v[3].pixels), (1, 0));
    assert!(v[0].gain_db > 0.0 && v[1].gain_db < 0.0);
}
