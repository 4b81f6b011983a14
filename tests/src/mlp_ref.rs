//! f64 reference of the light-field MLP (pipelines/src/mlp): the Fourier
//! encoding, the forward pass and the backward to every parameter.

use tgs_pipelines::mlp::{MlpShape, OUT};

/// gamma(a) = [a, sin(2^k pi a) (3), cos(2^k pi a) (3) for k < levels].
pub fn encode(a: [f64; 3], levels: u32) -> Vec<f64> {
    let mut out = a.to_vec();
    for k in 0..levels {
        let f = std::f64::consts::PI * (1u64 << k) as f64;
        out.extend(a.iter().map(|v| (f * v).sin()));
        out.extend(a.iter().map(|v| (f * v).cos()));
    }
    out
}

/// Every layer's input and output for one sample.
pub struct Trace {
    pub inputs: Vec<Vec<f64>>,
    pub outputs: Vec<Vec<f64>>,
}

/// Layer `l`'s pre-activations z = W x + b.
fn pre_activations(shape: &MlpShape, params: &[f64], l: u32, x: &[f64]) -> Vec<f64> {
    let (k, j) = (shape.fan_in(l) as usize, shape.fan_out(l) as usize);
    let w = &params[shape.offset(l) as usize..];
    (0..j)
        .map(|r| {
            let row = &w[r * (k + 1)..(r + 1) * (k + 1)];
            row[k] + (0..k).map(|c| row[c] * x[c]).sum::<f64>()
        })
        .collect()
}

fn layer(shape: &MlpShape, params: &[f64], l: u32, x: &[f64]) -> Vec<f64> {
    let z = pre_activations(shape, params, l, x);
    if l == shape.depth {
        z.iter().map(|z| 1.0 / (1.0 + (-z).exp())).collect()
    } else {
        z.iter().map(|z| z.max(0.0)).collect()
    }
}

/// The smallest |z| over the hidden (ReLU) units of one sample. Within
/// f32's rounding of 0, the GPU and this reference may take different
/// sides of the kink, and the gradients then differ by a whole step.
pub fn kink_margin(shape: &MlpShape, params: &[f64], sample: &[f64; 6]) -> f64 {
    let t = forward(shape, params, sample);
    (0..shape.depth).flat_map(|l| pre_activations(shape, params, l, &t.inputs[l as usize])).fold(f64::INFINITY, |m, z| m.min(z.abs()))
}

/// Phi(sample) with its trace; sample = (x normalized, w).
pub fn forward(shape: &MlpShape, params: &[f64], sample: &[f64; 6]) -> Trace {
    let gx = encode([sample[0], sample[1], sample[2]], shape.levels_x);
    let gw = encode([sample[3], sample[4], sample[5]], shape.levels_w);
    let mut inputs = Vec::new();
    let mut outputs: Vec<Vec<f64>> = Vec::new();
    for l in 0..shape.layers() {
        let x = match l {
            0 => gx.clone(),
            l if l == shape.skip => [outputs[l as usize - 1].clone(), gx.clone(), gw.clone()].concat(),
            _ => outputs[l as usize - 1].clone(),
        };
        outputs.push(layer(shape, params, l, &x));
        inputs.push(x);
    }
    Trace { inputs, outputs }
}

/// d(sum_s d_out[s] . Phi(sample_s)) / d params.
pub fn backward(shape: &MlpShape, params: &[f64], samples: &[[f64; 6]], d_out: &[[f64; 3]]) -> Vec<f64> {
    let mut g = vec![0.0; shape.params() as usize];
    for (s, d) in samples.iter().zip(d_out) {
        let t = forward(shape, params, s);
        let mut dy: Vec<f64> = d.to_vec();
        for l in (0..shape.layers()).rev() {
            let (k, j) = (shape.fan_in(l) as usize, shape.fan_out(l) as usize);
            let y = &t.outputs[l as usize];
            let x = &t.inputs[l as usize];
            let dz: Vec<f64> = (0..j)
                .map(|r| {
                    if l == shape.depth {
                        dy[r] * y[r] * (1.0 - y[r])
                    } else if y[r] > 0.0 {
                        dy[r]
                    } else {
                        0.0
                    }
                })
                .collect();
            let off = shape.offset(l) as usize;
            for r in 0..j {
                for c in 0..k {
                    g[off + r * (k + 1) + c] += dz[r] * x[c];
                }
                g[off + r * (k + 1) + k] += dz[r];
            }
            if l > 0 {
                let width = shape.width as usize;
                dy = (0..width).map(|c| (0..j).map(|r| dz[r] * params[off + r * (k + 1) + c]).sum()).collect();
            }
        }
    }
    debug_assert_eq!(OUT, 3);
    g
}
