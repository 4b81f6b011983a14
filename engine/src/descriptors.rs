//! Descriptor handling, in one place: each dispatch gets a descriptor set from
//! an arena owned by its recording; its pools go back to the context, reset,
//! when the recording is dropped, and the texel-buffer views it made are
//! destroyed then.

use crate::buffer::BufferBinding;
use crate::context::Context;
use crate::kernel::descriptor_type;
use crate::spirv::BindingKind;
use anyhow::{bail, Result};
use ash::vk;
use std::sync::Arc;

const SETS_PER_POOL: u32 = 256;
const BUFFERS_PER_POOL: u32 = SETS_PER_POOL * 16;
const TEXELS_PER_POOL: u32 = SETS_PER_POOL * 4;

pub(crate) struct DescriptorArena {
    ctx: Arc<Context>,
    pools: Vec<vk::DescriptorPool>,
    views: Vec<vk::BufferView>,
}

impl DescriptorArena {
    pub(crate) fn new(ctx: &Arc<Context>) -> Self {
        DescriptorArena { ctx: ctx.clone(), pools: Vec::new(), views: Vec::new() }
    }

    fn new_pool(&mut self) -> Result<vk::DescriptorPool> {
        let sizes = [
            vk::DescriptorPoolSize { ty: vk::DescriptorType::STORAGE_BUFFER, descriptor_count: BUFFERS_PER_POOL },
            vk::DescriptorPoolSize { ty: vk::DescriptorType::UNIFORM_TEXEL_BUFFER, descriptor_count: TEXELS_PER_POOL },
        ];
        let info = vk::DescriptorPoolCreateInfo::default().max_sets(SETS_PER_POOL).pool_sizes(&sizes);
        let spare = self.ctx.spare.lock().ok().and_then(|mut s| s.take_descriptor_pool());
        let pool = match spare {
            Some(p) => p,
            // SAFETY: the pool sizes the create info points to live until the call returns.
            None => unsafe { self.ctx.device.create_descriptor_pool(&info, None) }?,
        };
        self.pools.push(pool);
        Ok(pool)
    }

    /// A set for `layout`, written with `bindings` (binding i = bindings[i],
    /// of kind `kinds[i]`).
    pub(crate) fn bind(&mut self, kernel: &str, layout: vk::DescriptorSetLayout, kinds: &[BindingKind], bindings: &[BufferBinding]) -> Result<vk::DescriptorSet> {
        let caps = &self.ctx.caps;
        for (i, (b, k)) in bindings.iter().zip(kinds).enumerate() {
            if *k != BindingKind::Storage {
                let texels = b.range / 4;
                if texels > caps.max_texel_buffer_elements || b.range % 4 != 0 {
                    bail!(
                        "kernel '{kernel}' binding {i}: a texel buffer of {} bytes exceeds this device's maxTexelBufferElements ({} texels) or is not whole texels; bind it in slices",
                        b.range, caps.max_texel_buffer_elements
                    );
                }
                if b.offset % caps.min_texel_buffer_offset_alignment != 0 {
                    bail!("kernel '{kernel}' binding {i}: offset {} is not a multiple of minTexelBufferOffsetAlignment ({})", b.offset, caps.min_texel_buffer_offset_alignment);
                }
                continue;
            }
            if b.range > caps.max_storage_buffer_range {
                bail!(
                    "kernel '{kernel}' binding {i}: range of {:.1} MiB exceeds this device's maxStorageBufferRange ({:.1} MiB); bind it in slices",
                    b.range as f64 / 1048576.0,
                    caps.max_storage_buffer_range as f64 / 1048576.0
                );
            }
            if b.offset % caps.min_storage_buffer_offset_alignment != 0 {
                bail!("kernel '{kernel}' binding {i}: offset {} is not a multiple of minStorageBufferOffsetAlignment ({})", b.offset, caps.min_storage_buffer_offset_alignment);
            }
        }
        let layouts = [layout];
        let mut set = None;
        if let Some(&pool) = self.pools.last() {
            let info = vk::DescriptorSetAllocateInfo::default().descriptor_pool(pool).set_layouts(&layouts);
            // SAFETY: `pool` is this arena's and the layout lives as long as the kernel that asked; failure
            // (a full pool) is handled below.
            if let Ok(s) = unsafe { self.ctx.device.allocate_descriptor_sets(&info) } {
                set = Some(s[0]);
            }
        }
        let set = match set {
            Some(s) => s,
            None => {
                let pool = self.new_pool()?;
                let info = vk::DescriptorSetAllocateInfo::default().descriptor_pool(pool).set_layouts(&layouts);
                // SAFETY: a new, empty pool sized for at least one set of any kernel.
                unsafe { self.ctx.device.allocate_descriptor_sets(&info) }?[0]
            }
        };
        let infos: Vec<[vk::DescriptorBufferInfo; 1]> = bindings.iter().map(|b| [vk::DescriptorBufferInfo { buffer: b.buffer, offset: b.offset, range: b.range }]).collect();
        // A view per texel binding (kept until the recording is dropped).
        let mut views: Vec<[vk::BufferView; 1]> = Vec::with_capacity(bindings.len());
        for (b, k) in bindings.iter().zip(kinds) {
            let format = match k {
                BindingKind::Storage => {
                    views.push([vk::BufferView::null()]);
                    continue;
                }
                BindingKind::TexelF32 => vk::Format::R32_SFLOAT,
                BindingKind::TexelU32 => vk::Format::R32_UINT,
            };
            let info = vk::BufferViewCreateInfo::default().buffer(b.buffer).format(format).offset(b.offset).range(b.range);
            // SAFETY: the buffer is alive (the recording keeps it) and the range lies inside it with the
            // texel format's alignment.
            let view = unsafe { self.ctx.device.create_buffer_view(&info, None) }?;
            self.views.push(view);
            views.push([view]);
        }
        let writes: Vec<_> = infos
            .iter()
            .zip(&views)
            .zip(kinds)
            .enumerate()
            .map(|(i, ((info, view), k))| {
                let w = vk::WriteDescriptorSet::default().dst_set(set).dst_binding(i as u32).descriptor_type(descriptor_type(*k));
                match k {
                    BindingKind::Storage => w.buffer_info(info),
                    _ => w.texel_buffer_view(view),
                }
            })
            .collect();
        // SAFETY: every write names a set of this arena and a live buffer or view; the set is not in use by a
        // pending submission (it was allocated for this recording).
        unsafe { self.ctx.device.update_descriptor_sets(&writes, &[]) };
        Ok(set)
    }
}

impl Drop for DescriptorArena {
    fn drop(&mut self) {
        // The recording that used these sets has completed (or never ran).
        for v in self.views.drain(..) {
            // SAFETY: the recording that used these views has completed or never ran.
            unsafe { self.ctx.device.destroy_buffer_view(v, None) };
        }
        let mut spare = self.ctx.spare.lock();
        for p in self.pools.drain(..) {
            match spare.as_mut() {
                Ok(s) => s.give_descriptor_pool(&self.ctx.device, p),
                // SAFETY: as above: no set of the pool is in use; it is destroyed once.
                Err(_) => unsafe { self.ctx.device.destroy_descriptor_pool(p, None) },
            }
        }
    }
}
