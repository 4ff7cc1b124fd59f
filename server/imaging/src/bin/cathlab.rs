//! `cathlab`: command-line tools for patient images and vessel surfaces. `cathlab segment`
//! builds a vessel graph, centerlines with radii and a lumen surface from a CT angiography
//! volume; `cathlab case` turns a vessel surface or a CTA volume into a scene folder that
//! `cathlab-server --scenes` serves.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use cathlab_anatomy::io::LengthUnit;
use cathlab_imaging::ScalarVolume;
use cathlab_imaging::case::{AccessChoice, CaseOptions, Placement, write_case};
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
    /// Turns a vessel surface (.obj, .stl, .ply, .vtp) or a CTA volume (.mha, .mhd, .nii,
    /// .nii.gz, .dcm or a DICOM folder) into a scene folder: `<name>.toml`, the surface,
    /// graph.json, centerlines.vtp, preview.png (branch names), report.json (open ends,
    /// branches) and, for a volume, ct.mha. Serve it with `cathlab-server --scenes DIR`.
    Case {
        /// The surface or volume.
        input: PathBuf,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// The surface's length unit: mm, cm, m or um.
        #[arg(long, default_value = "mm")]
        unit: String,
        /// Rotation of the surface into patient LPS, about x then y then z (deg): "a,b,c".
        #[arg(long, value_parser = parse_triple, allow_hyphen_values = true)]
        rotate_deg: Option<[f64; 3]>,
        /// Then a translation (mm): "x,y,z".
        #[arg(long, value_parser = parse_triple, allow_hyphen_values = true)]
        translate_mm: Option<[f64; 3]>,
        /// Devices enter at this open end (ends are numbered by radius, largest first).
        #[arg(long, conflicts_with = "access_near")]
        access_end: Option<usize>,
        /// Devices enter at the open end nearest this LPS point (mm): "x,y,z".
        #[arg(long, value_parser = parse_triple, allow_hyphen_values = true)]
        access_near: Option<[f64; 3]>,
        /// The target is the vessel whose free end is nearest this LPS point (mm); by
        /// default the end farthest along the vessels from the access.
        #[arg(long, value_parser = parse_triple, allow_hyphen_values = true)]
        target_near: Option<[f64; 3]>,
        /// A volume's seed inside a contrast-filled vessel, LPS mm: "x,y,z".
        #[arg(long, value_parser = parse_triple, allow_hyphen_values = true, conflicts_with = "seed_voxel")]
        seed: Option<[f64; 3]>,
        /// A volume's seed as a voxel index: "i,j,k".
        #[arg(long, value_parser = parse_triple)]
        seed_voxel: Option<[f64; 3]>,
        /// A DICOM folder's series (SeriesInstanceUID) when it holds several.
        #[arg(long)]
        series: Option<String>,
        /// Voxel size for centerlines computed from a surface (mm).
        #[arg(long)]
        voxel_mm: Option<f64>,
        /// Most voxels for those centerlines (about 20 bytes each; millions).
        #[arg(long, default_value_t = 200)]
        max_megavoxels: usize,
        /// The scene's name (default: the output folder's name).
        #[arg(long)]
        name: Option<String>,
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

fn seed_of(seed: Option<[f64; 3]>, seed_voxel: Option<[f64; 3]>) -> Result<Option<Seed>, String> {
    match (seed, seed_voxel) {
        (Some(mm), _) => Ok(Some(Seed::Position(Point3::from(mm) * 1e-3))),
        (None, Some(v)) if v.iter().all(|x| *x >= 0.0 && x.fract() == 0.0) => {
            Ok(Some(Seed::Voxel(v.map(|x| x as usize))))
        }
        (None, Some(v)) => Err(format!(
            "--seed-voxel {v:?}: expected non-negative integers"
        )),
        (None, None) => Ok(None),
    }
}

fn main() -> ExitCode {
    match Cli::parse().command {
        Command::Segment {
            volume,
            seed,
            seed_voxel,
            out,
            threshold,
            upper_threshold,
            diffusion_iterations,
            local_window_mm,
            local_fraction,
        } => {
            let seed = match seed_of(seed, seed_voxel) {
                Ok(Some(seed)) => seed,
                Ok(None) => {
                    eprintln!("error: give --seed x,y,z (mm) or --seed-voxel i,j,k");
                    return ExitCode::from(2);
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::from(2);
                }
            };
            let settings = SegmentSettings {
                threshold,
                upper_threshold,
                diffusion_iterations,
                local_window_m: local_window_mm * 1e-3,
                local_fraction,
                ..SegmentSettings::default()
            };
            finish(run_segment(&volume, &seed, &settings, &out))
        }
        Command::Case {
            input,
            out,
            unit,
            rotate_deg,
            translate_mm,
            access_end,
            access_near,
            target_near,
            seed,
            seed_voxel,
            series,
            voxel_mm,
            max_megavoxels,
            name,
        } => {
            let seed = match seed_of(seed, seed_voxel) {
                Ok(seed) => seed,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::from(2);
                }
            };
            let unit = match LengthUnit::parse(&unit, "--unit") {
                Ok(unit) => unit,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::from(2);
                }
            };
            let options = CaseOptions {
                unit: Some(unit),
                placement: Placement {
                    rotation_deg: rotate_deg.unwrap_or_default(),
                    translation_mm: translate_mm.unwrap_or_default(),
                },
                access: match (access_end, access_near) {
                    (_, Some(p)) => AccessChoice::NearMm(p),
                    (Some(i), None) => AccessChoice::End(i),
                    (None, None) => AccessChoice::End(0),
                },
                target_near_mm: target_near,
                seed,
                series,
                voxel_m: voxel_mm.map(|v| v * 1e-3),
                max_voxels: max_megavoxels.saturating_mul(1_000_000),
                name,
            };
            finish(run_case(&input, &options, &out))
        }
    }
}

fn finish(result: cathlab_imaging::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run_case(input: &Path, options: &CaseOptions, out: &Path) -> cathlab_imaging::Result<()> {
    let started = std::time::Instant::now();
    let report = write_case(input, options, out)?;
    for end in &report.open_ends {
        println!(
            "open end {}: centre ({:.1}, {:.1}, {:.1}) mm, radius {:.2} mm, capped",
            end.index, end.centre_mm[0], end.centre_mm[1], end.centre_mm[2], end.radius_mm
        );
    }
    println!(
        "{} branches; access ({:.1}, {:.1}, {:.1}) mm; target {} ({:.0} mm along the vessels)",
        report.branches.len(),
        report.access_mm[0],
        report.access_mm[1],
        report.access_mm[2],
        report.target,
        report.route_mm
    );
    println!(
        "wrote {}/{}.toml with its files in {:.1} s; serve it with `cathlab-server --scenes {}`",
        out.display(),
        report.name,
        started.elapsed().as_secs_f64(),
        out.display()
    );
    Ok(())
}

fn run_segment(
    volume: &Path,
    seed: &Seed,
    settings: &SegmentSettings,
    out: &Path,
) -> cathlab_imaging::Result<()> {
    let input = ScalarVolume::load(volume)?;
    let result = segment(&input, seed, settings)?;
    export::write_all(&result, &input, out)?;
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
        "surface {} triangles (decimated from {}), watertight {}; stages {}",
        r.surface_triangles,
        r.polygonised_triangles,
        r.surface_watertight,
        r.stages_text()
    );
    println!(
        "wrote {} to {}",
        export::OUTPUT_FILES.join(", "),
        out.display()
    );
    Ok(())
}
