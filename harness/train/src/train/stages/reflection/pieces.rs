//! The reflection set in spatially separate pieces, each judged on the
//! validation views (issue 77: a piece stays only where it lowers their
//! error). Host-side and independent of the GPU: the partition, and the
//! per-piece error sums a verdict is drawn from.

use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// At most this many pieces are judged; smaller ones beyond are judged together.
pub const MAX_PIECES: usize = 48;

/// A pixel counts as the piece's where removing the piece moves a channel by more than this.
pub const CHANGE_EPS: f32 = 1e-5;

/// Labels (0..pieces) for the Gaussians at `means` (xyz each): connected
/// components at a linking distance of half a cell, cut further by a grid of
/// `cells` cells along the longest side of the set's bulk. Labels are ordered by piece
/// size (largest first, ties by the piece's first Gaussian); pieces past
/// [`MAX_PIECES`] − 1 share the last label. Deterministic for given means.
pub fn partition(means: &[f32], cells: u32) -> Vec<u32> {
    let n = means.len() / 3;
    if n == 0 {
        return Vec::new();
    }
    let p = |i: usize| [means[3 * i] as f64, means[3 * i + 1] as f64, means[3 * i + 2] as f64];
    // The grid spans the set's bulk (2nd to 98th percentile an axis), not a
    // few strays: those join its outer cells.
    let mut lo = [0.0f64; 3];
    let mut span = [0.0f64; 3];
    for k in 0..3 {
        let mut v: Vec<f64> = (0..n).map(|i| p(i)[k]).filter(|v| v.is_finite()).collect();
        v.sort_by(f64::total_cmp);
        if !v.is_empty() {
            let q = |f: f64| v[((v.len() - 1) as f64 * f).round() as usize];
            (lo[k], span[k]) = (q(0.02), q(0.98) - q(0.02));
        }
    }
    let side = span.iter().copied().fold(0.0f64, f64::max);
    let cell = if side > 0.0 { side / cells.max(1) as f64 } else { 1.0 };
    let link = 0.5 * cell;
    let across: [i64; 3] = std::array::from_fn(|k| ((span[k] / cell).ceil() as i64).max(1));
    let bin = |x: [f64; 3], size: f64| -> [i64; 3] { std::array::from_fn(|k| if x[k].is_finite() { ((x[k] - lo[k]) / size).floor() as i64 } else { i64::MIN }) };
    let grid_cell = |x: [f64; 3]| -> [i64; 3] {
        let b = bin(x, cell);
        std::array::from_fn(|k| b[k].clamp(0, across[k] - 1))
    };
    // Union-find over a hash grid of `link`-sized bins.
    let mut parent: Vec<usize> = (0..n).collect();
    let mut bins: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for i in 0..n {
        bins.entry(bin(p(i), link)).or_default().push(i);
    }
    for i in 0..n {
        let (a, b) = (p(i), bin(p(i), link));
        for d in 0..27i64 {
            let nb = [b[0].saturating_add(d % 3 - 1), b[1].saturating_add((d / 3) % 3 - 1), b[2].saturating_add(d / 9 - 1)];
            for &j in bins.get(&nb).map(Vec::as_slice).unwrap_or(&[]) {
                if j > i && (0..3).map(|k| (a[k] - p(j)[k]).powi(2)).sum::<f64>() <= link * link {
                    union(&mut parent, i, j);
                }
            }
        }
    }
    // A piece: a component within one grid cell.
    let mut ids: HashMap<(usize, [i64; 3]), usize> = HashMap::new();
    let mut raw = Vec::with_capacity(n);
    let mut sizes: Vec<(usize, usize)> = Vec::new(); // (count, first Gaussian)
    for i in 0..n {
        let root = find(&mut parent, i);
        let next = ids.len();
        let id = *ids.entry((root, grid_cell(p(i)))).or_insert(next);
        if id == sizes.len() {
            sizes.push((0, i));
        }
        sizes[id].0 += 1;
        raw.push(id);
    }
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    order.sort_by_key(|&id| (std::cmp::Reverse(sizes[id].0), sizes[id].1));
    let mut rank = vec![0u32; sizes.len()];
    for (r, &id) in order.iter().enumerate() {
        rank[id] = r.min(MAX_PIECES - 1) as u32;
    }
    raw.into_iter().map(|id| rank[id]).collect()
}

fn find(parent: &mut [usize], mut i: usize) -> usize {
    while parent[i] != i {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    i
}

fn union(parent: &mut [usize], a: usize, b: usize) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    // The smaller index is the root: the result does not depend on visiting order.
    if ra != rb {
        parent[ra.max(rb)] = ra.min(rb);
    }
}

/// One piece's squared errors over the validation pixels it changes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PieceErrors {
    /// Pixels whose colour the piece changes.
    pub pixels: u64,
    /// Sum over those pixels and channels of (render − target)², with the piece and without.
    pub sse_with: f64,
    pub sse_without: f64,
    /// Per [`BLOCK`]² tile of a view that the piece changes: its share of
    /// `sse_without − sse_with` (the samples of the gain's spread:
    /// neighbouring pixels' errors are not independent, tiles nearly are).
    pub blocks: Vec<f64>,
}

/// The side of the tiles the gain's spread is measured over (pixels).
pub const BLOCK: usize = 8;

impl PieceErrors {
    /// Add one view of `width` × `height`: `with` the whole set, `without`
    /// the piece, `target` (planes of `width` × `height`, as many each).
    pub fn add(&mut self, with: &[f32], without: &[f32], target: &[f32], width: usize, height: usize) {
        let pixels = width * height;
        let channels = with.len() / pixels.max(1);
        let tiles_x = width.div_ceil(BLOCK);
        let mut tiles = vec![None::<f64>; tiles_x * height.div_ceil(BLOCK)];
        for i in 0..pixels {
            let at = |c: usize| c * pixels + i;
            if !(0..channels).any(|c| (with[at(c)] - without[at(c)]).abs() > CHANGE_EPS) {
                continue;
            }
            self.pixels += 1;
            let (mut w, mut wo) = (0.0, 0.0);
            for c in 0..channels {
                let t = target[at(c)] as f64;
                w += (with[at(c)] as f64 - t).powi(2);
                wo += (without[at(c)] as f64 - t).powi(2);
            }
            self.sse_with += w;
            self.sse_without += wo;
            let tile = &mut tiles[(i / width) / BLOCK * tiles_x + (i % width) / BLOCK];
            *tile = Some(tile.unwrap_or(0.0) + wo - w);
        }
        self.blocks.extend(tiles.into_iter().flatten());
    }

    /// The piece's PSNR gain on its pixels (dB): how much worse they are
    /// without it. 0 where it changes no pixel (no evidence either way).
    pub fn gain_db(&self) -> f64 {
        self.gain_db_at(0.0)
    }

    /// The piece's gain (dB) with the error it removes taken `z` standard
    /// errors ([`Self::se`]) lower (negative `z`: higher); 0 where it
    /// changes no pixel.
    pub fn gain_db_at(&self, z: f64) -> f64 {
        if self.pixels == 0 {
            return 0.0;
        }
        let w = self.sse_with.max(1e-12);
        10.0 * ((self.sse_without - z * self.se()).max(1e-12) / w).log10()
    }

    /// The standard error of the error the piece removes
    /// (`sse_without − sse_with`), from its spread over tiles (0 with fewer
    /// than two tiles).
    pub fn se(&self) -> f64 {
        let b = self.blocks.len();
        if b < 2 {
            return 0.0;
        }
        let mean = self.blocks.iter().sum::<f64>() / b as f64;
        let var = self.blocks.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (b - 1) as f64;
        (var * b as f64).sqrt()
    }

    /// The error the piece removes in standard errors ([`Self::se`]): how
    /// far from chance its gain is (0 without a spread).
    pub fn z(&self) -> f64 {
        let se = self.se();
        if se > 0.0 {
            (self.sse_without - self.sse_with) / se
        } else {
            0.0
        }
    }
}

/// metrics.json's record of one piece (`reflection.pieces`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PieceVerdict {
    /// The piece's Gaussians (before the drop) and their mean position.
    pub gaussians: u32,
    pub centre: [f32; 3],
    /// Validation pixels it changes, and its PSNR gain there.
    pub pixels: u64,
    pub gain_db: f64,
    /// That gain in standard errors of its spread over tiles ([`PieceErrors::z`]).
    pub z: f64,
    pub kept: bool,
}

/// The verdicts of pieces labelled by `labels` (over Gaussians at
/// `means`) from their errors: kept where the piece changes a pixel and
/// its gain less `z` standard errors exceeds `margin_db`.
pub fn verdicts(labels: &[u32], means: &[f32], errors: &[PieceErrors], margin_db: f64, z: f64) -> Vec<PieceVerdict> {
    let mut out: Vec<PieceVerdict> = errors
        .iter()
        .map(|e| {
            let gain_db = e.gain_db();
            PieceVerdict { gaussians: 0, centre: [0.0; 3], pixels: e.pixels, gain_db, z: e.z(), kept: e.pixels > 0 && e.gain_db_at(z) > margin_db }
        })
        .collect();
    let mut sums = vec![[0.0f64; 3]; out.len()];
    for (i, &l) in labels.iter().enumerate() {
        let Some(v) = out.get_mut(l as usize) else { continue };
        v.gaussians += 1;
        for k in 0..3 {
            sums[l as usize][k] += means[3 * i + k] as f64;
        }
    }
    for (v, s) in out.iter_mut().zip(sums) {
        v.centre = s.map(|x| (x / v.gaussians.max(1) as f64) as f32);
    }
    out
}

/// The number of pieces `labels` name.
pub fn count(labels: &[u32]) -> usize {
    labels.iter().max().map_or(0, |&m| m as usize + 1)
}
