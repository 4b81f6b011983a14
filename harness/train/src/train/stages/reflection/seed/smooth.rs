//! Bilateral smoothing of the seeds' normals ([`SeedParams::smooth`]): a
//! mask hull bulges between the views that carve it (a glass box's faces
//! seen from 60 views at 50²: pillows 0.1 high at their middles), so each
//! seed's local plane leans 7–13° off a flat face, more where its
//! neighbourhood spans an edge. Each seed's normal becomes the mean of the
//! normals, within [`SMOOTH_DEGREES`] of its own (signs aligned), of its
//! nearest [`SMOOTH_SHARE`] of the seeds: over a face the lean averages
//! out, an edge is not crossed, and on a sphere the mean over a cap around
//! a point is that point's normal. One round only: repeated, the means
//! gather a curved surface into flat facets (a unit sphere's normals 1.4°
//! off radial after one round, 15° after six;
//! perf/journal/2026-12-06-sixty-fifth.md).

use super::{in_parallel, nearest, Seed};
use glam::DVec3;

/// The share of the seeds (the nearest to each) its mean reads.
pub const SMOOTH_SHARE: f64 = 0.25;
/// The most a neighbour's normal may turn from the seed's and count.
pub const SMOOTH_DEGREES: f64 = 30.0;

/// One round of smoothing of `seeds`' normals, each normal then turned to
/// the side it faced before. The same for any `threads` (each seed's mean
/// reads the normals as they were, in a fixed order).
pub fn smooth_normals(seeds: &mut [Seed], threads: usize) {
    if seeds.len() < 2 {
        return;
    }
    let pos: Vec<DVec3> = seeds.iter().map(|s| DVec3::from(s.position.map(f64::from))).collect();
    let n: Vec<DVec3> = seeds.iter().map(|s| DVec3::from(s.normal.map(f64::from)).normalize_or_zero()).collect();
    let k = ((SMOOTH_SHARE * seeds.len() as f64).ceil() as usize).clamp(1, seeds.len());
    let cos_min = SMOOTH_DEGREES.to_radians().cos();
    let index: Vec<usize> = (0..seeds.len()).collect();
    let mean = in_parallel(&index, threads, |run| {
        run.iter()
            .map(|&i| {
                let c = n[i];
                let sum: DVec3 = nearest(pos[i], pos.iter().copied(), None, k)
                    .into_iter()
                    .map(|(_, j)| (n[j], n[j].dot(c)))
                    .filter(|&(_, d)| d.abs() >= cos_min)
                    .map(|(m, d)| if d < 0.0 { -m } else { m })
                    .sum();
                sum.try_normalize().unwrap_or(c)
            })
            .collect::<Vec<_>>()
    })
    .concat();
    for (s, m) in seeds.iter_mut().zip(mean) {
        let old = DVec3::from(s.normal.map(f64::from));
        let m = if m.dot(old) < 0.0 { -m } else { m };
        s.normal = m.as_vec3().to_array();
    }
}
