fn main() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/anatomy/arch-to-cow");
    let a = cathlab_anatomy::real::load_arch_to_cow(&dir).unwrap();
    let (lo, hi) = a.lumen.mesh().bounding_box();
    println!("{lo:?} {hi:?}");
    for b in &a.graph.branches { println!("{} {:?} {:?} r {:.4}", b.name, b.points[0], b.points.last().unwrap(), b.radii[0]); }
}
