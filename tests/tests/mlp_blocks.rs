//! The light field's samples taken in blocks (`Mlp::scratch_in_blocks`):
//! what lets Stage III evaluate more samples than one storage binding holds
//! the activations of (a Mip-NeRF 360 frame's million on lavapipe, whose
//! bindings hold 236k samples of the small network).

use tgs_engine::{Buffer, Recorder};
use tgs_pipelines::mlp::{Mlp, MlpShape, OUT};
use tgs_tests::{check_validation, ctx_shared, seed, Rng};

fn uni(rng: &mut Rng) -> f32 {
    ((rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) as f32
}

/// Forward and backward of `n` samples on a scratch whose activations hold
/// `block` samples at a time; the outputs and gradients as bits.
fn run(mlp: &Mlp, shape: MlpShape, params: &Buffer<f32>, flat: &[f32], d: &Buffer<f32>, n: u32, block: u32) -> (Vec<u32>, Vec<u32>) {
    let ctx = ctx_shared();
    let s = mlp.scratch_in_blocks(shape, n, block).unwrap();
    assert_eq!((s.capacity(), s.block()), (n.max(1), block.clamp(1, n.max(1))));
    if n > 0 {
        s.samples.upload(&flat[..6 * n as usize]).unwrap();
    }
    let g = Buffer::from_slice(ctx, "grads", &vec![f32::NAN; shape.params() as usize]).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    mlp.record_forward(&mut rec, params, n, &s).unwrap();
    mlp.record_backward(&mut rec, params, n, d, &g, &s).unwrap();
    rec.submit_and_wait().unwrap();
    let out = if n > 0 { s.out.download_range(0, (OUT * n) as usize).unwrap() } else { Vec::new() };
    let bits = |v: Vec<f32>| v.iter().map(|x| x.to_bits()).collect();
    (bits(out), bits(g.download().unwrap()))
}

/// 1,300 samples in blocks of 512 and of 257 (the last ones partial): the
/// outputs are the one-block outputs bit for bit (a sample's forward does
/// not depend on its block); the weight gradients, summed block by block,
/// agree with the one-block sums to f32 rounding and rerun bit for bit;
/// no samples give zero gradients; the GPU-count paths refuse a scratch of
/// several blocks.
#[test]
fn samples_in_blocks_match_one_block() {
    let ctx = ctx_shared();
    let mlp = Mlp::new(ctx).unwrap();
    let mut rng = Rng(seed("samples_in_blocks_match_one_block"));
    let shape = MlpShape { depth: 3, width: 24, skip: 2, levels_x: 3, levels_w: 2 };
    let n = 1300u32;
    let params = Buffer::from_slice(ctx, "params", &shape.init_params(rng.next_u64())).unwrap();
    let flat: Vec<f32> = (0..n)
        .flat_map(|_| {
            let x = [uni(&mut rng), uni(&mut rng), uni(&mut rng)];
            let w = [uni(&mut rng), uni(&mut rng), uni(&mut rng) + 2.0];
            let l = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
            [x[0], x[1], x[2], w[0] / l, w[1] / l, w[2] / l]
        })
        .collect();
    let d = Buffer::from_slice(ctx, "d_out", &(0..OUT * n).map(|_| uni(&mut rng)).collect::<Vec<_>>()).unwrap();
    let (out1, g1) = run(&mlp, shape, &params, &flat, &d, n, n);
    let scale = g1.iter().map(|&b| f32::from_bits(b).abs()).fold(0.0f32, f32::max);
    assert!(scale > 0.0);
    for block in [512, 257] {
        let (out, g) = run(&mlp, shape, &params, &flat, &d, n, block);
        assert!(out == out1, "blocks of {block}: the outputs differ from one block's");
        for (i, (a, b)) in g.iter().zip(&g1).enumerate() {
            let (a, b) = (f32::from_bits(*a), f32::from_bits(*b));
            assert!(a.is_finite() && (a - b).abs() <= 1e-5 * (scale + b.abs()), "blocks of {block}: gradient {i} {a} against one block's {b}");
        }
        assert!(run(&mlp, shape, &params, &flat, &d, n, block) == (out, g), "blocks of {block}: a rerun differs");
    }
    let (_, g0) = run(&mlp, shape, &params, &flat, &d, 0, 1);
    assert!(g0.iter().all(|&b| f32::from_bits(b) == 0.0), "no samples must give zero gradients");
    let s = mlp.scratch_in_blocks(shape, n, 512).unwrap();
    let c = Buffer::from_slice(ctx, "count", &[n]).unwrap();
    let g = Buffer::uninit(ctx, "grads", shape.params() as usize).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    let e = format!("{:#}", mlp.record_forward_counted(&mut rec, &params, &c, &s).unwrap_err());
    assert!(e.contains("one block"), "{e}");
    let e = format!("{:#}", mlp.record_backward_counted(&mut rec, &params, &c, &d, &g, &s).unwrap_err());
    assert!(e.contains("one block"), "{e}");
    drop(rec);
    check_validation(ctx);
}
