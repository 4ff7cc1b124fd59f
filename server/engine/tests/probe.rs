use std::path::Path;
use std::time::Instant;
use cathlab_engine::*;
#[test]
fn probe() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let cat = SceneCatalog::read_dir(&dir).unwrap();
    let (spec, base) = cat.get("arch_to_cow_lcca").unwrap();
    let t = Instant::now();
    let cache = AssetCache::default();
    let a = cache.load(spec, &base).unwrap();
    println!("load {:?} dims {:?}", t.elapsed(), a.volume.dims);
    for b in &a.anatomy.graph.branches { println!("{} {} {}", b.name, b.start, b.end); }
    let mut w = World::new(a.clone()).unwrap();
    w.apply(1, &Command::PushVelocity(0.02)).unwrap();
    let t = Instant::now();
    for _ in 0..500 { w.step().unwrap(); }
    let s = w.snapshot();
    println!("500 steps {:?} inserted {} tip {:?} events {:?}", t.elapsed(), s.inserted_m, s.tip(), w.take_events());
    w.apply(2, &Command::Inject { volume_ml: 5.0, rate_ml_s: 5.0 }).unwrap();
    let t = Instant::now();
    for _ in 0..500 { w.step().unwrap(); }
    let s = w.snapshot();
    println!("500 steps {:?} contrast tubes {} metrics {:?}", t.elapsed(), s.contrast.len(), s.metrics);
}
