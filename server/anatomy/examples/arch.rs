//! scratch
fn main() {
    let t = std::time::Instant::now();
    let a = cathlab_anatomy::real::load_arch_to_cow(std::path::Path::new(
        "../../data/anatomy/arch-to-cow",
    ))
    .unwrap();
    println!("loaded in {:?}", t.elapsed());
    for b in &a.graph.branches {
        println!(
            "{} {:?} {:?} len {:.1} mm r {:.1}..{:.1} nodes {}->{}",
            b.name,
            b.kind,
            b.side,
            b.length() * 1e3,
            b.radii.iter().cloned().fold(1.0, f64::min) * 1e3,
            b.radii.iter().cloned().fold(0.0, f64::max) * 1e3,
            b.start,
            b.end
        );
    }
    let access = a.graph.landmarks["access"];
    for t in ["LCCA", "RCCA", "LVA", "RVA"] {
        let p = a.graph.path_to(&access, t).unwrap();
        println!(
            "{t}: {:.1} mm via {:?}",
            p.length * 1e3,
            p.legs
                .iter()
                .map(|l| a.graph.branches[l.branch].name.clone())
                .collect::<Vec<_>>()
        );
    }
}
