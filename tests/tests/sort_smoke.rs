use tgs_engine::{Buffer, Recorder};
use tgs_pipelines::{Count, RadixSort};
use tgs_tests::*;

#[test]
fn smoke() {
    let ctx = ctx();
    eprintln!("{}", ctx.caps().describe());
    let sort = RadixSort::new(&ctx).unwrap();
    eprintln!("{:?}", sort.config());
    let n = 100003usize;
    let mut rng = Rng(1);
    let keys: Vec<u32> = (0..n).map(|_| rng.next_u32()).collect();
    let vals: Vec<u32> = (0..n as u32).collect();
    let kb = Buffer::from_slice(&ctx, "k", &keys).unwrap();
    let vb = Buffer::from_slice(&ctx, "v", &vals).unwrap();
    let scratch = sort.scratch(n as u32).unwrap();
    let mut rec = Recorder::with_profiling(&ctx, 256).unwrap();
    sort.record(&mut rec, &kb, &vb, &Count::Host(n as u32), 32, &scratch).unwrap();
    let t = rec.submit_and_wait().unwrap();
    for s in tgs_engine::summarize(&t) { eprintln!("{} {:.3} ms x{}", s.name, s.total_ms, s.count); }
    let gk = kb.download().unwrap();
    let gv = vb.download().unwrap();
    let mut idx: Vec<u32> = (0..n as u32).collect();
    idx.sort_by_key(|&i| keys[i as usize]);
    let ek: Vec<u32> = idx.iter().map(|&i| keys[i as usize]).collect();
    let bad = gk.iter().zip(&ek).filter(|(a, b)| a != b).count();
    assert_eq!(bad, 0, "keys differ");
    assert_eq!(gv, idx);
    check_validation(&ctx);
}
