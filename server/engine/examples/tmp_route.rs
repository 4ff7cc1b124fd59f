use std::path::Path;
use cathlab_engine::{AssetCache, SceneFormat, SceneSpec};
fn main() {
    let path = Path::new("scenes/arch_to_cow_lcca_coaxial.toml");
    let text = std::fs::read_to_string(path).unwrap().replace("dir = \"../data/anatomy/arch-to-cow\"", "dir = \"../data/anatomy/arch-to-cow\"\ncircle_of_willis = true");
    let spec = SceneSpec::parse(&text, SceneFormat::Toml).unwrap();
    let t = std::time::Instant::now();
    let assets = AssetCache::default().load(&spec, path.parent().unwrap()).unwrap();
    println!("load {:?}", t.elapsed());
    let g = &assets.anatomy.graph;
    let access = g.landmarks["access"];
    for target in ["LCCA", "left_internal_carotid", "left_internal_carotid_communicating", "left_middle_cerebral", "right_middle_cerebral", "basilar"] {
        let p = g.path_to(&access, target).unwrap();
        let mut along = 0.0;
        let legs: Vec<String> = p.legs.iter().map(|l| { along += (l.to_arc - l.from_arc).abs(); format!("{}@{:.0}", g.branches[l.branch].name, along*1e3) }).collect();
        println!("{target}: {:.0} mm: {}", p.length * 1e3, legs.join(" "));
    }
    for b in &g.branches { println!("{} {:.1} mm r {:.2}..{:.2}", b.name, b.length()*1e3, b.radii.iter().cloned().fold(f64::INFINITY, f64::min)*1e3, b.radii.iter().cloned().fold(0.0, f64::max)*1e3); }
}
