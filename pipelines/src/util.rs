//! Small utility kernels: index sequences (values for sorts), directly or
//! through buffer device addresses for buffers of any size.

use crate::shaders;
use anyhow::{bail, Result};
use std::sync::Arc;
use tgs_engine::{groups_2d, Buffer, BufferBinding, Context, Kernel, KernelDesc, Recorder};

use crate::WG;

pub struct Iota {
    ctx: Arc<Context>,
    direct: Kernel,
    bda: Option<Kernel>,
}

impl Iota {
    pub fn new(ctx: &Arc<Context>) -> Result<Iota> {
        let spec = [(0, WG), (1, ctx.caps().min_subgroup_size.max(1)), (2, 1)];
        let direct = Kernel::new(ctx, &KernelDesc { name: "util.iota", spirv: shaders::UTIL_IOTA, spec: &spec, push_bytes: 8, subgroup_size: None, full_subgroups: false })?;
        let bda = if ctx.features().buffer_device_address {
            Some(Kernel::new(ctx, &KernelDesc { name: "util.iota_bda", spirv: shaders::UTIL_IOTA_BDA, spec: &spec, push_bytes: 16, subgroup_size: None, full_subgroups: false })?)
        } else {
            None
        };
        Ok(Iota { ctx: ctx.clone(), direct, bda })
    }

    fn grid(&self, count: u32) -> [u32; 3] {
        groups_2d(count.div_ceil(WG), self.ctx.caps().max_workgroup_count[0].min(65535))
    }

    /// `window[i] = start + i` for `i < count` (the binding may be a slice).
    pub fn record(&self, rec: &mut Recorder, window: BufferBinding, count: u32, start: u32) -> Result<()> {
        if count as u64 * 4 > window.range {
            bail!("iota of {count} elements into a window of {} bytes", window.range);
        }
        rec.dispatch(&self.direct, &[window], bytemuck::cast_slice(&[count, start]), self.grid(count))
    }

    /// `buf[first + i] = first + i` for `i < count`, through the device address.
    pub fn record_bda(&self, rec: &mut Recorder, buf: &Buffer<u32>, first: u32, count: u32) -> Result<()> {
        let Some(k) = &self.bda else { bail!("buffer device address is not enabled on this device") };
        if first as u64 + count as u64 > buf.len() as u64 {
            bail!("iota [{first}, {}) past the end of '{}' ({})", first as u64 + count as u64, buf.name(), buf.len());
        }
        let addr = buf.device_address()?;
        let mut push = [0u8; 16];
        push[..8].copy_from_slice(&addr.to_le_bytes());
        push[8..12].copy_from_slice(&first.to_le_bytes());
        push[12..].copy_from_slice(&count.to_le_bytes());
        // The recording must keep the buffer alive although it is not bound.
        rec.keep_alive(buf.binding());
        rec.dispatch(k, &[], &push, self.grid(count))
    }
}
