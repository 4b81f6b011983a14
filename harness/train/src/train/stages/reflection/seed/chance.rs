//! How many of the views that see a point must agree for it to beat
//! chance ([`super::SeedParams::significance`]).

/// For each number of views n in 0..=`views`, the fewest hits k whose
/// one-sided binomial tail P(X >= k | n, `coverage`) is at most `alpha`
/// (n + 1 where none is): a point seen by n views whose residual masks
/// cover a fraction `coverage` of their pixels lands on residual in k of
/// them that often by chance alone. Where the residual covers most of
/// every image (path-tracing noise, a textured floor), a point seen by a
/// handful of views near the cameras passes 0.9 agreement by chance, and
/// it lies in front of everything the other rays would find.
pub fn min_hits(views: usize, coverage: f64, alpha: f64) -> Vec<u32> {
    let p = coverage.clamp(0.0, 1.0);
    // ln n! for n in 0..=views: the whole table is O(views^2) at worst.
    let ln_fact: Vec<f64> = std::iter::once(0.0)
        .chain((1..=views).scan(0.0f64, |acc, i| {
            *acc += (i as f64).ln();
            Some(*acc)
        }))
        .collect();
    (0..=views)
        .map(|n| {
            if alpha >= 1.0 || p <= 0.0 {
                return 0;
            }
            if p >= 1.0 {
                return n as u32 + 1;
            }
            // ln C(n, j) + j ln p + (n - j) ln(1 - p), summed from j = n down.
            let ln_pmf = |j: usize| ln_fact[n] - ln_fact[j] - ln_fact[n - j] + j as f64 * p.ln() + (n - j) as f64 * (1.0 - p).ln();
            let mut tail = 0.0f64;
            let mut k = n + 1;
            for j in (0..=n).rev() {
                let t = tail + ln_pmf(j).exp();
                if t > alpha {
                    break;
                }
                tail = t;
                k = j;
            }
            k as u32
        })
        .collect()
}
