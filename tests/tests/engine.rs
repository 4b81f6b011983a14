//! Engine behaviour: capabilities, validation hook-up, adoption of a host
//! device, buffers over 128 MiB, profiling, and clear errors.

use std::sync::Arc;
use tgs_engine::{vk, Buffer, Context, ContextOptions, DeviceSelector, Kernel, KernelDesc, Recorder};
use tgs_pipelines::{shaders, Count, Iota, RadixSort};
use tgs_tests::*;

#[test]
fn capabilities_are_sane() {
    let ctx = ctx_shared();
    let c = ctx.caps();
    eprintln!("{}", c.describe());
    assert!(c.subgroup_size.is_power_of_two() && (4..=128).contains(&c.subgroup_size), "{}", c.subgroup_size);
    assert!(c.min_subgroup_size <= c.subgroup_size && c.subgroup_size <= c.max_subgroup_size);
    assert!(c.max_shared_memory >= 16 * 1024);
    assert!(c.max_storage_buffer_range >= 1 << 27);
    assert!(c.max_workgroup_count[0] >= 65535);
    if c.device_name.contains("llvmpipe") {
        // lavapipe: subgroup 8, or 4 with LP_NATIVE_VECTOR_WIDTH=128 (CI runs both).
        let want = if std::env::var("LP_NATIVE_VECTOR_WIDTH").as_deref() == Ok("128") { 4 } else { 8 };
        assert_eq!(c.subgroup_size, want);
        assert_eq!(c.max_storage_buffer_range, 128 << 20);
    }
}

#[test]
fn validation_layer_is_active_and_catches_errors() {
    let installed = std::path::Path::new("/usr/share/vulkan/explicit_layer.d/VkLayer_khronos_validation.json").exists();
    if !validation_wanted() || !installed {
        eprintln!("validation layer not installed or disabled: nothing to check");
        return;
    }
    assert!(ctx_shared().validation_enabled(), "tests must run with the validation layer");
    // A fresh context, so the deliberate error does not fail the other tests.
    let ctx = Context::new(&ContextOptions { device: DeviceSelector::from_arg_or_env(None), validation: Some(true) }).unwrap();
    // SAFETY: a deliberately invalid create info for the validation layer to report; a buffer it may still
    // return is destroyed at once.
    unsafe {
        // Invalid: size 0 (VUID-VkBufferCreateInfo-size-00912).
        let info = vk::BufferCreateInfo::default().size(0).usage(vk::BufferUsageFlags::STORAGE_BUFFER);
        if let Ok(b) = ctx.device().create_buffer(&info, None) {
            ctx.device().destroy_buffer(b, None);
        }
    }
    assert!(!ctx.validation_errors().is_empty(), "the validation hook did not report a deliberate error");
}

#[test]
fn adopts_a_host_device_and_leaves_it_alive() {
    let host = tgs_tests::host::Host::new();
    let ctx = host.adopt();
    assert!(!ctx.owns_device());
    assert!(!ctx.caps().buffer_device_address, "not enabled by the host, so not reported");
    let sort = RadixSort::new(&ctx).unwrap();
    let mut rng = Rng(seed("adopt"));
    let keys: Vec<u32> = (0..10_000).map(|_| rng.next_u32()).collect();
    let kb = Buffer::from_slice(&ctx, "k", &keys).unwrap();
    let vb = Buffer::from_slice(&ctx, "v", &(0..10_000u32).collect::<Vec<_>>()).unwrap();
    let scratch = sort.scratch(10_000).unwrap();

    // Record into the host's own command buffer; the host submits it.
    // SAFETY: the host's own command buffer and objects, waited for before they are freed; the buffers tgs
    // records into are alive until then.
    unsafe {
        let d = &host.device;
        let pool = d.create_command_pool(&vk::CommandPoolCreateInfo::default().queue_family_index(host.qf), None).unwrap();
        let cmd = d.allocate_command_buffers(&vk::CommandBufferAllocateInfo::default().command_pool(pool).command_buffer_count(1)).unwrap()[0];
        d.begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default()).unwrap();
        let mut rec = Recorder::record_into(&ctx, cmd, 16).unwrap();
        sort.record(&mut rec, &kb, &vb, &Count::Host(10_000), 32, &scratch).unwrap();
        rec.finish().unwrap();
        d.end_command_buffer(cmd).unwrap();
        let fence = d.create_fence(&vk::FenceCreateInfo::default(), None).unwrap();
        d.queue_submit(host.queue, &[vk::SubmitInfo::default().command_buffers(&[cmd])], fence).unwrap();
        d.wait_for_fences(&[fence], true, u64::MAX).unwrap();
        assert!(rec.timings().unwrap().iter().any(|t| t.name == "sort.downsweep") || !rec.profiling());
        drop(rec);
        d.destroy_fence(fence, None);
        d.destroy_command_pool(pool, None);
    }
    let mut expect = keys.clone();
    expect.sort();
    assert_eq!(kb.download().unwrap(), expect);
    drop((kb, vb, scratch, sort));
    drop(ctx);

    // The host's device is still alive and usable after tgs is gone.
    // SAFETY: tgs's context is dropped; the host's device is live and the buffer is destroyed before the
    // wait.
    unsafe {
        let b = host.device.create_buffer(&vk::BufferCreateInfo::default().size(64).usage(vk::BufferUsageFlags::STORAGE_BUFFER), None).unwrap();
        host.device.destroy_buffer(b, None);
        host.device.device_wait_idle().unwrap();
        host.device.destroy_device(None);
        host.instance.destroy_instance(None);
    }
}

#[test]
fn buffers_over_128_mib() {
    let ctx = ctx_shared();
    let range = ctx.caps().max_storage_buffer_range;
    // A buffer past the binding limit: 40 Mi u32 = 160 MiB (> 128 MiB on lavapipe).
    let n = ((range / 4) as usize + (8 << 20)).min(80 << 20);
    let buf = Buffer::<u32>::new(ctx, "big", n).unwrap();
    let iota = Iota::new(ctx).unwrap();

    // Binding it whole is refused with a clear message.
    let mut rec = Recorder::new(ctx).unwrap();
    let e = iota.record(&mut rec, buf.binding(), n as u32, 0).unwrap_err();
    assert!(format!("{e:#}").contains("maxStorageBufferRange"), "{e:#}");
    drop(rec);

    // Split bindings: windows of at most the range.
    let window = (range / 4) as usize / 2;
    let mut rec = Recorder::new(ctx).unwrap();
    let mut start = 0;
    while start < n {
        let count = window.min(n - start);
        iota.record(&mut rec, buf.slice(start, count), count as u32, start as u32).unwrap();
        start += count;
    }
    rec.submit_and_wait().unwrap();
    let tail = buf.download_range(n - 1000, 1000).unwrap();
    assert_eq!(tail, ((n - 1000) as u32..n as u32).collect::<Vec<_>>());
    let mid = buf.download_range(window - 3, 6).unwrap();
    assert_eq!(mid, ((window - 3) as u32..(window + 3) as u32).collect::<Vec<_>>());

    // Buffer device address: the whole buffer from one kernel, no binding.
    if ctx.features().buffer_device_address {
        let mut rec = Recorder::new(ctx).unwrap();
        rec.fill(&buf.slice(n - 4096, 4096), 0).unwrap();
        iota.record_bda(&mut rec, &buf, (n - 4096) as u32, 4096).unwrap();
        rec.submit_and_wait().unwrap();
        let tail = buf.download_range(n - 4096, 4096).unwrap();
        assert_eq!(tail, ((n - 4096) as u32..n as u32).collect::<Vec<_>>());
    } else {
        eprintln!("no buffer device address on this device: BDA part skipped");
    }
    check_validation(ctx);
}

#[test]
fn profiler_scopes_and_disabled_cost() {
    let ctx = ctx_shared();
    let sort = RadixSort::new(ctx).unwrap();
    let n = 50_000u32;
    let kb = Buffer::from_slice(ctx, "k", &(0..n).rev().collect::<Vec<_>>()).unwrap();
    let vb = Buffer::<u32>::new(ctx, "v", n as usize).unwrap();
    let scratch = sort.scratch(n).unwrap();
    let mut rec = Recorder::with_profiling(ctx, 128).unwrap();
    sort.record(&mut rec, &kb, &vb, &Count::Host(n), 32, &scratch).unwrap();
    let t = rec.submit_and_wait().unwrap();
    if ctx.caps().timestamp_valid_bits > 0 {
        let s = tgs_engine::summarize(&t);
        let passes = 32usize.div_ceil(sort.config().radix_bits as usize);
        let down = s.iter().find(|x| x.name == "sort.downsweep").expect("downsweep timed");
        assert_eq!(down.count, passes);
        assert!(s.iter().all(|x| x.total_ms.is_finite() && x.total_ms >= 0.0));
        assert!(down.total_ms > 0.0);
    }
    // Without profiling: no scopes, no timings.
    let mut rec = Recorder::new(ctx).unwrap();
    assert!(!rec.profiling());
    assert!(rec.begin_scope("x").is_none());
    sort.record(&mut rec, &kb, &vb, &Count::Host(n), 32, &scratch).unwrap();
    assert!(rec.submit_and_wait().unwrap().is_empty());
    check_validation(ctx);
}

#[test]
fn clear_errors() {
    let bad_index = Context::new(&ContextOptions { device: DeviceSelector::Index(999), validation: Some(false) });
    let e = format!("{:#}", bad_index.err().unwrap());
    assert!(e.contains("--device 999") && e.contains("only"), "{e}");
    let bad_name = Context::new(&ContextOptions { device: DeviceSelector::Name("no-such-gpu".into()), validation: Some(false) });
    let e = format!("{:#}", bad_name.err().unwrap());
    assert!(e.contains("no-such-gpu") && e.contains("devices are"), "{e}");

    let ctx = ctx_shared();
    let huge = Buffer::<u32>::new(ctx, "absurd", 1 << 40);
    let e = format!("{:#}", huge.err().unwrap());
    assert!(e.contains("absurd") && (e.contains("largest allocation") || e.contains("out of device memory")), "{e}");

    // Wrong number of bindings for a kernel.
    let k = Kernel::new(ctx, &KernelDesc { name: "util.iota", spirv: shaders::UTIL_IOTA, spec: &[(0, 64)], push_bytes: 8, subgroup_size: None, full_subgroups: false }).unwrap();
    assert_eq!(k.bindings(), 1);
    let mut rec = Recorder::new(ctx).unwrap();
    let e = format!("{:#}", rec.dispatch(&k, &[], &[0; 8], [1, 1, 1]).unwrap_err());
    assert!(e.contains("declares 1 buffers, 0 given"), "{e}");
    // Too many workgroups in one dimension.
    let b = Buffer::<u32>::new(ctx, "b", 4).unwrap();
    let e = format!("{:#}", rec.dispatch(&k, &[b.binding()], &[0; 8], [u32::MAX, 1, 1]).unwrap_err());
    assert!(e.contains("exceed the device limit"), "{e}");
    // An impossible subgroup size.
    let e = Kernel::new(ctx, &KernelDesc { name: "x", spirv: shaders::UTIL_IOTA, spec: &[], push_bytes: 8, subgroup_size: Some(1024), full_subgroups: false });
    assert!(format!("{:#}", e.err().unwrap()).contains("subgroup size 1024"));
    let _ = Arc::clone(ctx);
    check_validation(ctx);
}

#[test]
fn no_driver_error_says_what_to_do() {
    // Point the loader at no driver, in a child process (the environment is process-wide).
    if std::env::var("TGS_TEST_CHILD").as_deref() == Ok("no-driver") {
        let e = Context::new(&ContextOptions { device: DeviceSelector::Best, validation: Some(false) }).err().expect("no driver, no context");
        let msg = format!("{e:#}");
        assert!(msg.contains("mesa-vulkan-drivers"), "{msg}");
        eprintln!("child saw: {msg}");
        return;
    }
    let out = std::process::Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "no_driver_error_says_what_to_do", "--nocapture"])
        .env("TGS_TEST_CHILD", "no-driver")
        .env("VK_ICD_FILENAMES", "/nonexistent/icd.json")
        .env("VK_DRIVER_FILES", "/nonexistent/icd.json")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stderr).into_owned() + &String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.contains("child saw"), "child failed:\n{text}");
}

/// Device memory is reused between buffers (gpu-allocator sub-allocates one
/// block): a new buffer must still read as zeros, and an `uninit` one as the
/// poison pattern tests turn on, never as what the previous owner left.
#[test]
fn new_buffers_are_zero_even_on_reused_memory() {
    let ctx = ctx_shared();
    let n = 4096;
    for round in 0..4 {
        let junk: Vec<u32> = (0..n as u32).map(|i| 0xDEAD_0000 | i | round).collect();
        let dirty = Buffer::<u32>::from_slice(ctx, "dirty", &junk).unwrap();
        assert_eq!(dirty.download().unwrap(), junk);
        drop(dirty);
        let fresh = Buffer::<u32>::new(ctx, "fresh", n).unwrap();
        assert!(fresh.download().unwrap().iter().all(|&v| v == 0), "round {round}: Buffer::new is not zero");
        drop(fresh);
        let f = Buffer::<f32>::new(ctx, "fresh_f32", n).unwrap();
        assert!(f.download().unwrap().iter().all(|&v| v.to_bits() == 0));
        drop(f);
        let dirty = Buffer::<u32>::from_slice(ctx, "dirty", &junk).unwrap();
        drop(dirty);
        let u = Buffer::<u32>::uninit(ctx, "poisoned", n).unwrap();
        assert!(u.download().unwrap().iter().all(|&v| v == u32::MAX), "round {round}: uninit memory is not poisoned in tests");
    }
    check_validation(ctx);
}

/// The context counts the device memory its buffers hold, and the peak.
#[test]
fn memory_use_follows_buffers() {
    let ctx = tgs_tests::ctx();
    let before = ctx.memory_use();
    let a = tgs_engine::Buffer::<f32>::new(&ctx, "test.memory", 1 << 20).unwrap();
    let held = ctx.memory_use();
    assert!(held.live_bytes >= before.live_bytes + (4 << 20), "{before:?} -> {held:?}");
    assert!(held.peak_bytes >= held.live_bytes);
    drop(a);
    let after = ctx.memory_use();
    assert_eq!(after.live_bytes, before.live_bytes);
    assert_eq!(after.peak_bytes, held.peak_bytes);
    ctx.reset_peak_memory();
    assert_eq!(ctx.memory_use().peak_bytes, before.live_bytes);
}

/// A read-back rides its recording's submission: the host reads the copy
/// once that submission completed, with no staging buffer or submission of
/// its own; a range past the source is refused by name.
#[test]
fn read_backs_ride_their_submission() {
    let ctx = ctx_shared();
    let iota = Iota::new(ctx).unwrap();
    let src = Buffer::<u32>::new(ctx, "test.readback_src", 1000).unwrap();
    let back = tgs_engine::Readback::<u32>::new(ctx, "test.readback", 10).unwrap();
    assert_eq!(back.read().unwrap(), vec![0; 10]);
    for start in [0u32, 7] {
        let mut rec = Recorder::new(ctx).unwrap();
        iota.record(&mut rec, src.binding(), 1000, start).unwrap();
        rec.read_back(&src, 990, &back).unwrap();
        rec.submit_and_wait().unwrap();
        assert_eq!(back.read().unwrap(), (990..1000).map(|i| i + start).collect::<Vec<_>>());
    }
    let err = Recorder::new(ctx).unwrap().read_back(&src, 995, &back).expect_err("a read-back past the end");
    assert!(err.to_string().contains("test.readback_src"), "{err}");
    check_validation(ctx);
}

/// Recordings hand their command pool, descriptor pools and fence back to
/// the context, reset, and later recordings reuse them: a loop of
/// submissions creates no Vulkan objects once warm, and reused descriptor
/// sets bind what the new recording asks for.
#[test]
fn recordings_reuse_their_vulkan_objects() {
    let ctx = tgs_tests::ctx();
    let iota = Iota::new(&ctx).unwrap();
    let bufs: Vec<Buffer<u32>> = (0..3).map(|i| Buffer::new(&ctx, &format!("test.reuse{i}"), 64).unwrap()).collect();
    let mut counts = Vec::new();
    for round in 0..60u32 {
        let mut rec = Recorder::new(&ctx).unwrap();
        // Many dispatches every tenth round.
        let dispatches = if round % 10 == 0 { 300 } else { 3 };
        for k in 0..dispatches {
            iota.record(&mut rec, bufs[k % 3].binding(), 64, round * 1000 + k as u32).unwrap();
        }
        rec.submit_and_wait().unwrap();
        let last = |k: usize| round * 1000 + (dispatches - 3 + k) as u32;
        for (k, b) in bufs.iter().enumerate() {
            assert_eq!(b.download().unwrap()[5], last(k) + 5, "round {round}, buffer {k}");
        }
        // A recording dropped unsubmitted gives its objects back too.
        let mut dropped = Recorder::new(&ctx).unwrap();
        iota.record(&mut dropped, bufs[0].binding(), 64, 0).unwrap();
        drop(dropped);
        counts.push(ctx.spare_objects());
    }
    let (c, d, f) = counts[counts.len() - 1];
    assert!(c >= 1 && d >= 1 && f >= 1, "nothing is kept for reuse: {:?}", counts.last());
    assert!(c <= 16 && d <= 64 && f <= 16, "the spare lists are unbounded: {:?}", counts.last());
    assert_eq!(counts[25], counts[59], "objects accumulate from round to round");
    check_validation(&ctx);
}

fn iota_desc<'a>(name: &'a str, spec: &'a [(u32, u32)], push_bytes: u32) -> KernelDesc<'a> {
    KernelDesc { name, spirv: shaders::UTIL_IOTA, spec, push_bytes, subgroup_size: None, full_subgroups: false }
}

/// `window[i] = start + i` with the iota kernel `k` (workgroups of 256).
fn run_iota(ctx: &Arc<Context>, k: &Kernel, n: u32, start: u32) -> Vec<u32> {
    let buf = Buffer::<u32>::new(ctx, "test.pipeline_iota", n as usize).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    rec.dispatch(k, &[buf.binding()], bytemuck::cast_slice(&[n, start]), [n.div_ceil(256), 1, 1]).unwrap();
    rec.submit_and_wait().unwrap();
    buf.download().unwrap()
}

/// A context builds each distinct pipeline once: the same SPIR-V,
/// specialization constants and push-constant size under another name
/// reuse it, it outlives the kernels that asked for it, and other
/// specialization constants build another; a push-constant size that is
/// not the shader's block is refused.
#[test]
fn pipelines_are_built_once_per_context() {
    let ctx = tgs_tests::ctx();
    assert_eq!(ctx.pipelines_built(), 0);
    let sg = ctx.caps().min_subgroup_size.max(1);
    let spec = [(0, 256), (1, sg), (2, 1)];
    let a = Kernel::new(&ctx, &iota_desc("test.a", &spec, 8)).unwrap();
    assert_eq!(ctx.pipelines_built(), 1);
    let b = Kernel::new(&ctx, &iota_desc("test.b", &spec, 8)).unwrap();
    assert_eq!(ctx.pipelines_built(), 1, "the same pipeline under another name");
    assert_eq!((a.name(), b.name()), ("test.a", "test.b"));
    assert_eq!(a.pipeline(), b.pipeline());
    let want = |n: u32, start: u32| (0..n).map(|i| i + start).collect::<Vec<u32>>();
    assert_eq!(run_iota(&ctx, &a, 1000, 5), want(1000, 5));
    assert_eq!(run_iota(&ctx, &b, 300, 9), want(300, 9));
    let first = a.pipeline();
    drop((a, b));
    let c = Kernel::new(&ctx, &iota_desc("test.c", &spec, 8)).unwrap();
    assert_eq!(ctx.pipelines_built(), 1, "kept after its kernels were dropped");
    assert_eq!(c.pipeline(), first);
    assert_eq!(run_iota(&ctx, &c, 700, 1), want(700, 1));
    let spec_128 = [(0, 128), (1, sg), (2, 1)];
    let d = Kernel::new(&ctx, &iota_desc("test.d", &spec_128, 8)).unwrap();
    assert_eq!(ctx.pipelines_built(), 2, "other specialization constants");
    assert_ne!(d.pipeline(), first);
    // Workgroups of 128: twice the groups cover n.
    let buf = Buffer::<u32>::new(&ctx, "test.pipeline_iota128", 1000).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.dispatch(&d, &[buf.binding()], bytemuck::cast_slice(&[1000u32, 3]), [8, 1, 1]).unwrap();
    rec.submit_and_wait().unwrap();
    assert_eq!(buf.download().unwrap(), want(1000, 3));
    // A push-constant size other than the shader's block (8 bytes: count,
    // start) is refused, naming the kernel, before anything is built.
    let e = format!("{:#}", Kernel::new(&ctx, &iota_desc("test.e", &spec, 16)).err().expect("a 16-byte push for an 8-byte block"));
    assert!(e.contains("'test.e'") && e.contains("push-constant block is 8 bytes") && e.contains("declares 16"), "{e}");
    assert_eq!(ctx.pipelines_built(), 2, "nothing built for a refused kernel");
    // Four Iotas: their direct kernel is "test.a"'s pipeline, and the
    // device-address one (where enabled) is built once.
    let before = ctx.pipelines_built();
    let iotas: Vec<Iota> = (0..4).map(|_| Iota::new(&ctx).unwrap()).collect();
    assert_eq!(ctx.pipelines_built() - before, ctx.features().buffer_device_address as usize, "pipelines for four Iotas");
    drop(iotas);
    check_validation(&ctx);
}

/// Bindings a shader declares as uniform texel buffers (`samplerBuffer`,
/// `usamplerBuffer`) are bound as such, whole or as a slice, and read back
/// every texel exactly, beside a storage buffer; a slice whose offset breaks
/// the device's texel alignment is refused with the binding named.
#[test]
fn texel_buffer_bindings_read_exactly() {
    let ctx = tgs_tests::ctx();
    let k =
        Kernel::new(&ctx, &KernelDesc { name: "util.texel_read", spirv: shaders::UTIL_TEXEL_READ, spec: &[(0, 256)], push_bytes: 4, subgroup_size: None, full_subgroups: false })
            .unwrap();
    assert_eq!(k.bindings(), 3);
    let n = 1000usize;
    let f: Vec<f32> = (0..n + 8).map(|i| (i as f32 * 0.37).sin() * 1e3 + if i % 7 == 0 { f32::MIN_POSITIVE } else { 0.0 }).collect();
    let u: Vec<u32> = (0..n + 8).map(|i| (i as u32).wrapping_mul(2_654_435_761)).collect();
    let fb = Buffer::from_slice(&ctx, "test.texel_f", &f).unwrap();
    let ub = Buffer::from_slice(&ctx, "test.texel_u", &u).unwrap();
    let out = Buffer::<u32>::new(&ctx, "test.texel_out", n).unwrap();
    let align = ctx.caps().min_texel_buffer_offset_alignment as usize / 4;
    for (start, whole) in [(0, true), (align.max(1), false)] {
        let mut rec = Recorder::new(&ctx).unwrap();
        let (fbind, ubind) = if whole { (fb.binding(), ub.binding()) } else { (fb.slice(start, n), ub.slice(start, n)) };
        rec.dispatch(&k, &[fbind, ubind, out.binding()], bytemuck::bytes_of(&(n as u32)), [(n as u32).div_ceil(256), 1, 1]).unwrap();
        rec.submit_and_wait().unwrap();
        let got = out.download().unwrap();
        for i in 0..n {
            assert_eq!(got[i], f[start + i].to_bits() ^ u[start + i], "texel {i} from offset {start}");
        }
    }
    if ctx.caps().min_texel_buffer_offset_alignment > 4 {
        let mut rec = Recorder::new(&ctx).unwrap();
        let e = rec.dispatch(&k, &[fb.slice(1, n), ub.binding(), out.binding()], bytemuck::bytes_of(&(n as u32)), [1, 1, 1]).unwrap_err();
        let msg = format!("{e:#}");
        assert!(msg.contains("binding 0") && msg.contains("minTexelBufferOffsetAlignment"), "{msg}");
    }
    check_validation(&ctx);
}
