//! The outcome sweep: `cargo bench -p cathlab-thrombectomy --bench sweep` runs 200 seeded
//! scripted thrombectomies per setting on the neuro phantom's left M1 (the clot 4 mm into
//! the artery, the receiving catheter's tip 10 mm back down the internal carotid, at its terminus), prints the
//! table (markdown) and writes `docs/figures/thrombectomy_sweep.svg`. Under
//! `cargo test --benches` it runs 50 per setting, checks the trends the issue names and
//! writes nothing.

use cathlab_anatomy::phantom::{NeuroPhantomParams, neuro_phantom};
use cathlab_thrombectomy::sweep::{Setting, Site, Summary, Technique, sweep};
use cathlab_thrombectomy::{DEFAULT_SUCTION_PA, RetrievalPath, StentRetriever};
use nalgebra::Point3;
use plotters::prelude::*;

const INCH: f64 = 25.4e-3;

/// The left M1 of the scene `stroke_m1_thrombectomy`'s phantom, from the clot's proximal
/// end back through the ICA terminus to the receiving catheter.
fn site() -> Site {
    let graph = neuro_phantom(&NeuroPhantomParams {
        seed: 0,
        tortuosity: 0.3,
        ..NeuroPhantomParams::default()
    })
    .unwrap();
    let m1 = graph.branch("left_middle_cerebral").unwrap();
    let ica = graph.branch("left_internal_carotid").unwrap();
    let mut points: Vec<Point3<f64>> = Vec::new();
    let mut radii = Vec::new();
    // M1 from 4 mm back to its start, then the ICA from its end back 10 mm.
    let along = |pts: &[Point3<f64>], from_end: bool| -> Vec<(Point3<f64>, f64)> {
        let mut acc = 0.0;
        let mut out = Vec::new();
        let order: Vec<usize> = if from_end {
            (0..pts.len()).rev().collect()
        } else {
            (0..pts.len()).collect()
        };
        for (k, &i) in order.iter().enumerate() {
            if k > 0 {
                acc += (pts[i] - pts[order[k - 1]]).norm();
            }
            out.push((pts[i], acc));
        }
        out
    };
    for (k, &(p, s)) in along(&m1.points, false).iter().enumerate() {
        if s <= 4e-3 {
            points.push(p);
            radii.push(m1.radii[k]);
        }
    }
    points.reverse();
    radii.reverse();
    let n = ica.points.len();
    for (k, &(p, s)) in along(&ica.points, true).iter().enumerate().skip(1) {
        if s <= 10e-3 {
            points.push(p);
            radii.push(ica.radii[n - 1 - k]);
        }
    }
    Site {
        vessel_radius_m: radii[0],
        path: RetrievalPath::from_centerline(&points, &radii).unwrap(),
        channel_radius_m: 0.021 * INCH / 2.0,
    }
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let runs = if full { 200 } else { 50 };
    let site = site();
    let stent = StentRetriever::solitaire_class_4x20();
    let dac = |bore_in: f64, suction: f64| Technique::StentRetriever {
        stent,
        receiving_bore_m: bore_in * INCH,
        suction_pa: suction,
    };
    println!(
        "site: vessel radius {:.2} mm, way back {:.1} mm turning {:.0} deg; {runs} runs per setting\n",
        site.vessel_radius_m * 1e3,
        site.path.length_m() * 1e3,
        site.path.turning_rad().to_degrees()
    );
    println!(
        "| technique | clot (red-cell fraction) | pull (mm/s) | first-pass effect | retrieved ≤ 3 passes | mean passes | runs with emboli |"
    );
    println!("|---|---|---|---|---|---|---|");
    let mut rows: Vec<(Setting, Summary, String)> = Vec::new();
    let mut run = |label: String, setting: Setting| {
        let s = sweep(&setting, &site, runs, 1_000).unwrap();
        println!(
            "| {label} | {} | {:.0} | {:.0} % | {:.0} % | {:.2} | {:.0} % |",
            setting
                .red_cell_fraction
                .map_or("0.1–0.9".into(), |f| format!("{f:.1}")),
            setting.pull_speed_m_s * 1e3,
            s.first_pass_rate * 100.0,
            s.success_rate * 100.0,
            s.mean_passes,
            s.emboli_rate * 100.0
        );
        rows.push((setting, s, label));
    };
    let speeds = [2e-3, 5e-3, 10e-3, 20e-3];
    for fraction in [0.2, 0.5, 0.8] {
        for speed in speeds {
            run(
                "stent into 0.071\" DAC".into(),
                Setting {
                    technique: dac(0.071, 0.0),
                    red_cell_fraction: Some(fraction),
                    pull_speed_m_s: speed,
                },
            );
        }
    }
    run(
        "stent into 0.071\" DAC with suction".into(),
        Setting {
            technique: dac(0.071, DEFAULT_SUCTION_PA),
            red_cell_fraction: Some(0.5),
            pull_speed_m_s: 5e-3,
        },
    );
    for bore in [0.058, 0.071, 0.088] {
        run(
            format!("aspiration, {bore}\" bore"),
            Setting {
                technique: Technique::Aspiration {
                    bore_m: bore * INCH,
                    suction_pa: DEFAULT_SUCTION_PA,
                },
                red_cell_fraction: None,
                pull_speed_m_s: 5e-3,
            },
        );
    }
    // The trends the issue names, on these seeds.
    let stent_rate = |fraction: f64, speed: f64| {
        rows.iter()
            .find(|(s, _, l)| {
                l == "stent into 0.071\" DAC"
                    && s.red_cell_fraction == Some(fraction)
                    && s.pull_speed_m_s == speed
            })
            .unwrap()
            .1
            .success_rate
    };
    for fraction in [0.2, 0.5, 0.8] {
        assert!(
            stent_rate(fraction, 2e-3) > stent_rate(fraction, 20e-3),
            "success falls with pull speed ({fraction})"
        );
    }
    for speed in speeds {
        assert!(
            stent_rate(0.8, speed) > stent_rate(0.2, speed),
            "fibrin-rich clots fail more ({speed})"
        );
    }
    let aspiration: Vec<f64> = rows
        .iter()
        .filter(|r| r.2.starts_with("aspiration"))
        .map(|r| r.1.success_rate)
        .collect();
    assert!(
        aspiration.windows(2).all(|w| w[1] > w[0]),
        "aspiration success rises with bore: {aspiration:?}"
    );
    if full {
        chart(&rows, &speeds);
    }
}

fn chart(rows: &[(Setting, Summary, String)], speeds: &[f64]) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../docs/figures/thrombectomy_sweep.svg");
    let root = SVGBackend::new(&path, (760, 440)).into_drawing_area();
    root.fill(&WHITE).unwrap();
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Stent retriever: retrieved within 3 passes (200 seeded runs each)",
            ("sans-serif", 17),
        )
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(55)
        .build_cartesian_2d(0.0..22.0, 0.0..100.0)
        .unwrap();
    chart
        .configure_mesh()
        .x_desc("pull speed (mm/s)")
        .y_desc("success (%)")
        .draw()
        .unwrap();
    for (fraction, color) in [(0.2, RED), (0.5, MAGENTA), (0.8, BLUE)] {
        let data: Vec<(f64, f64)> = speeds
            .iter()
            .map(|&v| {
                let r = rows
                    .iter()
                    .find(|(s, _, l)| {
                        l == "stent into 0.071\" DAC"
                            && s.red_cell_fraction == Some(fraction)
                            && s.pull_speed_m_s == v
                    })
                    .unwrap();
                (v * 1e3, r.1.success_rate * 100.0)
            })
            .collect();
        let style = ShapeStyle::from(color).stroke_width(2);
        chart
            .draw_series(LineSeries::new(data.clone(), style))
            .unwrap()
            .label(format!("red-cell fraction {fraction}"))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], style));
        chart
            .draw_series(data.iter().map(|&p| Circle::new(p, 3, color.filled())))
            .unwrap();
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .unwrap();
    root.present().unwrap();
    println!("\nwrote {}", path.display());
}
