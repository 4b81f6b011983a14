//! The reflection set's box: where the scene light is rendered from
//! (env_init = "scene"), the parallax proxy's centre, and Stage III's
//! normalisation of positions.

/// The box Phi's positions are normalized by: the reflection set's 1st-99th
/// percentile per axis, widened by 10% (so that x_refl of the covered
/// pixels lies mostly inside [-1, 1]^3).
pub fn normalization_box(means: &[f32]) -> ([f32; 3], [f32; 3]) {
    let n = means.len() / 3;
    let mut centre = [0.0; 3];
    let mut half = [1.0; 3];
    if n == 0 {
        return (centre, half);
    }
    for a in 0..3 {
        let mut v: Vec<f32> = (0..n).map(|i| means[3 * i + a]).filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            continue;
        }
        v.sort_by(f32::total_cmp);
        let q = |p: f64| v[((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
        let (lo, hi) = (q(0.01), q(0.99));
        centre[a] = 0.5 * (lo + hi);
        half[a] = (0.55 * (hi - lo)).max(1e-3);
    }
    (centre, half)
}
