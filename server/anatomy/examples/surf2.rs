//! scratch
use cathlab_anatomy::Lumen;
use cathlab_anatomy::phantom::*;
use cathlab_anatomy::surface::*;
use nalgebra::{Point3, Vector3};
fn main() {
    let r = 2e-3;
    let l = 40e-3;
    let big = 15e-3;
    let cpr: f64 = std::env::var("CPR")
        .map(|v| v.parse().unwrap())
        .unwrap_or(3.0);
    let it: usize = std::env::var("IT").map(|v| v.parse().unwrap()).unwrap_or(4);
    let s = SurfaceSettings {
        cells_per_radius: cpr,
        smoothing_iterations: it,
        ..Default::default()
    };
    let mut seed = 99u64;
    let mut rnd = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed as f64 / u64::MAX as f64
    };
    for name in ["tube", "torus"] {
        let g = if name == "tube" {
            straight_tube(r, l).unwrap()
        } else {
            torus_segment(big, r, 2.0).unwrap()
        };
        let m = lumen_surface(&g, &s).unwrap();
        let ntri = m.triangles.len();
        let lumen = Lumen::new(m, name).unwrap();
        let (mut ed, mut en): (f64, f64) = (0.0, 0.0);
        for _ in 0..20000 {
            let rho = r * 1.3 * rnd();
            let th = 6.283 * rnd();
            let (p, axis_pt) = if name == "tube" {
                let z = l * 0.2 + l * 0.6 * rnd();
                (
                    Point3::new(rho * th.cos(), rho * th.sin(), z),
                    Point3::new(0.0, 0.0, z),
                )
            } else {
                let phi = 0.3 + 1.4 * rnd();
                let c = Point3::new(big * phi.cos(), big * phi.sin(), 0.0);
                let radial = Vector3::new(phi.cos(), phi.sin(), 0.0);
                (c + (radial * th.cos() + Vector3::z() * th.sin()) * rho, c)
            };
            let q = lumen.query(&p);
            let d = (p - axis_pt).norm();
            let exact = d - r;
            ed = ed.max((q.signed_distance - exact).abs() / r);
            if d > 0.5 * r {
                en = en.max((q.outward_normal - (p - axis_pt) / d).norm());
            }
        }
        println!("{name} cpr {cpr}: tris {ntri} max dist err {ed:.4} r, normal err {en:.4}");
    }
}
