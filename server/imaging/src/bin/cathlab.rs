//! `cathlab`: command-line tools for patient images and vessel surfaces. `cathlab segment` builds a vessel
//! graph, centerlines with radii and a lumen surface from a CT angiography volume.

use std::path::PathBuf;
use std::process::ExitCode;

use cathlab_imaging::ScalarVolume;
use cathlab_imaging::segment::{Seed, SegmentSettings, export, segment};
use clap::{Parser, Subcommand};
use nalgebra::Point3;

#[derive(Parser)]
#[command(name = "cathlab", about = "cathlab image and anatomy tools")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Segments the vessel tree that holds a seed from a CTA volume (.mha, .mhd, .nii,
    /// .nii.gz) and writes graph.json, centerlines.vtp, surface.{vtp,obj,stl}, mask.mha,
    /// report.json and figure.png.
    Segment {
        /// The volume.
        volume: PathBuf,
        /// Seed inside a contrast-filled vessel, patient LPS coordinates in mm: "x,y,z".
        #[arg(long, value_parser = parse_triple, allow_hyphen_values = true, conflicts_with = "seed_voxel")]
        seed: Option<[f64; 3]>,
        /// Seed as a voxel index: "i,j,k".
        #[arg(long, value_parser = parse_triple)]
        seed_voxel: Option<[f64; 3]>,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Lumen threshold (image units); chosen from the data when absent.
        #[arg(long, allow_hyphen_values = true)]
        threshold: Option<f64>,
        /// Values above this are not lumen (e.g. bone).
        #[arg(long, allow_hyphen_values = true)]
        upper_threshold: Option<f64>,
        /// Half-width (mm) of the box whose brightest value is the local lumen value; 0 for
        /// one threshold everywhere.
        #[arg(long, default_value_t = SegmentSettings::default().local_window_m * 1e3)]
        local_window_mm: f64,
        /// Where the threshold lies between the tissue (0) and the local lumen value (1).
        #[arg(long, default_value_t = SegmentSettings::default().local_fraction)]
        local_fraction: f64,
        /// Perona–Malik diffusion steps.
        #[arg(long, default_value_t = SegmentSettings::default().diffusion_iterations)]
        diffusion_iterations: usize,
    },
}

fn parse_triple(text: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!(
            "expected three comma-separated numbers, got {text:?}"
        ));
    }
    let mut out = [0.0; 3];
    for (o, p) in out.iter_mut().zip(&parts) {
        *o = p
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("{p:?} is not a finite number"))?;
    }
    Ok(out)
}

fn main() -> ExitCode {
    let Command::Segment {
        volume,
        seed,
        seed_voxel,
        out,
        threshold,
        upper_threshold,
        diffusion_iterations,
        local_window_mm,
        local_fraction,
    } = Cli::parse().command;
    let seed = match (seed, seed_voxel) {
        (Some(mm), _) => Seed::Position(Point3::from(mm) * 1e-3),
        (None, Some(v)) if v.iter().all(|x| *x >= 0.0 && x.fract() == 0.0) => {
            Seed::Voxel(v.map(|x| x as usize))
        }
        (None, Some(v)) => {
            eprintln!("error: --seed-voxel {v:?}: expected non-negative integers");
            return ExitCode::from(2);
        }
        (None, None) => {
            eprintln!("error: give --seed x,y,z (mm) or --seed-voxel i,j,k");
            return ExitCode::from(2);
        }
    };
    let run = || -> cathlab_imaging::Result<()> {
        let input = ScalarVolume::load(&volume)?;
        let settings = SegmentSettings {
            threshold,
            upper_threshold,
            diffusion_iterations,
            local_window_m: local_window_mm * 1e-3,
            local_fraction,
            ..SegmentSettings::default()
        };
        let result = segment(&input, &seed, &settings)?;
        export::write_all(&result, &input, &out)?;
        let r = &result.report;
        println!(
            "{}: threshold {:.0}–{:.0} (lumen {:.0}, tissue {:.0}, noise σ {:.1}); {} lumen voxels ({:.1} mL)",
            volume.display(),
            r.threshold_range[0],
            r.threshold_range[1],
            r.lumen_value,
            r.background_value,
            r.noise_sigma,
            r.lumen_voxels,
            r.lumen_volume_ml
        );
        println!(
            "{} branches, {} end points, {} branch points, {} spurs pruned; centerline {:.0} mm; \
             radius {:.2}–{:.2} mm (median {:.2})",
            r.branches,
            r.end_points,
            r.branch_points,
            r.spurs_pruned,
            r.total_length_mm,
            r.radius_mm[0],
            r.radius_mm[2],
            r.radius_mm[1]
        );
        println!(
            "surface {} triangles, watertight {}; stages {}",
            r.surface_triangles,
            r.surface_watertight,
            r.stages_text()
        );
        println!(
            "wrote {} to {}",
            export::OUTPUT_FILES.join(", "),
            out.display()
        );
        Ok(())
    };
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
