//! A view's blend weights kept for later renders of the same geometry
//! (Stage III, where the scattering set's colour alone trains): each
//! pixel's contributions (the Gaussian and its weight w = alpha T, in
//! blending order) and its final transmittance, captured once after a
//! forward that fitted its frame (`glsl/raster/capture.comp`), and the same
//! contributions grouped by Gaussian. With the geometry and opacity fixed,
//! a view's colour is linear in the Gaussians' colours: a later render is
//! C = sum_j w_j c_j + T bg over the pixel's list
//! (`glsl/raster/kept_colour.comp`, bit for bit the tile forward's colour
//! planes; the other planes are not written) and the colour gradient of
//! Gaussian g is sum w gC over the pixels it reached
//! (`glsl/raster/kept_grad.comp`), in pixel order, as one gradient record
//! per Gaussian that the per-Gaussian reduce then takes through the SH
//! chain rule (and, fused, Adam) as after the tile backward. Neither walks
//! a tile's splats or intersects a ray with one: on lavapipe the
//! scattering set's colour step in Stage III took the forward and the
//! colour-only tile backward, about half of a Stage III iteration
//! (perf/RESULTS.md, forty-eighth entry). The gradient is the colour-only
//! backward's up to the order of the sums (tests/tests/kept_weights.rs).

use super::{Camera, Frame, Gaussians, Moments, Push, Rasterizer, RecordAccess, Splats, WG};
use crate::shaders;
use anyhow::{bail, Context as _, Result};
use tgs_engine::{Buffer, BufferBinding, Kernel, KernelDesc, Recorder};

/// The kept-weights kernels for one tile size (the capture walks tiles).
pub(super) struct KeptKernels {
    /// The projection's variant that writes the colours alone.
    project: Kernel,
    count: Kernel,
    write: Kernel,
    colour: Kernel,
    grad: Kernel,
}

/// One view's blend weights, kept (see the module's note).
pub struct KeptWeights {
    n: u32,
    size: (u32, u32),
    contributions: u32,
    /// Passes of the colour and the gradient kernels (the most
    /// contributions of one pixel, of one Gaussian, over the span).
    pixel_passes: u32,
    gaussian_passes: u32,
    /// [0, npix]: each pixel's first contribution; then each contribution's Gaussian.
    pix: Buffer<u32>,
    /// [0, npix): each pixel's final transmittance; then each contribution's weight.
    pix_w: Buffer<f32>,
    /// [0, n]: each Gaussian's first contribution; then each one's pixel.
    gau: Buffer<u32>,
    /// Each contribution's weight, grouped by Gaussian.
    gau_w: Buffer<f32>,
    /// The output planes after the features (alpha .. distortion), where
    /// kept: a render from the weights then restores them.
    planes: Option<Buffer<f32>>,
}

impl KeptWeights {
    /// Bytes of device memory held.
    pub fn bytes(&self) -> u64 {
        self.pix.bytes() + self.pix_w.bytes() + self.gau.bytes() + self.gau_w.bytes() + self.planes.as_ref().map_or(0, |p| p.bytes())
    }
    /// Pixel-Gaussian contributions kept.
    pub fn contributions(&self) -> u32 {
        self.contributions
    }
}

/// Bytes of the kept weights of `npix` pixels, `n` Gaussians and `c`
/// contributions, with `planes` output planes per pixel.
fn weights_bytes(npix: u64, n: u64, c: u64, planes: u64) -> u64 {
    4 * ((npix + 1 + c) + (npix + c) + (n + 1 + c) + c + planes * npix)
}

impl Rasterizer {
    fn kept_kernels(&self, tile: u32) -> Result<&KeptKernels> {
        let slot = &self.kept_kernels[(tile == super::SMALL_TILE) as usize];
        if let Some(k) = slot.get() {
            return Ok(k);
        }
        let caps = self.ctx.caps();
        let spec = [(0, WG), (1, caps.min_subgroup_size.max(1)), (4, self.channels), (5, self.batch), (7, tile)];
        let push_bytes = std::mem::size_of::<Push>() as u32;
        let k = |name, spirv| Kernel::new(&self.ctx, &KernelDesc { name, spirv, spec: &spec, push_bytes, subgroup_size: None, full_subgroups: false });
        let grad = if self.records == RecordAccess::Address { shaders::RASTER_KEPT_GRAD_RECORDS_BDA } else { shaders::RASTER_KEPT_GRAD };
        // The colours as the tile kernels' projection computes them (its
        // storage or texel variant).
        let project = match self.kernels {
            super::RasterKernels::Workgroup => shaders::RASTER_PROJECT_COLOUR,
            super::RasterKernels::Subgroup => shaders::RASTER_PROJECT_TEXEL_COLOUR,
        };
        let kernels = KeptKernels {
            project: k("raster.project", project)?,
            count: k("raster.capture", shaders::RASTER_CAPTURE)?,
            write: k("raster.capture", shaders::RASTER_CAPTURE_WRITE)?,
            colour: k("raster.kept_colour", shaders::RASTER_KEPT_COLOUR)?,
            grad: k("raster.kept_grad", grad)?,
        };
        Ok(slot.get_or_init(|| kernels))
    }

    /// Contributions one invocation of the colour or gradient kernel sums
    /// per pass: within the loop budget of a CPU driver (each contribution
    /// a loop over the channels), one pass elsewhere; a forced span
    /// ([`Rasterizer::with_span`]) where given (tests: several passes).
    fn kept_span(&self) -> u32 {
        if let Some(s) = self.tile_spec.span {
            s
        } else if self.ctx.caps().is_cpu() {
            (super::LOOP_BUDGET as u32 / (self.channels + 2)).max(1)
        } else {
            1 << 30
        }
    }

    /// Keep the blend weights of `frame`'s last view of `g` (call it after
    /// [`Rasterizer::fit`] returned true for that forward and before
    /// anything else used the frame), and with `planes` its output planes
    /// after the features (alpha, depth, normal, median depth, distortion:
    /// fixed with the geometry), which a render from the weights then
    /// restores. `Ok(None)` when they would take more than `max_bytes`, a
    /// texel buffer's largest length, or a frame whose gradient records
    /// cannot hold one per Gaussian: that view is then rendered in full.
    /// Two submissions (counting, then writing), and the grouping by
    /// Gaussian on the host.
    pub fn keep_weights(&self, g: &Gaussians, frame: &Frame, max_bytes: u64, planes: bool) -> Result<Option<KeptWeights>> {
        let (n, npix) = (g.n, (frame.width * frame.height) as usize);
        if frame.last_intersections > frame.capacity {
            bail!("the frame's last view ({} intersections) did not fit its capacity of {}: there are no weights to keep", frame.last_intersections, frame.capacity);
        }
        if frame.capacity < n {
            return Ok(None);
        }
        let k = self.kept_kernels(frame.tile)?;
        let push = self.push(g, frame, 0);
        let groups = self.groups(frame.tiles() * frame.tile * frame.tile);
        let state = Buffer::<u32>::uninit(&self.ctx, "raster.capture_state", 3 * npix).context("capturing a view's blend weights")?;
        let mut bindings = vec![frame.cam.binding(), frame.ranges.binding(), frame.isect_vals.binding(), frame.isect_gid.binding(), frame.proj.binding(), state.binding()];
        let capture = |kernel: &Kernel, bindings: &[BufferBinding]| -> Result<()> {
            let mut rec = Recorder::new(&self.ctx)?;
            for s in 0..frame.spans {
                rec.dispatch(kernel, bindings, bytemuck::bytes_of(&Push { span_index: s, ..push }), groups)?;
            }
            rec.submit_and_wait().map(|_| ())
        };
        capture(&k.count, &bindings)?;
        let counts = state.download_range(npix, npix)?;
        let mut first = Vec::with_capacity(npix + 1);
        let mut total = 0u64;
        for &c in &counts {
            first.push(total as u32);
            total += c as u64;
        }
        let most_per_pixel = counts.iter().copied().max().unwrap_or(0);
        let max_texels = self.ctx.caps().max_texel_buffer_elements;
        // The kernels read the lists, the projected colours and the image
        // gradient as texel buffers.
        let longest = (npix as u64 + 1 + total).max(n as u64 + 1 + total).max(frame.pfeat.len() as u64).max(frame.grad_out.len() as u64);
        let rest = if planes { (super::Plane::count(self.channels) - self.channels) as usize } else { 0 };
        if total > u32::MAX as u64 / 2 || longest > max_texels || weights_bytes(npix as u64, n as u64, total, rest as u64) > max_bytes {
            return Ok(None);
        }
        let c = total as usize;
        first.push(c as u32);
        first.resize(npix + 1 + c, 0);
        let pix = Buffer::from_slice(&self.ctx, "raster.kept_pixels", &first).context("keeping a view's blend weights")?;
        let pix_w = Buffer::<f32>::uninit(&self.ctx, "raster.kept_pixel_weights", npix + c).context("keeping a view's blend weights")?;
        bindings.extend([pix.binding(), pix_w.binding()]);
        capture(&k.write, &bindings)?;
        let planes = match rest {
            0 => None,
            _ => {
                let kept = Buffer::<f32>::uninit(&self.ctx, "raster.kept_planes", rest * npix).context("keeping a view's planes")?;
                let mut rec = Recorder::new(&self.ctx)?;
                rec.copy(&frame.out.slice(self.channels as usize * npix, rest * npix), &kept.binding(), 4 * (rest * npix) as u64)?;
                rec.submit_and_wait()?;
                Some(kept)
            }
        };

        // Grouped by Gaussian, each group in pixel order.
        let ids = pix.download_range(npix + 1, c)?;
        let w = pix_w.download_range(npix, c)?;
        let mut gfirst = vec![0u32; n as usize + 1];
        for &id in &ids {
            if id >= n {
                bail!("a captured contribution names Gaussian {id} of {n}");
            }
            gfirst[id as usize + 1] += 1;
        }
        let most_per_gaussian = gfirst.iter().copied().max().unwrap_or(0);
        for i in 0..n as usize {
            gfirst[i + 1] += gfirst[i];
        }
        let mut at = gfirst.clone();
        let mut gau = gfirst;
        gau.resize(n as usize + 1 + c, 0);
        let mut gau_w = vec![0f32; c];
        for px in 0..npix {
            for j in first[px] as usize..first[px + 1] as usize {
                let slot = &mut at[ids[j] as usize];
                gau[n as usize + 1 + *slot as usize] = px as u32;
                gau_w[*slot as usize] = w[j];
                *slot += 1;
            }
        }
        let span = self.kept_span();
        Ok(Some(KeptWeights {
            n,
            size: (frame.width, frame.height),
            contributions: c as u32,
            pixel_passes: most_per_pixel.div_ceil(span).max(1),
            gaussian_passes: most_per_gaussian.div_ceil(span).max(1),
            pix,
            pix_w,
            gau: Buffer::from_slice(&self.ctx, "raster.kept_gaussians", &gau).context("keeping a view's blend weights")?,
            gau_w: Buffer::from_slice(&self.ctx, "raster.kept_gaussian_weights", &gau_w).context("keeping a view's blend weights")?,
            planes,
        }))
    }

    fn check_kept(&self, kept: &KeptWeights, g: &Gaussians, frame: &Frame) -> Result<()> {
        if kept.n != g.n {
            bail!("the kept weights are of {} Gaussians; the set has {}", kept.n, g.n);
        }
        if kept.size != (frame.width, frame.height) {
            bail!("the kept weights are of a {}x{} view; the frame is {}x{}", kept.size.0, kept.size.1, frame.width, frame.height);
        }
        Ok(())
    }

    /// Record the colour planes of the view whose weights `kept` holds (the
    /// same Gaussians' geometry and opacity, the same camera; the colours
    /// may differ): the projection (this step's colours), then the sums.
    /// The other planes of `frame.out` are restored where `kept` holds
    /// them, and left as they are otherwise. The view fits its frame
    /// ([`Rasterizer::fit`] and the fit gate see no intersections).
    pub fn record_forward_weights(&self, rec: &mut Recorder, s: Splats, cam: &Camera, background: &[f32], frame: &Frame, kept: &KeptWeights) -> Result<()> {
        self.check_kept(kept, s.g, frame)?;
        let push = self.begin_forward(rec, &s, cam, background, frame)?;
        let k = self.kept_kernels(frame.tile)?;
        // The splats are the weights' (frozen with the geometry): only the
        // colours are projected again.
        self.record_project_with(rec, &k.project, false, s.g, s.features, &push, frame)?;
        let bindings = [frame.cam.binding(), frame.pfeat.binding(), kept.pix.binding(), kept.pix_w.binding(), frame.out.binding()];
        let sc = rec.begin_scope("raster.kept_colour");
        for p in 0..kept.pixel_passes {
            let push = Push { span: self.kept_span(), span_index: p, spans: kept.pixel_passes, ..push };
            rec.dispatch(&k.colour, &bindings, bytemuck::bytes_of(&push), self.groups(frame.width * frame.height))?;
        }
        let npix = (frame.width * frame.height) as usize;
        if let Some(p) = &kept.planes {
            rec.copy(&p.binding(), &frame.out.slice(self.channels as usize * npix, p.len()), p.bytes())?;
        }
        rec.end_scope(sc);
        rec.update(&frame.stats.slice(0, 2), bytemuck::cast_slice(&[0u32, 0]))?;
        rec.read_back(&frame.stats, 0, &frame.stats_host)
    }

    /// The colour gradient records of the view whose weights `kept` holds,
    /// from the colour planes' gradients in `frame.grad_out`, one record
    /// per Gaussian, with the reduce's order and ranges (in
    /// `frame.depth_ids` and `frame.offsets`). Returns the records' binding.
    fn record_kept_grad(&self, rec: &mut Recorder, g: &Gaussians, frame: &Frame, kept: &KeptWeights) -> Result<BufferBinding> {
        self.check_kept(kept, g, frame)?;
        if frame.capacity < g.n {
            bail!("the frame's gradient records hold {} intersections; the kept weights need one per Gaussian ({})", frame.capacity, g.n);
        }
        let k = self.kept_kernels(frame.tile)?;
        let records = match &frame.records_address {
            Some(a) => {
                rec.keep_alive(frame.isect_grads.binding());
                a.binding()
            }
            None => frame.isect_grads.binding(),
        };
        let bindings = [frame.grad_out.binding(), kept.gau.binding(), kept.gau_w.binding(), frame.depth_ids.binding(), frame.offsets.binding(), records.clone()];
        let sc = rec.begin_scope("raster.kept_grad");
        for p in 0..kept.gaussian_passes {
            let push = Push { span: self.kept_span(), span_index: p, spans: kept.gaussian_passes, ..self.push(g, frame, 0) };
            rec.dispatch(&k.grad, &bindings, bytemuck::bytes_of(&push), self.groups(g.n))?;
        }
        rec.end_scope(sc);
        Ok(records)
    }

    /// [`Rasterizer::record_backward_colour_with`] for a view rendered by
    /// [`Rasterizer::record_forward_weights`]: the feature gradients to
    /// `d_features` (and the colour's dependence on the view direction in
    /// the others, in `grads`) from the kept weights.
    pub fn record_backward_colour_weights(&self, rec: &mut Recorder, s: Splats, grads: &Gaussians, d_features: &Buffer<f32>, frame: &Frame, kept: &KeptWeights) -> Result<()> {
        let records = self.record_kept_grad(rec, s.g, frame, kept)?;
        self.record_reduce(rec, s, grads, d_features, frame, records)
    }

    /// [`Rasterizer::record_backward_adam`] with `step.features_only` for a
    /// view rendered by [`Rasterizer::record_forward_weights`]: the colour's
    /// Adam step from the kept weights.
    pub fn record_colour_adam_weights(&self, rec: &mut Recorder, g: &Gaussians, step: Moments, sh_degree: u32, frame: &Frame, kept: &KeptWeights) -> Result<()> {
        if !step.features_only {
            bail!("kept weights step the colour alone (the geometry they were captured with must not change)");
        }
        self.check_moments(g, &step)?;
        let records = self.record_kept_grad(rec, g, frame, kept)?;
        self.record_reduce_adam(rec, g, step, sh_degree, frame, records, None)
    }
}
