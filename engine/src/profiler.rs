//! GPU timing from timestamp queries: named scopes, milliseconds per scope.
//! A recording without profiling has no query pool and scopes cost nothing.

use crate::context::Context;
use anyhow::Result;
use ash::vk;
use std::sync::Arc;

/// Time one scope took on the GPU.
#[derive(Clone, Debug)]
pub struct Timing {
    pub name: String,
    pub ms: f64,
}

/// Timings with the same name added up, in order of first appearance.
#[derive(Clone, Debug)]
pub struct TimingSummary {
    pub name: String,
    pub total_ms: f64,
    pub count: usize,
}

pub fn summarize(timings: &[Timing]) -> Vec<TimingSummary> {
    let mut out: Vec<TimingSummary> = Vec::new();
    for t in timings {
        match out.iter_mut().find(|s| s.name == t.name) {
            Some(s) => {
                s.total_ms += t.ms;
                s.count += 1;
            }
            None => out.push(TimingSummary { name: t.name.clone(), total_ms: t.ms, count: 1 }),
        }
    }
    out
}

pub(crate) struct Profiler {
    ctx: Arc<Context>,
    pool: vk::QueryPool,
    capacity: u32,
    next: u32,
    /// (name, begin query, end query or u32::MAX while open)
    scopes: Vec<(String, u32, u32)>,
    pub(crate) dropped: usize,
}

impl Profiler {
    /// `None` when the queue has no timestamps.
    pub(crate) fn new(ctx: &Arc<Context>, max_scopes: u32) -> Result<Option<Profiler>> {
        if ctx.caps.timestamp_valid_bits == 0 || ctx.caps.timestamp_period <= 0.0 {
            return Ok(None);
        }
        let capacity = max_scopes * 2;
        let info = vk::QueryPoolCreateInfo::default().query_type(vk::QueryType::TIMESTAMP).query_count(capacity);
        // SAFETY: timestamps are supported (checked above) and the create info is complete.
        let pool = unsafe { ctx.device.create_query_pool(&info, None) }?;
        Ok(Some(Profiler { ctx: ctx.clone(), pool, capacity, next: 0, scopes: Vec::new(), dropped: 0 }))
    }

    pub(crate) fn reset(&mut self, cmd: vk::CommandBuffer) {
        // SAFETY: `cmd` is recording, outside a render pass, and the pool is this profiler's.
        unsafe { self.ctx.device.cmd_reset_query_pool(cmd, self.pool, 0, self.capacity) };
        self.next = 0;
        self.scopes.clear();
    }

    pub(crate) fn begin(&mut self, cmd: vk::CommandBuffer, name: &str) -> Option<usize> {
        if self.next + 2 > self.capacity {
            self.dropped += 1;
            return None;
        }
        let q = self.next;
        self.next += 2;
        // SAFETY: `q` < capacity (checked above) and was reset at the start of this recording.
        unsafe { self.ctx.device.cmd_write_timestamp(cmd, vk::PipelineStageFlags::BOTTOM_OF_PIPE, self.pool, q) };
        self.scopes.push((name.to_string(), q, u32::MAX));
        Some(self.scopes.len() - 1)
    }

    pub(crate) fn end(&mut self, cmd: vk::CommandBuffer, scope: usize) {
        let q = self.scopes[scope].1 + 1;
        // SAFETY: `q` is the pair of the query the scope began with, inside the pool and reset.
        unsafe { self.ctx.device.cmd_write_timestamp(cmd, vk::PipelineStageFlags::BOTTOM_OF_PIPE, self.pool, q) };
        self.scopes[scope].2 = q;
    }

    /// Read results; call only after the work completed.
    pub(crate) fn read(&self) -> Result<Vec<Timing>> {
        if self.next == 0 {
            return Ok(Vec::new());
        }
        let mut data = vec![0u64; self.next as usize];
        // SAFETY: the submission that wrote these queries completed (results are read after submit_and_wait);
        // `data` holds one u64 for each query asked for.
        unsafe { self.ctx.device.get_query_pool_results(self.pool, 0, &mut data, vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT) }?;
        let bits = self.ctx.caps.timestamp_valid_bits;
        let mask = if bits >= 64 { u64::MAX } else { (1u64 << bits) - 1 };
        let period = self.ctx.caps.timestamp_period as f64;
        Ok(self
            .scopes
            .iter()
            .filter(|s| s.2 != u32::MAX)
            .map(|(name, b, e)| {
                let ticks = (data[*e as usize] & mask).wrapping_sub(data[*b as usize] & mask) & mask;
                Timing { name: name.clone(), ms: ticks as f64 * period / 1e6 }
            })
            .collect())
    }
}

impl Drop for Profiler {
    fn drop(&mut self) {
        // SAFETY: the recording that used the pool has completed or never ran.
        unsafe { self.ctx.device.destroy_query_pool(self.pool, None) };
    }
}
