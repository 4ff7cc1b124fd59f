//! Real anatomy assembled from files: a lumen surface plus centerline curves, joined into one
//! vessel graph through centred lumen paths from an access point. The bundled
//! `data/anatomy/arch-to-cow` anatomy loads with [`load_arch_to_cow`].

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::Point3;

use crate::centerline::lumen_path_tree;
use crate::error::{AnatomyError, Result};
use crate::graph::{BranchSpec, Side, VesselGraph, VesselKind};
use crate::io::slicer::{self, Centerline};
use crate::io::{LengthUnit, obj};
use crate::lumen::Lumen;
use crate::mesh::TriangleMesh;

/// A lumen surface with its vessel graph.
#[derive(Debug)]
pub struct Anatomy {
    /// Centerlines, junctions and landmarks (`access`).
    pub graph: VesselGraph,
    /// The wall, ready for queries.
    pub lumen: Lumen,
}

/// Anatomical identity from a conventional abbreviation in a curve's name (LCCA, RVA, ICA...).
pub fn guess_kind(name: &str) -> (VesselKind, Side) {
    let upper = name.to_ascii_uppercase();
    let (side, rest) = match upper.chars().next() {
        Some('L') if upper.len() > 2 => (Side::Left, &upper[1..]),
        Some('R') if upper.len() > 2 => (Side::Right, &upper[1..]),
        _ => (Side::Midline, upper.as_str()),
    };
    let kind = match rest {
        "CCA" => VesselKind::CommonCarotid,
        "ICA" => VesselKind::InternalCarotid,
        "ECA" => VesselKind::ExternalCarotid,
        "VA" => VesselKind::Vertebral,
        "SA" | "SCA" => VesselKind::Subclavian,
        "MCA" => VesselKind::MiddleCerebral,
        "ACA" => VesselKind::AnteriorCerebral,
        "PCA" => VesselKind::PosteriorCerebral,
        "PCOM" => VesselKind::PosteriorCommunicating,
        _ => match upper.as_str() {
            "BA" | "BASILAR" => VesselKind::Basilar,
            "ACOM" => VesselKind::AnteriorCommunicating,
            "AORTA" => VesselKind::Aorta,
            "BCT" | "BT" => VesselKind::Brachiocephalic,
            _ => VesselKind::Other,
        },
    };
    if kind == VesselKind::Other {
        (kind, Side::Midline)
    } else {
        (kind, side)
    }
}

/// Joins `curves` (each from a vessel origin towards a target) to `access` through the
/// lumen of `mesh`, and returns the surface and graph. Curves keep their names; the joining
/// paths are named `descending_aorta` (the part shared by all) and `arch_to_<curves>`.
pub fn assemble(
    mesh: TriangleMesh,
    curves: Vec<Centerline>,
    access: Point3<f64>,
    source: &str,
) -> Result<Anatomy> {
    let lumen = Lumen::new(mesh, source)?;
    let mut graph = VesselGraph::new();
    // Distinct curve starts are the targets of the lumen paths.
    let mut starts: Vec<(Point3<f64>, Vec<String>)> = Vec::new();
    for c in &curves {
        match starts
            .iter_mut()
            .find(|(p, _)| (p - c.points[0]).norm() < 1e-3)
        {
            Some((_, names)) => names.push(c.name.clone()),
            None => starts.push((c.points[0], vec![c.name.clone()])),
        }
    }
    let targets: Vec<Point3<f64>> = starts.iter().map(|s| s.0).collect();
    let chains = lumen_path_tree(&lumen, &access, &targets, 1e-3)?;
    for chain in chains {
        let mut points = chain.points;
        let radii = chain.radii;
        let last = points.len() - 1;
        if chain.serves.len() == 1 {
            // End exactly on the curve's first point so that the graph connects.
            points[last] = targets[chain.serves[0]];
        }
        if points[0] == points[last] {
            continue;
        }
        let (name, kind) = if chain.serves.len() == targets.len() {
            ("descending_aorta".to_owned(), VesselKind::Aorta)
        } else {
            let names: Vec<String> = chain
                .serves
                .iter()
                .flat_map(|&t| starts[t].1.clone())
                .collect();
            (format!("arch_to_{}", names.join("+")), VesselKind::Aorta)
        };
        graph.add_branch(BranchSpec {
            name,
            kind,
            side: Side::Midline,
            points,
            radii,
        })?;
    }
    for c in curves {
        let (kind, side) = guess_kind(&c.name);
        graph.add_branch(BranchSpec {
            name: c.name,
            kind,
            side,
            points: c.points,
            radii: c.radii,
        })?;
    }
    if graph.connected_components() != 1 {
        return Err(AnatomyError::InvalidGraph(format!(
            "{source}: the centerlines and lumen paths form {} disconnected pieces",
            graph.connected_components()
        )));
    }
    graph.landmarks.insert("access".into(), access);
    Ok(Anatomy { graph, lumen })
}

/// Access point of the bundled arch-to-cow anatomy (m, LPS): the centre of the descending
/// aorta about 85 mm below the left common carotid's origin (the deepest lumen point of the
/// cross-section there, 12 mm from the wall).
pub const ARCH_TO_COW_ACCESS_M: [f64; 3] = [-0.300, 0.060, -0.068];

/// The arch-to-cow directory's surface (mm → m) and its curves, named by their files.
fn read_arch_to_cow(dir: &Path) -> Result<(TriangleMesh, Vec<Centerline>, String)> {
    let surface_path = dir.join("vessels.obj");
    let mesh = obj::load(&surface_path, LengthUnit::Mm)?;
    let mut curve_files: Vec<_> = std::fs::read_dir(dir.join("centerlines"))
        .map_err(|source| AnatomyError::Io {
            file: dir.join("centerlines"),
            source,
        })?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.to_string_lossy().ends_with(".mrk.json"))
        .collect();
    curve_files.sort();
    let mut curves = Vec::new();
    for f in &curve_files {
        curves.extend(slicer::load(f)?);
    }
    if curves.is_empty() {
        return Err(AnatomyError::Empty {
            file: dir.join("centerlines").display().to_string(),
            message: "no .mrk.json centerlines".into(),
        });
    }
    // Slicer's curve names here are generic ("Centerline curve (8)"); use the file names.
    for (c, f) in curves.iter_mut().zip(&curve_files) {
        if let Some(stem) = f
            .file_name()
            .and_then(|n| n.to_str())
            .and_then(|n| n.split('.').next())
        {
            c.name = stem.to_owned();
        }
    }
    Ok((mesh, curves, surface_path.display().to_string()))
}

/// Loads the arch-to-circle-of-Willis anatomy from a directory holding `vessels.obj` (mm)
/// and `centerlines/*.mrk.json`.
pub fn load_arch_to_cow(dir: &Path) -> Result<Anatomy> {
    let (mesh, curves, source) = read_arch_to_cow(dir)?;
    assemble(mesh, curves, Point3::from(ARCH_TO_COW_ACCESS_M), &source)
}

/// The patient's left and superior directions in the arch-to-cow surface's frame.
pub const ARCH_TO_COW_LEFT_SUPERIOR: [[f64; 3]; 2] = [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]];

/// [`load_arch_to_cow`] with every curve ending `trim_m` (m) earlier (at the first point at
/// least that far back along it), and where each curve now ends, by name: what the head's
/// vessels computed from the surface join.
pub fn load_arch_to_cow_trimmed(
    dir: &Path,
    trim_m: f64,
) -> Result<(Anatomy, BTreeMap<String, Point3<f64>>)> {
    let (mesh, mut curves, source) = read_arch_to_cow(dir)?;
    let mut ends = BTreeMap::new();
    for c in &mut curves {
        let mut back = 0.0;
        let mut keep = c.points.len();
        while keep > 2 && back < trim_m {
            back += (c.points[keep - 1] - c.points[keep - 2]).norm();
            keep -= 1;
        }
        c.points.truncate(keep);
        c.radii.truncate(keep);
        ends.insert(c.name.clone(), c.points[keep - 1]);
    }
    let anatomy = assemble(mesh, curves, Point3::from(ARCH_TO_COW_ACCESS_M), &source)?;
    Ok((anatomy, ends))
}
