//! Training configuration: defaults from method-notes §1.8–1.12 (the
//! `paper` preset), a `quick` preset for minutes on a CPU driver, a TOML
//! file, and `--set key=value` overrides, applied in that order.

use super::stage::{added_settings, Stage};
pub use super::stages::light_field::config::LightFieldConfig;
pub use super::stages::reflection::config::ReflectionConfig;
use anyhow::{bail, Context as _, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TrainConfig {
    /// Stage I iterations.
    pub iterations: u32,
    pub seed: u64,
    /// Largest SH degree; the active degree grows by one every `sh_interval`.
    pub sh_degree: u32,
    pub sh_interval: u32,
    pub lambda_ssim: f32,
    pub lambda_normal: f32,
    pub normal_from: u32,
    pub lambda_dist: f32,
    pub dist_from: u32,
    /// Position lr (x scene extent), log-linear from `lr_means` to `lr_means_final` over the stage.
    pub lr_means: f32,
    pub lr_means_final: f32,
    pub lr_features_dc: f32,
    pub lr_features_rest: f32,
    pub lr_opacity: f32,
    pub lr_scales: f32,
    pub lr_quats: f32,
    pub adam_eps: f32,
    pub densify_from: u32,
    pub densify_until: u32,
    pub densify_interval: u32,
    pub densify_grad: f32,
    pub percent_dense: f32,
    pub prune_opacity: f32,
    pub opacity_reset_interval: u32,
    /// An opacity reset runs only when at least this many Stage I iterations
    /// follow it (a reset leaves the set near-blank until opacities recover:
    /// measured on glass-tiny, test PSNR is 1.8 dB short 60 iterations after
    /// a reset, 0.6 dB after 100, 0.1 dB after 200).
    pub opacity_reset_min_after: u32,
    /// Prune Gaussians larger than this many pixels (after the first opacity reset).
    pub max_screen_size: f32,
    /// Prune Gaussians larger than this fraction of the scene extent (likewise).
    pub max_world_size: f32,
    /// Hard cap on the Gaussian count (growth stops there).
    pub max_gaussians: u32,
    /// Random initialisation when the dataset has no points: count and cube half-size.
    pub init_points: u32,
    pub init_half_extent: f32,
    /// Random initialisation also places this fraction of `init_points`
    /// in the far field the cameras see beyond the cube and the camera
    /// sphere (uniform in inverse depth out to `init_far_depth` × the scene
    /// extent along training rays; 0: the cube only). Without them a sky or
    /// a distant floor is painted view by view on nearby Gaussians, misfit
    /// the Stage I residual then mistakes for reflection
    /// (perf/journal/2026-11-24-twentieth.md, perf/journal/2026-11-24-twenty-first.md).
    pub init_far_fraction: f32,
    pub init_far_depth: f32,
    /// Background colour: "white", "black" or "r,g,b".
    pub background: String,
    pub downscale: u32,
    /// COLMAP test split: every n-th image (0: no test split).
    pub holdout: u32,
    /// Evaluate the test views every this many iterations (0: only at the end).
    pub test_interval: u32,
    /// Write a checkpoint every this many iterations (0: only at the end).
    pub checkpoint_interval: u32,
    /// The stages to run, in order: "I", "I,II" or "I,II,III".
    pub stages: String,
    /// Hold every n-th training view (views n-1, 2n-1, ...) out of the
    /// later stages (seeding, cache, gradients) and measure each stage on
    /// them (`validation` in metrics.json); 0: none, all views train every
    /// stage. With it, Stage II's reflection set is kept only when it
    /// raises the validation PSNR over Stage I's by more than
    /// `validation_margin_db` (else Stage I's model is the result).
    pub validation_every: u32,
    /// The validation PSNR gain (dB) a later stage must show to be kept.
    pub validation_margin_db: f32,
    /// Hold the validation views out of Stage I too, so that no stage has
    /// seen them (Stage I then trains on fewer views; without it Stage I
    /// has fitted them and the comparison leans its way).
    pub validation_all_stages: bool,
    /// Stage II settings (`[reflection]` in TOML, `--set reflection.KEY=V`).
    pub reflection: ReflectionConfig,
    /// Stage III settings (`[light_field]`, `--set light_field.KEY=V`).
    pub light_field: LightFieldConfig,
    /// The settings sections of stages added by `stages::register`, as
    /// TOML under each stage's key (none without them); any other key is
    /// refused by [`TrainConfig::validate`].
    #[serde(flatten)]
    pub sections: BTreeMap<String, toml::Value>,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self::paper()
    }
}

impl TrainConfig {
    /// Active SH degree at Stage I iteration `it` (one more every `sh_interval`).
    pub fn sh_degree_at(&self, it: u32) -> u32 {
        (it / self.sh_interval).min(self.sh_degree)
    }

    /// The 2DGS schedule of method-notes §1.8–1.12 (30k iterations).
    pub fn paper() -> TrainConfig {
        TrainConfig {
            iterations: 30_000,
            seed: 0,
            sh_degree: 3,
            sh_interval: 1000,
            lambda_ssim: 0.2,
            lambda_normal: 0.05,
            normal_from: 7000,
            lambda_dist: 0.0,
            dist_from: 3000,
            lr_means: 1.6e-4,
            lr_means_final: 1.6e-6,
            lr_features_dc: 2.5e-3,
            lr_features_rest: 2.5e-3 / 20.0,
            lr_opacity: 0.05,
            lr_scales: 5e-3,
            lr_quats: 1e-3,
            adam_eps: 1e-15,
            densify_from: 500,
            densify_until: 15_000,
            densify_interval: 100,
            densify_grad: 2e-4,
            percent_dense: 0.01,
            prune_opacity: 0.05,
            opacity_reset_interval: 3000,
            opacity_reset_min_after: 1000,
            max_screen_size: 20.0,
            max_world_size: 0.1,
            max_gaussians: 2_000_000,
            init_points: 100_000,
            init_half_extent: 1.3,
            init_far_fraction: 2.0,
            init_far_depth: 30.0,
            background: "white".into(),
            downscale: 1,
            holdout: 8,
            test_interval: 5000,
            checkpoint_interval: 5000,
            stages: "I,II,III".into(),
            validation_every: 0,
            validation_margin_db: 0.0,
            validation_all_stages: false,
            reflection: ReflectionConfig::default(),
            light_field: LightFieldConfig::default(),
            sections: registered_sections("paper"),
        }
    }

    /// The same schedule compressed ~10x (3,000 iterations, 10k initial
    /// points), for minutes on a CPU driver.
    pub fn quick() -> TrainConfig {
        TrainConfig {
            iterations: 3000,
            sh_interval: 500,
            normal_from: 1500,
            dist_from: 1000,
            densify_from: 300,
            densify_until: 2000,
            opacity_reset_interval: 1000,
            opacity_reset_min_after: 300,
            init_points: 10_000,
            max_gaussians: 200_000,
            test_interval: 1000,
            checkpoint_interval: 500,
            reflection: ReflectionConfig::quick(),
            light_field: LightFieldConfig::quick(),
            sections: registered_sections("quick"),
            ..Self::paper()
        }
    }

    pub fn preset(name: &str) -> Result<TrainConfig> {
        match name {
            "paper" => Ok(Self::paper()),
            "quick" => Ok(Self::quick()),
            _ => bail!("unknown preset '{name}' (quick or paper)"),
        }
    }

    /// Overlay the keys of a TOML file.
    pub fn merge_toml_file(&mut self, path: &Path) -> Result<()> {
        let text = read_text_capped(path, "config")?;
        let table: toml::Table = text.parse().with_context(|| format!("{}: not valid TOML", path.display()))?;
        self.merge(table).with_context(|| format!("{}", path.display()))
    }

    /// Apply `key=value` (value in TOML syntax; bare words are strings).
    pub fn set(&mut self, kv: &str) -> Result<()> {
        let (k, v) = kv.split_once('=').with_context(|| format!("--set '{kv}': expected KEY=VALUE"))?;
        let (k, v) = (k.trim(), v.trim());
        let value: toml::Value = format!("x = {v}").parse::<toml::Table>().ok().and_then(|mut t| t.remove("x")).unwrap_or_else(|| toml::Value::String(v.to_string()));
        let mut table = toml::Table::new();
        table.insert(k.to_string(), value);
        self.merge(table).with_context(|| format!("--set '{kv}'"))
    }

    fn merge(&mut self, overlay: toml::Table) -> Result<()> {
        let mut base = toml::Table::try_from(&*self).context("serialising the config")?;
        for (k, v) in flatten(&overlay) {
            // `section.key` names a key of a section table.
            let (table, key) = match k.split_once('.') {
                Some((sec, key)) => match base.get_mut(sec) {
                    Some(toml::Value::Table(t)) => (t, key.to_string()),
                    _ => bail!("unknown setting '{k}'"),
                },
                None => (&mut base, k.clone()),
            };
            let Some(old) = table.get(&key) else { bail!("unknown setting '{k}'") };
            // Integers given for float settings are fine.
            let v = match (old, v) {
                (toml::Value::Float(_), toml::Value::Integer(i)) => toml::Value::Float(i as f64),
                (toml::Value::Table(_), _) => bail!("'{k}' is a section; set its keys ({k}.KEY)"),
                (_, v) => v,
            };
            table.insert(key, v);
        }
        *self = base.try_into().context("invalid setting")?;
        self.validate()
    }

    /// The stages to run, parsed from `stages`: Stage I and the later
    /// stages after it in order, each starting from the one before.
    pub fn stage_list(&self) -> Result<Vec<&'static str>> {
        let all: Vec<&'static str> = Stage::all().iter().map(|s| s.name()).collect();
        let mut out = Vec::new();
        for s in self.stages.split(',').map(str::trim) {
            match Stage::named(s) {
                Some(a) => out.push(a.name()),
                None => bail!("stages: unknown stage '{s}' ({}; e.g. \"{}\")", all.join(", "), all.join(",")),
            }
        }
        if out.is_empty() || out[..] != all[..out.len().min(all.len())] {
            let prefixes: Vec<String> = (1..=all.len()).map(|k| format!("\"{}\"", all[..k].join(","))).collect();
            let (last, rest) = prefixes.split_last().expect("Stage I is always a stage");
            let list = if rest.is_empty() { last.clone() } else { format!("{} or {last}", rest.join(", ")) };
            bail!("stages must be {list}, not \"{}\" (each stage starts from the one before; use --from RUN to reuse a run's)", self.stages);
        }
        Ok(out)
    }

    /// Whether the stage named `name` ("II", ...) is scheduled.
    pub fn wants(&self, name: &str) -> bool {
        self.stage_list().map(|s| s.contains(&name)).unwrap_or(false)
    }

    /// Whether the opacity reset follows iteration `it` (2DGS: every
    /// `opacity_reset_interval` while densifying, and once at `densify_from`
    /// on a white background). A reset leaves every opacity at 0.01, so one
    /// with fewer than `opacity_reset_min_after` Stage I iterations after it
    /// is skipped: no schedule ends on a freshly reset, near-blank set.
    pub fn opacity_reset_after(&self, it: u32, white_background: bool) -> bool {
        let due = it > 0
            && it < self.densify_until
            && self.opacity_reset_interval > 0
            && (it.is_multiple_of(self.opacity_reset_interval) || (white_background && it == self.densify_from));
        due && self.iterations.saturating_sub(it) >= self.opacity_reset_min_after.max(1)
    }

    /// The rules between settings, checked once all are given (each
    /// `--set` is validated alone as it is applied): the initial set no
    /// larger than densification's cap.
    pub fn validate_together(&self) -> Result<()> {
        if self.init_points > self.max_gaussians {
            bail!(
                "init_points {} is more than max_gaussians {}: densification could never grow such a set; lower init_points or raise max_gaussians too",
                self.init_points,
                self.max_gaussians
            );
        }
        Ok(())
    }

    pub fn validate(&self) -> Result<()> {
        // Every float setting must be a number: NaN or infinity anywhere is
        // an error naming the key.
        let table = toml::Table::try_from(self).context("serialising the config")?;
        for (k, v) in &flatten(&table) {
            if let toml::Value::Float(f) = v {
                if !f.is_finite() {
                    bail!("setting '{k}' is {f}; it must be a finite number");
                }
                if is_learning_rate(k) && *f > LR_LIMIT {
                    bail!("{k} = {:e}: beyond any sane learning rate (at most {}; Adam moves a parameter by about its rate every iteration)", *f as f32, LR_LIMIT);
                }
            }
        }
        if self.iterations == 0 {
            bail!("iterations must be at least 1");
        }
        if self.sh_degree > 3 {
            bail!("sh_degree must be 0..=3, not {}", self.sh_degree);
        }
        for (k, v) in [("sh_interval", self.sh_interval), ("densify_interval", self.densify_interval), ("init_points", self.init_points), ("max_gaussians", self.max_gaussians)] {
            if v == 0 {
                bail!("{k} must be at least 1");
            }
        }
        if !(0.0..=1.0).contains(&self.lambda_ssim) {
            bail!("lambda_ssim must be in [0, 1], not {}", self.lambda_ssim);
        }
        if self.downscale == 0 {
            bail!("downscale must be at least 1");
        }
        if self.validation_every == 1 {
            bail!("validation_every 1 would hold out every training view; give 0 (none) or n >= 2 (every n-th view)");
        }
        let non_negative = [
            ("lr_means", self.lr_means),
            ("lr_means_final", self.lr_means_final),
            ("lr_features_dc", self.lr_features_dc),
            ("lr_features_rest", self.lr_features_rest),
            ("lr_opacity", self.lr_opacity),
            ("lr_scales", self.lr_scales),
            ("lr_quats", self.lr_quats),
            ("adam_eps", self.adam_eps),
            ("lambda_normal", self.lambda_normal),
            ("lambda_dist", self.lambda_dist),
            ("densify_grad", self.densify_grad),
            ("percent_dense", self.percent_dense),
        ];
        for (k, v) in non_negative {
            if v < 0.0 {
                bail!("{k} must be non-negative, not {v}");
            }
        }
        for (k, v) in [
            ("init_half_extent", self.init_half_extent),
            ("init_far_depth", self.init_far_depth),
            ("max_screen_size", self.max_screen_size),
            ("max_world_size", self.max_world_size),
        ] {
            if v <= 0.0 {
                bail!("{k} must be positive, not {v}");
            }
        }
        if !(0.0..=10.0).contains(&self.init_far_fraction) {
            bail!("init_far_fraction must be in [0, 10] (a fraction of init_points), not {}", self.init_far_fraction);
        }
        if !(0.0..1.0).contains(&self.prune_opacity) {
            bail!("prune_opacity must be in [0, 1), not {}", self.prune_opacity);
        }
        self.background_rgb()?;
        self.stage_list()?;
        self.reflection.validate()?;
        self.light_field.validate()?;
        let added = added_settings();
        for (key, v) in &self.sections {
            let s = added.iter().find(|s| s.key == key).with_context(|| format!("unknown setting '{key}'"))?;
            let toml::Value::Table(t) = v else { bail!("'{key}' is a section; set its keys ({key}.KEY)") };
            (s.check)(t)?;
        }
        Ok(())
    }

    /// The settings section `key` of a stage added by `stages::register`,
    /// as `T` (`T`'s defaults where the section, or a key of it, is missing).
    pub fn section<T: serde::de::DeserializeOwned + Default>(&self, key: &str) -> Result<T> {
        match self.sections.get(key) {
            Some(v) => v.clone().try_into().with_context(|| format!("settings section '{key}'")),
            None => Ok(T::default()),
        }
    }

    pub fn background_rgb(&self) -> Result<[f32; 3]> {
        match self.background.as_str() {
            "white" => Ok([1.0; 3]),
            "black" => Ok([0.0; 3]),
            s => {
                let v: Vec<f32> =
                    s.split(',').map(|t| t.trim().parse::<f32>()).collect::<Result<_, _>>().map_err(|_| anyhow::anyhow!("background '{s}' is not white, black or r,g,b"))?;
                match v.as_slice() {
                    [r, g, b] if v.iter().all(|x| (0.0..=1.0).contains(x)) => Ok([*r, *g, *b]),
                    _ => bail!("background '{s}' must be three values in [0, 1]"),
                }
            }
        }
    }
}

/// Training pixels the paper preset's schedule was made for: the 2DGS
/// schedule (30,000 Stage I iterations) on ~100 views at 800x800.
pub const PAPER_SCHEDULE_PIXELS: u64 = 100 * 800 * 800;

/// The registered stages' settings sections under `preset`.
fn registered_sections(preset: &str) -> BTreeMap<String, toml::Value> {
    added_settings().iter().map(|s| (s.key.to_string(), toml::Value::Table((s.defaults)(preset)))).collect()
}

/// A note for `--preset paper` on a dataset with less than an eighth of
/// [`PAPER_SCHEDULE_PIXELS`] (`sizes`: the training views' width and
/// height), None otherwise. Measured on the H100 (perf/RESULTS.md,
/// twenty-second session): on the built-in glass (32 views at 64x64) the
/// paper preset ended at 27.15 dB test PSNR against the quick preset's
/// 28.73, and on `lantern` (60 views at 200x200) at 25.62 against 28.84,
/// its training views at 55-57 dB: the long schedule fits the few views'
/// noise. Only the two datasets were measured, hence a note, not a change.
pub fn paper_schedule_note(preset: &str, sizes: &[(u32, u32)]) -> Option<String> {
    let pixels: u64 = sizes.iter().map(|&(w, h)| w as u64 * h as u64).sum();
    if preset != "paper" || pixels.saturating_mul(8) >= PAPER_SCHEDULE_PIXELS {
        return None;
    }
    let (w, h) = sizes.first().copied().unwrap_or((0, 0));
    Some(format!(
        "note: --preset paper's schedule was made for ~100 views at 800x800 ({:.0} M training pixels); this dataset has {} views{} ({:.2} M). \
         On datasets this small it scored below --preset quick in our measurements (built-in glass 27.15 against 28.73 dB, lantern at 200x200 \
         25.62 against 28.84; perf/RESULTS.md): the long schedule fits the training views' noise",
        PAPER_SCHEDULE_PIXELS as f64 / 1e6,
        sizes.len(),
        if sizes.iter().all(|&s| s == (w, h)) && !sizes.is_empty() { format!(" at {w}x{h}") } else { String::new() },
        pixels as f64 / 1e6
    ))
}

/// A learning rate (a setting named `lr...`) above this is refused before
/// training: Adam moves a parameter by about its rate every iteration.
pub const LR_LIMIT: f64 = 1e3;

/// Whether the setting `key` (`section.key` or `key`) is a learning rate:
/// its own name starts with `lr`.
pub fn is_learning_rate(key: &str) -> bool {
    key.rsplit('.').next().is_some_and(|last| last.starts_with("lr"))
}

/// The most bytes a settings file (`--config`, `sweep --grid`) may hold.
pub const SETTINGS_FILE_LIMIT: u64 = 1 << 20;

/// A settings file's text (`what`: "config", "grid"): a regular file of
/// at most [`SETTINGS_FILE_LIMIT`] bytes of UTF-8, read no further than
/// that (`/dev/zero` or a FIFO is refused, not read until memory runs out).
pub fn read_text_capped(path: &Path, what: &str) -> Result<String> {
    use std::io::Read as _;
    crate::data::image_io::regular_file(path, what)?;
    let f = std::fs::File::open(path).with_context(|| format!("{}: cannot read the {what}", path.display()))?;
    let mut bytes = Vec::new();
    f.take(SETTINGS_FILE_LIMIT + 1).read_to_end(&mut bytes).with_context(|| format!("{}: cannot read the {what}", path.display()))?;
    if bytes.len() as u64 > SETTINGS_FILE_LIMIT {
        bail!("{}: over {} KiB; a {what} file is a few lines of TOML", path.display(), SETTINGS_FILE_LIMIT >> 10);
    }
    String::from_utf8(bytes).map_err(|_| anyhow::anyhow!("{}: not UTF-8 text; the {what} must be a TOML file", path.display()))
}

/// A table's keys with section keys as `section.key` (one level).
pub fn flatten(t: &toml::Table) -> Vec<(String, toml::Value)> {
    let mut out = Vec::new();
    for (k, v) in t {
        match v {
            toml::Value::Table(sub) => out.extend(sub.iter().map(|(k2, v2)| (format!("{k}.{k2}"), v2.clone()))),
            v => out.push((k.clone(), v.clone())),
        }
    }
    out
}
