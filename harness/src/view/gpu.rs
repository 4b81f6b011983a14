//! The viewer's Vulkan host: an instance with the window system's surface
//! extensions, a device whose queue computes and presents, and a swapchain
//! the frames are copied into. tgs adopts this device and queue
//! ([`Context::adopt`]), as any host renderer embedding it would.

use anyhow::{bail, Context as _, Result};
use ash::vk;
use raw_window_handle::{HasDisplayHandle, HasWindowHandle};
use std::sync::Arc;
use tgs_engine::{AdoptInfo, Buffer, Context, DeviceSelector, EnabledFeatures, Recorder};
use tgs_pipelines::PixelOrder;

/// The swapchain of the window's current size.
struct Chain {
    swapchain: vk::SwapchainKHR,
    images: Vec<vk::Image>,
    /// Signalled when the copy into image i is done; presentation waits on it.
    copied: Vec<vk::Semaphore>,
    extent: (u32, u32),
}

pub struct Gpu {
    _entry: ash::Entry,
    instance: ash::Instance,
    surface_fn: ash::khr::surface::Instance,
    surface: vk::SurfaceKHR,
    physical: vk::PhysicalDevice,
    device: ash::Device,
    queue: vk::Queue,
    swapchain_fn: ash::khr::swapchain::Device,
    pool: vk::CommandPool,
    fence: vk::Fence,
    acquired: vk::Semaphore,
    format: vk::SurfaceFormatKHR,
    pub order: PixelOrder,
    chain: Option<Chain>,
    /// The adopted context; dropped before the device.
    ctx: Option<Arc<Context>>,
    pub device_name: String,
}

/// What became of a frame.
pub enum Presented {
    /// Shown (the pixels captured when asked).
    Shown(Option<Vec<u32>>),
    /// The window has no area (minimised): nothing shown.
    Hidden,
    /// The surface changed: the swapchain was rebuilt; draw again.
    Stale,
}

impl Gpu {
    /// A device for `window` chosen by `sel` among those whose queue can
    /// compute and present to it.
    pub fn new(window: &(impl HasDisplayHandle + HasWindowHandle), sel: &DeviceSelector) -> Result<Gpu> {
        let display = window.display_handle().context("the window's display")?.as_raw();
        let handle = window.window_handle().context("the window's handle")?.as_raw();
        // SAFETY: loading the system's Vulkan loader; its symbols are used only through ash.
        let entry = unsafe { ash::Entry::load() }.context("no Vulkan loader (install mesa-vulkan-drivers or a GPU driver; scripts/setup.sh)")?;
        let exts = ash_window::enumerate_required_extensions(display).context("the window system's Vulkan surface extensions")?;
        let app = vk::ApplicationInfo::default().application_name(c"tgs view").api_version(vk::API_VERSION_1_3);
        // SAFETY: the create info and the extension names it points to live until the call returns.
        let instance = unsafe { entry.create_instance(&vk::InstanceCreateInfo::default().application_info(&app).enabled_extension_names(exts), None) }
            .context("creating a Vulkan instance with surface support")?;
        // SAFETY: the display and window handles come from a live window that outlives the surface (the
        // viewer drops the Gpu before the window).
        let surface = unsafe { ash_window::create_surface(&entry, &instance, display, handle, None) }.context("creating the window's Vulkan surface")?;
        let surface_fn = ash::khr::surface::Instance::new(&entry, &instance);
        let (physical, family, device_name) = pick(&instance, &surface_fn, surface, sel)?;
        // SAFETY: `physical` was enumerated from `instance`.
        let features = unsafe { enabled_features(&instance, physical) };
        let mut want13 =
            vk::PhysicalDeviceVulkan13Features::default().subgroup_size_control(features.subgroup_size_control).compute_full_subgroups(features.compute_full_subgroups);
        let prio = [1.0f32];
        let queues = [vk::DeviceQueueCreateInfo::default().queue_family_index(family).queue_priorities(&prio)];
        let dev_exts = [ash::khr::swapchain::NAME.as_ptr()];
        let info = vk::DeviceCreateInfo::default().queue_create_infos(&queues).enabled_extension_names(&dev_exts).push_next(&mut want13);
        // SAFETY: every pointer in `info` lives until the call returns; the family supports compute and present.
        let device = unsafe { instance.create_device(physical, &info, None) }.context("creating the Vulkan device")?;
        // SAFETY: queue 0 of a family the device was created with.
        let queue = unsafe { device.get_device_queue(family, 0) };
        let swapchain_fn = ash::khr::swapchain::Device::new(&instance, &device);
        // SAFETY: plain create infos on the live device.
        let (pool, fence, acquired) = unsafe {
            (
                device.create_command_pool(&vk::CommandPoolCreateInfo::default().queue_family_index(family).flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER), None)?,
                device.create_fence(&vk::FenceCreateInfo::default(), None)?,
                device.create_semaphore(&vk::SemaphoreCreateInfo::default(), None)?,
            )
        };
        // SAFETY: the surface belongs to this instance and `physical` can present to it.
        let formats = unsafe { surface_fn.get_physical_device_surface_formats(physical, surface) }?;
        let (format, order) = choose_format(&formats)?;
        let enabled = EnabledFeatures { buffer_device_address: false, ..features };
        // SAFETY: the handles are this Gpu's own and outlive the context (dropped first in Drop).
        let ctx = unsafe {
            Context::adopt(AdoptInfo {
                entry: entry.clone(),
                instance: instance.handle(),
                physical_device: physical,
                device: device.handle(),
                queue_family_index: family,
                queue,
                enabled,
            })?
        };
        Ok(Gpu {
            _entry: entry,
            instance,
            surface_fn,
            surface,
            physical,
            device,
            queue,
            swapchain_fn,
            pool,
            fence,
            acquired,
            format,
            order,
            chain: None,
            ctx: Some(ctx),
            device_name,
        })
    }

    pub fn ctx(&self) -> &Arc<Context> {
        self.ctx.as_ref().expect("the context lives as long as the Gpu")
    }

    /// The swapchain's size for a window of `size`, rebuilt when it differs
    /// or the surface went stale; None while the window has no area.
    pub fn extent(&mut self, size: (u32, u32)) -> Result<Option<(u32, u32)>> {
        // SAFETY: the surface and physical device are this Gpu's.
        let caps = unsafe { self.surface_fn.get_physical_device_surface_capabilities(self.physical, self.surface) }?;
        let want = if caps.current_extent.width != u32::MAX { (caps.current_extent.width, caps.current_extent.height) } else { size };
        if want.0 == 0 || want.1 == 0 {
            return Ok(None);
        }
        if self.chain.as_ref().is_some_and(|c| c.extent == want) {
            return Ok(Some(want));
        }
        self.rebuild(want, &caps)?;
        Ok(Some(want))
    }

    fn rebuild(&mut self, extent: (u32, u32), caps: &vk::SurfaceCapabilitiesKHR) -> Result<()> {
        // SAFETY: waiting for the queue: no submission uses the old swapchain after this.
        unsafe { self.device.queue_wait_idle(self.queue) }?;
        let old = self.chain.take();
        let count = (caps.min_image_count + 1).min(if caps.max_image_count == 0 { u32::MAX } else { caps.max_image_count });
        let usage = vk::ImageUsageFlags::TRANSFER_DST | vk::ImageUsageFlags::TRANSFER_SRC;
        if !caps.supported_usage_flags.contains(usage) {
            bail!("this surface's images cannot be copied to and from ({:?}); tgs view needs both", caps.supported_usage_flags);
        }
        let info = vk::SwapchainCreateInfoKHR::default()
            .surface(self.surface)
            .min_image_count(count)
            .image_format(self.format.format)
            .image_color_space(self.format.color_space)
            .image_extent(vk::Extent2D { width: extent.0, height: extent.1 })
            .image_array_layers(1)
            .image_usage(usage)
            .pre_transform(caps.current_transform)
            .composite_alpha(vk::CompositeAlphaFlagsKHR::OPAQUE)
            .present_mode(vk::PresentModeKHR::FIFO)
            .clipped(true)
            .old_swapchain(old.as_ref().map_or(vk::SwapchainKHR::null(), |c| c.swapchain));
        // SAFETY: the info names this Gpu's surface and the old swapchain (retired, idle).
        let swapchain = unsafe { self.swapchain_fn.create_swapchain(&info, None) }.with_context(|| format!("creating a {}x{} swapchain", extent.0, extent.1))?;
        if let Some(c) = old {
            self.destroy_chain(c);
        }
        // SAFETY: the swapchain was just created on this device.
        let images = unsafe { self.swapchain_fn.get_swapchain_images(swapchain) }?;
        // SAFETY: plain create infos on the live device.
        let copied = images.iter().map(|_| unsafe { self.device.create_semaphore(&vk::SemaphoreCreateInfo::default(), None) }).collect::<Result<Vec<_>, _>>()?;
        self.chain = Some(Chain { swapchain, images, copied, extent });
        Ok(())
    }

    fn destroy_chain(&self, c: Chain) {
        // SAFETY: the queue is idle (every caller waited), so nothing uses the chain's objects.
        unsafe {
            for s in c.copied {
                self.device.destroy_semaphore(s, None);
            }
            self.swapchain_fn.destroy_swapchain(c.swapchain, None);
        }
    }

    /// Show `pixels` (packed in [`Gpu::order`], the swapchain's size):
    /// `draw` records what writes them (tgs commands into the frame's
    /// command buffer) and says whether the frame will be whole; the copy
    /// to the next image follows in the same submission. With `capture`,
    /// the image is read back after the copy (what the window shows).
    pub fn present(&mut self, pixels: &Buffer<u32>, capture: bool, draw: impl FnOnce(&mut Recorder) -> Result<()>) -> Result<Presented> {
        let Some(chain) = self.chain.as_ref() else { return Ok(Presented::Hidden) };
        let (w, h) = chain.extent;
        if pixels.len() < (w * h) as usize {
            bail!("{} packed pixels for a {w}x{h} swapchain", pixels.len());
        }
        // SAFETY: the swapchain is live; the semaphore is unsignalled (each acquire's wait completed).
        let index = match unsafe { self.swapchain_fn.acquire_next_image(chain.swapchain, u64::MAX, self.acquired, vk::Fence::null()) } {
            Ok((i, _)) => i,
            Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => return self.stale(),
            Err(e) => return Err(e).context("acquiring a swapchain image"),
        };
        let (image, copied) = (chain.images[index as usize], chain.copied[index as usize]);
        let readback = if capture { Some(Buffer::<u32>::uninit(self.ctx(), "view.capture", (w * h) as usize)?) } else { None };
        // SAFETY: `pool` is this Gpu's and no command buffer of it is pending (every frame is waited for).
        let cmd = unsafe { self.device.allocate_command_buffers(&vk::CommandBufferAllocateInfo::default().command_pool(self.pool).command_buffer_count(1))? }[0];
        // SAFETY: `cmd` was just allocated: it is in the initial state.
        unsafe { self.device.begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT))? };
        // SAFETY: `cmd` is a primary command buffer of a pool of the context's queue family, and recording.
        let mut rec = unsafe { Recorder::record_into(self.ctx(), cmd, 0)? };
        let drawn = draw(&mut rec).and_then(|_| rec.finish().map(|_| ()));
        // SAFETY: `cmd` is recording; tgs's trailing barrier makes its writes visible to the copy.
        unsafe { self.record_copy(cmd, image, (w, h), pixels.raw(), readback.as_ref().map(|b| b.raw())) };
        // SAFETY: `cmd` is recording; it ends once.
        unsafe { self.device.end_command_buffer(cmd) }?;
        let waits = [self.acquired];
        let stages = [vk::PipelineStageFlags::TRANSFER];
        let signals = [copied];
        let cmds = [cmd];
        let submit = vk::SubmitInfo::default().wait_semaphores(&waits).wait_dst_stage_mask(&stages).command_buffers(&cmds).signal_semaphores(&signals);
        // SAFETY: everything the submission names is live until the fence is waited for below.
        let done = unsafe {
            self.device
                .queue_submit(self.queue, &[submit], self.fence)
                .and_then(|_| self.device.wait_for_fences(&[self.fence], true, u64::MAX))
                .and_then(|_| self.device.reset_fences(&[self.fence]))
        };
        drop(rec);
        // SAFETY: the submission that used `cmd` completed (or never started).
        unsafe { self.device.free_command_buffers(self.pool, &cmds) };
        done.context("submitting the frame")?;
        drawn?;
        let swapchains = [chain.swapchain];
        let indices = [index];
        // SAFETY: the image was acquired and its copy signals `copied`, which presentation waits on.
        let shown =
            unsafe { self.swapchain_fn.queue_present(self.queue, &vk::PresentInfoKHR::default().wait_semaphores(&signals).swapchains(&swapchains).image_indices(&indices)) };
        let pixels = readback.map(|b| b.download()).transpose()?;
        match shown {
            Ok(false) => Ok(Presented::Shown(pixels)),
            // Suboptimal or out of date: shown or not, rebuild for the next frame.
            Ok(true) | Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => {
                self.stale()?;
                Ok(Presented::Shown(pixels))
            }
            Err(e) => Err(e).context("presenting the frame"),
        }
    }

    /// Forget the swapchain; the next [`Gpu::extent`] builds a new one.
    fn stale(&mut self) -> Result<Presented> {
        // SAFETY: waiting for the queue: no submission uses the chain after this.
        unsafe { self.device.queue_wait_idle(self.queue) }?;
        if let Some(c) = self.chain.take() {
            self.destroy_chain(c);
        }
        Ok(Presented::Stale)
    }

    /// Buffer -> image (then image -> `readback`), with the layout changes.
    ///
    /// # Safety
    /// `cmd` is recording; `image` is an acquired swapchain image of `extent`;
    /// the buffers hold `extent` pixels and live until the submission completes.
    unsafe fn record_copy(&self, cmd: vk::CommandBuffer, image: vk::Image, extent: (u32, u32), src: vk::Buffer, readback: Option<vk::Buffer>) {
        let d = &self.device;
        let range = vk::ImageSubresourceRange { aspect_mask: vk::ImageAspectFlags::COLOR, base_mip_level: 0, level_count: 1, base_array_layer: 0, layer_count: 1 };
        let layers = vk::ImageSubresourceLayers { aspect_mask: vk::ImageAspectFlags::COLOR, mip_level: 0, base_array_layer: 0, layer_count: 1 };
        let region = vk::BufferImageCopy::default().image_subresource(layers).image_extent(vk::Extent3D { width: extent.0, height: extent.1, depth: 1 });
        let to = |old, new, src_access, dst_access| {
            vk::ImageMemoryBarrier::default()
                .old_layout(old)
                .new_layout(new)
                .src_access_mask(src_access)
                .dst_access_mask(dst_access)
                .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .image(image)
                .subresource_range(range)
        };
        let (t, flags) = (vk::PipelineStageFlags::TRANSFER, vk::DependencyFlags::empty());
        let dst = vk::ImageLayout::TRANSFER_DST_OPTIMAL;
        d.cmd_pipeline_barrier(cmd, t, t, flags, &[], &[], &[to(vk::ImageLayout::UNDEFINED, dst, vk::AccessFlags::empty(), vk::AccessFlags::TRANSFER_WRITE)]);
        d.cmd_copy_buffer_to_image(cmd, src, image, dst, &[region]);
        let mut last = (dst, vk::AccessFlags::TRANSFER_WRITE);
        if let Some(rb) = readback {
            let read = vk::ImageLayout::TRANSFER_SRC_OPTIMAL;
            d.cmd_pipeline_barrier(cmd, t, t, flags, &[], &[], &[to(dst, read, vk::AccessFlags::TRANSFER_WRITE, vk::AccessFlags::TRANSFER_READ)]);
            d.cmd_copy_image_to_buffer(cmd, image, read, rb, &[region]);
            let host = [vk::MemoryBarrier::default().src_access_mask(vk::AccessFlags::TRANSFER_WRITE).dst_access_mask(vk::AccessFlags::MEMORY_READ)];
            d.cmd_pipeline_barrier(cmd, t, vk::PipelineStageFlags::ALL_COMMANDS, flags, &host, &[], &[]);
            last = (read, vk::AccessFlags::TRANSFER_READ);
        }
        let present = to(last.0, vk::ImageLayout::PRESENT_SRC_KHR, last.1, vk::AccessFlags::empty());
        d.cmd_pipeline_barrier(cmd, t, vk::PipelineStageFlags::BOTTOM_OF_PIPE, flags, &[], &[], &[present]);
    }
}

impl Drop for Gpu {
    fn drop(&mut self) {
        // SAFETY: the context goes first, then the queue is idle, so nothing uses these objects; each is
        // destroyed once, children before their parents.
        unsafe {
            let _ = self.device.device_wait_idle();
            self.ctx = None;
            if let Some(c) = self.chain.take() {
                self.destroy_chain(c);
            }
            self.device.destroy_semaphore(self.acquired, None);
            self.device.destroy_fence(self.fence, None);
            self.device.destroy_command_pool(self.pool, None);
            self.device.destroy_device(None);
            self.surface_fn.destroy_surface(self.surface, None);
            self.instance.destroy_instance(None);
        }
    }
}

/// An 8-bit UNORM format in RGBA or BGRA order (the frame's values are
/// already display-encoded, as in tgs's PNGs, so not an sRGB format).
fn choose_format(formats: &[vk::SurfaceFormatKHR]) -> Result<(vk::SurfaceFormatKHR, PixelOrder)> {
    for f in formats {
        match f.format {
            vk::Format::B8G8R8A8_UNORM => return Ok((*f, PixelOrder::Bgra)),
            vk::Format::R8G8B8A8_UNORM => return Ok((*f, PixelOrder::Rgba)),
            _ => {}
        }
    }
    bail!("the window's surface offers no 8-bit RGBA/BGRA UNORM format (it offers {:?})", formats.iter().map(|f| f.format).collect::<Vec<_>>())
}

/// The first device by `sel` (the best kind first, as tgs picks for
/// training) with a queue family that computes and presents to `surface`.
fn pick(instance: &ash::Instance, surface_fn: &ash::khr::surface::Instance, surface: vk::SurfaceKHR, sel: &DeviceSelector) -> Result<(vk::PhysicalDevice, u32, String)> {
    // SAFETY: the instance is live.
    let pds = unsafe { instance.enumerate_physical_devices() }?;
    let mut found = Vec::new();
    for (index, &pd) in pds.iter().enumerate() {
        // SAFETY: `pd` was enumerated from `instance`.
        let (props, families) = unsafe { (instance.get_physical_device_properties(pd), instance.get_physical_device_queue_family_properties(pd)) };
        let name = props.device_name_as_c_str().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let wanted = match sel {
            DeviceSelector::Best => true,
            DeviceSelector::Index(i) => *i == index,
            DeviceSelector::Name(n) => name.to_lowercase().contains(&n.to_lowercase()),
        };
        let family = families.iter().enumerate().position(|(f, q)| {
            // SAFETY: `pd`, the family index and the surface are valid.
            q.queue_flags.contains(vk::QueueFlags::COMPUTE) && unsafe { surface_fn.get_physical_device_surface_support(pd, f as u32, surface) }.unwrap_or(false)
        });
        if let (true, Some(f)) = (wanted, family) {
            let rank = match props.device_type {
                vk::PhysicalDeviceType::DISCRETE_GPU => 0,
                vk::PhysicalDeviceType::INTEGRATED_GPU => 1,
                vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
                _ => 3,
            };
            found.push((rank, pd, f as u32, name));
        }
    }
    found.sort_by_key(|f| f.0);
    let (_, pd, f, name) = found.into_iter().next().context("no Vulkan device can both compute and present to this window (see `tgs devices`; --device chooses one)")?;
    Ok((pd, f, name))
}

/// The Vulkan 1.3 features tgs uses that `physical` has.
///
/// # Safety
/// `physical` belongs to `instance`.
unsafe fn enabled_features(instance: &ash::Instance, physical: vk::PhysicalDevice) -> EnabledFeatures {
    let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
    let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f13);
    instance.get_physical_device_features2(physical, &mut f2);
    EnabledFeatures { buffer_device_address: false, subgroup_size_control: f13.subgroup_size_control == vk::TRUE, compute_full_subgroups: f13.compute_full_subgroups == vk::TRUE }
}
