//! An f64 reference for LPIPS (AlexNet v0.1) on the same weights as
//! `tgs::lpips`, written independently of it: maps stored channel-major
//! ([c][y][x]), convolutions as direct sums, no blocking or threads.

use tgs::lpips::{Lpips, CONVS};

/// Channel-major f64 map.
struct Map {
    c: usize,
    h: usize,
    w: usize,
    v: Vec<f64>,
}

impl Map {
    fn at(&self, c: usize, y: usize, x: usize) -> f64 {
        self.v[(c * self.h + y) * self.w + x]
    }
}

fn conv(x: &Map, wt: &[f32], bias: &[f32], k: usize, stride: usize, pad: usize, co: usize) -> Map {
    let h = (x.h + 2 * pad - k) / stride + 1;
    let w = (x.w + 2 * pad - k) / stride + 1;
    let mut v = vec![0.0; co * h * w];
    for o in 0..co {
        for oy in 0..h {
            for ox in 0..w {
                let mut s = bias[o] as f64;
                for ky in 0..k {
                    for kx in 0..k {
                        let (iy, ix) = ((oy * stride + ky) as i64 - pad as i64, (ox * stride + kx) as i64 - pad as i64);
                        if iy < 0 || ix < 0 || iy >= x.h as i64 || ix >= x.w as i64 {
                            continue;
                        }
                        for ci in 0..x.c {
                            // HWIO: kernel[ky][kx][ci][o]
                            s += x.at(ci, iy as usize, ix as usize) * wt[((ky * k + kx) * x.c + ci) * co + o] as f64;
                        }
                    }
                }
                v[(o * h + oy) * w + ox] = s.max(0.0);
            }
        }
    }
    Map { c: co, h, w, v }
}

fn pool(x: &Map) -> Map {
    let (h, w) = ((x.h - 3) / 2 + 1, (x.w - 3) / 2 + 1);
    let mut v = Vec::with_capacity(x.c * h * w);
    for c in 0..x.c {
        for oy in 0..h {
            for ox in 0..w {
                let m = (0..9).map(|i| x.at(c, 2 * oy + i / 3, 2 * ox + i % 3)).fold(f64::NEG_INFINITY, f64::max);
                v.push(m);
            }
        }
    }
    Map { c: x.c, h, w, v }
}

fn unit(x: &Map) -> Map {
    let mut out = Map { c: x.c, h: x.h, w: x.w, v: x.v.clone() };
    for y in 0..x.h {
        for xx in 0..x.w {
            let n = (0..x.c).map(|c| x.at(c, y, xx).powi(2)).sum::<f64>().sqrt() + 1e-10;
            for c in 0..x.c {
                out.v[(c * x.h + y) * x.w + xx] /= n;
            }
        }
    }
    out
}

fn features(net: &Lpips, rgb: &[f32], w: usize, h: usize) -> Vec<Map> {
    let shift = [-0.030, -0.088, -0.188];
    let scale = [0.458, 0.448, 0.450];
    let n = w * h;
    let mut x = Map { c: 3, h, w, v: (0..3 * n).map(|i| ((2.0 * rgb[i] as f64 - 1.0) - shift[i / n]) / scale[i / n]).collect() };
    let mut out = Vec::new();
    for (l, &(k, s, p, _, co)) in CONVS.iter().enumerate() {
        if l == 1 || l == 2 {
            x = pool(&x);
        }
        x = conv(&x, &net.conv[l].0, &net.conv[l].1, k, s, p, co);
        out.push(unit(&x));
    }
    out
}

/// LPIPS of two planar RGB images in [0, 1] (`w` x `h`, each side at least
/// `tgs::lpips::MIN_SIDE`), in f64.
pub fn lpips(net: &Lpips, a: &[f32], b: &[f32], w: usize, h: usize) -> f64 {
    let (fa, fb) = (features(net, a, w, h), features(net, b, w, h));
    let mut total = 0.0;
    for (l, (x, y)) in fa.iter().zip(&fb).enumerate() {
        let mut s = 0.0;
        for c in 0..x.c {
            let lw = net.lin[l][c] as f64;
            for i in 0..x.h * x.w {
                let d = x.v[c * x.h * x.w + i] - y.v[c * x.h * x.w + i];
                s += lw * d * d;
            }
        }
        total += s / (x.h * x.w) as f64;
    }
    total
}
