//! Chart command: `cargo bench -p cathlab-hemo --bench charts` advects a 5 mm contrast bolus
//! 150 mm down a tube at CFL 0.5 with each limiter and writes the profiles against the exact
//! one to `docs/figures/contrast_bolus_{0.25,1}mm.svg` (and a CSV of every point). Under
//! `cargo test --benches` it runs the cases and writes nothing.

use std::fmt::Write as _;
use std::path::PathBuf;

use cathlab_hemo::Limiter;
use cathlab_hemo::scenarios::{BolusShape, advect_bolus};
use plotters::prelude::*;

type Series = (String, Vec<(f64, f64)>, RGBColor);

fn profile_chart(path: &PathBuf, title: &str, series: &[Series]) {
    let lo = series
        .iter()
        .flat_map(|s| s.1.iter())
        .filter(|p| p.1 > 1.0)
        .map(|p| p.0)
        .fold(f64::MAX, f64::min);
    let hi = series
        .iter()
        .flat_map(|s| s.1.iter())
        .filter(|p| p.1 > 1.0)
        .map(|p| p.0)
        .fold(f64::MIN, f64::max);
    let root = SVGBackend::new(path, (760, 480)).into_drawing_area();
    root.fill(&WHITE).unwrap();
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(lo - 2.0..hi + 2.0, -5.0..320.0)
        .unwrap();
    chart
        .configure_mesh()
        .x_desc("position along the tube (mm)")
        .y_desc("iodine (mg/mL)")
        .draw()
        .unwrap();
    for (name, data, color) in series {
        let style = ShapeStyle::from(color).stroke_width(2);
        chart
            .draw_series(LineSeries::new(data.clone(), style))
            .unwrap()
            .label(name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], style));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperLeft)
        .draw()
        .unwrap();
    root.present().unwrap();
}

fn main() {
    // `cargo bench` passes --bench; `cargo test --benches` does not: then nothing is written.
    let full = std::env::args().any(|a| a == "--bench");
    let figures = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../docs/figures");
    let mut csv = String::from("cells_mm,series,position_mm,concentration_mg_per_ml\n");
    for (dx, tag) in [(0.25e-3, "0.25"), (1e-3, "1")] {
        let mut series: Vec<Series> = Vec::new();
        let limiters = [
            ("first-order upwind", Limiter::Upwind, RED),
            ("van Leer", Limiter::VanLeer, GREEN),
            (
                "monotonized central (default)",
                Limiter::MonotonizedCentral,
                BLUE,
            ),
            ("superbee", Limiter::Superbee, MAGENTA),
        ];
        for (i, (name, limiter, color)) in limiters.into_iter().enumerate() {
            let run = advect_bolus(limiter, BolusShape::Plug, dx, 0.5, 5e-3, 0.15).unwrap();
            let x = |k: usize| (k as f64 + 0.5) * run.cell_length * 1e3;
            if i == 0 {
                series.push((
                    "exact".into(),
                    run.exact
                        .iter()
                        .enumerate()
                        .map(|(k, &c)| (x(k), c))
                        .collect(),
                    BLACK,
                ));
            }
            println!(
                "{tag} mm cells, {name}: peak kept {:.1} %, L1 error {:.1} %",
                100.0 * run.peak_kept(),
                100.0 * run.relative_l1_error()
            );
            series.push((
                format!("{name}: peak {:.0} %", 100.0 * run.peak_kept()),
                run.profile
                    .iter()
                    .enumerate()
                    .map(|(k, &c)| (x(k), c))
                    .collect(),
                color,
            ));
        }
        for s in &series {
            for (x, y) in s.1.iter().filter(|p| p.1 > 1e-3) {
                writeln!(csv, "{tag},{},{x:.4},{y:.6e}", s.0).unwrap();
            }
        }
        if full {
            profile_chart(
                &figures.join(format!("contrast_bolus_{tag}mm.svg")),
                &format!("5 mm contrast plug after 150 mm at CFL 0.5, {tag} mm cells"),
                &series,
            );
        }
    }
    if full {
        std::fs::write(figures.join("contrast_bolus.csv"), csv).unwrap();
        println!("wrote docs/figures/contrast_bolus_*.svg and contrast_bolus.csv");
    }
}
