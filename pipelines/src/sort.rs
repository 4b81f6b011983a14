//! Stable key-value LSD radix sort over u32 keys and u32 values.
//!
//! Reduce-then-scan per digit pass: up-sweep (per-partition digit
//! histograms, digit-major), spine (the [`PrefixSum`] over all histograms),
//! down-sweep (subgroup ballot ranking, shared-memory reorder, scatter).
//! Only the `bits` low bits of the keys are sorted (`ceil(bits / RADIX_BITS)`
//! passes). The count may come from a GPU buffer. No decoupled look-back, no
//! cross-workgroup waiting: safe on lavapipe. Any subgroup size from 4 to 128.
//!
//! Per-invocation loop trip counts are bounded by the configuration, not by
//! n: at most `KPT * (RADIX_BITS + 4) + subgroups + RADIX/WG` iterations
//! (well under 1,000 against lavapipe's 65,535 budget). The largest n is
//! bounded by the storage-buffer range: `maxStorageBufferRange / 4` keys
//! (33,554,432 on lavapipe).

use crate::scan::{Count, PrefixSum, ScanScratch};
use crate::shaders;
use anyhow::{bail, Result};
use std::sync::Arc;
use tgs_engine::{Buffer, Capabilities, Context, Kernel, KernelDesc, Recorder};

/// Shape of the sort kernels (specialization constants).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SortConfig {
    /// Workgroup size (multiple of the largest subgroup size, >= 2^radix_bits / 2).
    pub wg: u32,
    /// Keys per invocation; a partition is `wg * kpt` keys.
    pub kpt: u32,
    /// Digit width: 4 (16 bins) or 8 (256 bins).
    pub radix_bits: u32,
}

impl SortConfig {
    /// Shared memory the down-sweep needs, in bytes.
    pub fn shared_bytes(&self, min_sg: u32) -> u32 {
        let radix = 1u32 << self.radix_bits;
        let max_sg = self.wg / min_sg.max(1);
        4 * (max_sg * radix / 2 + 2 * radix + self.wg * self.kpt + max_sg + 1)
    }

    /// The widest digit whose shared memory fits (at most 24 KiB used), for this device.
    pub fn for_device(caps: &Capabilities) -> SortConfig {
        let budget = caps.max_shared_memory.min(28 * 1024);
        let min_sg = caps.min_subgroup_size.max(1);
        let candidates = [SortConfig { wg: 256, kpt: 8, radix_bits: 8 }, SortConfig { wg: 128, kpt: 16, radix_bits: 8 }, SortConfig { wg: 256, kpt: 8, radix_bits: 4 }];
        for c in candidates {
            if c.shared_bytes(min_sg) <= budget && c.wg % caps.max_subgroup_size.max(1) == 0 {
                return c;
            }
        }
        SortConfig { wg: 256, kpt: 8, radix_bits: 4 }
    }

    pub fn partition(&self) -> u32 {
        self.wg * self.kpt
    }

    fn check(&self, caps: &Capabilities) -> Result<()> {
        let min_sg = caps.min_subgroup_size.max(1);
        if !(self.radix_bits == 4 || self.radix_bits == 8) {
            bail!("radix_bits must be 4 or 8, not {}", self.radix_bits);
        }
        if self.wg < (1 << (self.radix_bits - 1)) || !self.wg.is_power_of_two() || self.wg > caps.max_workgroup_invocations {
            bail!("sort workgroup {} must be a power of two >= {} and <= {}", self.wg, 1 << (self.radix_bits - 1), caps.max_workgroup_invocations);
        }
        if self.wg * self.kpt > 65535 {
            bail!("sort partition wg*kpt = {} must be below 65,536 (16-bit counters)", self.wg * self.kpt);
        }
        if !self.wg.is_multiple_of(caps.max_subgroup_size.max(1)) {
            bail!("sort workgroup {} is not a multiple of the subgroup size {}", self.wg, caps.max_subgroup_size);
        }
        if self.kpt == 0 || self.kpt > 32 {
            bail!("keys per invocation must be 1..=32, not {}", self.kpt);
        }
        let need = self.shared_bytes(min_sg);
        if need > caps.max_shared_memory {
            bail!("sort config {self:?} needs {need} bytes of shared memory; device has {}", caps.max_shared_memory);
        }
        Ok(())
    }
}

/// The radix sort kernels for one configuration.
pub struct RadixSort {
    ctx: Arc<Context>,
    cfg: SortConfig,
    scan: PrefixSum,
    upsweep: Kernel,
    downsweep: Kernel,
    copy: Kernel,
}

/// Scratch for sorting up to `capacity` keys: ping-pong buffers, histograms,
/// spine scan state.
pub struct SortScratch {
    capacity: u32,
    keys: Buffer<u32>,
    vals: Buffer<u32>,
    hist: Buffer<u32>,
    spine: ScanScratch,
}

impl SortScratch {
    pub fn capacity(&self) -> u32 {
        self.capacity
    }

    /// After the sort ran: the count the GPU read, if it exceeded the
    /// capacity (only the first `capacity` pairs were sorted). One read-back.
    pub fn overflow(&self) -> Result<Option<u32>> {
        let requested = self.spine.requested_count()?;
        Ok((requested > self.capacity).then_some(requested))
    }
}

impl RadixSort {
    /// The sort with the configuration chosen for this device.
    pub fn new(ctx: &Arc<Context>) -> Result<RadixSort> {
        Self::with_config(ctx, SortConfig::for_device(ctx.caps()))
    }

    pub fn with_config(ctx: &Arc<Context>, cfg: SortConfig) -> Result<RadixSort> {
        cfg.check(ctx.caps())?;
        let spec = [(0, cfg.wg), (1, ctx.caps().min_subgroup_size.max(1)), (2, cfg.kpt), (3, cfg.radix_bits)];
        let k = |name, spirv, push_bytes| Kernel::new(ctx, &KernelDesc { name, spirv, spec: &spec, push_bytes, subgroup_size: None, full_subgroups: true });
        Ok(RadixSort {
            ctx: ctx.clone(),
            cfg,
            scan: PrefixSum::new(ctx)?,
            upsweep: k("sort.upsweep", shaders::SORT_UPSWEEP, 8)?,
            downsweep: k("sort.downsweep", shaders::SORT_DOWNSWEEP, 8)?,
            copy: k("sort.copy", shaders::SORT_COPY, 0)?,
        })
    }

    pub fn config(&self) -> SortConfig {
        self.cfg
    }

    /// Largest number of keys one sort can take on this device.
    pub fn max_keys(&self) -> u64 {
        self.ctx.caps().max_storage_buffer_range / 4
    }

    /// Scratch for up to `capacity` keys.
    pub fn scratch(&self, capacity: u32) -> Result<SortScratch> {
        if capacity as u64 > self.max_keys() {
            bail!("sort capacity {capacity} exceeds this device's maximum of {} keys", self.max_keys());
        }
        let parts = capacity.div_ceil(self.cfg.partition()).max(1);
        let radix = 1u32 << self.cfg.radix_bits;
        Ok(SortScratch {
            capacity,
            // Each pass writes the first `count` entries before the next reads them.
            keys: Buffer::uninit(&self.ctx, "sort.keys_tmp", capacity as usize)?,
            vals: Buffer::uninit(&self.ctx, "sort.vals_tmp", capacity as usize)?,
            hist: Buffer::new(&self.ctx, "sort.hist", (parts * radix) as usize)?,
            spine: ScanScratch::new(&self.ctx, parts * radix)?,
        })
    }

    /// Record a stable sort of the first `count` (key, value) pairs by the
    /// low `bits` bits of the key, in place. Keys' higher bits are ignored
    /// for ordering but kept. Both buffers must hold `scratch.capacity()`.
    pub fn record(&self, rec: &mut Recorder, keys: &Buffer<u32>, vals: &Buffer<u32>, count: &Count, bits: u32, scratch: &SortScratch) -> Result<()> {
        let cap = scratch.capacity;
        if (keys.len() as u64) < cap as u64 || (vals.len() as u64) < cap as u64 {
            bail!("sort buffers ({} keys / {} values) smaller than the scratch capacity {cap}", keys.len(), vals.len());
        }
        if bits > 32 {
            bail!("bits must be <= 32, not {bits}");
        }
        if bits == 0 {
            return Ok(());
        }
        let radix = 1u32 << self.cfg.radix_bits;
        let sc = rec.begin_scope("sort.plan");
        self.scan.record_plan(rec, &scratch.spine, count, crate::scan::Plan { mode: 1, part_size: self.cfg.partition(), radix }, cap)?;
        // (A GPU count over `cap` is clamped; `SortScratch::overflow` reports it.)
        rec.end_scope(sc);
        let params = scratch.spine.params.binding();
        let mut parts_args = scratch.spine.args.binding();
        parts_args.range = 16;

        let passes = bits.div_ceil(self.cfg.radix_bits);
        let bufs = [(keys, vals), (&scratch.keys, &scratch.vals)];
        for pass in 0..passes {
            let shift = pass * self.cfg.radix_bits;
            let pbits = (bits - shift).min(self.cfg.radix_bits);
            let push = [shift, pbits];
            let (ki, vi) = bufs[(pass % 2) as usize];
            let (ko, vo) = bufs[((pass + 1) % 2) as usize];

            let sc = rec.begin_scope("sort.upsweep");
            rec.dispatch_indirect(&self.upsweep, &[params.clone(), ki.binding(), scratch.hist.binding()], bytemuck::bytes_of(&push), &parts_args)?;
            rec.end_scope(sc);

            let sc = rec.begin_scope("sort.spine");
            self.scan.record_levels(rec, &scratch.spine, 0, scratch.hist.binding(), scratch.hist.binding(), false)?;
            rec.end_scope(sc);

            let sc = rec.begin_scope("sort.downsweep");
            rec.dispatch_indirect(
                &self.downsweep,
                &[params.clone(), ki.binding(), vi.binding(), scratch.hist.binding(), ko.binding(), vo.binding()],
                bytemuck::bytes_of(&push),
                &parts_args,
            )?;
            rec.end_scope(sc);
        }
        if passes % 2 == 1 {
            let sc = rec.begin_scope("sort.copy");
            // Only the first n (known on the GPU) move: the caller's data past n stays.
            rec.dispatch_indirect(&self.copy, &[params.clone(), scratch.keys.binding(), scratch.vals.binding(), keys.binding(), vals.binding()], &[], &parts_args)?;
            rec.end_scope(sc);
        }
        Ok(())
    }
}
