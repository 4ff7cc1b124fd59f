//! Figure command: `cargo run --release -p cathlab-imaging --example circle_of_willis_figure`
//! computes the circle of Willis of the real arch-to-cow surface (what scenes with
//! `anatomy.circle_of_willis = true` load), names its arteries, and draws them seen from
//! above over the surface's vertices to `docs/figures/circle_of_willis.svg`.

use std::path::Path;

use cathlab_anatomy::real::load_arch_to_cow_trimmed;
use cathlab_imaging::circle_of_willis::{CircleInflows, CircleSettings, circle_of_willis};
use nalgebra::Point3;
use plotters::prelude::*;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let (anatomy, ends) =
        load_arch_to_cow_trimmed(&root_dir.join("data/anatomy/arch-to-cow"), 20e-3)?;
    let inflows = CircleInflows::arch_to_cow(&ends)?;
    let (left, superior) = (inflows.left, inflows.superior);
    let anterior = left.cross(&superior);
    let started = std::time::Instant::now();
    let circle = circle_of_willis(&anatomy.lumen, &inflows, &CircleSettings::default())?;
    println!(
        "{} arteries named in {:.1} s ({:.1} mm voxels, {} loop(s) rejoined, {:.0} mm of centerline unnamed)",
        circle.branches.len(),
        started.elapsed().as_secs_f64(),
        circle.voxel_m * 1e3,
        circle.loops_closed,
        circle.unnamed_length_m * 1e3
    );
    for b in &circle.branches {
        let length: f64 = b.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        let mut radii = b.radii.clone();
        radii.sort_by(f64::total_cmp);
        println!(
            "  {:38} {:5.1} mm long, median radius {:.2} mm",
            b.name,
            length * 1e3,
            radii[radii.len() / 2] * 1e3
        );
    }
    // Seen from above: patient left to the right of the figure, anterior up (mm from the
    // basilar top).
    let origin = circle.landmarks["basilar_top"];
    let view = |p: &Point3<f64>| {
        let d = p - origin;
        (d.dot(&left) * 1e3, d.dot(&anterior) * 1e3)
    };
    let above = superior.dot(&origin.coords) - 25e-3;
    let out = root_dir.join("docs/figures/circle_of_willis.svg");
    let root = SVGBackend::new(&out, (900, 760)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Circle of Willis computed from the arch-to-cow surface, seen from above",
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(-30.0..40.0, -35.0..30.0)?;
    chart
        .configure_mesh()
        .x_desc("to the patient's left (mm)")
        .y_desc("anterior (mm)")
        .draw()?;
    let mesh = anatomy.lumen.mesh();
    chart.draw_series(
        mesh.vertices
            .iter()
            .filter(|v| superior.dot(&v.coords) > above)
            .map(|v| Circle::new(view(v), 2, RGBColor(200, 200, 200).filled())),
    )?;
    let palette = [
        RGBColor(31, 119, 180),
        RGBColor(214, 39, 40),
        RGBColor(44, 160, 44),
        RGBColor(148, 103, 189),
        RGBColor(255, 127, 14),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(23, 190, 207),
        RGBColor(188, 189, 34),
    ];
    for (i, b) in circle.branches.iter().enumerate() {
        let colour = palette[i % palette.len()];
        let line: Vec<(f64, f64)> = b.points.iter().map(view).collect();
        chart.draw_series(LineSeries::new(
            line.clone(),
            ShapeStyle::from(colour).stroke_width(3),
        ))?;
        let label = b
            .name
            .replace("anterior_cerebral_", "ACA ")
            .replace("posterior_cerebral_", "PCA ")
            .replace("posterior_communicating", "PCom")
            .replace("anterior_communicating", "ACom")
            .replace("internal_carotid_communicating", "ICA C7")
            .replace("internal_carotid", "ICA")
            .replace("middle_cerebral", "MCA M1")
            .replace("vertebral", "VA")
            .replace('_', " ");
        let at = line[line.len() / 2];
        chart.draw_series(std::iter::once(Text::new(
            label,
            (at.0 + 0.6, at.1 + 0.6),
            ("sans-serif", 13).into_font().color(&colour),
        )))?;
    }
    chart.draw_series(
        circle
            .landmarks
            .values()
            .map(|p| Circle::new(view(p), 4, BLACK.filled())),
    )?;
    root.present()?;
    println!("wrote {}", out.display());
    Ok(())
}
