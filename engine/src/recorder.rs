//! Command recording: dispatches with automatic barriers, buffer transfers,
//! GPU timestamp scopes, submission.

use crate::buffer::{BufferBinding, RawBuffer};
use crate::context::Context;
use crate::descriptors::DescriptorArena;
use crate::kernel::Kernel;
use crate::profiler::{Profiler, Timing};
use anyhow::{anyhow, bail, Result};
use ash::vk;
use std::any::Any;
use std::sync::Arc;

/// Split `groups` workgroups into a 2-D grid within `max_x` per dimension
/// (kernels linearize `gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x`
/// and skip ids past their count).
pub fn groups_2d(groups: u32, max_x: u32) -> [u32; 3] {
    if groups <= max_x {
        [groups, 1, 1]
    } else {
        [max_x, groups.div_ceil(max_x), 1]
    }
}

/// Records compute work into one command buffer.
///
/// Every command that reads GPU memory is preceded by a memory barrier if an
/// earlier command wrote memory, so recorded kernels see each other's results
/// in order. Objects referenced by the recording (kernels, buffers bound
/// through [`BufferBinding`]s, descriptor sets) are kept alive by the recorder.
pub struct Recorder {
    ctx: Arc<Context>,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    owned: bool,
    arena: DescriptorArena,
    dirty: bool,
    ended: bool,
    submitted: bool,
    profiler: Option<Profiler>,
    keep: Vec<Arc<dyn Any + Send + Sync>>,
    kernels: Vec<Kernel>,
    /// A [`Recorder::read_back`] was recorded: end with a host-read barrier.
    host_reads: bool,
}

impl Recorder {
    /// A new command buffer, begun, without profiling.
    pub fn new(ctx: &Arc<Context>) -> Result<Recorder> {
        Self::create(ctx, 0)
    }

    /// A new command buffer with up to `max_scopes` timestamp scopes. On a
    /// queue without timestamps, scopes are silently not recorded.
    pub fn with_profiling(ctx: &Arc<Context>, max_scopes: u32) -> Result<Recorder> {
        Self::create(ctx, max_scopes)
    }

    /// [`Recorder::with_profiling`] with 256 scopes when `profile`, else
    /// [`Recorder::new`].
    pub fn profiled_if(ctx: &Arc<Context>, profile: bool) -> Result<Recorder> {
        Self::create(ctx, if profile { 256 } else { 0 })
    }

    fn create(ctx: &Arc<Context>, max_scopes: u32) -> Result<Recorder> {
        let d = &ctx.device;
        let spare = ctx.spare.lock().ok().and_then(|mut s| s.take_commands());
        let (pool, cmd) = match spare {
            Some(pc) => pc,
            None => {
                // SAFETY: the create info names this context's queue family.
                let pool = unsafe { d.create_command_pool(&vk::CommandPoolCreateInfo::default().queue_family_index(ctx.queue_family), None) }?;
                // SAFETY: `pool` was just created on `d`.
                match unsafe {
                    d.allocate_command_buffers(&vk::CommandBufferAllocateInfo::default().command_pool(pool).level(vk::CommandBufferLevel::PRIMARY).command_buffer_count(1))
                } {
                    Ok(c) => (pool, c[0]),
                    Err(e) => {
                        // SAFETY: the allocation failed, so the pool holds no command buffer in use.
                        unsafe { d.destroy_command_pool(pool, None) };
                        return Err(anyhow!("allocating a command buffer: {e}"));
                    }
                }
            }
        };
        // SAFETY: `cmd` is a fresh or reset primary command buffer of `pool`, in the initial state.
        if let Err(e) = unsafe { d.begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT)) } {
            // SAFETY: beginning failed, so `cmd` is not pending.
            unsafe { d.destroy_command_pool(pool, None) };
            return Err(anyhow!("beginning a command buffer: {e}"));
        }
        Self::assemble(ctx, pool, cmd, true, max_scopes)
    }

    fn assemble(ctx: &Arc<Context>, pool: vk::CommandPool, cmd: vk::CommandBuffer, owned: bool, max_scopes: u32) -> Result<Recorder> {
        let mut r = Recorder {
            ctx: ctx.clone(),
            pool,
            cmd,
            owned,
            arena: DescriptorArena::new(ctx),
            // A host command buffer may hold earlier writes: start with a barrier.
            dirty: !owned,
            ended: false,
            submitted: false,
            profiler: None,
            keep: Vec::new(),
            kernels: Vec::new(),
            host_reads: false,
        };
        if max_scopes > 0 {
            r.profiler = Profiler::new(ctx, max_scopes)?;
            if let Some(p) = r.profiler.as_mut() {
                p.reset(cmd);
            }
        }
        Ok(r)
    }

    /// Record into a command buffer the host application owns and has begun.
    /// tgs inserts a barrier first (so host writes are visible) and, at
    /// [`Recorder::finish`], one after (so host reads see tgs results). Keep the
    /// recorder alive until the host's submission completes.
    ///
    /// # Safety
    /// `cmd` must be a primary command buffer in the recording state, from a
    /// pool of this context's queue family.
    pub unsafe fn record_into(ctx: &Arc<Context>, cmd: vk::CommandBuffer, max_scopes: u32) -> Result<Recorder> {
        Self::assemble(ctx, vk::CommandPool::null(), cmd, false, max_scopes)
    }

    pub fn context(&self) -> &Arc<Context> {
        &self.ctx
    }
    pub fn cmd(&self) -> vk::CommandBuffer {
        self.cmd
    }

    fn check_open(&self) -> Result<()> {
        if self.ended {
            bail!("recording already finished");
        }
        Ok(())
    }

    /// Global memory barrier: all earlier compute/transfer writes become
    /// visible to all later compute/transfer/indirect reads and writes, and
    /// earlier indirect reads finish before later writes (a reused slot of
    /// indirect arguments).
    pub fn barrier(&mut self) {
        let mb = [vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE | vk::AccessFlags::SHADER_READ | vk::AccessFlags::TRANSFER_READ)
            .dst_access_mask(
                vk::AccessFlags::SHADER_READ
                    | vk::AccessFlags::SHADER_WRITE
                    | vk::AccessFlags::TRANSFER_READ
                    | vk::AccessFlags::TRANSFER_WRITE
                    | vk::AccessFlags::INDIRECT_COMMAND_READ,
            )];
        // SAFETY: `self.cmd` is recording (check_open) and the barrier is a plain memory barrier.
        unsafe {
            self.ctx.device.cmd_pipeline_barrier(
                self.cmd,
                vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER | vk::PipelineStageFlags::DRAW_INDIRECT,
                vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER | vk::PipelineStageFlags::DRAW_INDIRECT,
                vk::DependencyFlags::empty(),
                &mb,
                &[],
                &[],
            )
        };
        self.dirty = false;
    }

    fn before(&mut self) {
        if self.dirty {
            self.barrier();
        }
    }

    fn bind(&mut self, kernel: &Kernel, bindings: &[BufferBinding], push: &[u8]) -> Result<()> {
        self.check_open()?;
        let k = &kernel.inner;
        if bindings.len() != k.kinds.len() {
            bail!("kernel '{}' declares {} buffers, {} given", k.name, k.kinds.len(), bindings.len());
        }
        if push.len() as u32 != k.push_bytes {
            bail!("kernel '{}' takes {} push-constant bytes, {} given", k.name, k.push_bytes, push.len());
        }
        let set = self.arena.bind(&k.name, k.set_layout, &k.kinds, bindings)?;
        self.before();
        let d = &self.ctx.device;
        // SAFETY: `self.cmd` is recording; the pipeline, its layout and the set were made on this device and
        // outlive the recording (the set's arena and the kernel are kept).
        unsafe {
            d.cmd_bind_pipeline(self.cmd, vk::PipelineBindPoint::COMPUTE, k.pipeline);
            d.cmd_bind_descriptor_sets(self.cmd, vk::PipelineBindPoint::COMPUTE, k.layout, 0, &[set], &[]);
            if !push.is_empty() {
                d.cmd_push_constants(self.cmd, k.layout, vk::ShaderStageFlags::COMPUTE, 0, push);
            }
        }
        for b in bindings {
            if let Some(keep) = &b.keep {
                self.keep.push(keep.clone());
            }
        }
        if !self.kernels.iter().any(|x| Arc::ptr_eq(&x.inner, &kernel.inner)) {
            self.kernels.push(kernel.clone());
        }
        Ok(())
    }

    /// Dispatch `groups` workgroups (each dimension within the device limit).
    pub fn dispatch(&mut self, kernel: &Kernel, bindings: &[BufferBinding], push: &[u8], groups: [u32; 3]) -> Result<()> {
        let max = self.ctx.caps.max_workgroup_count;
        if groups.iter().zip(max.iter()).any(|(g, m)| g > m) {
            bail!("kernel '{}': {:?} workgroups exceed the device limit {:?} (use groups_2d)", kernel.name(), groups, max);
        }
        self.bind(kernel, bindings, push)?;
        if groups.iter().all(|&g| g > 0) {
            // SAFETY: `self.cmd` is recording with a compute pipeline and its descriptor set bound (bind
            // above); every group count is positive.
            unsafe { self.ctx.device.cmd_dispatch(self.cmd, groups[0], groups[1], groups[2]) };
        }
        self.dirty = true;
        Ok(())
    }

    /// Dispatch with the workgroup counts read from `args` (3 u32 at its offset),
    /// written earlier on the GPU: no host read-back.
    pub fn dispatch_indirect(&mut self, kernel: &Kernel, bindings: &[BufferBinding], push: &[u8], args: &BufferBinding) -> Result<()> {
        self.bind(kernel, bindings, push)?;
        if let Some(keep) = &args.keep {
            self.keep.push(keep.clone());
        }
        // SAFETY: as above, with the indirect arguments' buffer kept alive by the recording.
        unsafe { self.ctx.device.cmd_dispatch_indirect(self.cmd, args.buffer, args.offset) };
        self.dirty = true;
        Ok(())
    }

    /// Fill `dst` with a repeated u32.
    pub fn fill(&mut self, dst: &BufferBinding, value: u32) -> Result<()> {
        self.check_open()?;
        self.before();
        // SAFETY: `self.cmd` is recording; the range lies inside its buffer and is whole 4-byte elements
        // (Buffer::binding of u32/f32 elements, or BufferBinding::external's contract), and the recording
        // keeps a tgs buffer alive.
        unsafe { self.ctx.device.cmd_fill_buffer(self.cmd, dst.buffer, dst.offset, dst.range, value) };
        if let Some(k) = &dst.keep {
            self.keep.push(k.clone());
        }
        self.dirty = true;
        Ok(())
    }

    /// Write small data (≤ 65,536 bytes, a multiple of 4) into `dst` from the command stream.
    pub fn update(&mut self, dst: &BufferBinding, data: &[u8]) -> Result<()> {
        self.check_open()?;
        if data.is_empty() {
            return Ok(());
        }
        if data.len() > 65536 || !data.len().is_multiple_of(4) || data.len() as u64 > dst.range {
            bail!("update of {} bytes into a range of {}", data.len(), dst.range);
        }
        self.before();
        // SAFETY: the data is at most 65,536 bytes, a multiple of 4, and fits the range (checked above).
        unsafe { self.ctx.device.cmd_update_buffer(self.cmd, dst.buffer, dst.offset, data) };
        if let Some(k) = &dst.keep {
            self.keep.push(k.clone());
        }
        self.dirty = true;
        Ok(())
    }

    /// Copy `bytes` from `src` to `dst` (at their offsets).
    pub fn copy(&mut self, src: &BufferBinding, dst: &BufferBinding, bytes: u64) -> Result<()> {
        self.check_open()?;
        if bytes == 0 {
            return Ok(());
        }
        if bytes > src.range || bytes > dst.range {
            bail!("copy of {bytes} bytes exceeds a range ({} / {})", src.range, dst.range);
        }
        self.before();
        let region = [vk::BufferCopy { src_offset: src.offset, dst_offset: dst.offset, size: bytes }];
        // SAFETY: both ranges lie inside their buffers and the copy fits both (checked above); the recording
        // keeps tgs buffers alive.
        unsafe { self.ctx.device.cmd_copy_buffer(self.cmd, src.buffer, dst.buffer, &region) };
        for k in [&src.keep, &dst.keep].into_iter().flatten() {
            self.keep.push(k.clone());
        }
        self.dirty = true;
        Ok(())
    }

    pub(crate) fn copy_raw_at(&mut self, src: &Arc<RawBuffer>, src_off: u64, dst: &Arc<RawBuffer>, dst_off: u64, bytes: u64) -> Result<()> {
        self.check_open()?;
        self.before();
        let region = [vk::BufferCopy { src_offset: src_off, dst_offset: dst_off, size: bytes }];
        // SAFETY: the crate's callers (Buffer's upload and download) copy within both buffers: the staging
        // buffer is sized from the same range; the recording keeps both alive.
        unsafe { self.ctx.device.cmd_copy_buffer(self.cmd, src.raw, dst.raw, &region) };
        self.keep.push(src.clone());
        self.keep.push(dst.clone());
        self.dirty = true;
        Ok(())
    }

    /// Copy elements `[start, start + dst.len())` of `src` into `dst`, to be
    /// read on the host once this recording's submission has completed.
    pub fn read_back<T: bytemuck::Pod>(&mut self, src: &crate::Buffer<T>, start: usize, dst: &crate::Readback<T>) -> Result<()> {
        if start + dst.len() > src.len() {
            bail!("read-back of [{start}, {}) from buffer '{}' of {}", start + dst.len(), src.name(), src.len());
        }
        if dst.is_empty() {
            return Ok(());
        }
        let sz = std::mem::size_of::<T>() as u64;
        self.copy_raw_at(src.raw_arc(), start as u64 * sz, dst.raw(), 0, dst.len() as u64 * sz)?;
        self.host_reads = true;
        Ok(())
    }

    /// Keep a buffer alive until the recording is dropped (for buffers reached
    /// through device addresses rather than bindings).
    pub fn keep_alive(&mut self, b: BufferBinding) {
        if let Some(k) = b.keep {
            self.keep.push(k);
        }
    }

    /// Open a named GPU timing scope (no-op without profiling).
    pub fn begin_scope(&mut self, name: &str) -> Option<usize> {
        let cmd = self.cmd;
        self.profiler.as_mut().and_then(|p| p.begin(cmd, name))
    }

    /// Close a scope returned by [`Recorder::begin_scope`].
    pub fn end_scope(&mut self, scope: Option<usize>) {
        let cmd = self.cmd;
        if let (Some(p), Some(s)) = (self.profiler.as_mut(), scope) {
            p.end(cmd, s);
        }
    }

    /// Whether timing scopes are being recorded.
    pub fn profiling(&self) -> bool {
        self.profiler.is_some()
    }

    /// End the recording. For a host-owned command buffer this only adds the
    /// trailing barrier; the host ends and submits it.
    pub fn finish(&mut self) -> Result<vk::CommandBuffer> {
        if self.ended {
            return Ok(self.cmd);
        }
        if !self.owned {
            let mb = [vk::MemoryBarrier::default()
                .src_access_mask(vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE)
                .dst_access_mask(vk::AccessFlags::MEMORY_READ | vk::AccessFlags::MEMORY_WRITE | vk::AccessFlags::HOST_READ)];
            // SAFETY: `self.cmd` is recording (it has not ended yet).
            unsafe {
                self.ctx.device.cmd_pipeline_barrier(
                    self.cmd,
                    vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
                    vk::PipelineStageFlags::ALL_COMMANDS | vk::PipelineStageFlags::HOST,
                    vk::DependencyFlags::empty(),
                    &mb,
                    &[],
                    &[],
                )
            };
        } else {
            if self.host_reads {
                let mb = [vk::MemoryBarrier::default().src_access_mask(vk::AccessFlags::TRANSFER_WRITE).dst_access_mask(vk::AccessFlags::HOST_READ)];
                // SAFETY: as above: the last command of the recording.
                unsafe {
                    self.ctx.device.cmd_pipeline_barrier(self.cmd, vk::PipelineStageFlags::TRANSFER, vk::PipelineStageFlags::HOST, vk::DependencyFlags::empty(), &mb, &[], &[])
                };
            }
            // SAFETY: `self.cmd` is recording; it ends once (`ended` is set below).
            unsafe { self.ctx.device.end_command_buffer(self.cmd) }?;
        }
        self.ended = true;
        Ok(self.cmd)
    }

    /// Submit to the context's queue, wait, and return the timings.
    pub fn submit_and_wait(mut self) -> Result<Vec<Timing>> {
        if !self.owned {
            bail!("this recording belongs to a host command buffer; the host submits it");
        }
        let cmd = self.finish()?;
        self.ctx.submit_and_wait(cmd)?;
        self.submitted = true;
        self.timings()
    }

    /// Timings of a completed submission (empty without profiling).
    pub fn timings(&self) -> Result<Vec<Timing>> {
        match &self.profiler {
            Some(p) => p.read(),
            None => Ok(Vec::new()),
        }
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        if self.owned {
            // SAFETY: the pool is owned by this recorder and its command buffer is no longer pending: it
            // completed, never ran, or the device was waited for above.
            unsafe {
                if self.ended && !self.submitted {
                    // Possibly handed to another queue: be safe.
                    let _ = self.ctx.device.device_wait_idle();
                }
                match self.ctx.spare.lock() {
                    Ok(mut s) => s.give_commands(&self.ctx.device, self.pool, self.cmd),
                    Err(_) => self.ctx.device.destroy_command_pool(self.pool, None),
                }
            }
        }
    }
}
