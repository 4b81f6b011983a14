//! Exclusive prefix sum against the CPU.

use tgs_engine::{Buffer, Recorder};
use tgs_pipelines::{Count, PrefixSum, ScanScratch};
use tgs_tests::*;

fn cpu_scan(x: &[u32]) -> Vec<u32> {
    let mut acc = 0u32;
    x.iter()
        .map(|&v| {
            let r = acc;
            acc = acc.wrapping_add(v);
            r
        })
        .collect()
}

#[test]
fn lengths_in_and_out_of_place() {
    let ctx = ctx_shared();
    let scan = PrefixSum::new(ctx).unwrap();
    let mut rng = Rng(seed("scan"));
    for n in [0usize, 1, 7, 255, 256, 1023, 1024, 1025, 4095, 100_003, (1 << 20) + 3, 3_000_017] {
        let x: Vec<u32> = (0..n).map(|_| rng.below(1000)).collect();
        let expect = cpu_scan(&x);
        let scratch = ScanScratch::new(ctx, n as u32).unwrap();
        // Out of place.
        let src = Buffer::from_slice(ctx, "src", &x).unwrap();
        let dst = Buffer::<u32>::new(ctx, "dst", n).unwrap();
        let mut rec = Recorder::new(ctx).unwrap();
        scan.record(&mut rec, &src, &dst, &Count::Host(n as u32), &scratch).unwrap();
        rec.submit_and_wait().unwrap();
        assert_eq!(dst.download().unwrap(), expect, "n={n} out of place");
        assert_eq!(src.download().unwrap(), x, "n={n}: input modified");
        // In place.
        let mut rec = Recorder::new(ctx).unwrap();
        scan.record(&mut rec, &src, &src, &Count::Host(n as u32), &scratch).unwrap();
        rec.submit_and_wait().unwrap();
        assert_eq!(src.download().unwrap(), expect, "n={n} in place");
    }
    check_validation(ctx);
}

#[test]
fn wrapping_sums_and_gpu_count() {
    let ctx = ctx_shared();
    let scan = PrefixSum::new(ctx).unwrap();
    let mut rng = Rng(seed("scan-gpu"));
    let cap = 300_000usize;
    let x: Vec<u32> = (0..cap).map(|_| rng.next_u32()).collect(); // sums wrap mod 2^32
    let scratch = ScanScratch::new(ctx, cap as u32).unwrap();
    for n in [0u32, 5, 1024, 200_000, 300_000] {
        let src = Buffer::from_slice(ctx, "src", &x).unwrap();
        let dst = Buffer::from_slice(ctx, "dst", &vec![0xAAAA_AAAAu32; cap]).unwrap();
        let count = Buffer::from_slice(ctx, "count", &[n]).unwrap();
        let mut rec = Recorder::new(ctx).unwrap();
        scan.record(&mut rec, &src, &dst, &Count::Gpu { buffer: count.binding(), index: 0 }, &scratch).unwrap();
        rec.submit_and_wait().unwrap();
        let got = dst.download().unwrap();
        assert_eq!(&got[..n as usize], &cpu_scan(&x[..n as usize])[..], "n={n}");
        assert!(got[n as usize..].iter().all(|&v| v == 0xAAAA_AAAA), "n={n}: wrote past the count");
        assert_eq!(scratch.overflow().unwrap(), None);
    }
    // Over capacity: clamped, and reported.
    let src = Buffer::from_slice(ctx, "src", &x).unwrap();
    let dst = Buffer::<u32>::new(ctx, "dst", cap).unwrap();
    let count = Buffer::from_slice(ctx, "count", &[cap as u32 * 2]).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    scan.record(&mut rec, &src, &dst, &Count::Gpu { buffer: count.binding(), index: 0 }, &scratch).unwrap();
    rec.submit_and_wait().unwrap();
    assert_eq!(dst.download().unwrap(), cpu_scan(&x), "clamped to capacity");
    assert_eq!(scratch.overflow().unwrap(), Some(cap as u32 * 2));
    check_validation(ctx);
}

#[test]
fn host_count_over_capacity_is_an_error() {
    let ctx = ctx_shared();
    let scan = PrefixSum::new(ctx).unwrap();
    let scratch = ScanScratch::new(ctx, 100).unwrap();
    let b = Buffer::<u32>::new(ctx, "b", 100).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    let e = scan.record(&mut rec, &b, &b, &Count::Host(101), &scratch).unwrap_err();
    assert!(format!("{e:#}").contains("exceeds capacity"), "{e:#}");
}
