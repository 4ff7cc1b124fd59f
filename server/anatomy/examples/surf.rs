//! scratch
use cathlab_anatomy::phantom::*;
use cathlab_anatomy::surface::*;
fn main() {
    let r = 2e-3;
    let l = 40e-3;
    for (name, g) in [
        ("tube", straight_tube(r, l).unwrap()),
        ("torus", torus_segment(15e-3, r, 2.0).unwrap()),
        ("y", y_bifurcation(3e-3, 2e-3, 20e-3, 20e-3, 0.5).unwrap()),
    ] {
        let t = std::time::Instant::now();
        let m = lumen_surface(&g, &SurfaceSettings::default());
        let dt = t.elapsed();
        match m {
            Ok(m) => {
                let topo = m.topology();
                let mut dev: f64 = 0.0;
                let mut minarea = f64::INFINITY;
                for t in &m.triangles {
                    let [a, b, c] = m.corners(t);
                    minarea = minarea.min(0.5 * (b - a).cross(&(c - a)).norm());
                }
                if name == "tube" {
                    for p in &m.vertices {
                        if p.z > 2.0 * r && p.z < l - 2.0 * r {
                            dev = dev.max(((p.x * p.x + p.y * p.y).sqrt() - r).abs() / r);
                        }
                    }
                }
                println!(
                    "{name}: {:?} tris {} vol ratio {} dev {dev} minarea {minarea:e} genus {} in {dt:?}",
                    topo.is_closed_oriented_manifold(),
                    m.triangles.len(),
                    m.enclosed_volume() / (std::f64::consts::PI * r * r * l),
                    topo.genus()
                );
            }
            Err(e) => println!("{name}: {e} in {dt:?}"),
        }
    }
}
