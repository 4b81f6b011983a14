//! Embedding tgs in a host application's Vulkan renderer.
//!
//! The host creates its own instance, device, queue, command buffer and
//! output buffer; tgs adopts the device and queue, loads a trained run (any
//! stage: the scattering set, plus the reflection set with its environment
//! map or light field) and records the deferred render of one of the run's
//! test cameras into the host's command buffer, writing the colour into the
//! host's buffer. The host submits, waits, and "presents" the frame by
//! writing a PNG.
//!
//!     cargo run --release --example embed -- RUN [--view N] [--out frame.png]

use anyhow::{bail, Context as _, Result};
use ash::vk;
use std::path::PathBuf;
use tgs::embed::SceneRenderer;
use tgs_engine::{AdoptInfo, BufferBinding, Context, EnabledFeatures, Recorder};

struct Args {
    run: PathBuf,
    view: usize,
    out: PathBuf,
}

fn args() -> Result<Args> {
    let mut it = std::env::args().skip(1);
    let (mut run, mut view, mut out) = (None, 0, PathBuf::from("frame.png"));
    while let Some(a) = it.next() {
        match a.as_str() {
            "--view" => view = it.next().context("--view N")?.parse().context("--view N")?,
            "--out" => out = it.next().context("--out FILE")?.into(),
            s if !s.starts_with('-') && run.is_none() => run = Some(PathBuf::from(s)),
            s => bail!("unknown argument '{s}'"),
        }
    }
    let run = run.context("usage: embed RUN [--view N] [--out frame.png] (RUN: a `tgs train` output directory)")?;
    Ok(Args { run, view, out })
}

/// The host renderer's own Vulkan objects.
struct Host {
    entry: ash::Entry,
    instance: ash::Instance,
    physical: vk::PhysicalDevice,
    device: ash::Device,
    family: u32,
    queue: vk::Queue,
    features: EnabledFeatures,
}

impl Host {
    fn new() -> Result<Host> {
        // SAFETY: a host's ordinary Vulkan set-up: every create info lives until its call returns and each
        // handle comes from the object before it.
        unsafe {
            let entry = ash::Entry::load().context("no Vulkan loader")?;
            let app = vk::ApplicationInfo::default().application_name(c"tgs embed example").api_version(vk::API_VERSION_1_3);
            let instance = entry.create_instance(&vk::InstanceCreateInfo::default().application_info(&app), None)?;
            let physical = *instance.enumerate_physical_devices()?.first().context("no Vulkan device")?;
            let family =
                instance.get_physical_device_queue_family_properties(physical).iter().position(|q| q.queue_flags.contains(vk::QueueFlags::COMPUTE)).context("no compute queue")?
                    as u32;
            // Enable what tgs can use, when the device has it.
            let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
            let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f13);
            instance.get_physical_device_features2(physical, &mut f2);
            let features = EnabledFeatures {
                buffer_device_address: false,
                subgroup_size_control: f13.subgroup_size_control == vk::TRUE,
                compute_full_subgroups: f13.compute_full_subgroups == vk::TRUE,
            };
            let mut want13 =
                vk::PhysicalDeviceVulkan13Features::default().subgroup_size_control(features.subgroup_size_control).compute_full_subgroups(features.compute_full_subgroups);
            let prio = [1.0f32];
            let queues = [vk::DeviceQueueCreateInfo::default().queue_family_index(family).queue_priorities(&prio)];
            let device = instance.create_device(physical, &vk::DeviceCreateInfo::default().queue_create_infos(&queues).push_next(&mut want13), None)?;
            let queue = device.get_device_queue(family, 0);
            Ok(Host { entry, instance, physical, device, family, queue, features })
        }
    }

    /// A host-visible storage buffer the host owns (its memory too).
    fn buffer(&self, bytes: u64) -> Result<(vk::Buffer, vk::DeviceMemory)> {
        // SAFETY: `buf` and `mem` are new objects of this device; the memory type was chosen from the
        // buffer's requirements.
        unsafe {
            let usage = vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::TRANSFER_DST;
            let buf = self.device.create_buffer(&vk::BufferCreateInfo::default().size(bytes).usage(usage), None)?;
            let req = self.device.get_buffer_memory_requirements(buf);
            let props = self.instance.get_physical_device_memory_properties(self.physical);
            let want = vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
            let ty = (0..props.memory_type_count)
                .find(|&i| req.memory_type_bits & (1 << i) != 0 && props.memory_types[i as usize].property_flags.contains(want))
                .context("no host-visible memory")?;
            let mem = self.device.allocate_memory(&vk::MemoryAllocateInfo::default().allocation_size(req.size).memory_type_index(ty), None)?;
            self.device.bind_buffer_memory(buf, mem, 0)?;
            Ok((buf, mem))
        }
    }
    /// Read `bytes` of the host-visible `mem` (the colour planes of a
    /// `width`x`height` frame tgs rendered) and write them as a PNG.
    fn present(&self, mem: vk::DeviceMemory, bytes: u64, (width, height): (u32, u32), out: &std::path::Path) -> Result<()> {
        let d = &self.device;
        // SAFETY: the memory is host-visible and coherent, `bytes` long, and the GPU's writes completed.
        let planes = unsafe {
            let p = d.map_memory(mem, 0, bytes, vk::MemoryMapFlags::empty())? as *const f32;
            let v = std::slice::from_raw_parts(p, SceneRenderer::output_len(width, height)).to_vec();
            d.unmap_memory(mem);
            v
        };
        tgs::data::image_io::write_png(out, &tgs::data::image_io::ImageF::from_planar(width, height, 3, &planes))?;
        Ok(())
    }
}

fn main() -> Result<()> {
    let a = args()?;
    let host = Host::new()?;
    // tgs runs on the host's device and queue; it never destroys them.
    // SAFETY: the handles are the host's own, belong together, and outlive `ctx` (it is dropped before they
    // are destroyed below).
    let ctx = unsafe {
        Context::adopt(AdoptInfo {
            entry: host.entry.clone(),
            instance: host.instance.handle(),
            physical_device: host.physical,
            device: host.device.handle(),
            queue_family_index: host.family,
            queue: host.queue,
            enabled: host.features,
        })?
    };
    println!("device: {}", ctx.caps().describe());
    let mut scene = SceneRenderer::load(&ctx, &a.run)?;
    let cams = tgs::embed::run_cameras(&a.run)?;
    let (name, cam) = cams.get(a.view).with_context(|| format!("--view {}: the run has {} test cameras", a.view, cams.len()))?.clone();
    println!("{}: Stage {} run, camera '{name}' ({}x{})", a.run.display(), scene.stage, cam.width, cam.height);

    let bytes = 4 * SceneRenderer::output_len(cam.width, cam.height) as u64;
    let (out, mem) = host.buffer(bytes)?;
    let d = &host.device;
    // SAFETY: the create info names the host's queue family.
    let pool = unsafe { d.create_command_pool(&vk::CommandPoolCreateInfo::default().queue_family_index(host.family), None)? };
    // SAFETY: a default create info on the host's device.
    let fence = unsafe { d.create_fence(&vk::FenceCreateInfo::default(), None)? };
    let mut recordings = 0;
    loop {
        // The host's frame: its command buffer, tgs's commands inside it.
        // SAFETY: `pool` is the host's and no command buffer of it is pending (each frame is waited for).
        let cmd = unsafe { d.allocate_command_buffers(&vk::CommandBufferAllocateInfo::default().command_pool(pool).command_buffer_count(1))?[0] };
        // SAFETY: `cmd` was just allocated: it is in the initial state.
        unsafe { d.begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default())? };
        // SAFETY: `cmd` is a primary command buffer of a pool of the context's queue family, and recording.
        let mut rec = unsafe { Recorder::record_into(&ctx, cmd, 0)? };
        // SAFETY: `out` is a live storage buffer of the host's device holding `bytes` bytes, alive until the
        // frame completes.
        scene.record(&mut rec, &cam, &unsafe { BufferBinding::external(out, 0, bytes) })?;
        rec.finish()?;
        // SAFETY: the recording finished inside `cmd`; the fence is unsignalled and waited for before it is
        // reset.
        unsafe {
            d.end_command_buffer(cmd)?;
            d.queue_submit(host.queue, &[vk::SubmitInfo::default().command_buffers(&[cmd])], fence)?;
            d.wait_for_fences(&[fence], true, u64::MAX)?;
            d.reset_fences(&[fence])?;
        }
        drop(rec);
        // SAFETY: the submission that used `cmd` completed (the fence was waited for).
        unsafe { d.free_command_buffers(pool, &[cmd]) };
        recordings += 1;
        // The first frame of a size may outgrow tgs's buffers: record it again.
        if scene.complete(&cam)? {
            break;
        }
    }
    // "Present": read the host's buffer and write a PNG.
    host.present(mem, bytes, (cam.width, cam.height), &a.out)?;
    println!("rendered in {recordings} recording(s) of the host's command buffer; wrote {}", a.out.display());

    drop(scene);
    drop(ctx);
    // SAFETY: tgs's context is dropped and the queue is idle, so nothing uses these objects; each is
    // destroyed once.
    unsafe {
        d.destroy_fence(fence, None);
        d.destroy_command_pool(pool, None);
        d.destroy_buffer(out, None);
        d.free_memory(mem, None);
        d.destroy_device(None);
        host.instance.destroy_instance(None);
    }
    Ok(())
}
