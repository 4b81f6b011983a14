//! The Vulkan context: instance, device, compute queue and memory allocator,
//! either created by tgs (headless) or adopted from a host application.

use crate::caps::Capabilities;
use crate::select::{self, DeviceSelector};
use crate::validation::{self, ValidationLog};
use anyhow::{anyhow, bail, Context as _, Result};
use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use std::mem::ManuallyDrop;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// Options for [`Context::new`].
#[derive(Clone, Debug, Default)]
pub struct ContextOptions {
    pub device: DeviceSelector,
    /// Enable `VK_LAYER_KHRONOS_validation` if installed. `None`: follow the
    /// `TGS_VALIDATION` environment variable (`1` enables).
    pub validation: Option<bool>,
}

/// Device features tgs may use; on an adopted device, say which ones the host enabled.
#[derive(Clone, Copy, Debug, Default)]
pub struct EnabledFeatures {
    /// `bufferDeviceAddress` (Vulkan 1.2 feature) is enabled.
    pub buffer_device_address: bool,
    /// `subgroupSizeControl` (Vulkan 1.3) is enabled.
    pub subgroup_size_control: bool,
    /// `computeFullSubgroups` (Vulkan 1.3) is enabled.
    pub compute_full_subgroups: bool,
}

/// Handles of a host application's Vulkan objects, for [`Context::adopt`].
/// tgs never destroys them. The device must support Vulkan 1.2.
pub struct AdoptInfo {
    pub entry: ash::Entry,
    pub instance: vk::Instance,
    pub physical_device: vk::PhysicalDevice,
    pub device: vk::Device,
    /// A queue family with compute support, and a queue of it.
    pub queue_family_index: u32,
    pub queue: vk::Queue,
    pub enabled: EnabledFeatures,
}

/// Device memory held by a context's buffers, bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MemoryUse {
    pub live_bytes: u64,
    pub peak_bytes: u64,
}

/// A Vulkan device ready for compute. Share it as `Arc<Context>`.
pub struct Context {
    pub(crate) entry: ash::Entry,
    pub(crate) instance: ash::Instance,
    pub(crate) physical: vk::PhysicalDevice,
    pub(crate) device: ash::Device,
    pub(crate) queue: Mutex<vk::Queue>,
    pub(crate) queue_family: u32,
    pub(crate) allocator: ManuallyDrop<Mutex<Allocator>>,
    pub(crate) caps: Capabilities,
    pub(crate) features: EnabledFeatures,
    owns: bool,
    debug: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    validation: Arc<ValidationLog>,
    /// Fill buffers made with `Buffer::uninit` with 0xFFFFFFFF (NaN as f32).
    pub(crate) poison_uninit: std::sync::atomic::AtomicBool,
    live_bytes: AtomicU64,
    peak_bytes: AtomicU64,
    /// Command pools, descriptor pools and fences to hand out again.
    pub(crate) spare: Mutex<crate::spare::Spare>,
    /// Every pipeline built on this context ([`crate::Kernel::new`]).
    pub(crate) pipelines: Mutex<crate::kernel::Pipelines>,
    submissions: AtomicU64,
}

pub(crate) fn load_entry() -> Result<ash::Entry> {
    // SAFETY: loading the system's Vulkan loader runs its initialisers; nothing of ours is shared with it
    // yet.
    unsafe { ash::Entry::load() }.map_err(|e| {
        anyhow!(
            "cannot load the Vulkan loader (libvulkan.so.1): {e}. Install it with \
             `apt-get install libvulkan1 mesa-vulkan-drivers` (or run scripts/setup.sh)"
        )
    })
}

type Debug = Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>;

pub(crate) fn create_instance(entry: &ash::Entry, validation: bool) -> Result<(ash::Instance, bool)> {
    let app = vk::ApplicationInfo::default().application_name(c"tgs").engine_name(c"tgs-engine").api_version(vk::API_VERSION_1_3);
    let use_layer = validation && validation::layer_available(entry);
    if validation && !use_layer {
        eprintln!("tgs: validation requested but VK_LAYER_KHRONOS_validation is not installed (apt-get install vulkan-validationlayers)");
    }
    let layers = if use_layer { vec![validation::LAYER.as_ptr()] } else { vec![] };
    let exts = if use_layer { vec![ash::ext::debug_utils::NAME.as_ptr()] } else { vec![] };
    let info = vk::InstanceCreateInfo::default().application_info(&app).enabled_layer_names(&layers).enabled_extension_names(&exts);
    // SAFETY: the create info and the strings it points to live until the call returns.
    let instance = unsafe { entry.create_instance(&info, None) }.map_err(|e| match e {
        vk::Result::ERROR_INCOMPATIBLE_DRIVER => anyhow!(
            "no Vulkan driver found (VK_ERROR_INCOMPATIBLE_DRIVER). Without a GPU, install lavapipe: \
             `apt-get install mesa-vulkan-drivers` (or run scripts/setup.sh)"
        ),
        e => anyhow!("vkCreateInstance failed: {e}"),
    })?;
    Ok((instance, use_layer))
}

fn create_messenger(entry: &ash::Entry, instance: &ash::Instance, log: &Arc<ValidationLog>) -> Result<Debug> {
    let du = ash::ext::debug_utils::Instance::new(entry, instance);
    let info = vk::DebugUtilsMessengerCreateInfoEXT::default()
        .message_severity(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR | vk::DebugUtilsMessageSeverityFlagsEXT::WARNING)
        .message_type(vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION | vk::DebugUtilsMessageTypeFlagsEXT::GENERAL | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE)
        .pfn_user_callback(Some(validation::callback))
        .user_data(Arc::as_ptr(log) as *mut std::ffi::c_void);
    // SAFETY: `du` belongs to the live instance; the callback is a plain function with no captured state.
    let m = unsafe { du.create_debug_utils_messenger(&info, None) }.context("creating the validation messenger")?;
    Ok(Some((du, m)))
}

impl Context {
    /// Create a headless instance and device.
    pub fn new(opts: &ContextOptions) -> Result<Arc<Context>> {
        let validation = opts.validation.unwrap_or_else(|| std::env::var("TGS_VALIDATION").map(|v| v == "1").unwrap_or(false));
        let entry = load_entry()?;
        let (instance, layer_on) = create_instance(&entry, validation)?;
        let log = Arc::new(ValidationLog::default());
        let debug = if layer_on {
            match create_messenger(&entry, &instance, &log) {
                Ok(d) => d,
                Err(e) => {
                    // SAFETY: no device or messenger was created from the instance yet, and nothing else
                    // holds it.
                    unsafe { instance.destroy_instance(None) };
                    return Err(e);
                }
            }
        } else {
            None
        };
        // SAFETY: called only on failure paths, after every object created from the instance is destroyed;
        // each handle is destroyed once.
        let destroy = |instance: &ash::Instance, debug: &Debug| unsafe {
            if let Some((du, m)) = debug {
                du.destroy_debug_utils_messenger(*m, None);
            }
            instance.destroy_instance(None);
        };
        let result = (|| {
            let devices = select::describe_all(&instance)?;
            let idx = select::choose(&devices, &opts.device)?;
            let (pd, info) = &devices[idx];
            let qf = info.compute_queue_family.expect("usable device has a compute queue");
            let caps = &info.caps;
            let api13 = vk::api_version_minor(caps.api_version) >= 3;
            let features = EnabledFeatures {
                buffer_device_address: caps.buffer_device_address,
                subgroup_size_control: caps.subgroup_size_control,
                compute_full_subgroups: caps.compute_full_subgroups,
            };
            let prio = [1.0f32];
            let qinfo = [vk::DeviceQueueCreateInfo::default().queue_family_index(qf).queue_priorities(&prio)];
            let mut f12 = vk::PhysicalDeviceVulkan12Features::default().buffer_device_address(features.buffer_device_address);
            let mut f13 =
                vk::PhysicalDeviceVulkan13Features::default().subgroup_size_control(features.subgroup_size_control).compute_full_subgroups(features.compute_full_subgroups);
            let mut dinfo = vk::DeviceCreateInfo::default().queue_create_infos(&qinfo).push_next(&mut f12);
            if api13 {
                dinfo = dinfo.push_next(&mut f13);
            }
            // SAFETY: `pd` comes from this instance and the create info (queues, features, extensions) lives
            // until the call returns.
            let device = unsafe { instance.create_device(*pd, &dinfo, None) }.with_context(|| format!("vkCreateDevice on {}", caps.device_name))?;
            Ok::<_, anyhow::Error>((*pd, device, qf, features))
        })();
        let (pd, device, qf, features) = match result {
            Ok(r) => r,
            Err(e) => {
                destroy(&instance, &debug);
                return Err(e);
            }
        };
        match Self::finish(entry, instance, pd, device, qf, None, features, debug, log) {
            Ok(c) => Ok(c),
            Err((e, instance, device, debug)) => {
                // SAFETY: `finish` failed before anything was created on the device; it is idle and owned
                // here.
                unsafe { device.destroy_device(None) };
                destroy(&instance, &debug);
                Err(e)
            }
        }
    }

    /// Run on a host application's device and queue. tgs creates only its own
    /// objects (allocator, pipelines, buffers) and destroys only those; the
    /// host keeps ownership of the instance, device and queue. The host must not
    /// use the queue from another thread while tgs submits to it (or it can
    /// record with [`crate::Recorder`] and submit the command buffer itself).
    ///
    /// # Safety
    /// The handles must be valid, belong together, and outlive the returned context.
    pub unsafe fn adopt(info: AdoptInfo) -> Result<Arc<Context>> {
        let instance = ash::Instance::load(info.entry.static_fn(), info.instance);
        let props = instance.get_physical_device_properties(info.physical_device);
        if vk::api_version_major(props.api_version) == 1 && vk::api_version_minor(props.api_version) < 2 {
            bail!("adopted device supports Vulkan {}.{}; tgs needs 1.2", vk::api_version_major(props.api_version), vk::api_version_minor(props.api_version));
        }
        let device = ash::Device::load(instance.fp_v1_0(), info.device);
        Self::finish(info.entry, instance, info.physical_device, device, info.queue_family_index, Some(info.queue), info.enabled, None, Arc::new(ValidationLog::default()))
            .map_err(|(e, ..)| e)
    }

    // The parts of a device being built, and an error that hands back the
    // handles the caller owns and must destroy (built once per context).
    #[allow(clippy::too_many_arguments, clippy::type_complexity, clippy::result_large_err)]
    fn finish(
        entry: ash::Entry,
        instance: ash::Instance,
        physical: vk::PhysicalDevice,
        device: ash::Device,
        queue_family: u32,
        adopted_queue: Option<vk::Queue>,
        features: EnabledFeatures,
        debug: Debug,
        validation: Arc<ValidationLog>,
    ) -> std::result::Result<Arc<Context>, (anyhow::Error, ash::Instance, ash::Device, Debug)> {
        // SAFETY: `physical` comes from `instance` (checked by the caller, or by `adopt`'s contract).
        let mut caps = unsafe { Capabilities::query(&instance, physical, queue_family) };
        // Report what is enabled, not merely what exists.
        caps.buffer_device_address &= features.buffer_device_address;
        if !features.subgroup_size_control {
            caps.subgroup_size_control = false;
            caps.min_subgroup_size = caps.subgroup_size;
            caps.max_subgroup_size = caps.subgroup_size;
        }
        caps.compute_full_subgroups &= features.compute_full_subgroups;
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device: physical,
            debug_settings: Default::default(),
            buffer_device_address: features.buffer_device_address,
            allocation_sizes: Default::default(),
        });
        let allocator = match allocator {
            Ok(a) => a,
            Err(e) => return Err((anyhow!("creating the memory allocator: {e}"), instance, device, debug)),
        };
        let owns = adopted_queue.is_none();
        // SAFETY: the device was created (or adopted) with one queue of `queue_family`.
        let queue = adopted_queue.unwrap_or_else(|| unsafe { device.get_device_queue(queue_family, 0) });
        Ok(Arc::new(Context {
            entry,
            instance,
            physical,
            device,
            queue: Mutex::new(queue),
            queue_family,
            allocator: ManuallyDrop::new(Mutex::new(allocator)),
            caps,
            features,
            owns,
            debug,
            validation,
            poison_uninit: std::sync::atomic::AtomicBool::new(false),
            live_bytes: AtomicU64::new(0),
            peak_bytes: AtomicU64::new(0),
            spare: Mutex::new(crate::spare::Spare::default()),
            pipelines: Mutex::new(Default::default()),
            submissions: AtomicU64::new(0),
        }))
    }

    pub fn caps(&self) -> &Capabilities {
        &self.caps
    }
    pub fn features(&self) -> EnabledFeatures {
        self.features
    }
    pub fn device(&self) -> &ash::Device {
        &self.device
    }
    pub fn instance(&self) -> &ash::Instance {
        &self.instance
    }
    pub fn entry(&self) -> &ash::Entry {
        &self.entry
    }
    pub fn physical_device(&self) -> vk::PhysicalDevice {
        self.physical
    }
    pub fn queue_family(&self) -> u32 {
        self.queue_family
    }
    /// Whether this context created (and will destroy) the device.
    pub fn owns_device(&self) -> bool {
        self.owns
    }
    /// Whether the validation layer is active on this context.
    pub fn validation_enabled(&self) -> bool {
        self.debug.is_some()
    }

    /// From now on, fill every buffer made with `Buffer::uninit` with the bit
    /// pattern 0xFFFFFFFF (a NaN as f32, the largest u32) instead of leaving
    /// it undefined, so that a kernel reading memory nobody wrote fails the
    /// same way every run instead of depending on what an earlier user of the
    /// memory left there. Tests turn this on; it costs one fill per buffer.
    pub fn set_poison_uninit(&self, on: bool) {
        self.poison_uninit.store(on, std::sync::atomic::Ordering::SeqCst);
    }

    /// Bytes of device memory held by this context's buffers now, and the
    /// most held at once since the context was made (or since
    /// [`Context::reset_peak_memory`]).
    pub fn memory_use(&self) -> MemoryUse {
        MemoryUse { live_bytes: self.live_bytes.load(Ordering::SeqCst), peak_bytes: self.peak_bytes.load(Ordering::SeqCst) }
    }
    /// Start the peak over from what is held now.
    pub fn reset_peak_memory(&self) {
        self.peak_bytes.store(self.live_bytes.load(Ordering::SeqCst), Ordering::SeqCst);
    }
    pub(crate) fn memory_allocated(&self, bytes: u64) {
        let live = self.live_bytes.fetch_add(bytes, Ordering::SeqCst) + bytes;
        self.peak_bytes.fetch_max(live, Ordering::SeqCst);
    }
    pub(crate) fn memory_freed(&self, bytes: u64) {
        self.live_bytes.fetch_sub(bytes, Ordering::SeqCst);
    }

    /// Validation errors reported so far (empty without the layer).
    pub fn validation_errors(&self) -> Vec<String> {
        self.validation.errors.lock().map(|e| e.clone()).unwrap_or_default()
    }

    /// Submit a command buffer on the compute queue and wait for it.
    pub fn submit_and_wait(&self, cmd: vk::CommandBuffer) -> Result<()> {
        let d = &self.device;
        self.submissions.fetch_add(1, Ordering::Relaxed);
        // SAFETY: the fence is unsignalled (new or reset by the spare pool) and the command buffer has ended
        // recording; the queue is used under its lock, as external synchronisation requires.
        unsafe {
            let spare = self.spare.lock().ok().and_then(|mut s| s.take_fence());
            let fence = match spare {
                Some(f) => f,
                None => d.create_fence(&vk::FenceCreateInfo::default(), None)?,
            };
            let cmds = [cmd];
            let submit = [vk::SubmitInfo::default().command_buffers(&cmds)];
            let r = {
                let q = self.queue.lock().map_err(|_| anyhow!("queue lock poisoned"))?;
                d.queue_submit(*q, &submit, fence)
            };
            let r = r.and_then(|_| d.wait_for_fences(&[fence], true, u64::MAX));
            match (&r, self.spare.lock()) {
                (Ok(()), Ok(mut s)) => s.give_fence(d, fence),
                // A failed submission or wait may leave it pending: wait for the device first.
                _ => {
                    let _ = d.device_wait_idle();
                    d.destroy_fence(fence, None);
                }
            }
            r.map_err(|e| match e {
                vk::Result::ERROR_DEVICE_LOST => anyhow!(
                    "Vulkan device lost while running tgs kernels (a kernel faulted or ran too long; \
                     on lavapipe this can mean too little memory)"
                ),
                vk::Result::ERROR_OUT_OF_DEVICE_MEMORY | vk::Result::ERROR_OUT_OF_HOST_MEMORY => {
                    anyhow!("out of memory submitting work ({e}); reduce the problem size")
                }
                e => anyhow!("queue submit/wait failed: {e}"),
            })
        }
    }

    /// Submissions made through this context so far (each waited for).
    pub fn submissions(&self) -> u64 {
        self.submissions.load(Ordering::Relaxed)
    }

    /// Distinct pipelines built on this context so far: [`crate::Kernel::new`]
    /// builds each once and returns it again for the same SPIR-V,
    /// specialization constants, push-constant size and subgroup requests.
    pub fn pipelines_built(&self) -> usize {
        self.pipelines.lock().map(|p| p.len()).unwrap_or_default()
    }

    /// Command pools, descriptor pools and fences held for reuse by later
    /// recordings (bounded; see `Recorder`).
    pub fn spare_objects(&self) -> (usize, usize, usize) {
        self.spare.lock().map(|s| s.counts()).unwrap_or_default()
    }

    pub fn wait_idle(&self) -> Result<()> {
        // SAFETY: the device is live for the context's lifetime; waiting is always allowed.
        unsafe { self.device.device_wait_idle() }.context("vkDeviceWaitIdle")
    }
}

impl Drop for Context {
    fn drop(&mut self) {
        // SAFETY: the context is dropped only when no recorder, buffer or kernel holds it (they keep an Arc);
        // after the wait the device is idle, so every object made on it can be destroyed, and an adopted
        // device is left to its host.
        unsafe {
            let _ = self.device.device_wait_idle();
            if let Ok(spare) = self.spare.get_mut() {
                spare.destroy(&self.device);
            }
            if let Ok(built) = self.pipelines.get_mut() {
                crate::kernel::destroy_pipelines(&self.device, built);
            }
            ManuallyDrop::drop(&mut self.allocator);
            if self.owns {
                self.device.destroy_device(None);
                if let Some((du, m)) = self.debug.take() {
                    du.destroy_debug_utils_messenger(m, None);
                }
                self.instance.destroy_instance(None);
            }
        }
    }
}
