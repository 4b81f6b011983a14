//! Stage II as the trainer drives it: the transition from Stage I (the
//! residual, the decision whether the scene calls for a reflection set, the
//! seeds and the light), and one iteration of the reflection set.

use super::bounds::normalization_box;
use super::checkpoint::{host_reflection_set, ReflHeader};
use super::env_init::{scene_env_map, SceneLight};
use super::model::{residual, ReflStepInput, ReflectionModel, ScatTrain};
use super::outputs::write_residual;
use super::seed::{hull_seeding, pane_seeds, SeedParams, SeedView};
use super::view_dependence::{view_dependence, VdMap};
use crate::outdir::OutDir;
use crate::train::config::TrainConfig;
use crate::train::stage::Stage;
use crate::train::stages::kind::{parse, Begun, LaterKind, Transition};
use crate::train::stages::layer::RenderLayer;
use crate::train::stages::rendered::ReflRendered;
use crate::train::stages::scattering::StepOutput;
use crate::train::stages::shared::{Iteration, LaterStage, Shared};
use anyhow::{Context as _, Result};
use std::any::Any;
use std::path::Path;
use std::sync::Arc;
use tgs_engine::{Buffer, Context};
use tgs_pipelines::{Camera, EnvProxy, HostEnvMap, Plane, ReflectionShading, TrainableSet};

pub use super::decision::ReflDecision;
pub use super::env_init::EnvInit;
pub use super::masks::seed_masks;
use super::masks::{glass_masks, GlassMask, MaskSource};

/// Stage II.
pub const STAGE: Stage = Stage("II");

/// Stage II as the schedule and the checkpoint know it.
pub struct Kind;

impl LaterKind for Kind {
    fn stage(&self) -> Stage {
        STAGE
    }

    fn key(&self) -> &'static str {
        "reflection"
    }

    fn iterations(&self, cfg: &TrainConfig) -> u32 {
        cfg.reflection.iterations
    }

    fn resumable(&self) -> &'static [&'static str] {
        &["reflection.iterations", "reflection.reseed"]
    }

    fn output_settings(&self) -> &'static [&'static str] {
        &["reflection.normal_min_r", "reflection.residual_normal_min_r", "reflection.normal_min_alpha"]
    }

    fn trains_scattering(&self, cfg: &TrainConfig) -> bool {
        cfg.reflection.train_scattering
    }

    /// The glass masks of `reflection.seed_masks`, read and matched to the views.
    fn preflight(&self, cfg: &TrainConfig, view_names: &[String], cameras: &[Camera]) -> Result<()> {
        let dir = &cfg.reflection.seed_masks;
        if !dir.is_empty() {
            seed_masks(Path::new(dir), view_names, cameras, cfg.downscale)?;
        }
        Ok(())
    }

    /// Also on a resume inside Stage II (its set exists, the frozen
    /// scattering colours are not cached yet), and as Stage II begins
    /// again after Stage III (`reflection.reseed`).
    fn needs_begin(&self, running: Option<&dyn LaterStage>, cache_empty: bool) -> bool {
        running.map(|m| m.stage()) != Some(STAGE) || cache_empty
    }

    /// The residual (maps into RUN/residual, or residual/round2), the
    /// decision, the seeds and the light; on a resume inside the stage
    /// only the cache, keeping the set and the decision it began with.
    fn begin(&self, t: Transition<'_>) -> Result<Begun> {
        let Transition { shared, previous, decision, round, files, quiet, .. } = t;
        // Stage II again (reflection.reseed): the light field and its
        // reflection set give way to a set seeded afresh.
        let reseed = previous.as_ref().is_some_and(|m| m.stage() != STAGE);
        let previous = previous.filter(|m| m.stage() == STAGE);
        let existing = previous.as_ref().map(|m| m.set().len());
        if existing.is_none() && !quiet {
            eprintln!("Stage II: measuring the residual of {} training views", shared.views.cameras.len());
        }
        let mut maps = match &files {
            Some(f) => Some(OutDir::open(&f.dir.join(if reseed { "residual/round2" } else { "residual" }), Some(f.dataset))?),
            None => None,
        };
        let names = files.as_ref().map(|f| f.view_names).unwrap_or_default();
        let iterations = shared.cfg.reflection.iterations;
        let kept = decision.clone();
        let lambda_mask = shared.cfg.reflection.lambda_mask > 0.0;
        let (masks, source) = if existing.is_some() && !lambda_mask { (None, MaskSource::None) } else { glass_masks(&shared, names)? };
        let ctx = shared.views.ctx.clone();
        let stems = crate::data::file_stems(names.iter().map(String::as_str));
        let (mut d, model) = begin(shared, existing, kept.as_ref(), reseed, round, masks.as_deref(), |i, cam, r| match (&mut maps, stems.get(i)) {
            (Some(maps), Some(name)) if existing.is_none() => write_residual(maps, name, cam, r),
            _ => Ok(()),
        })?;
        if d.seed_mask_coverage.is_some() {
            d.seed_mask_source = source.recorded();
        }
        *decision = Some(d.clone());
        let mut model: Option<Box<dyn LaterStage>> = match model {
            Some(m) => Some(Box::new(m)),
            None => previous,
        };
        // reflection.lambda_mask: the masks stay on the device for the losses.
        if let (true, Some(masks), Some(m)) = (lambda_mask, masks.as_deref(), model.as_mut().and_then(|m| m.as_any_mut()).and_then(|a| a.downcast_mut::<ReflectionModel>())) {
            m.masks = masks.iter().map(|mask| mask.as_deref().map(|g| GlassMask::upload(&ctx, g)).transpose()).collect::<Result<_>>()?;
        }
        let mut event = serde_json::Map::new();
        event.insert("reflection".into(), serde_json::to_value(&d)?);
        Ok(Begun { model, runs: d.run, message: d.message(reseed, iterations), event })
    }

    fn restore(&self, header: &serde_json::Value, ctx: &Arc<Context>, cfg: &TrainConfig, arrays: Vec<Vec<f32>>) -> Result<(Box<dyn LaterStage>, ReflDecision)> {
        let h: ReflHeader = parse(self, header)?;
        Ok((Box::new(h.restore(ctx, cfg, arrays)?), h.decision))
    }

    fn render_layer(&self, header: &serde_json::Value, cfg: &TrainConfig, arrays: Vec<Vec<f32>>, ctx: &Arc<Context>) -> Result<Box<dyn RenderLayer>> {
        let h: ReflHeader = parse(self, header)?;
        let k = h.check(&arrays)?;
        let set = host_reflection_set(&arrays)?;
        let env = h.env(&arrays, k);
        Ok(Box::new(super::render::EnvLayer::upload(ctx, &set, &env, cfg.reflection.fresnel.pipeline())?))
    }

    fn dropped_unless_kept(&self) -> Option<&'static str> {
        Some("reflection set")
    }

    fn files(&self) -> &'static [&'static str] {
        &["reflection.ply", "envmap.exr", "envmap.png", "envmap_depth.exr", "envmap_depth.png"]
    }

    /// `reflection.scattering_sh`.
    fn scattering_sh(&self, cfg: &TrainConfig, stage1: u32) -> u32 {
        cfg.reflection.scattering_degree(stage1)
    }
}

/// With glass masks (`SeedParams::relax`): the significance levels tried,
/// in order, where no hull point beats chance at
/// `reflection.seed_significance`. The masks are no noise, but few masked
/// views cannot beat 1e-6: 15 views whose masks cover 45% of the pixels
/// cannot even all together (0.45^15 = 6e-6).
const MASK_SIGNIFICANCE: [f64; 3] = [1e-4, 1e-2, 1e-1];

/// The view-dependence measure reduces each view to at most this many
/// pixels a side (box-averaged: Monte Carlo noise in the images, which
/// also spreads the residual across views, is then about as strong at any
/// image size) and samples at most this many pixels in all.
const VD_MAX_SIDE: u32 = 64;
const VD_SAMPLES: usize = 1 << 16;

/// Between Stage I and II: render every training view with the frozen
/// scattering set (cached in `s.cache` for Stage II), measure the residual
/// I_gt - I_scat on the GPU, and decide: below `reflection.min_residual`
/// the scene shows no view-dependent energy worth a reflection set (the
/// trainer then ends the schedule after Stage I). `existing`: the size of
/// a reflection set that exists (a resumed Stage II), with the decision it
/// was started with in `kept`; `reseed`: the second round, after Stage III
/// (`reflection.reseed`), which runs whatever its residual; `round`: 1 or 2.
/// `on_view(i, residual planes)` sees every view's residual (4 planes: r,
/// mean |r|) for saving. `masks`: each view's glass mask
/// (`reflection.seed_masks`), which the hull's seeds then come from, and
/// which make the stage run whatever the residual measured (if any pixel
/// is glass). Returns the decision and the new reflection set with its
/// light (None when one exists or the stage does not run).
pub fn begin(
    mut s: Shared<'_>,
    existing: Option<u32>,
    kept: Option<&ReflDecision>,
    reseed: bool,
    round: u32,
    masks: Option<&[Option<Vec<bool>>]>,
    on_view: impl FnMut(usize, &Camera, &[f32]) -> Result<()>,
) -> Result<(ReflDecision, Option<ReflectionModel>)> {
    let (cfg, v) = (s.cfg, s.views);
    let sh = cfg.sh_degree_at(cfg.iterations);
    let (copy, hull) = cfg.reflection.init.parts();
    let m = measure_views(&mut s, sh, hull && existing.is_none(), masks, on_view)?;
    // A resumed Stage II (its set exists) keeps the decision and seed
    // counts it was started with; only the cache was needed.
    if let (Some(kept), true) = (kept, existing.is_some()) {
        return Ok((kept.clone(), None));
    }
    let views = v.cameras.len().max(1);
    let vd = view_dependence(&m.vd_maps, (v.centre, v.extent), VD_SAMPLES);
    let mut d = ReflDecision {
        residual_mean: m.sum / views as f64,
        residual_fraction_over_0_05: m.over as f64 / m.pixels.max(1) as f64,
        threshold: cfg.reflection.min_residual as f64,
        view_dependence: vd.spread,
        view_dependence_samples: vd.samples,
        view_dependence_threshold: cfg.reflection.min_view_dependence as f64,
        run: false,
        reflection_gaussians: 0,
        seeds: 0,
        copied: 0,
        hull_empty: false,
        significance_dropped: false,
        env_from: None,
        env_proxy: None,
        seed_mask_coverage: None,
        seed_rim: None,
        seed_rim_curved: None,
        seed_planes: None,
        seed_faces: None,
        seed_faces_marked: false,
        seed_panes: None,
        seed_mask_source: None,
        seed_mask_views: None,
        seed_significance: None,
        pieces: None,
        round,
    };
    if let Some(m) = masks {
        let (glass, all) = m.iter().flatten().fold((0usize, 0usize), |(g, a), v| (g + v.iter().filter(|&&x| x).count(), a + v.len()));
        d.seed_mask_coverage = Some(glass as f64 / all.max(1) as f64);
        d.seed_mask_views = Some([m.iter().flatten().count() as u32, m.len() as u32]);
    }
    // A reflection set that exists (a resumed Stage II without a
    // recorded decision) was decided on when it was made, and the
    // second round (reflection.reseed) runs whatever its residual: the
    // first decided.
    // Glass masks decide alone: some glass, the stage runs whatever the
    // residual measured; none in any view, there is nothing to reflect.
    d.run = reseed
        || existing.is_some()
        || match d.seed_mask_coverage {
            Some(c) => c > 0.0,
            None => d.residual_mean >= d.threshold && d.view_dependence >= d.view_dependence_threshold,
        };
    let mut model = None;
    if d.run {
        if existing.is_none() {
            model = Some(seed_model(&s, &mut d, &m.maps, masks, (copy, hull), sh)?);
        }
        d.reflection_gaussians = model.as_ref().map(|m| m.set.len()).or(existing).unwrap_or(0);
    } else {
        s.cache.clear();
    }
    Ok((d, model))
}

/// What [`measure_views`] measured of the training views.
struct Measured {
    /// The sum over views of the mean residual magnitude.
    sum: f64,
    /// Pixels whose residual magnitude is over 0.05, and pixels in all.
    over: usize,
    pixels: usize,
    /// (view, hull map, depth) of the views that seed.
    maps: Vec<(usize, Vec<f32>, Vec<f32>)>,
    /// Every view reduced for the view-dependence measure.
    vd_maps: Vec<VdMap>,
}

/// Render every training view with the frozen scattering set (cached in
/// `s.cache` for Stage II at its own SH degree), measure the residual and
/// Stage I's surface depth, and keep the hull's maps when `seeding`
/// (each view's glass mask where `masks` are given, else its residual).
fn measure_views(
    s: &mut Shared<'_>,
    sh: u32,
    seeding: bool,
    masks: Option<&[Option<Vec<bool>>]>,
    mut on_view: impl FnMut(usize, &Camera, &[f32]) -> Result<()>,
) -> Result<Measured> {
    let (cfg, v) = (s.cfg, s.views);
    let shading = ReflectionShading::new(&v.ctx)?;
    let sh_view = cfg.reflection.scattering_degree(sh);
    let mut m = Measured { sum: 0.0, over: 0, pixels: 0, maps: Vec::new(), vd_maps: Vec::new() };
    s.cache.clear();
    for (i, cam) in v.cameras.iter().enumerate() {
        let n = (cam.width * cam.height) as usize;
        let buf = Buffer::<f32>::new(&v.ctx, "train.scat_cache", 3 * n)?;
        s.scattering.render_color_into(cam, sh, &v.background, &buf)?;
        let r = residual(&v.ctx, &shading, &v.targets[i], &buf, n as u32)?;
        let mag = &r[3 * n..4 * n];
        m.sum += mag.iter().map(|&v| v as f64).sum::<f64>() / n as f64;
        m.over += mag.iter().filter(|&&v| v > 0.05).count();
        m.pixels += n;
        on_view(i, cam, &r)?;
        // The frame still holds this view's render.
        let depth = s.scattering.last_plane(cam.width, cam.height, Plane::Median)?;
        // Stage II's scattering layer at its own degree (the residual
        // above, for the decision and the seeds, is Stage I's colour).
        if sh_view != sh {
            s.scattering.render_color_into(cam, sh_view, &v.background, &buf)?;
        }
        m.vd_maps.push(VdMap::new(cam, &r, &depth, VD_MAX_SIDE));
        if seeding {
            // Given masks stand in for the residual: 1 on the glass, 0
            // elsewhere, taken as they are (no blur, threshold 0.5).
            // A view without a mask among masked ones takes no part.
            match masks.map(|m| m.get(i).and_then(Option::as_ref)) {
                Some(Some(mask)) => m.maps.push((i, mask.iter().map(|&g| g as u8 as f32).collect(), depth)),
                Some(None) => {}
                None => m.maps.push((i, mag.to_vec(), depth)),
            }
        }
        s.cache.push(buf, sh_view);
    }
    Ok(m)
}

/// The new reflection set: the hull's seeds from `maps` (and a copy of
/// the Stage I set with `init` "copy", or when the hull is empty), with its
/// light; what it did is recorded in `d`. `init`: (copy, hull).
fn seed_model(
    s: &Shared<'_>,
    d: &mut ReflDecision,
    maps: &[(usize, Vec<f32>, Vec<f32>)],
    masks: Option<&[Option<Vec<bool>>]>,
    init: (bool, bool),
    sh: u32,
) -> Result<ReflectionModel> {
    let (cfg, v) = (s.cfg, s.views);
    let (copy, hull) = init;
    let rc = &cfg.reflection;
    let views: Vec<SeedView> = maps.iter().map(|(i, r, z)| SeedView { camera: v.cameras[*i], residual: r, depth: z }).collect();
    let p = SeedParams {
        threshold: rc.min_residual,
        agree: rc.seed_agree,
        max_rays: rc.seed_rays,
        normal: rc.seed_normal.for_source(masks.is_some()),
        significance: rc.seed_significance as f64,
        ..SeedParams::default()
    };
    // Regions marked in `tgs view`: their hull's facets are the marking's.
    d.seed_faces_marked = masks.is_some() && rc.seed_faces && !rc.seed_masks.is_empty() && super::masks::marked_regions(Path::new(&rc.seed_masks));
    let p = if masks.is_some() {
        SeedParams {
            threshold: 0.5,
            blur: 0,
            rim: rc.seed_rim,
            rim_all_around: rc.seed_rim_all_around,
            rim_hull: rc.seed_rim_hull,
            rim_curved: rc.seed_rim_curved,
            planes: rc.seed_planes,
            smooth: rc.seed_smooth,
            faces: rc.seed_faces && !d.seed_faces_marked,
            relax: &MASK_SIGNIFICANCE,
            ..p
        }
    } else {
        p
    };
    let panes = if masks.is_some() && rc.seed_panes && !rc.seed_masks.is_empty() { super::masks::marked_panes(Path::new(&rc.seed_masks))? } else { None };
    let seeds = if let (true, Some(panes)) = (hull, &panes) {
        let seeds = pane_seeds(&views, panes, &p);
        d.seed_panes = Some([panes.len() as u32, seeds.len() as u32]);
        seeds
    } else if hull {
        let h = hull_seeding(&views, &p);
        d.seed_significance = h.significance_relaxed;
        d.significance_dropped = h.significance_dropped;
        d.seed_rim = p.rim.then_some([h.rim_views as u32, h.rim_seeds as u32]);
        d.seed_rim_curved = (p.rim && p.rim_curved).then_some(h.rim_curved as u32);
        d.seed_planes = p.planes.then_some([h.plane_pieces as u32, h.plane_seeds as u32]);
        d.seed_faces = p.faces.then_some(h.faces.map(|c| c as u32));
        h.seeds
    } else {
        Vec::new()
    };
    // No ray crossed carved space into the hull (e.g. a Stage I
    // too short to carve anything): the paper's initialisation,
    // a copy of the Stage I set, rather than no Stage II.
    d.hull_empty = hull && seeds.is_empty();
    let g = if copy || d.hull_empty { Some(s.scattering.set.params.download()?) } else { None };
    d.seeds = seeds.len() as u32;
    d.copied = g.as_ref().map(|g| g.len() as u32).unwrap_or(0);
    let mut means: Vec<f32> = g.as_ref().map(|g| g.means.clone()).unwrap_or_default();
    means.extend(seeds.iter().flat_map(|s| s.position));
    let env = initial_light(s, d, &means, sh)?;
    ReflectionModel::from_scattering(&v.ctx, g.as_ref(), &seeds, env, rc, cfg.adam_eps)
}

/// The reflection set's first light (`reflection.env_init`: black, or the
/// scene seen from the set's points, with its depth), with the proxy
/// sphere of `reflection.env_radius`; recorded in `d`.
fn initial_light(s: &Shared<'_>, d: &mut ReflDecision, means: &[f32], sh: u32) -> Result<HostEnvMap> {
    use crate::train::stages::reflection::settings::EnvStart;
    let (cfg, v) = (s.cfg, s.views);
    let rc = &cfg.reflection;
    let mut env = if matches!(rc.env_init, EnvStart::Scene | EnvStart::SceneDepth) {
        let scat = s.scattering.set.params.download()?;
        let depth = rc.env_init == EnvStart::SceneDepth;
        let (env, info) = scene_env_map(&v.ctx, SceneLight { set: &scat, sh_degree: sh, background: &v.background }, means, rc.env_res, cfg.adam_eps, depth)?;
        d.env_from = Some(info);
        // The depth map's proxy: at the centre it was rendered from.
        d.env_proxy = env.proxy.map(|p| EnvProxy::packed(Some(p)));
        env
    } else {
        HostEnvMap::constant(rc.env_res, 0.0)?
    };
    if rc.env_radius > 0.0 {
        let p = env_proxy(means, &v.cameras, rc.env_radius);
        d.env_proxy = p.map(|p| EnvProxy::packed(Some(p)));
        env.proxy = p;
    }
    Ok(env)
}

impl LaterStage for ReflectionModel {
    fn stage(&self) -> Stage {
        STAGE
    }

    fn iterate(&mut self, s: Shared<'_>, x: &Iteration) -> Result<StepOutput> {
        let (cfg, v) = (s.cfg, s.views);
        let cam = v.cameras[x.view as usize];
        let train = cfg.reflection.train_scattering;
        let scat = if train { None } else { Some(s.cache.get(x.view as usize).context("the scattering colour cache is missing")?) };
        let sh_degree = cfg.reflection.scattering_degree(cfg.sh_degree_at(cfg.iterations));
        let scat_train = train.then_some(ScatTrain { model: s.scattering, sh_degree, background: v.background, global_iteration: x.global });
        let masks = std::mem::take(&mut self.masks);
        let input = ReflStepInput {
            iteration: x.stage,
            camera: &cam,
            target: &v.targets[x.view as usize],
            scat,
            // The reflection geometry starts converged: positions move at
            // Stage I's final rate (method-notes §3.7), times
            // `lr_means_scale`.
            lr_means: cfg.lr_means_final * cfg.reflection.lr_means_scale * v.extent,
            profile: x.profile,
            mask: masks.get(x.view as usize).and_then(Option::as_ref),
        };
        let out = self.step(cfg, &input, scat_train);
        self.masks = masks;
        out
    }

    fn render(&mut self, cam: &Camera, scat: &Buffer<f32>) -> Result<ReflRendered> {
        ReflectionModel::render(self, cam, scat)
    }

    fn set(&self) -> &TrainableSet {
        &self.set
    }

    fn write_outputs(&self, out: &Path) -> Result<()> {
        ReflectionModel::write_outputs(self, out)
    }

    fn into_set(self: Box<Self>) -> TrainableSet {
        ReflectionModel::into_set(*self)
    }

    fn save_state<'a>(&'a self, d: &ReflDecision, bufs: &mut Vec<(&'a Buffer<f32>, usize)>) -> Result<serde_json::Value> {
        Ok(serde_json::to_value(ReflHeader::save(self, d, bufs))?)
    }

    fn as_any(&self) -> &dyn Any {
        self
    }

    fn as_any_mut(&mut self) -> Option<&mut dyn Any> {
        Some(self)
    }
}

/// The cube map's parallax proxy for `reflection.env_radius` = `radius`:
/// centred on the box of the reflection set's starting positions `means`
/// (as `env_init = "scene"` renders from), of `radius` x the mean distance
/// from there to the `cameras`. None when nothing sets a positive radius.
pub fn env_proxy(means: &[f32], cameras: &[Camera], radius: f32) -> Option<EnvProxy> {
    if means.is_empty() || cameras.is_empty() {
        return None;
    }
    let (centre, _) = normalization_box(means);
    let dist = cameras
        .iter()
        .map(|c| {
            let e = c.centre();
            (0..3).map(|k| ((e[k] - centre[k]) as f64).powi(2)).sum::<f64>().sqrt()
        })
        .sum::<f64>()
        / cameras.len() as f64;
    let r = (radius as f64 * dist) as f32;
    (r > 0.0 && r.is_finite()).then_some(EnvProxy { centre, radius: r })
}
