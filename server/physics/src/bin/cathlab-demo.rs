//! The run command's physics demo (until the server exists): the distal 10 cm of a 0.014"
//! micro-guidewire, clamped at its base, pressed sideways at the tip until it settles, then
//! released, then twisted at the base; prints what it does.

use std::time::Instant;

use cathlab_physics::{BeamModel, SolverSettings, StepMode, presets};
use nalgebra::Vector3;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let device = presets::micro_guidewire_014();
    let inserted = 0.10;
    let elements = 100;
    let settings = SolverSettings::default();
    let mut model = BeamModel::from_device_part(
        &device,
        device.length_m() - inserted,
        device.length_m(),
        elements,
        settings,
    )?;
    println!(
        "cathlab physics demo: {} ({} sections)",
        device.name,
        device.sections.len()
    );
    for s in &device.sections {
        println!(
            "  {:<10} {:>6.0} mm, OD {:.3} mm, E {:>5.1} GPa, mu {:.2}, rest {:?}",
            s.name,
            s.length_m * 1e3,
            2e3 * s.cross_section.outer_radius_m,
            s.material.young_modulus_pa / 1e9,
            s.friction_coefficient,
            s.rest_shape
        );
    }
    println!(
        "simulating the distal {:.0} mm in {elements} elements",
        inserted * 1e3
    );
    let print_tip = |label: &str, model: &BeamModel| {
        let tip = model.tip_position() * 1e3;
        println!(
            "  {label:<28} tip at ({:8.3}, {:8.3}, {:8.3}) mm",
            tip.x, tip.y, tip.z
        );
    };
    print_tip("rest", &model);

    // 1. A 0.2 mN lateral force on the tip (a vessel wall pushing back), paper mode: one
    //    linear solve per step, as in real time.
    let tip = model.node_count() - 1;
    model.set_load(tip, Vector3::new(0.0, 0.0, -2e-4), Vector3::zeros())?;
    println!("paper mode, 0.2 mN lateral tip load (one solve per step):");
    let start = Instant::now();
    for step in 1..=30 {
        let report = model.step()?;
        if step <= 5 || step % 5 == 0 {
            println!(
                "  step {step:>3}: largest increment {:.3e} m, {:.3e} rad",
                report.last_translation_increment_m, report.last_rotation_increment_rad
            );
        }
    }
    let per_step = start.elapsed().as_secs_f64() / 30.0;
    print_tip("after 30 paper steps", &model);

    // 2. The converged mode settles the same load to 1e-8 in one step.
    model.set_settings(SolverSettings {
        mode: StepMode::CONVERGED,
        ..settings
    });
    let report = model.step()?;
    print_tip("converged equilibrium", &model);
    println!("  converged in {} iterations", report.iterations);
    let reaction = model.base_reaction();
    println!(
        "  base reaction force ({:.3e}, {:.3e}, {:.3e}) N",
        reaction[0], reaction[1], reaction[2]
    );

    // 3. Release: the wire springs back to its rest shape.
    model.clear_loads();
    model.step()?;
    print_tip("released", &model);

    // 4. Twist the base by 90° in 9 steps: the angled tip turns.
    for _ in 0..9 {
        model.drive_base(0.0, 10f64.to_radians())?;
        model.step()?;
    }
    print_tip("base twisted 90°", &model);
    // 5. Push 10 mm.
    model.drive_base(0.010, 0.0)?;
    model.step()?;
    print_tip("pushed 10 mm", &model);
    println!(
        "one paper step at N = {elements}: {:.1} µs (frames, element matrices, substructure solve, flexibility)",
        per_step * 1e6
    );
    Ok(())
}
