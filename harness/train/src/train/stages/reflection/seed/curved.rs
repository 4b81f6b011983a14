//! A curved rim membrane: where a view's rim points lie off their plane the
//! way a bent front's do (a windshield, a section of a cylinder, whose
//! plane is its chord), 1 / z quadratic in the normalised image
//! coordinates through them instead: a ruled or gently curved front's rim
//! rings its inside, so the fit interpolates the bend between its edges;
//! where the rim runs along two edges only, a ridge ([`CURVE_RIDGE`])
//! keeps the bend the rim does not fix flat.

use super::geometry::{reweighted_fit, solve};
use super::membrane::Membrane;

/// The plane's median distance from its rim points (a share of their
/// depth) must exceed this for a curved membrane to be tried: below it the
/// points are on a plane to within Stage I's noise.
pub const CURVE_MIN: f64 = 0.004;
/// The curved membrane replaces the plane where it brings the points'
/// median distance to at most this share of the plane's: the suite's
/// curved front reads 0.52–0.82 a view, its flat fronts 0.87 and more
/// (perf/journal/2026-12-07-seventy-third.md).
pub const CURVE_GAIN: f64 = 0.7;

/// The curved membrane through `pts` ([x, y, 1 / z]) where they call for
/// it against their plane `flat` ([`CURVE_MIN`], [`CURVE_GAIN`]).
pub(super) fn curved(pts: &[[f64; 3]], flat: &Membrane) -> Option<Membrane> {
    // The plane first: where it fits, the six-term fit is not run at all.
    let f = median_off(pts, flat);
    if f <= CURVE_MIN {
        return None;
    }
    let c = fit_bent(pts)?;
    let bent = Membrane { coef: [c[0], c[1], c[2]], corner: None, bend: [c[3], c[4], c[5]] };
    (median_off(pts, &bent) <= CURVE_GAIN * f).then_some(bent)
}

/// The median distance of `pts` from `m`, as a share of their depth.
pub(super) fn median_off(pts: &[[f64; 3]], m: &Membrane) -> f64 {
    let mut off: Vec<f64> = pts.iter().map(|p| m.off(p)).collect();
    off.sort_by(f64::total_cmp);
    off.get(off.len() / 2).copied().unwrap_or(f64::INFINITY)
}

/// The ridge on the quadratic terms, a share of the points' weight times
/// their spread (mean x² + y²) squared: a rim seen along two edges only (a
/// windshield's top and bottom, its sides free) leaves the bend across them
/// unfixed, and the bare fit bowed the inside by the points' noise
/// (perf/journal/2026-12-08-seventy-fourth.md).
pub const CURVE_RIDGE: f64 = 0.01;

/// 1 / z = a x + b y + c + d x² + e x y + f y² through `pts` by the
/// plane's reweighted least squares ([`reweighted_fit`]), with
/// [`CURVE_RIDGE`] on d, e and f. None where the points do not fix the
/// plane's terms.
fn fit_bent(pts: &[[f64; 3]]) -> Option<[f64; 6]> {
    let ridged = |mut a: [[f64; 6]; 6], b: [f64; 6]| {
        // a[2][2] is the rows' weight; a[0][0] + a[1][1] their weighted x² + y².
        let spread = (a[0][0] + a[1][1]) / a[2][2];
        let ridge = CURVE_RIDGE * a[2][2] * spread * spread;
        for k in 3..6 {
            a[k][k] += ridge;
        }
        solve(a, b)
    };
    reweighted_fit(pts, |p| [p[0], p[1], 1.0, p[0] * p[0], p[0] * p[1], p[1] * p[1]], ridged)
}
