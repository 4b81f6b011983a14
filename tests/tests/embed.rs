//! Embedding: a host application creates its own instance, device, queue,
//! command buffers and output buffer; tgs adopts the device, loads a trained
//! run of each stage (Stage I; Stage II with its environment map; Stage III
//! with its light field) and records the deferred render into the host's
//! command buffer, writing the host's buffer. The pixels equal `tgs
//! render`'s (the trainer's render of the checkpoint) bit for bit, also
//! for a Stage II that composites with the scattering set's degree-0 colour.

use std::path::Path;
use tgs::embed::SceneRenderer;
use tgs::train::run::{train, TrainArgs};
use tgs_engine::{BufferBinding, Recorder};
use tgs_tests::ctx_shared;
use tgs_tests::host::Host;

fn args(out: &Path, set: &[&str], stages: &str, from: Option<&Path>) -> TrainArgs {
    let _ = std::fs::remove_dir_all(out);
    let scene = tgs_tests::tiny_glass_scene(&Path::new(env!("CARGO_TARGET_TMPDIR")).join("embed-scene"));
    let mut set: Vec<String> = set.iter().map(|s| s.to_string()).collect();
    set.extend(["test_interval=0", "checkpoint_interval=0"].map(String::from));
    TrainArgs {
        dataset: if from.is_some() { None } else { Some(scene) },
        out: out.to_path_buf(),
        preset: if from.is_some() { None } else { Some("quick".into()) },
        set,
        stages: Some(stages.into()),
        from: from.map(Path::to_path_buf),
        quiet: true,
        ..Default::default()
    }
}

/// Render every test camera of `run` in the host's command buffers and
/// compare with the trainer's render of the same checkpoint.
fn check_run(host: &Host, run: &Path, stage: &str) {
    let ctx = host.adopt();
    let mut scene = SceneRenderer::load(&ctx, run).unwrap();
    assert_eq!(scene.stage, stage);
    let cams = tgs::embed::run_cameras(run).unwrap();
    assert_eq!(cams.len(), 4);
    let (mut tr, _) = tgs::train::run::open_run(ctx_shared(), run).unwrap();
    for (name, cam) in &cams {
        let n = SceneRenderer::output_len(cam.width, cam.height);
        let out = host.buffer(4 * n as u64);
        let mut recordings = 0;
        loop {
            let mut rec = None;
            host.submit(|cmd| {
                // SAFETY: `cmd` is the host's primary command buffer, recording, from a pool of the adopted
                // queue family.
                let mut r = unsafe { Recorder::record_into(&ctx, cmd, 0) }.unwrap();
                // SAFETY: `out` is a live storage buffer of the host's device, `out.bytes` long, alive until
                // the submission completes.
                scene.record(&mut r, cam, &unsafe { BufferBinding::external(out.buffer, 0, out.bytes) }).unwrap();
                r.finish().unwrap();
                rec = Some(r);
            });
            drop(rec);
            recordings += 1;
            if scene.complete(cam).unwrap() {
                break;
            }
            assert!(recordings < 4, "{name}: the frame never fitted");
        }
        if stage == "III" {
            let k = scene.last_samples.unwrap();
            assert!(k > 0 && (k as usize) < n / 3, "{name}: the light field ran on {k} of {} pixels", n / 3);
        }
        let got = host.read(&out);
        host.free(out);
        let want = tr.render(cam).unwrap().planes[..n].to_vec();
        assert!(got.iter().all(|v| v.is_finite()), "{stage} {name}: NaN/Inf");
        let diff = got.iter().zip(&want).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
        assert_eq!(diff, 0, "Stage {stage} {name}: {diff} of {n} values differ from `tgs render`");
        // The same through tgs's own queue, and again (bit-identical reruns).
        assert!(scene.render(cam).unwrap().iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits()));
    }
    // A too-small output is refused before anything is recorded.
    let (_, cam) = &cams[0];
    let small = tgs_engine::Buffer::<f32>::new(&ctx, "small", 10).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let e = scene.record(&mut rec, cam, &small.binding()).unwrap_err();
    assert!(format!("{e:#}").contains("needs"), "{e:#}");
}

#[test]
fn host_renders_each_stage_like_tgs_render() {
    let host = Host::new();
    let b = tgs_tests::TempDir::new("embed");
    let one = b.join("one");
    // 300 iterations: enough for the residual hull to seed the glass (a
    // shorter Stage I carves nothing and Stage II copies the whole set).
    train(ctx_shared(), &args(&one, &["iterations=300"], "I", None)).unwrap();
    let two = b.join("two");
    // The significance test off: this short Stage I's residual beats chance
    // nowhere, and the fallback's seeds (each ray's most agreed point)
    // cover every pixel of this small scene; the first agreeing points
    // leave some uncovered, so that Stage III's light field runs on fewer
    // pixels than the frame holds and the GPU-counted path is the one drawn.
    train(ctx_shared(), &args(&two, &["reflection.iterations=30", "reflection.seed_significance=1"], "II", Some(&one))).unwrap();
    let three = b.join("three");
    train(ctx_shared(), &args(&three, &["light_field.iterations=30"], "III", Some(&two))).unwrap();
    check_run(&host, &one, "I");
    check_run(&host, &two, "II");
    check_run(&host, &three, "III");

    // reflection.scattering_sh = 0: Stage II composites with the scattering
    // set's view-independent colour. A Stage I that reaches SH degree 3
    // (one degree every 100 iterations), then Stage II: the trainer's
    // scattering layer is Stage I's set rendered at degree 0 bit for bit
    // (not at 3, which differs), and the host's render equals the trainer's.
    let one_sh = b.join("one-sh");
    train(ctx_shared(), &args(&one_sh, &["iterations=300", "sh_interval=100"], "I", None)).unwrap();
    let two_dc = b.join("two-dc");
    train(ctx_shared(), &args(&two_dc, &["reflection.iterations=10", "reflection.scattering_sh=0"], "II", Some(&one_sh))).unwrap();
    check_run(&host, &two_dc, "II");
    let (mut tr, _) = tgs::train::run::open_run(ctx_shared(), &two_dc).unwrap();
    let bg = tr.cfg.background_rgb().unwrap();
    for (name, cam) in tgs::embed::run_cameras(&two_dc).unwrap() {
        let n = 3 * (cam.width * cam.height) as usize;
        let r = tr.render(&cam).unwrap();
        let layer = r.layers.as_ref().expect("a Stage II render has layers").0.planes[..n].to_vec();
        let dc = tr.scattering.render(&cam, 0, &bg).unwrap().planes[..n].to_vec();
        let full = tr.scattering.render(&cam, 3, &bg).unwrap().planes[..n].to_vec();
        assert!(layer.iter().zip(&dc).all(|(a, b)| a.to_bits() == b.to_bits()), "{name}: the scattering layer is not the degree-0 colour");
        assert!(layer.iter().zip(&full).any(|(a, b)| a != b), "{name}: degree 3 renders the same colour, so this checks nothing");
    }

    // Bad inputs name the file.
    let ctx = host.adopt();
    let e = SceneRenderer::load(&ctx, &b.join("missing")).err().unwrap();
    assert!(format!("{e:#}").contains("missing"), "{e:#}");
    let bad = b.join("bad");
    std::fs::create_dir_all(&bad).unwrap();
    let bytes = std::fs::read(three.join("checkpoint.bin")).unwrap();
    std::fs::write(bad.join("checkpoint.bin"), &bytes[..bytes.len() - 8]).unwrap();
    let e = SceneRenderer::load(&ctx, &bad).err().unwrap();
    assert!(format!("{e:#}").contains("checkpoint.bin"), "{e:#}");
    drop(ctx);
    host.destroy();
}

/// The viewer's pack kernel: each pixel quantised as the host's
/// `pack_pixel` (PNG) does, in both byte orders; and a moving camera's
/// smaller frame enlarged: pixel (x, y) of a 5x4 window shows pixel
/// (x / 2, y / 2) of its 3x2 frame, at 1/3 pixel (x / 3, y / 3) of 2x2.
#[test]
fn the_pack_kernel_enlarges_a_smaller_frame_pixel_for_pixel() {
    use tgs_engine::Buffer;
    use tgs_pipelines::{pack_pixel, Pack, PixelOrder};
    let ctx = ctx_shared();
    let pack = Pack::new(ctx).unwrap();
    let (w, h) = (5u32, 4u32);
    for (scale, order) in [(1, PixelOrder::Rgba), (2, PixelOrder::Bgra), (3, PixelOrder::Rgba)] {
        let (sw, sh) = (w.div_ceil(scale), h.div_ceil(scale));
        let n = (sw * sh) as usize;
        // Distinct colours, some out of [0, 1] and not finite.
        let planes: Vec<f32> = (0..3 * n).map(|i| if i == 4 { f32::NAN } else { i as f32 / n as f32 - 0.3 }).collect();
        let src = Buffer::from_slice(ctx, "test.planes", &planes).unwrap();
        let out = Buffer::<u32>::new(ctx, "test.packed", (w * h) as usize).unwrap();
        let mut rec = Recorder::new(ctx).unwrap();
        pack.record_scaled(&mut rec, &src.binding(), (w, h), scale, order, &out.binding()).unwrap();
        rec.submit_and_wait().unwrap();
        let got = out.download().unwrap();
        for y in 0..h {
            for x in 0..w {
                let j = ((y / scale) * sw + x / scale) as usize;
                let want = pack_pixel([planes[j], planes[n + j], planes[2 * n + j]], order);
                assert_eq!(got[(y * w + x) as usize], want, "scale {scale}: pixel ({x}, {y})");
            }
        }
        // Planes too small for the frame are refused, not read past.
        let small = Buffer::<f32>::new(ctx, "test.small", 3 * n - 1).unwrap();
        let mut rec = Recorder::new(ctx).unwrap();
        assert!(pack.record_scaled(&mut rec, &small.binding(), (w, h), scale, order, &out.binding()).is_err());
    }
}
