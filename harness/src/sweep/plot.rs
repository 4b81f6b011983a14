//! The sweep's plots (plotters, PNG): test PSNR and normal MAE against
//! training wall time, every run a point, the Pareto front joined. The
//! front's runs are numbered beside their points, each number placed where
//! it overlaps no other (`place_labels`), and named in a table to the right
//! of the chart. The time axis is logarithmic when the runs' times span more
//! than 5x (one slow run would otherwise squeeze the others together).

use super::{pareto, Row};
use anyhow::{anyhow, bail, Context, Result};
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Plot size; the chart takes the left `CHART_W` pixels, the table the rest.
const SIZE: (u32, u32) = (960, 640);
const CHART_W: u32 = 690;
/// Times spanning more than this ratio get a log axis.
const LOG_SPAN: f64 = 5.0;
/// Label font size and the width of one character in it (an over-estimate
/// for digits of a sans-serif face), in pixels.
const FONT: u32 = 13;
const CHAR_W: i32 = 8;

/// Where the text's face is looked for when `TGS_PLOT_FONT` is unset: the
/// paths of DejaVu Sans, Liberation Sans or FreeSans on Debian/Ubuntu,
/// Fedora, Arch and Alpine, and Arial on macOS. The text is drawn in pure
/// Rust (plotters' ab_glyph backend): tgs links no fontconfig or FreeType,
/// so its binary runs on a bare GPU server; only the plots need a font file.
const FONT_FILES: &[&str] = &[
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu-sans-fonts/DejaVuSans.ttf",
    "/usr/share/fonts/ttf-dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/liberation-sans/LiberationSans-Regular.ttf",
    "/usr/share/fonts/truetype/freefont/FreeSans.ttf",
    "/System/Library/Fonts/Supplemental/Arial.ttf",
    "/Library/Fonts/Arial.ttf",
];

/// The font file for the plots' text: `TGS_PLOT_FONT` (`env`) if set, which
/// must exist, else the first of `candidates` that does.
pub fn font_file(env: Option<OsString>, candidates: &[&str]) -> Result<PathBuf> {
    if let Some(p) = env.filter(|p| !p.is_empty()) {
        let p = PathBuf::from(p);
        if !p.is_file() {
            bail!("TGS_PLOT_FONT={}: no such file (a TrueType or OpenType font for the plots' text)", p.display());
        }
        return Ok(p);
    }
    candidates.iter().map(PathBuf::from).find(|p| p.is_file()).ok_or_else(|| {
        anyhow!("no font for the plots' text: set TGS_PLOT_FONT=FILE.ttf, or install DejaVu Sans (Debian/Ubuntu: fonts-dejavu-core); looked for {}", candidates.join(", "))
    })
}

/// Registers the plots' face once per process (its bytes live as long as
/// the process, as plotters asks); later calls return the first outcome.
pub fn font_ready() -> Result<()> {
    static READY: OnceLock<std::result::Result<PathBuf, String>> = OnceLock::new();
    let r = READY.get_or_init(|| {
        let load = || -> Result<PathBuf> {
            let p = font_file(std::env::var_os("TGS_PLOT_FONT"), FONT_FILES)?;
            let bytes = std::fs::read(&p).with_context(|| format!("{}: cannot read the plots' font", p.display()))?;
            register_font("sans-serif", FontStyle::Normal, Box::leak(bytes.into_boxed_slice())).map_err(|_| anyhow!("{}: not a TrueType or OpenType font", p.display()))?;
            Ok(p)
        };
        load().map_err(|e| format!("{e:#}"))
    });
    r.as_ref().map(|_| ()).map_err(|e| anyhow!("{e}"))
}

/// Draws the plots into `dir`; an error if no font can be found for their
/// text (`font_ready`) or a plot cannot be written.
pub fn draw(dir: &Path, rows: &[Row]) -> Result<()> {
    font_ready()?;
    one(&dir.join("psnr_vs_time.png"), rows, ("test PSNR (dB)", "higher is better"), |r| r.psnr, true)?;
    one(&dir.join("normal_mae_vs_time.png"), rows, ("test normal MAE on the glass (degrees)", "lower is better"), |r| r.normal_mae_deg, false)?;
    // Without the LPIPS weights every row's is NaN: no empty chart.
    if rows.iter().any(|r| r.lpips.is_finite()) {
        one(&dir.join("lpips_vs_time.png"), rows, ("test LPIPS (AlexNet)", "lower is better"), |r| r.lpips, false)?;
    }
    Ok(())
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

/// Whether wall times `t` call for a log axis: all positive and the largest
/// more than [`LOG_SPAN`] times the smallest.
pub fn log_time_axis(t: &[f64]) -> bool {
    let pos: Vec<f64> = t.iter().copied().filter(|x| x.is_finite()).collect();
    if pos.is_empty() || pos.iter().any(|&x| x <= 0.0) {
        return false;
    }
    let (lo, hi) = pos.iter().fold((f64::INFINITY, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
    hi > LOG_SPAN * lo
}

/// A pixel rectangle: left, top, right, bottom.
type Rect = (i32, i32, i32, i32);

fn overlap(a: Rect, b: Rect) -> bool {
    a.0 < b.2 && b.0 < a.2 && a.1 < b.3 && b.1 < a.3
}

/// Offsets (from each point, in pixels) for labels of `sizes` (width,
/// height) beside the points `at` (pixels), chosen in order so that no label
/// box overlaps another label or the marker (`marker` pixels around it) of
/// a labelled point or of an unlabelled one in `others`, and stays inside
/// `area`: the first of the candidate places around the point that is free,
/// then the same further out. A label with no free place takes the first
/// candidate (the table still names it).
pub fn place_labels(at: &[(i32, i32)], sizes: &[(i32, i32)], others: &[(i32, i32)], marker: i32, area: Rect) -> Vec<(i32, i32)> {
    let markers: Vec<Rect> = at.iter().chain(others).map(|&(x, y)| (x - marker, y - marker, x + marker + 1, y + marker + 1)).collect();
    let mut placed: Vec<Rect> = Vec::new();
    let mut out = Vec::with_capacity(at.len());
    for (&(x, y), &(w, h)) in at.iter().zip(sizes) {
        let g = marker + 2;
        let mut candidates = Vec::new();
        for ring in 0..4 {
            let d = g + ring * h;
            candidates.extend([(d, -d - h), (d, d), (-d - w, -d - h), (-d - w, d), (d, -h / 2), (-d - w, -h / 2), (-w / 2, -d - h), (-w / 2, d)]);
        }
        let free = |&(dx, dy): &(i32, i32)| {
            let r = (x + dx, y + dy, x + dx + w, y + dy + h);
            r.0 >= area.0 && r.1 >= area.1 && r.2 <= area.2 && r.3 <= area.3 && !placed.iter().chain(&markers).any(|&p| overlap(p, r))
        };
        let pick = candidates.iter().copied().find(free).unwrap_or(candidates[0]);
        placed.push((x + pick.0, y + pick.1, x + pick.0 + w, y + pick.1 + h));
        out.push(pick);
    }
    out
}

/// `name` cut to `max` characters with an ellipsis.
fn cut(name: &str, max: usize) -> String {
    if name.chars().count() <= max {
        name.to_string()
    } else {
        name.chars().take(max - 1).collect::<String>() + "…"
    }
}

/// One plot, drawn into an RGB buffer and written as a PNG with the
/// project's own `image` (plotters' encoder would build a second one).
fn one(path: &Path, rows: &[Row], axis: (&str, &str), y: impl Fn(&Row) -> f64, higher_better: bool) -> Result<()> {
    let mut rgb = vec![0u8; 3 * SIZE.0 as usize * SIZE.1 as usize];
    draw_plot(&mut rgb, path, rows, axis, y, higher_better)?;
    image::save_buffer(path, &rgb, SIZE.0, SIZE.1, image::ExtendedColorType::Rgb8).with_context(|| format!("writing the plot {}", path.display()))
}

fn draw_plot(rgb: &mut [u8], path: &Path, rows: &[Row], (what, better): (&str, &str), y: impl Fn(&Row) -> f64, higher_better: bool) -> Result<()> {
    let err = |e: &dyn std::fmt::Display| anyhow!("{}: drawing the plot: {e}", path.display());
    let root = BitMapBackend::with_buffer(rgb, SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let (left, right) = root.split_horizontally(CHART_W);
    let times: Vec<f64> = rows.iter().map(|r| r.wall_s).collect();
    let log = log_time_axis(&times);
    // On a log axis the chart's x is log10(seconds), labelled in seconds.
    let tx = |t: f64| if log { t.log10() } else { t };
    let (x0, x1) = if log { range(times.iter().map(|&t| t.log10())) } else { range(times.iter().copied().chain([0.0])) };
    let x0 = if log { x0 } else { x0.max(0.0) };
    let (y0, y1) = range(rows.iter().map(&y));
    let mut chart = ChartBuilder::on(&left)
        .caption(format!("{what} vs training wall time ({better})"), ("sans-serif", 20))
        .margin(16)
        .x_label_area_size(44)
        .y_label_area_size(64)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| err(&e))?;
    let seconds = |v: &f64| {
        let s = if log { 10f64.powf(*v) } else { *v };
        if s >= 100.0 {
            format!("{s:.0}")
        } else if s >= 1.0 {
            format!("{s:.1}")
        } else {
            format!("{s:.2}")
        }
    };
    let x_desc = if log { "training wall time (s, log scale)" } else { "training wall time (s)" };
    chart.configure_mesh().x_desc(x_desc).y_desc(what).x_label_formatter(&seconds).draw().map_err(|e| err(&e))?;
    let pts: Vec<(f64, f64)> = rows.iter().map(|r| (tx(r.wall_s), y(r))).filter(|p| p.0.is_finite() && p.1.is_finite()).collect();
    chart.draw_series(pts.iter().map(|&p| Circle::new(p, 4, BLUE.mix(0.7).filled()))).map_err(|e| err(&e))?.label("run").legend(|(x, y)| Circle::new((x, y), 4, BLUE.filled()));
    let front: Vec<usize> = pareto(rows, |r| if higher_better { y(r) } else { -y(r) }).into_iter().filter(|&i| rows[i].wall_s.is_finite() && y(&rows[i]).is_finite()).collect();
    let line: Vec<(f64, f64)> = front.iter().map(|&i| (tx(rows[i].wall_s), y(&rows[i]))).collect();
    chart
        .draw_series(LineSeries::new(line.clone(), RED.stroke_width(2)))
        .map_err(|e| err(&e))?
        .label("Pareto front")
        .legend(|(x, y)| PathElement::new([(x - 8, y), (x + 8, y)], RED.stroke_width(2)));
    chart.draw_series(line.iter().map(|&p| Circle::new(p, 6, RED.stroke_width(2)))).map_err(|e| err(&e))?;
    // Numbers beside the front's points, placed clear of each other and of
    // every point (all runs' markers count).
    let px: Vec<(i32, i32)> = line.iter().map(|&p| chart.backend_coord(&p)).collect();
    let all_px: Vec<(i32, i32)> = pts.iter().map(|&p| chart.backend_coord(&p)).collect();
    let labels: Vec<String> = (1..=front.len()).map(|k| k.to_string()).collect();
    let sizes: Vec<(i32, i32)> = labels.iter().map(|l| (CHAR_W * l.len() as i32, FONT as i32 + 2)).collect();
    let (xr, yr) = chart.plotting_area().get_pixel_range();
    let area = (xr.start, yr.start, xr.end, yr.end);
    let offsets = place_labels(&px, &sizes, &all_px, 6, area);
    let font = ("sans-serif", FONT).into_font().color(&BLACK);
    for ((&(x, y), &(dx, dy)), label) in px.iter().zip(&offsets).zip(&labels) {
        left.draw(&Text::new(label.clone(), (x + dx, y + dy), font.clone())).map_err(|e| err(&e))?;
    }
    chart.configure_series_labels().border_style(BLACK).background_style(WHITE.mix(0.8)).position(SeriesLabelPosition::LowerRight).draw().map_err(|e| err(&e))?;
    // The table: each front run's number, name, time and value.
    let head = ("sans-serif", 15).into_font().color(&BLACK);
    let body = ("sans-serif", 12).into_font().color(&BLACK);
    right.draw(&Text::new("Pareto front", (8, 40), head)).map_err(|e| err(&e))?;
    let per_row = 30;
    let fits = ((SIZE.1 as i32 - 80) / per_row).max(1) as usize;
    for (k, &i) in front.iter().enumerate().take(fits) {
        let top = 64 + per_row * k as i32;
        right.draw(&Text::new(format!("{}  {}", k + 1, cut(&rows[i].name, 34)), (8, top), body.clone())).map_err(|e| err(&e))?;
        right.draw(&Text::new(format!("    {:.1} s, {:.3}", rows[i].wall_s, y(&rows[i])), (8, top + 14), body.clone())).map_err(|e| err(&e))?;
    }
    if front.len() > fits {
        right.draw(&Text::new(format!("… and {} more (sweep.csv)", front.len() - fits), (8, 64 + per_row * fits as i32), body)).map_err(|e| err(&e))?;
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_font_is_found_or_named() {
        let dir = std::env::temp_dir().join(format!("tgs-font-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let face = dir.join("face.ttf");
        std::fs::write(&face, b"x").unwrap();
        let face_s = face.to_str().unwrap();
        let missing = dir.join("none.ttf");
        let missing_s = missing.to_str().unwrap();
        // The first existing candidate, when the variable is unset or empty.
        assert_eq!(font_file(None, &[missing_s, face_s]).unwrap(), face);
        assert_eq!(font_file(Some("".into()), &[face_s]).unwrap(), face);
        // The variable wins, and must exist.
        assert_eq!(font_file(Some(face.clone().into()), &[missing_s]).unwrap(), face);
        let e = format!("{:#}", font_file(Some(missing.clone().into()), &[face_s]).unwrap_err());
        assert!(e.contains("TGS_PLOT_FONT") && e.contains(missing_s), "{e}");
        // None found: the error names the variable, the package and where it looked.
        let e = format!("{:#}", font_file(None, &[missing_s]).unwrap_err());
        assert!(e.contains("TGS_PLOT_FONT") && e.contains("fonts-dejavu-core") && e.contains(missing_s), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn log_axis_only_when_times_span_more_than_five_times() {
        assert!(!log_time_axis(&[10.0, 20.0, 49.0]));
        assert!(log_time_axis(&[10.0, 20.0, 51.0]));
        assert!(!log_time_axis(&[0.0, 100.0]), "a zero time has no logarithm");
        assert!(!log_time_axis(&[]));
        assert!(log_time_axis(&[f64::NAN, 1.0, 6.0]));
    }

    #[test]
    fn labels_of_crowded_points_do_not_overlap() {
        // Twelve points within a few pixels of each other (runs of nearly
        // the same time and score), two-digit labels.
        let at: Vec<(i32, i32)> = (0..12).map(|k| (300 + 3 * (k % 4), 200 + 2 * (k / 4))).collect();
        let sizes = vec![(16, 15); at.len()];
        let area = (0, 0, 690, 640);
        let off = place_labels(&at, &sizes, &[], 6, area);
        let boxes: Vec<Rect> = at.iter().zip(&off).zip(&sizes).map(|((&(x, y), &(dx, dy)), &(w, h))| (x + dx, y + dy, x + dx + w, y + dy + h)).collect();
        for (i, a) in boxes.iter().enumerate() {
            assert!(a.0 >= area.0 && a.1 >= area.1 && a.2 <= area.2 && a.3 <= area.3, "label {i} leaves the chart: {a:?}");
            for (j, b) in boxes.iter().enumerate().skip(i + 1) {
                assert!(!overlap(*a, *b), "labels {i} and {j} overlap: {a:?} {b:?}");
            }
            for (j, &(x, y)) in at.iter().enumerate() {
                assert!(!overlap(*a, (x - 6, y - 6, x + 7, y + 7)), "label {i} covers point {j}");
            }
        }
        // Unlabelled points obstruct only with their markers: a label may
        // lie just beside one (here above-right of its own point, clear of
        // the other's marker).
        let off = place_labels(&[(130, 90)], &[(16, 15)], &[(135, 89)], 6, area);
        assert_eq!(off[0], (8, -23), "the first place beside the point is free");
        // ... and not over it.
        let off = place_labels(&[(130, 90)], &[(16, 15)], &[(145, 75)], 6, area);
        assert_ne!(off[0], (8, -23), "a label over another point's marker");
        // A point in a corner puts its label inside the chart.
        let off = place_labels(&[(685, 5)], &[(16, 15)], &[], 6, area);
        assert!(685 + off[0].0 + 16 <= 690 && 5 + off[0].1 >= 0, "{off:?}");
    }
}

#[cfg(test)]
mod drawn {
    use super::*;

    /// Ten runs close together and one 20x slower: the plots draw (log
    /// time axis), at the documented size.
    #[test]
    fn a_crowded_sweep_with_one_slow_run_draws() {
        let dir = std::env::temp_dir().join(format!("tgs-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut rows: Vec<Row> = (0..10)
            .map(|k| Row {
                name: format!("reflection.lr_quats=1e-{k},reflection.iterations={}", 100 * k),
                wall_s: 30.0 + k as f64,
                psnr: 28.0 + 0.02 * k as f64,
                normal_mae_deg: 40.0 - 0.1 * k as f64,
                ..Row::default()
            })
            .collect();
        rows.push(Row { name: "paper".into(), wall_s: 700.0, psnr: 28.5, normal_mae_deg: 30.0, ..Row::default() });
        draw(&dir, &rows).unwrap();
        for p in ["psnr_vs_time.png", "normal_mae_vs_time.png"] {
            let img = image::open(dir.join(p)).unwrap();
            assert_eq!((img.width(), img.height()), SIZE);
        }
        if std::env::var_os("TGS_KEEP_PLOTS").is_none() {
            let _ = std::fs::remove_dir_all(&dir);
        }
    }
}
