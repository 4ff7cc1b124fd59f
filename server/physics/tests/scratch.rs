use cathlab_physics::*;
use nalgebra::Vector3;

fn props(r: f64) -> BeamProperties {
    BeamProperties::new(&CircularSection::solid(r), &Material { young_modulus_pa: 200e9, poisson_ratio: 0.3, density_kg_m3: 7800.0 })
}

#[test]
fn scratch() {
    let p = props(1e-4);
    for alpha in [1.0, 2.0, 5.0, 10.0] {
        let reference = elastica::tip_loaded_cantilever(alpha);
        println!("alpha {alpha}: ref {:.6} {:.6}", reference.deflection, reference.shortening);
        for n in [10, 25, 50, 100] {
            let mut m = BeamModel::straight(p, 1.0, n, SolverSettings { mode: StepMode::CONVERGED, ..Default::default() }).unwrap();
            let load = alpha * p.bending_stiffness_nm2;
            let inc = 10;
            let mut its = 0;
            for k in 1..=inc {
                m.set_load(n, Vector3::new(0.0, -load * k as f64 / inc as f64, 0.0), Vector3::zeros()).unwrap();
                let r = m.step().unwrap();
                its += r.iterations;
                assert!(r.converged, "{r:?}");
            }
            let tip = m.tip_position();
            let err = ((-tip.y - reference.deflection).powi(2) + ((1.0 - tip.x) - reference.shortening).powi(2)).sqrt();
            println!("  n {n}: tip {:.6} {:.6} err {:.3e} its {its}", -tip.y, 1.0 - tip.x, err);
        }
    }
}
