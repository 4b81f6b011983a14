//! Vulkan objects a context hands out again instead of creating one per
//! recording: command pools (each with its one command buffer), descriptor
//! pools and fences. A recording takes what it needs and gives it back,
//! reset, when it is dropped (its submission has completed by then), so a
//! training loop creates no Vulkan objects per iteration once warm.

use ash::vk;

/// At most this many of each kind are kept; more are destroyed on return.
const KEEP: usize = 16;
const KEEP_DESCRIPTOR_POOLS: usize = 64;

#[derive(Default)]
pub(crate) struct Spare {
    commands: Vec<(vk::CommandPool, vk::CommandBuffer)>,
    descriptor_pools: Vec<vk::DescriptorPool>,
    fences: Vec<vk::Fence>,
}

impl Spare {
    /// A reset command pool and its command buffer (initial state).
    pub(crate) fn take_commands(&mut self) -> Option<(vk::CommandPool, vk::CommandBuffer)> {
        self.commands.pop()
    }
    /// An empty descriptor pool.
    pub(crate) fn take_descriptor_pool(&mut self) -> Option<vk::DescriptorPool> {
        self.descriptor_pools.pop()
    }
    /// An unsignalled fence.
    pub(crate) fn take_fence(&mut self) -> Option<vk::Fence> {
        self.fences.pop()
    }

    /// Take back a command pool whose command buffer is no longer pending.
    pub(crate) fn give_commands(&mut self, device: &ash::Device, pool: vk::CommandPool, cmd: vk::CommandBuffer) {
        // SAFETY: the caller gives back a pool whose command buffer is not pending; a pool not kept is
        // destroyed once.
        unsafe {
            if self.commands.len() < KEEP && device.reset_command_pool(pool, vk::CommandPoolResetFlags::empty()).is_ok() {
                self.commands.push((pool, cmd));
            } else {
                device.destroy_command_pool(pool, None);
            }
        }
    }
    /// Take back a descriptor pool none of whose sets is in use.
    pub(crate) fn give_descriptor_pool(&mut self, device: &ash::Device, pool: vk::DescriptorPool) {
        // SAFETY: no set of the pool is in use by a pending submission (the caller's contract); a pool not
        // kept is destroyed once.
        unsafe {
            if self.descriptor_pools.len() < KEEP_DESCRIPTOR_POOLS && device.reset_descriptor_pool(pool, vk::DescriptorPoolResetFlags::empty()).is_ok() {
                self.descriptor_pools.push(pool);
            } else {
                device.destroy_descriptor_pool(pool, None);
            }
        }
    }
    /// Take back a fence that is not in use by a pending submission.
    pub(crate) fn give_fence(&mut self, device: &ash::Device, fence: vk::Fence) {
        // SAFETY: the fence is not used by a pending submission (the caller waited on it); one not kept is
        // destroyed once.
        unsafe {
            if self.fences.len() < KEEP && device.reset_fences(&[fence]).is_ok() {
                self.fences.push(fence);
            } else {
                device.destroy_fence(fence, None);
            }
        }
    }

    /// Destroy everything held (the device must be idle).
    pub(crate) fn destroy(&mut self, device: &ash::Device) {
        // SAFETY: the device is idle (the context's Drop waited) and each object here is held only by this
        // pool.
        unsafe {
            for (pool, _) in self.commands.drain(..) {
                device.destroy_command_pool(pool, None);
            }
            for pool in self.descriptor_pools.drain(..) {
                device.destroy_descriptor_pool(pool, None);
            }
            for fence in self.fences.drain(..) {
                device.destroy_fence(fence, None);
            }
        }
    }

    /// Objects held: (command pools, descriptor pools, fences).
    pub(crate) fn counts(&self) -> (usize, usize, usize) {
        (self.commands.len(), self.descriptor_pools.len(), self.fences.len())
    }
}
