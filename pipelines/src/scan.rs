//! Exclusive prefix sum over u32, any length (0 included), with the length
//! optionally read from a GPU buffer (indirect dispatch, no read-back).
//!
//! Reduce-then-scan: each level reduces blocks of `WG * KPT` elements to
//! block sums, the sums are scanned recursively, and a down-sweep scans each
//! block adding its offset. No cross-workgroup waiting, so it is safe on
//! lavapipe; per-invocation loop counts are `KPT` and `subgroups / SG`.

use crate::shaders;
use anyhow::{bail, Result};
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;
use tgs_engine::{Buffer, BufferBinding, Context, Kernel, KernelDesc, Recorder};

/// Where an element count comes from.
#[derive(Clone)]
pub enum Count {
    /// Known on the host: written into the command stream.
    Host(u32),
    /// The u32 at `index` of a GPU buffer, written by earlier GPU work.
    Gpu { buffer: BufferBinding, index: u32 },
}

use crate::WG;
pub(crate) const KPT: u32 = 4;
pub(crate) const BLOCK: u32 = WG * KPT;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct PlanPush {
    pub count_index: u32,
    pub mode: u32,
    pub part_size: u32,
    pub radix: u32,
    pub block: u32,
    pub levels: u32,
    pub max_x: u32,
    pub capacity: u32,
}

/// The scan kernels (also used as the radix sort's spine).
pub struct PrefixSum {
    ctx: Arc<Context>,
    plan: Kernel,
    reduce: Kernel,
    block: Kernel,
}

/// Per-capacity scratch buffers for a scan (or a sort's spine).
pub struct ScanScratch {
    pub(crate) capacity: u32,
    pub(crate) levels: u32,
    pub(crate) params: Buffer<u32>,
    pub(crate) args: Buffer<u32>,
    pub(crate) count: Buffer<u32>,
    pub(crate) sums: Vec<Buffer<u32>>,
}

impl ScanScratch {
    /// Scratch for scans of up to `capacity` elements.
    pub fn new(ctx: &Arc<Context>, capacity: u32) -> Result<ScanScratch> {
        let mut lens = vec![capacity];
        while *lens.last().unwrap() > BLOCK {
            let l = lens.last().unwrap().div_ceil(BLOCK);
            lens.push(l);
        }
        let levels = lens.len() as u32;
        let sums = lens[1..].iter().enumerate().map(|(i, &len)| Buffer::new(ctx, &format!("scan.sums{i}"), len as usize)).collect::<Result<Vec<_>>>()?;
        Ok(ScanScratch {
            capacity,
            levels,
            params: Buffer::new(ctx, "scan.params", 3 + levels as usize)?,
            args: Buffer::new(ctx, "scan.args", 4 * (1 + levels as usize))?,
            count: Buffer::new(ctx, "scan.count", 4)?,
            sums,
        })
    }

    pub fn capacity(&self) -> u32 {
        self.capacity
    }

    /// After the work ran: the count the GPU read, if it exceeded the
    /// capacity (the scan or sort then processed only `capacity` elements).
    /// Reads back one u32; call it when checking, not inside an iteration.
    pub fn overflow(&self) -> anyhow::Result<Option<u32>> {
        let requested = self.requested_count()?;
        Ok((requested > self.capacity).then_some(requested))
    }

    /// The count the plan kernel last read, before clamping.
    pub(crate) fn requested_count(&self) -> anyhow::Result<u32> {
        Ok(self.params.download_range(2 + self.levels as usize, 1)?[0])
    }
}

fn spec(ctx: &Context) -> [(u32, u32); 3] {
    [(0, WG), (1, ctx.caps().min_subgroup_size.max(1)), (2, KPT)]
}

/// What the plan kernel plans (its push constants besides the count):
/// `mode` 0 scans `n` elements; 1 scans the radix sort's per-partition
/// digit counts (`n` keys in partitions of `part_size`, `radix` digits).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Plan {
    pub mode: u32,
    pub part_size: u32,
    pub radix: u32,
}

impl Plan {
    /// A plain scan of n elements.
    pub const ELEMENTS: Plan = Plan { mode: 0, part_size: 1, radix: 1 };
}

impl PrefixSum {
    pub fn new(ctx: &Arc<Context>) -> Result<PrefixSum> {
        let s = spec(ctx);
        let k = |name, spirv, push_bytes, spec: &[(u32, u32)], full| Kernel::new(ctx, &KernelDesc { name, spirv, spec, push_bytes, subgroup_size: None, full_subgroups: full });
        Ok(PrefixSum {
            ctx: ctx.clone(),
            plan: k("scan.plan", shaders::SCAN_PLAN, 32, &[], false)?,
            reduce: k("scan.reduce", shaders::SCAN_REDUCE, 4, &s, true)?,
            block: k("scan.block", shaders::SCAN_BLOCK, 8, &s, true)?,
        })
    }

    fn max_x(&self) -> u32 {
        self.ctx.caps().max_workgroup_count[0].min(65535)
    }

    /// Record the plan kernel: n from `count`, lengths and dispatch grids
    /// into scratch, for the scan `plan` describes.
    pub(crate) fn record_plan(&self, rec: &mut Recorder, s: &ScanScratch, count: &Count, plan: Plan, capacity: u32) -> Result<()> {
        let Plan { mode, part_size, radix } = plan;
        let (cbuf, index) = match count {
            Count::Host(n) => {
                if *n > capacity {
                    bail!("count {n} exceeds capacity {capacity}");
                }
                rec.update(&s.count.binding(), bytemuck::bytes_of(n))?;
                (s.count.binding(), 0)
            }
            Count::Gpu { buffer, index } => (buffer.clone(), *index),
        };
        let push = PlanPush { count_index: index, mode, part_size, radix, block: BLOCK, levels: s.levels, max_x: self.max_x(), capacity };
        rec.dispatch(&self.plan, &[cbuf, s.params.binding(), s.args.binding()], bytemuck::bytes_of(&push), [1, 1, 1])
    }

    /// Record the scan levels from level `l` on (lengths already planned).
    pub(crate) fn record_levels(&self, rec: &mut Recorder, s: &ScanScratch, l: u32, src: BufferBinding, dst: BufferBinding, scopes: bool) -> Result<()> {
        let args = |slot: u32| {
            let mut b = s.args.binding();
            b.offset += 16 * slot as u64;
            b.range = 16;
            b
        };
        let len_slot = 2 + l;
        let last = l + 1 == s.levels;
        if last {
            let sc = if scopes { rec.begin_scope("scan.block") } else { None };
            let push = [len_slot, 0u32];
            rec.dispatch_indirect(&self.block, &[s.params.binding(), src, dst, s.params.binding()], bytemuck::bytes_of(&push), &args(1 + l))?;
            rec.end_scope(sc);
            return Ok(());
        }
        let sums = s.sums[l as usize].binding();
        let sc = if scopes { rec.begin_scope("scan.reduce") } else { None };
        rec.dispatch_indirect(&self.reduce, &[s.params.binding(), src.clone(), sums.clone()], bytemuck::bytes_of(&len_slot), &args(1 + l))?;
        rec.end_scope(sc);
        self.record_levels(rec, s, l + 1, sums.clone(), sums.clone(), scopes)?;
        let sc = if scopes { rec.begin_scope("scan.block") } else { None };
        let push = [len_slot, 1u32];
        rec.dispatch_indirect(&self.block, &[s.params.binding(), src, dst, sums], bytemuck::bytes_of(&push), &args(1 + l))?;
        rec.end_scope(sc);
        Ok(())
    }

    /// Record an exclusive prefix sum of `count` u32s from `src` into `dst`
    /// (which may be the same buffer). Both must hold `scratch.capacity()` elements.
    pub fn record(&self, rec: &mut Recorder, src: &Buffer<u32>, dst: &Buffer<u32>, count: &Count, scratch: &ScanScratch) -> Result<()> {
        let cap = scratch.capacity;
        if (src.len() as u64) < cap as u64 || (dst.len() as u64) < cap as u64 {
            bail!("scan buffers ({} / {}) smaller than the scratch capacity {cap}", src.len(), dst.len());
        }
        let sc = rec.begin_scope("scan.plan");
        self.record_plan(rec, scratch, count, Plan::ELEMENTS, cap)?;
        rec.end_scope(sc);
        self.record_levels(rec, scratch, 0, src.binding(), dst.binding(), true)
    }
}
