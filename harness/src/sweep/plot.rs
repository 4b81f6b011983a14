//! The sweep's plots (plotters, PNG): test PSNR and normal MAE against
//! training wall time, every run a point, the Pareto front joined and its
//! runs named.

use super::{pareto, Row};
use anyhow::{anyhow, Result};
use plotters::prelude::*;
use std::path::Path;

pub fn draw(dir: &Path, rows: &[Row]) -> Result<()> {
    one(&dir.join("psnr_vs_time.png"), rows, ("test PSNR (dB)", "higher is better"), |r| r.psnr, true)?;
    one(&dir.join("normal_mae_vs_time.png"), rows, ("test normal MAE on the glass (degrees)", "lower is better"), |r| r.normal_mae_deg, false)
}

/// Lower and upper bounds of `v` with 8% margins (a unit span when flat).
fn range(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = v.filter(|x| x.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x), b.max(x)));
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.08).max(0.5 * (hi.abs() * 1e-3).max(1e-3));
    (lo - pad, hi + pad)
}

fn one(path: &Path, rows: &[Row], (what, better): (&str, &str), y: impl Fn(&Row) -> f64, higher_better: bool) -> Result<()> {
    let err = |e: &dyn std::fmt::Display| anyhow!("{}: drawing the plot: {e}", path.display());
    let root = BitMapBackend::new(path, (960, 640)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let (x0, x1) = range(rows.iter().map(|r| r.wall_s).chain([0.0]));
    // Room on the right for the names of the front's runs.
    let x1 = x1 + 0.25 * (x1 - x0);
    let (y0, y1) = range(rows.iter().map(&y));
    let mut chart = ChartBuilder::on(&root)
        .caption(format!("{what} vs training wall time ({better})"), ("sans-serif", 22))
        .margin(16)
        .x_label_area_size(44)
        .y_label_area_size(64)
        .build_cartesian_2d(x0.max(0.0)..x1, y0..y1)
        .map_err(|e| err(&e))?;
    chart.configure_mesh().x_desc("training wall time (s)").y_desc(what).draw().map_err(|e| err(&e))?;
    let pts: Vec<(f64, f64)> = rows.iter().map(|r| (r.wall_s, y(r))).filter(|p| p.0.is_finite() && p.1.is_finite()).collect();
    chart.draw_series(pts.iter().map(|&p| Circle::new(p, 4, BLUE.mix(0.7).filled()))).map_err(|e| err(&e))?.label("run").legend(|(x, y)| Circle::new((x, y), 4, BLUE.filled()));
    let front = pareto(rows, |r| if higher_better { y(r) } else { -y(r) });
    let line: Vec<(f64, f64)> = front.iter().map(|&i| (rows[i].wall_s, y(&rows[i]))).collect();
    chart.draw_series(LineSeries::new(line.clone(), RED.stroke_width(2))).map_err(|e| err(&e))?.label("Pareto front").legend(|(x, y)| PathElement::new([(x - 8, y), (x + 8, y)], RED.stroke_width(2)));
    chart.draw_series(line.iter().map(|&p| Circle::new(p, 6, RED.stroke_width(2)))).map_err(|e| err(&e))?;
    chart
        .draw_series(front.iter().map(|&i| EmptyElement::at((rows[i].wall_s, y(&rows[i]))) + Text::new(rows[i].name.clone(), (8, -16), ("sans-serif", 13).into_font().color(&BLACK))))
        .map_err(|e| err(&e))?;
    chart.configure_series_labels().border_style(BLACK).background_style(WHITE.mix(0.8)).position(SeriesLabelPosition::LowerRight).draw().map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}
