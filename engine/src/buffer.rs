//! Typed device buffers with staging upload/download.

use crate::context::Context;
use crate::recorder::Recorder;
use anyhow::{anyhow, bail, Context as _, Result};
use ash::vk;
use bytemuck::Pod;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;
use std::any::Any;
use std::marker::PhantomData;
use std::sync::{Arc, Mutex};

pub(crate) struct RawBuffer {
    ctx: Arc<Context>,
    pub(crate) raw: vk::Buffer,
    alloc: Mutex<Option<Allocation>>,
    pub(crate) bytes: u64,
    pub(crate) name: String,
}

impl RawBuffer {
    pub(crate) fn new(ctx: &Arc<Context>, name: &str, bytes: u64, location: MemoryLocation) -> Result<Arc<Self>> {
        let mut usage = vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::TRANSFER_SRC | vk::BufferUsageFlags::TRANSFER_DST;
        if location == MemoryLocation::GpuOnly {
            // Texel-buffer reads: kernels that read an input through a
            // uniform texel buffer (cheaper than a storage-buffer load on
            // CPU drivers; `Kernel`'s binding kinds).
            usage |= vk::BufferUsageFlags::INDIRECT_BUFFER | vk::BufferUsageFlags::UNIFORM_TEXEL_BUFFER;
            if ctx.features.buffer_device_address {
                usage |= vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS;
            }
        }
        // Vulkan forbids empty buffers; keep a small one so empty inputs need no special cases.
        let size = bytes.max(16).next_multiple_of(4);
        if size > ctx.caps.max_memory_allocation {
            bail!("buffer '{name}' needs {:.1} MiB, over this device's largest allocation ({:.1} MiB)", size as f64 / 1048576.0, ctx.caps.max_memory_allocation as f64 / 1048576.0);
        }
        let d = &ctx.device;
        let info = vk::BufferCreateInfo::default().size(size).usage(usage).sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: the create info is complete and `d` is this context's live device.
        let raw = unsafe { d.create_buffer(&info, None) }.with_context(|| format!("vkCreateBuffer '{name}'"))?;
        // SAFETY: `raw` was just created on `d` and is not yet destroyed.
        let req = unsafe { d.get_buffer_memory_requirements(raw) };
        let alloc = ctx.allocator.lock().map_err(|_| anyhow!("allocator lock poisoned"))?.allocate(&AllocationCreateDesc {
            name,
            requirements: req,
            location,
            linear: true,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        });
        let alloc = match alloc {
            Ok(a) => a,
            Err(e) => {
                // SAFETY: `raw` was created on `d`, is bound to no memory and used by nothing yet.
                unsafe { d.destroy_buffer(raw, None) };
                return Err(match e {
                    gpu_allocator::AllocationError::OutOfMemory => anyhow!(
                        "out of device memory allocating {:.1} MiB for buffer '{name}' on {}; reduce the problem size or pick another device (--device)",
                        size as f64 / 1048576.0,
                        ctx.caps.device_name
                    ),
                    e => anyhow!("allocating buffer '{name}' ({size} bytes): {e}"),
                });
            }
        };
        // SAFETY: `raw` and the allocation's memory belong to `d`; the allocation is at least `req.size` at
        // an offset of the required alignment.
        if let Err(e) = unsafe { d.bind_buffer_memory(raw, alloc.memory(), alloc.offset()) } {
            let _ = ctx.allocator.lock().map(|mut a| a.free(alloc));
            // SAFETY: binding failed, so `raw` is used by nothing; it is destroyed once.
            unsafe { d.destroy_buffer(raw, None) };
            return Err(anyhow!("vkBindBufferMemory '{name}': {e}"));
        }
        ctx.memory_allocated(alloc.size());
        Ok(Arc::new(RawBuffer { ctx: ctx.clone(), raw, alloc: Mutex::new(Some(alloc)), bytes, name: name.to_string() }))
    }

    fn with_mapped<R>(&self, f: impl FnOnce(&mut [u8]) -> R) -> Result<R> {
        let mut guard = self.alloc.lock().map_err(|_| anyhow!("buffer lock poisoned"))?;
        let alloc = guard.as_mut().ok_or_else(|| anyhow!("buffer freed"))?;
        let slice = alloc.mapped_slice_mut().ok_or_else(|| anyhow!("staging buffer '{}' is not host-mapped", self.name))?;
        Ok(f(&mut slice[..self.bytes as usize]))
    }

    /// The first `count` elements of a host-mapped buffer.
    fn read_mapped<T: Pod>(&self, count: usize) -> Result<Vec<T>> {
        let mut out = vec![T::zeroed(); count];
        let n = std::mem::size_of_val(out.as_slice());
        self.with_mapped(|m| bytemuck::cast_slice_mut::<T, u8>(&mut out).copy_from_slice(&m[..n]))?;
        Ok(out)
    }
}

impl Drop for RawBuffer {
    fn drop(&mut self) {
        // SAFETY: the last owner is dropping it; every recording that used it kept a clone until its
        // submission completed, so the GPU no longer reads it.
        unsafe { self.ctx.device.destroy_buffer(self.raw, None) };
        if let Some(a) = self.alloc.get_mut().ok().and_then(|a| a.take()) {
            self.ctx.memory_freed(a.size());
            if let Ok(mut al) = self.ctx.allocator.lock() {
                let _ = al.free(a);
            }
        }
    }
}

/// A view of a buffer for binding to a kernel: byte offset and range.
/// It keeps the buffer alive for as long as a recording refers to it.
#[derive(Clone)]
pub struct BufferBinding {
    pub buffer: vk::Buffer,
    pub offset: u64,
    pub range: u64,
    pub(crate) keep: Option<Arc<dyn Any + Send + Sync>>,
}

impl BufferBinding {
    /// A binding of a buffer tgs does not own (e.g. a host renderer's buffer).
    ///
    /// # Safety
    /// The buffer must have STORAGE_BUFFER usage and outlive every recording using it.
    pub unsafe fn external(buffer: vk::Buffer, offset: u64, range: u64) -> Self {
        BufferBinding { buffer, offset, range, keep: None }
    }
}

/// A device-local buffer of `len` elements of `T`.
pub struct Buffer<T> {
    inner: Arc<RawBuffer>,
    len: usize,
    _t: PhantomData<T>,
}

impl<T: Pod> Buffer<T> {
    /// Allocate `len` elements, all zero. This is the default: device memory
    /// is reused between buffers, so undefined contents would differ from run
    /// to run.
    pub fn new(ctx: &Arc<Context>, name: &str, len: usize) -> Result<Self> {
        let b = Self::alloc(ctx, name, len)?;
        b.fill_bits(0)?;
        Ok(b)
    }

    /// Allocate `len` elements with undefined contents. Only for buffers that
    /// a kernel or copy writes completely (every element later read) before
    /// anything reads them; say at the call site what writes them. On a
    /// context with [`Context::set_poison_uninit`] on, the memory is filled
    /// with 0xFFFFFFFF so a read before a write shows up deterministically.
    pub fn uninit(ctx: &Arc<Context>, name: &str, len: usize) -> Result<Self> {
        let b = Self::alloc(ctx, name, len)?;
        if ctx.poison_uninit.load(std::sync::atomic::Ordering::SeqCst) {
            b.fill_bits(u32::MAX)?;
        }
        Ok(b)
    }

    fn alloc(ctx: &Arc<Context>, name: &str, len: usize) -> Result<Self> {
        let bytes = (len as u64).checked_mul(std::mem::size_of::<T>() as u64).ok_or_else(|| anyhow!("buffer '{name}': size overflow"))?;
        Ok(Buffer { inner: RawBuffer::new(ctx, name, bytes, MemoryLocation::GpuOnly)?, len, _t: PhantomData })
    }

    /// Fill the whole allocation with a repeated 32-bit pattern (blocking).
    fn fill_bits(&self, bits: u32) -> Result<()> {
        let mut rec = Recorder::new(&self.inner.ctx)?;
        rec.fill(&self.binding(), bits)?;
        rec.submit_and_wait().with_context(|| format!("initialising buffer '{}'", self.name()))?;
        Ok(())
    }

    /// Allocate and fill from `data`.
    pub fn from_slice(ctx: &Arc<Context>, name: &str, data: &[T]) -> Result<Self> {
        let b = Self::uninit(ctx, name, data.len())?;
        b.upload(data)?;
        Ok(b)
    }

    pub fn len(&self) -> usize {
        self.len
    }
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    pub fn bytes(&self) -> u64 {
        self.inner.bytes
    }
    pub fn raw(&self) -> vk::Buffer {
        self.inner.raw
    }
    pub(crate) fn raw_arc(&self) -> &Arc<RawBuffer> {
        &self.inner
    }
    pub fn name(&self) -> &str {
        &self.inner.name
    }

    /// The whole buffer as a binding.
    pub fn binding(&self) -> BufferBinding {
        BufferBinding { buffer: self.inner.raw, offset: 0, range: self.inner.bytes.max(16).next_multiple_of(4), keep: Some(self.inner.clone() as Arc<dyn Any + Send + Sync>) }
    }

    /// Elements `[start, start+count)` as a binding. This is how buffers larger
    /// than `maxStorageBufferRange` (128 MiB on lavapipe) are bound in windows.
    pub fn slice(&self, start: usize, count: usize) -> BufferBinding {
        let sz = std::mem::size_of::<T>() as u64;
        BufferBinding { buffer: self.inner.raw, offset: start as u64 * sz, range: (count as u64 * sz).max(4), keep: Some(self.inner.clone() as Arc<dyn Any + Send + Sync>) }
    }

    /// GPU virtual address (needs `bufferDeviceAddress`), for kernels that
    /// reach buffers of any size through `GL_EXT_buffer_reference`.
    pub fn device_address(&self) -> Result<u64> {
        if !self.inner.ctx.features.buffer_device_address {
            bail!("buffer device address is not enabled on {}", self.inner.ctx.caps.device_name);
        }
        let info = vk::BufferDeviceAddressInfo::default().buffer(self.inner.raw);
        // SAFETY: bufferDeviceAddress is enabled (checked above) and the buffer was created with the
        // device-address usage on this device.
        Ok(unsafe { self.inner.ctx.device.get_buffer_device_address(&info) })
    }

    /// Copy `data` to the start of the buffer (blocking).
    pub fn upload(&self, data: &[T]) -> Result<()> {
        if data.len() > self.len {
            bail!("upload of {} elements into buffer '{}' of {}", data.len(), self.name(), self.len);
        }
        if data.is_empty() {
            return Ok(());
        }
        let ctx = &self.inner.ctx;
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let staging = RawBuffer::new(ctx, "staging-upload", bytes.len() as u64, MemoryLocation::CpuToGpu)?;
        staging.with_mapped(|m| m.copy_from_slice(bytes))?;
        let mut rec = Recorder::new(ctx)?;
        rec.copy_raw_at(&staging, 0, &self.inner, 0, bytes.len() as u64)?;
        rec.submit_and_wait().with_context(|| format!("uploading buffer '{}'", self.name()))?;
        Ok(())
    }

    /// Read the whole buffer back (blocking).
    pub fn download(&self) -> Result<Vec<T>> {
        self.download_range(0, self.len)
    }

    /// Read elements `[start, start+count)` back (blocking).
    pub fn download_range(&self, start: usize, count: usize) -> Result<Vec<T>> {
        if start + count > self.len {
            bail!("download of [{start}, {}) from buffer '{}' of {}", start + count, self.name(), self.len);
        }
        if count == 0 {
            return Ok(Vec::new());
        }
        let ctx = &self.inner.ctx;
        let sz = std::mem::size_of::<T>() as u64;
        let bytes = count as u64 * sz;
        let staging = RawBuffer::new(ctx, "staging-download", bytes, MemoryLocation::GpuToCpu)?;
        let mut rec = Recorder::new(ctx)?;
        rec.copy_raw_at(&self.inner, start as u64 * sz, &staging, 0, bytes)?;
        rec.submit_and_wait().with_context(|| format!("downloading buffer '{}'", self.name()))?;
        staging.read_mapped(count)
    }
}

/// A host-visible buffer of `len` elements that a recording copies results
/// into ([`Recorder::read_back`]); read it once that recording's submission
/// has completed. A result that rides an existing submission this way costs
/// no submission, staging allocation or wait of its own.
pub struct Readback<T> {
    inner: Arc<RawBuffer>,
    len: usize,
    _t: PhantomData<T>,
}

impl<T: Pod> Readback<T> {
    /// `len` elements, zero until a recording copies into them.
    pub fn new(ctx: &Arc<Context>, name: &str, len: usize) -> Result<Self> {
        let bytes = (len.max(1) * std::mem::size_of::<T>()) as u64;
        let inner = RawBuffer::new(ctx, name, bytes, MemoryLocation::GpuToCpu)?;
        inner.with_mapped(|m| m.fill(0))?;
        Ok(Readback { inner, len, _t: PhantomData })
    }

    pub fn len(&self) -> usize {
        self.len
    }
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The elements as the last completed copy left them.
    pub fn read(&self) -> Result<Vec<T>> {
        self.inner.read_mapped(self.len)
    }

    pub(crate) fn raw(&self) -> &Arc<RawBuffer> {
        &self.inner
    }
}
