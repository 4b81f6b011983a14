//! tgs-engine: a thin Vulkan compute runtime with no knowledge of splatting.
//!
//! * [`Context`]: instance/device creation (headless) or adoption of a host
//!   application's `VkDevice` and queue, plus the memory allocator.
//! * [`Capabilities`]: what kernels need to know about the device.
//! * [`Buffer`]: typed device buffers with staging upload/download.
//! * [`Kernel`]: a compute pipeline from SPIR-V with specialization and push constants.
//! * [`Recorder`]: command recording with automatic barriers, descriptor
//!   handling and optional GPU timestamp scopes ([`Timing`]).

mod buffer;
mod caps;
mod context;
mod descriptors;
mod kernel;
mod profiler;
mod recorder;
mod select;
mod spare;
mod spirv;
mod validation;

pub use ash::vk;
pub use buffer::{Buffer, BufferBinding, Readback};
pub use caps::Capabilities;
pub use context::{AdoptInfo, Context, ContextOptions, EnabledFeatures, MemoryUse};
pub use kernel::{Kernel, KernelDesc};
pub use profiler::{summarize, Timing, TimingSummary};
pub use recorder::{groups_2d, Recorder};
pub use select::{list_devices, DeviceInfo, DeviceSelector};
