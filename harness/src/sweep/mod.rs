//! `tgs sweep`: train a grid of settings that trade accuracy for time and
//! tabulate what each costs and buys.
//!
//! A grid file (TOML) names a base (settings every run shares, as with
//! `tgs train --set`) and knobs (each a setting with a list of values):
//!
//! ```toml
//! preset = "quick"            # optional, as tgs train --preset
//! mode = "one_at_a_time"      # or "product"
//! [base]
//! iterations = 1500
//! [knobs]
//! iterations = [500, 1500, 3000]
//! "light_field.preset" = ["small", "paper"]
//! ```
//!
//! `one_at_a_time` runs the base and then each knob value with the other
//! knobs at the base (duplicates of the base run once); `product` runs
//! every combination. Each run trains in `DIR/runs/NAME` with GPU
//! timestamps on, and its row (settings, wall time, GPU ms per iteration,
//! test PSNR / SSIM / normal MAE / LPIPS per stage) is added to `DIR/sweep.csv` as
//! soon as it finishes; `DIR/psnr_vs_time.png`, `DIR/normal_mae_vs_time.png`
//! and `DIR/lpips_vs_time.png` (with the LPIPS weights) are redrawn with the Pareto front marked. Running the same command again
//! resumes: finished runs (in the CSV) are kept, an interrupted run is
//! trained again from the start (so every wall time is one uninterrupted
//! run's), the rest follow. Each row is keyed by its run's complete
//! settings and the dataset's fingerprint (the `key` column): a row whose
//! key no longer matches (the base, preset, a default or the dataset
//! changed) is dropped and its run trained again.

mod plot;

use crate::train::run::{train, TrainArgs};
use anyhow::{bail, Context as _, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use tgs_engine::Context;

/// The grid used when no file is given: the knobs docs/usage.md's accuracy /
/// time section discusses, one at a time around the quick preset.
pub const DEFAULT_GRID: &str = r#"
preset = "quick"
mode = "one_at_a_time"
[base]
[knobs]
iterations = [1000, 3000]
"reflection.iterations" = [100, 300]
"light_field.iterations" = [300, 1000]
sh_degree = [1, 3]
"reflection.env_res" = [32, 128]
"light_field.preset" = ["small", "paper"]
"light_field.lambda_hf" = [0.0, 0.1]
"light_field.threshold" = [0.0, 0.01, 0.05]
"#;

/// The most runs a grid may make: each trains a model (minutes at least),
/// so more is a mistake in the grid, not a plan.
pub const MAX_RUNS: usize = 10_000;

/// Settings as (key, value), in order.
pub type Settings = Vec<(String, toml::Value)>;

#[derive(Clone, Debug, PartialEq)]
pub struct Grid {
    pub preset: String,
    pub product: bool,
    pub base: Settings,
    pub knobs: Vec<(String, Vec<toml::Value>)>,
}

/// A value as `--set` takes it (TOML syntax).
fn show(v: &toml::Value) -> String {
    v.to_string()
}

/// A value as run names and the CSV show it (strings unquoted).
fn plain(v: &toml::Value) -> String {
    show(v).trim_matches('"').to_string()
}

impl Grid {
    pub fn parse(text: &str, what: &str) -> Result<Grid> {
        let t: toml::Table = toml::from_str(text).with_context(|| format!("{what}: not valid TOML"))?;
        let mut g = Grid { preset: "quick".into(), product: false, base: Vec::new(), knobs: Vec::new() };
        for (k, v) in &t {
            match (k.as_str(), v) {
                ("preset", toml::Value::String(s)) => g.preset = s.clone(),
                ("mode", toml::Value::String(s)) => {
                    g.product = match s.as_str() {
                        "product" => true,
                        "one_at_a_time" => false,
                        _ => bail!("{what}: mode = \"{s}\": expected \"one_at_a_time\" or \"product\""),
                    }
                }
                ("base", toml::Value::Table(b)) => g.base = crate::train::config::flatten(b),
                ("knobs", toml::Value::Table(kn)) => {
                    for (key, vals) in crate::train::config::flatten(kn) {
                        match vals {
                            toml::Value::Array(a) if !a.is_empty() => g.knobs.push((key, a)),
                            _ => bail!("{what}: knob '{key}' must be a non-empty list of values"),
                        }
                    }
                }
                _ => bail!("{what}: unknown entry '{k}' (expected preset, mode, [base], [knobs])"),
            }
        }
        if g.knobs.is_empty() {
            bail!("{what}: no [knobs]: nothing to sweep");
        }
        Ok(g)
    }

    /// The runs: each a list of (key, value) overriding the base, named
    /// after them ("base" for none). Each run's settings are checked.
    pub fn runs(&self, quiet: bool) -> Result<Vec<(String, Settings)>> {
        let count =
            if self.product { self.knobs.iter().try_fold(1usize, |n, (_, v)| n.checked_mul(v.len())) } else { Some(1 + self.knobs.iter().map(|(_, v)| v.len()).sum::<usize>()) };
        match count {
            Some(n) if n <= MAX_RUNS => {}
            Some(n) => bail!("the grid makes {n} runs; at most {MAX_RUNS} (every run trains a model: split the grid)"),
            None => bail!("the grid makes more runs than can be counted; at most {MAX_RUNS} (every run trains a model: split the grid)"),
        }
        let mut sets: Vec<Settings> = vec![Vec::new()];
        if self.product {
            for (k, vals) in &self.knobs {
                sets = sets.iter().flat_map(|s| vals.iter().map(move |v| [s.clone(), vec![(k.clone(), v.clone())]].concat())).collect();
            }
        } else {
            for (k, vals) in &self.knobs {
                sets.extend(vals.iter().map(|v| vec![(k.clone(), v.clone())]));
            }
        }
        let mut out: Vec<(String, Settings)> = Vec::new();
        let mut seen: Vec<crate::train::TrainConfig> = Vec::new();
        let bar = (!quiet && sets.len() >= 1000).then(|| {
            eprintln!("sweep: checking the settings of the grid's {} runs", sets.len());
            indicatif::ProgressBar::new(sets.len() as u64)
        });
        for s in sets {
            if let Some(b) = &bar {
                b.inc(1);
            }
            let cfg = self.config(&s).with_context(|| format!("grid run {}", name_of(&s)))?;
            // A knob value equal to the base's is the base run.
            if seen.contains(&cfg) {
                continue;
            }
            seen.push(cfg);
            out.push((name_of(&s), s));
        }
        if let Some(b) = bar {
            b.finish_and_clear();
        }
        Ok(out)
    }

    fn set_args(&self, run: &[(String, toml::Value)]) -> Vec<String> {
        self.base.iter().chain(run).map(|(k, v)| format!("{k}={}", show(v))).collect()
    }

    fn config(&self, run: &[(String, toml::Value)]) -> Result<crate::train::TrainConfig> {
        let a = TrainArgs { preset: Some(self.preset.clone()), set: self.set_args(run), ..Default::default() };
        crate::train::run::config_from_args(&a)
    }
}

fn name_of(run: &[(String, toml::Value)]) -> String {
    if run.is_empty() {
        return "base".into();
    }
    run.iter().map(|(k, v)| format!("{k}={}", plain(v))).collect::<Vec<_>>().join(",")
}

/// A directory name for a run name.
fn dir_name(name: &str) -> String {
    name.chars().map(|c| if c.is_ascii_alphanumeric() || "._-=,".contains(c) { c } else { '_' }).collect()
}

/// One run's row.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Row {
    pub name: String,
    /// The run's complete settings and the dataset's fingerprint, hashed.
    pub key: String,
    pub settings: BTreeMap<String, String>,
    pub wall_s: f64,
    pub gpu_ms_per_iteration: f64,
    pub iterations: u64,
    /// stage -> (psnr, ssim, normal MAE, LPIPS), wall s.
    pub stages: BTreeMap<String, ([f64; 4], f64)>,
    /// The last stage's.
    pub psnr: f64,
    pub ssim: f64,
    pub normal_mae_deg: f64,
    /// NaN without the LPIPS weights.
    pub lpips: f64,
}

/// The stages' names, in run order: the CSV's per-stage column groups.
fn stage_names() -> Vec<&'static str> {
    crate::train::stage::Stage::all().into_iter().map(|s| s.name()).collect()
}

impl Row {
    fn from_metrics(name: &str, key: &str, settings: BTreeMap<String, String>, m: &serde_json::Value) -> Result<Row> {
        let f = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
        let gpu = m["gpu_ms_per_iteration"].as_object().map(|k| k.iter().filter(|(n, _)| !crate::bench::nested_scope(n)).map(|(_, v)| f(v)).sum()).unwrap_or(f64::NAN);
        let mut stages = BTreeMap::new();
        for s in m["stages"].as_array().context("metrics.json has no stages")? {
            let t = &s["test"];
            stages.insert(s["stage"].as_str().unwrap_or("?").to_string(), ([f(&t["psnr"]), f(&t["ssim"]), f(&t["normal_mae_deg"]), f(&t["lpips"])], f(&s["wall_s"])));
        }
        let t = &m["test"];
        Ok(Row {
            name: name.into(),
            key: key.into(),
            settings,
            wall_s: f(&m["train_wall_s"]),
            gpu_ms_per_iteration: gpu,
            iterations: m["iterations"].as_u64().unwrap_or(0),
            stages,
            psnr: f(&t["psnr"]),
            ssim: f(&t["ssim"]),
            normal_mae_deg: f(&t["normal_mae_deg"]),
            lpips: f(&t["lpips"]),
        })
    }
}

fn header(keys: &[String]) -> Vec<String> {
    let mut h = vec!["run".to_string(), "key".to_string()];
    h.extend(keys.iter().cloned());
    h.extend(["wall_s", "gpu_ms_per_iteration", "total_iterations", "psnr", "ssim", "normal_mae_deg", "lpips"].map(String::from));
    for s in stage_names() {
        h.extend([format!("{s}_psnr"), format!("{s}_ssim"), format!("{s}_normal_mae_deg"), format!("{s}_lpips"), format!("{s}_wall_s")]);
    }
    h
}

/// A number as the shortest text that reads back to the same f64.
fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v}")
    } else {
        String::new()
    }
}

/// CSV field: quoted when it holds a comma or a quote.
fn field(s: &str) -> String {
    if s.contains(',') || s.contains('"') {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn csv_line(r: &Row, keys: &[String]) -> String {
    let mut v = vec![field(&r.name), field(&r.key)];
    v.extend(keys.iter().map(|k| field(r.settings.get(k).map(String::as_str).unwrap_or(""))));
    v.extend([num(r.wall_s), num(r.gpu_ms_per_iteration), r.iterations.to_string(), num(r.psnr), num(r.ssim), num(r.normal_mae_deg), num(r.lpips)]);
    for s in stage_names() {
        match r.stages.get(s) {
            Some((t, w)) => v.extend([num(t[0]), num(t[1]), num(t[2]), num(t[3]), num(*w)]),
            None => v.extend(["", "", "", "", ""].map(String::from)),
        }
    }
    v.join(",")
}

/// Split one CSV line (fields quoted as [`field`] writes them).
fn split_csv(line: &str) -> Vec<String> {
    let (mut out, mut cur, mut quoted, mut chars) = (Vec::new(), String::new(), false, line.chars().peekable());
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                cur.push('"');
                chars.next();
            }
            ('"', _) => quoted = !quoted,
            (',', false) => out.push(std::mem::take(&mut cur)),
            (c, _) => cur.push(c),
        }
    }
    out.push(cur);
    out
}

/// The rows of an existing sweep.csv written with the same columns.
fn read_csv(path: &Path, keys: &[String]) -> Result<Vec<Row>> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e).with_context(|| format!("{}: cannot read", path.display())),
    };
    let mut lines = text.lines();
    let want = header(keys);
    if lines.next().map(split_csv) != Some(want.clone()) {
        bail!("{}: written by another grid or an older tgs (its columns differ); use another --out or move it away", path.display());
    }
    let p = |s: &String| s.parse::<f64>().unwrap_or(f64::NAN);
    let mut rows = Vec::new();
    for (i, line) in lines.enumerate() {
        let v = split_csv(line);
        if v.len() != want.len() {
            bail!("{}: line {} has {} fields, expected {}", path.display(), i + 2, v.len(), want.len());
        }
        let k = keys.len() + 1;
        let mut r = Row { name: v[0].clone(), key: v[1].clone(), ..Default::default() };
        r.settings = keys.iter().cloned().zip(v[2..=k].iter().cloned()).filter(|(_, s)| !s.is_empty()).collect();
        (r.wall_s, r.gpu_ms_per_iteration) = (p(&v[k + 1]), p(&v[k + 2]));
        r.iterations = v[k + 3].parse().unwrap_or(0);
        (r.psnr, r.ssim, r.normal_mae_deg, r.lpips) = (p(&v[k + 4]), p(&v[k + 5]), p(&v[k + 6]), p(&v[k + 7]));
        for (j, s) in stage_names().iter().enumerate() {
            let b = k + 8 + 5 * j;
            if v.len() > b + 4 && !v[b].is_empty() {
                r.stages.insert(s.to_string(), ([p(&v[b]), p(&v[b + 1]), p(&v[b + 2]), p(&v[b + 3])], p(&v[b + 4])));
            }
        }
        rows.push(r);
    }
    Ok(rows)
}

fn write_csv(path: &Path, rows: &[Row], keys: &[String]) -> Result<()> {
    let mut s = header(keys).iter().map(|h| field(h)).collect::<Vec<_>>().join(",");
    s.push('\n');
    for r in rows {
        s.push_str(&csv_line(r, keys));
        s.push('\n');
    }
    crate::export::atomic_write(path, s.as_bytes())
}

pub struct SweepArgs {
    pub dataset: Option<PathBuf>,
    pub out: PathBuf,
    pub grid: Option<PathBuf>,
    pub quiet: bool,
}

/// What a sweep did.
pub struct SweepOutcome {
    pub rows: Vec<Row>,
    /// Runs trained by this call (the others were in the CSV already).
    pub trained: usize,
    pub interrupted: bool,
}

pub fn sweep(ctx: &Arc<Context>, a: &SweepArgs) -> Result<SweepOutcome> {
    // SIGINT / SIGTERM from here on stop the sweep at the next safe point
    // (between runs, or a run's next iteration); a second one aborts.
    crate::train::run::install_signal_handler();
    let signals = crate::train::run::signals_received();
    let stop = || crate::train::run::signals_received() > signals;
    let grid = match &a.grid {
        Some(p) => Grid::parse(&crate::train::config::read_text_capped(p, "grid")?, &p.display().to_string())?,
        None => Grid::parse(DEFAULT_GRID, "the default grid")?,
    };
    let runs = grid.runs(a.quiet)?;
    let keys: Vec<String> = grid.knobs.iter().map(|k| k.0.clone()).collect();
    crate::outdir::refuse_dataset(&a.out, a.dataset.as_deref())?;
    let _lock = crate::lock::create_and_lock(&a.out, "tgs sweep", a.quiet)?;
    // Without a dataset: the built-in scene, written once to OUT/scene as `tgs train` does.
    let dataset = crate::train::run::dataset_dir(&TrainArgs { dataset: a.dataset.clone(), out: a.out.clone(), ..Default::default() }, a.quiet)?;
    let csv = a.out.join("sweep.csv");
    let mut rows = read_csv(&csv, &keys)?;
    // Each run's key: its complete settings and the dataset's fingerprint.
    let base_cfg = grid.config(&[])?;
    let digest = crate::train::run::load_dataset(&dataset, &base_cfg)?.fingerprint()?.digest();
    let run_keys: Vec<String> = runs.iter().map(|(_, s)| Ok(run_key(&toml::to_string(&grid.config(s)?)?, digest))).collect::<Result<_>>()?;
    drop_stale_rows(&mut rows, &runs, &run_keys, &csv, a.quiet);
    let plots = plots_ready();
    let mut trained = 0;
    for (i, (name, set)) in runs.iter().enumerate() {
        if rows.iter().any(|r| &r.name == name) {
            continue;
        }
        if stop() {
            return Ok(SweepOutcome { rows, trained, interrupted: true });
        }
        if !a.quiet {
            eprintln!("sweep: run {}/{}: {name}", i + 1, runs.len());
        }
        let dir = a.out.join("runs").join(dir_name(name));
        // An interrupted run trains again from the start: its wall time is one run's.
        if dir.exists() {
            std::fs::remove_dir_all(&dir).with_context(|| format!("{}: cannot remove the unfinished run", dir.display()))?;
        }
        let args = TrainArgs {
            dataset: Some(dataset.clone()),
            out: dir.clone(),
            preset: Some(grid.preset.clone()),
            set: grid.set_args(set),
            profile: true,
            quiet: a.quiet,
            ..Default::default()
        };
        let o = train(ctx, &args).with_context(|| format!("sweep run {name}"))?;
        if o.interrupted || stop() {
            return Ok(SweepOutcome { rows, trained, interrupted: true });
        }
        let m: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("metrics.json")).with_context(|| format!("{}: no metrics.json", dir.display()))?)?;
        let settings = set.iter().map(|(k, v)| (k.clone(), plain(v))).collect();
        rows.push(Row::from_metrics(name, &run_keys[i], settings, &m)?);
        trained += 1;
        write_csv(&csv, &rows, &keys)?;
        if plots {
            plot::draw(&a.out, &rows)?;
        }
    }
    if trained == 0 {
        // Nothing new: the CSV and plots as the rows stand (drawn again if removed).
        write_csv(&csv, &rows, &keys)?;
        if plots {
            plot::draw(&a.out, &rows)?;
        }
    }
    Ok(SweepOutcome { rows, trained, interrupted: false })
}

/// Drop the CSV's rows whose run key no longer matches (other settings or
/// another dataset): their runs train again.
fn drop_stale_rows(rows: &mut Vec<Row>, runs: &[(String, Settings)], run_keys: &[String], csv: &Path, quiet: bool) {
    let before = rows.len();
    rows.retain(|r| runs.iter().zip(run_keys).any(|((n, _), k)| &r.name == n && &r.key == k));
    if rows.len() < before && !quiet {
        eprintln!(
            "sweep: {} row(s) of {} were trained with other settings or another dataset (the base, preset, defaults or data changed): dropped, their runs train again",
            before - rows.len(),
            csv.display()
        );
    }
}

/// Whether the plots can be drawn: without a font for their text, said
/// before any training, and the sweep goes on without them (the CSV holds
/// every number they show).
fn plots_ready() -> bool {
    match plot::font_ready() {
        Ok(()) => true,
        Err(e) => {
            eprintln!("sweep: plots not drawn: {e:#}");
            false
        }
    }
}

/// A run's key: FNV-1a over its settings (TOML) and the dataset digest.
fn run_key(settings_toml: &str, dataset_digest: u64) -> String {
    use crate::data::fingerprint::{fnv1a, FNV_START};
    format!("{:016x}", fnv1a(fnv1a(FNV_START, settings_toml.as_bytes()), &dataset_digest.to_le_bytes()))
}

/// Indices of the rows on the Pareto front of (wall time down, `score` up):
/// no other row is at least as fast and at least as good, and strictly
/// better in one. Sorted by wall time.
pub fn pareto(rows: &[Row], score: impl Fn(&Row) -> f64) -> Vec<usize> {
    let ok: Vec<usize> = (0..rows.len()).filter(|&i| rows[i].wall_s.is_finite() && score(&rows[i]).is_finite()).collect();
    let mut front: Vec<usize> = ok
        .iter()
        .copied()
        .filter(|&i| {
            !ok.iter().any(|&j| {
                let (a, b) = (&rows[j], &rows[i]);
                j != i && a.wall_s <= b.wall_s && score(a) >= score(b) && (a.wall_s < b.wall_s || score(a) > score(b))
            })
        })
        .collect();
    front.sort_by(|&a, &b| rows[a].wall_s.total_cmp(&rows[b].wall_s));
    front
}
