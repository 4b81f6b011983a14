//! A stand-in for a host application's renderer: it creates its own
//! instance, device and queue (no optional features), command buffers and
//! host-visible buffers, and hands tgs the handles to adopt.

use ash::vk;
use std::sync::Arc;
use tgs_engine::{AdoptInfo, Context, EnabledFeatures};

pub struct Host {
    pub entry: ash::Entry,
    pub instance: ash::Instance,
    pub pd: vk::PhysicalDevice,
    pub device: ash::Device,
    pub qf: u32,
    pub queue: vk::Queue,
}

impl Default for Host {
    fn default() -> Host {
        Host::new()
    }
}

impl Host {
    pub fn new() -> Host {
        // SAFETY: a test host's Vulkan set-up: every create info lives until its call returns and each handle
        // comes from the object before it.
        unsafe {
            let entry = ash::Entry::load().unwrap();
            let app = vk::ApplicationInfo::default().api_version(vk::API_VERSION_1_3);
            let instance = entry.create_instance(&vk::InstanceCreateInfo::default().application_info(&app), None).unwrap();
            let pds = instance.enumerate_physical_devices().unwrap();
            let pd = pds[0];
            let qf = instance.get_physical_device_queue_family_properties(pd).iter().position(|q| q.queue_flags.contains(vk::QueueFlags::COMPUTE)).unwrap() as u32;
            let prio = [1.0f32];
            let qi = [vk::DeviceQueueCreateInfo::default().queue_family_index(qf).queue_priorities(&prio)];
            let device = instance.create_device(pd, &vk::DeviceCreateInfo::default().queue_create_infos(&qi), None).unwrap();
            let queue = device.get_device_queue(qf, 0);
            Host { entry, instance, pd, device, qf, queue }
        }
    }

    /// tgs on this host's device and queue (the host enabled no optional features).
    pub fn adopt(&self) -> Arc<Context> {
        // SAFETY: the handles are this host's, belong together, and outlive the context (tests drop it before
        // Host::destroy).
        unsafe {
            Context::adopt(AdoptInfo {
                entry: self.entry.clone(),
                instance: self.instance.handle(),
                physical_device: self.pd,
                device: self.device.handle(),
                queue_family_index: self.qf,
                queue: self.queue,
                enabled: EnabledFeatures::default(),
            })
            .unwrap()
        }
    }

    /// Record with `f` into a command buffer of the host's own pool, submit
    /// it on the host's queue and wait.
    pub fn submit(&self, f: impl FnOnce(vk::CommandBuffer)) {
        // SAFETY: the pool, command buffer and fence are new and used only here; the submission is waited for
        // before they are destroyed.
        unsafe {
            let d = &self.device;
            let pool = d.create_command_pool(&vk::CommandPoolCreateInfo::default().queue_family_index(self.qf), None).unwrap();
            let cmd = d.allocate_command_buffers(&vk::CommandBufferAllocateInfo::default().command_pool(pool).command_buffer_count(1)).unwrap()[0];
            d.begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default()).unwrap();
            f(cmd);
            d.end_command_buffer(cmd).unwrap();
            let fence = d.create_fence(&vk::FenceCreateInfo::default(), None).unwrap();
            d.queue_submit(self.queue, &[vk::SubmitInfo::default().command_buffers(&[cmd])], fence).unwrap();
            d.wait_for_fences(&[fence], true, u64::MAX).unwrap();
            d.destroy_fence(fence, None);
            d.destroy_command_pool(pool, None);
        }
    }

    /// A host-visible, coherent storage buffer of `bytes` the host owns.
    pub fn buffer(&self, bytes: u64) -> HostBuffer {
        // SAFETY: `buffer` and `memory` are new objects of this device; the memory type was chosen from the
        // buffer's requirements.
        unsafe {
            let usage = vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::TRANSFER_DST;
            let buffer = self.device.create_buffer(&vk::BufferCreateInfo::default().size(bytes).usage(usage), None).unwrap();
            let req = self.device.get_buffer_memory_requirements(buffer);
            let props = self.instance.get_physical_device_memory_properties(self.pd);
            let want = vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
            let ty = (0..props.memory_type_count).find(|&i| req.memory_type_bits & (1 << i) != 0 && props.memory_types[i as usize].property_flags.contains(want)).unwrap();
            let memory = self.device.allocate_memory(&vk::MemoryAllocateInfo::default().allocation_size(req.size).memory_type_index(ty), None).unwrap();
            self.device.bind_buffer_memory(buffer, memory, 0).unwrap();
            HostBuffer { buffer, memory, bytes }
        }
    }

    pub fn read(&self, b: &HostBuffer) -> Vec<f32> {
        // SAFETY: the memory is host-visible and coherent, `b.bytes` long, and no submission writing it is
        // pending.
        unsafe {
            let p = self.device.map_memory(b.memory, 0, b.bytes, vk::MemoryMapFlags::empty()).unwrap() as *const f32;
            let v = std::slice::from_raw_parts(p, (b.bytes / 4) as usize).to_vec();
            self.device.unmap_memory(b.memory);
            v
        }
    }

    pub fn free(&self, b: HostBuffer) {
        // SAFETY: the caller's submissions that used the buffer have completed; each handle is destroyed
        // once.
        unsafe {
            self.device.destroy_buffer(b.buffer, None);
            self.device.free_memory(b.memory, None);
        }
    }

    /// Destroy the host's device and instance (after everything using them).
    pub fn destroy(self) {
        // SAFETY: everything made on the device (tgs's context included) is gone; the device is waited for
        // before it is destroyed.
        unsafe {
            self.device.device_wait_idle().unwrap();
            self.device.destroy_device(None);
            self.instance.destroy_instance(None);
        }
    }
}

pub struct HostBuffer {
    pub buffer: vk::Buffer,
    pub memory: vk::DeviceMemory,
    pub bytes: u64,
}
