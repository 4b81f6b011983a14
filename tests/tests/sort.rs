//! The radix sort against the CPU's stable `sort_by_key`, over sizes and key
//! distributions; stability is checked through the values (original indices).
//! CI runs this file twice: default lavapipe (subgroup 8) and with
//! `LP_NATIVE_VECTOR_WIDTH=128` (subgroup 4).

use tgs_engine::{Buffer, Recorder};
use tgs_pipelines::{Count, RadixSort, SortConfig, SortScratch};
use tgs_tests::*;

const SIZES: &[usize] = &[0, 1, 7, 8, 255, 256, 257, 4095, 100_003, (1 << 20) + 3];

#[derive(Clone, Copy, Debug)]
enum Dist {
    Uniform,
    AllEqual,
    Sorted,
    Reversed,
    FewUnique,
    HighBitsOnly,
}
const DISTS: &[Dist] = &[Dist::Uniform, Dist::AllEqual, Dist::Sorted, Dist::Reversed, Dist::FewUnique, Dist::HighBitsOnly];

fn keys(d: Dist, n: usize, rng: &mut Rng) -> Vec<u32> {
    match d {
        Dist::Uniform => (0..n).map(|_| rng.next_u32()).collect(),
        Dist::AllEqual => vec![0xDEAD_BEEF; n],
        Dist::Sorted => {
            let mut k: Vec<u32> = (0..n).map(|_| rng.next_u32()).collect();
            k.sort();
            k
        }
        Dist::Reversed => {
            let mut k: Vec<u32> = (0..n).map(|_| rng.next_u32()).collect();
            k.sort_by(|a, b| b.cmp(a));
            k
        }
        Dist::FewUnique => {
            let pool = [3u32, 0xFFFF_FFFF, 17, 0x8000_0000, 0x10];
            (0..n).map(|_| pool[rng.below(5) as usize]).collect()
        }
        Dist::HighBitsOnly => (0..n).map(|_| rng.next_u32() & 0xF000_0000).collect(),
    }
}

/// Sort `keys_in` (capacity = its length) with values 0..len on the GPU;
/// returns the keys, the values and the scratch (for `overflow`).
fn run_sort(sort: &RadixSort, keys_in: &[u32], count: &Count, bits: u32) -> (Vec<u32>, Vec<u32>, SortScratch) {
    let ctx = ctx_shared();
    let n = keys_in.len();
    let kb = Buffer::from_slice(ctx, "keys", keys_in).unwrap();
    let vb = Buffer::from_slice(ctx, "vals", &(0..n as u32).collect::<Vec<_>>()).unwrap();
    let scratch = sort.scratch(n as u32).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    sort.record(&mut rec, &kb, &vb, count, bits, &scratch).unwrap();
    rec.submit_and_wait().unwrap();
    (kb.download().unwrap(), vb.download().unwrap(), scratch)
}

/// Sort on the GPU and compare with the CPU's stable sort on the low `bits`.
fn check(sort: &RadixSort, keys_in: &[u32], bits: u32, what: &str) {
    let n = keys_in.len();
    let (gk, gv, _) = run_sort(sort, keys_in, &Count::Host(n as u32), bits);
    let mask = if bits == 32 { u32::MAX } else { (1u32 << bits) - 1 };
    // Stable order by masked key == unstable order by (masked key, index).
    let mut pairs: Vec<(u32, u32)> = keys_in.iter().enumerate().map(|(i, &k)| (k & mask, i as u32)).collect();
    pairs.sort_unstable();
    let idx: Vec<u32> = pairs.into_iter().map(|p| p.1).collect();
    if let Some(i) = (0..n).find(|&i| gv[i] != idx[i]) {
        panic!("{what}: first mismatch at {i}: value {} (key {:#x}), expected {} (key {:#x})", gv[i], keys_in[gv[i] as usize], idx[i], keys_in[idx[i] as usize]);
    }
    let ek: Vec<u32> = idx.iter().map(|&i| keys_in[i as usize]).collect();
    assert!(gk == ek, "{what}: keys differ although values match");
}

#[test]
fn sizes_and_distributions_full_32_bits() {
    let ctx = ctx_shared();
    let sort = RadixSort::new(ctx).unwrap();
    eprintln!("device: {}  config: {:?}", ctx.caps().describe(), sort.config());
    let mut rng = Rng(seed("sort"));
    for &n in SIZES {
        for &d in DISTS {
            let k = keys(d, n, &mut rng);
            check(&sort, &k, 32, &format!("n={n} {d:?} bits=32"));
        }
    }
    check_validation(ctx);
}

#[test]
fn partial_bit_counts() {
    // Tile-sort style: only the low bits are ordered, higher bits ride along.
    let ctx = ctx_shared();
    let sort = RadixSort::new(ctx).unwrap();
    let mut rng = Rng(seed("sort-bits"));
    for bits in [1u32, 3, 4, 5, 13, 16, 31] {
        for &n in &[257usize, 4095, 100_003] {
            let k = keys(Dist::Uniform, n, &mut rng);
            check(&sort, &k, bits, &format!("n={n} bits={bits}"));
        }
    }
    // bits = 0 leaves the input untouched.
    let k = keys(Dist::Uniform, 1000, &mut rng);
    check(&sort, &k, 0, "bits=0");
    check_validation(ctx);
}

#[test]
fn other_configurations() {
    // Every configuration the device accepts must give the same answer.
    let ctx = ctx_shared();
    let mut rng = Rng(seed("sort-configs"));
    let k = keys(Dist::Uniform, 70_001, &mut rng);
    let mut tried = 0;
    for radix_bits in [4u32, 8] {
        for wg in [64u32, 128, 256, 512] {
            for kpt in [1u32, 4, 8, 16] {
                let cfg = SortConfig { wg, kpt, radix_bits };
                let Ok(sort) = RadixSort::with_config(ctx, cfg) else { continue };
                tried += 1;
                check(&sort, &k, 32, &format!("{cfg:?}"));
                check(&sort, &k[..777], 32, &format!("{cfg:?} n=777"));
            }
        }
    }
    eprintln!("{tried} configurations sorted");
    assert!(tried >= 6, "too few sort configurations valid on this device ({tried})");
    check_validation(ctx);
}

#[test]
fn count_from_gpu_buffer() {
    // The count is read by the GPU (indirect dispatch): the capacity is larger
    // than the count, and elements past the count must stay untouched.
    let ctx = ctx_shared();
    let sort = RadixSort::new(ctx).unwrap();
    let mut rng = Rng(seed("sort-gpu-count"));
    let cap = 50_000usize;
    for (n, bits) in [(0u32, 32u32), (1, 32), (12_345, 32), (50_000, 32), (12_345, 1), (777, 5)] {
        let k = keys(Dist::Uniform, cap, &mut rng);
        let count = Buffer::from_slice(ctx, "count", &[7u32, n]).unwrap();
        let (_, gv, scratch) = run_sort(&sort, &k, &Count::Gpu { buffer: count.binding(), index: 1 }, bits);
        let mut idx: Vec<u32> = (0..n).collect();
        let mask = if bits == 32 { u32::MAX } else { (1 << bits) - 1 };
        idx.sort_by_key(|&i| k[i as usize] & mask);
        assert_eq!(&gv[..n as usize], &idx[..], "n={n} bits={bits}");
        // Odd or even pass counts: the tail is the caller's data, untouched.
        assert_eq!(&gv[n as usize..], &(n..cap as u32).collect::<Vec<_>>()[..], "tail n={n} bits={bits}");
        assert_eq!(scratch.overflow().unwrap(), None);
    }
    // A GPU count over the capacity: the first `cap` pairs are sorted, and the overflow is reported.
    let k = keys(Dist::Uniform, cap, &mut rng);
    let count = Buffer::from_slice(ctx, "count", &[cap as u32 + 5]).unwrap();
    let (gk, _, scratch) = run_sort(&sort, &k, &Count::Gpu { buffer: count.binding(), index: 0 }, 32);
    assert_eq!(scratch.overflow().unwrap(), Some(cap as u32 + 5));
    let mut expect = k.clone();
    expect.sort();
    assert_eq!(gk, expect);
    check_validation(ctx);
}

#[test]
fn deterministic() {
    let ctx = ctx_shared();
    let sort = RadixSort::new(ctx).unwrap();
    let mut rng = Rng(seed("sort-det"));
    let k = keys(Dist::FewUnique, 200_000, &mut rng);
    let run = || {
        let (gk, gv, _) = run_sort(&sort, &k, &Count::Host(k.len() as u32), 32);
        (gk, gv)
    };
    assert!(run() == run());
}

#[test]
fn two_d_grids_and_the_largest_size() {
    let ctx = ctx_shared();
    let mut rng = Rng(seed("sort-large"));
    // Small partitions (128 keys) so that there are more than 65,535 of them:
    // the up-sweep, down-sweep and spine run on 2-D grids.
    let cfg = SortConfig { wg: 128, kpt: 1, radix_bits: 8 };
    let small = RadixSort::with_config(ctx, cfg).unwrap();
    let n = 65_535 * 128 + 1001;
    let k = keys(Dist::Uniform, n, &mut rng);
    check(&small, &k, 32, &format!("{cfg:?} n={n} (2-D grid)"));

    // The largest n this device takes: maxStorageBufferRange / 4 keys
    // (2^25 on lavapipe), capped at 2^25 to bound test time elsewhere.
    let sort = RadixSort::new(ctx).unwrap();
    let n = sort.max_keys().min(1 << 25) as usize;
    let k = keys(Dist::Uniform, n, &mut rng);
    check(&sort, &k, 32, &format!("largest n={n}"));
    assert!(sort.scratch(sort.max_keys() as u32 + 1).is_err() || sort.max_keys() >= u32::MAX as u64);
    check_validation(ctx);
}
