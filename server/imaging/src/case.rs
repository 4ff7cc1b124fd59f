//! A patient's vessels from a surface file: read in its unit, placed into patient LPS, its
//! open ends found and capped, the access chosen (an end by index or nearest a point), the
//! centerlines read (a graph, curves, a tree) or computed from the surface, and branches
//! renamed. The engine's `surface` anatomy and `cathlab case` both build anatomy here.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use cathlab_anatomy::capping::{OpenEnd, cap_open_ends};
use cathlab_anatomy::io::{self, LengthUnit, slicer, swc, vtp};
use cathlab_anatomy::lumen::GridSettings;
use cathlab_anatomy::real::{Anatomy, assemble};
use cathlab_anatomy::{Lumen, TriangleMesh, VesselGraph};
use nalgebra::{Matrix3, Point3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{ImagingError, Result};
use crate::surface_centerlines::{SurfaceCenterlineSettings, centerlines_from_surface};

/// Where a surface's own coordinates lie in patient LPS.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Placement {
    /// Rotations about the x, then the y, then the z axis (deg), applied first.
    #[serde(default)]
    pub rotation_deg: [f64; 3],
    /// Then this translation (mm).
    #[serde(default)]
    pub translation_mm: [f64; 3],
}

impl Placement {
    /// The rotation part.
    pub fn rotation(&self) -> Matrix3<f64> {
        let [x, y, z] = self.rotation_deg.map(f64::to_radians);
        *(Rotation3::from_axis_angle(&Vector3::z_axis(), z)
            * Rotation3::from_axis_angle(&Vector3::y_axis(), y)
            * Rotation3::from_axis_angle(&Vector3::x_axis(), x))
        .matrix()
    }

    /// A point of the surface's frame (m) in LPS (m).
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.rotation() * p.coords + Vector3::from(self.translation_mm) * 1e-3)
    }

    /// True when it changes nothing ("as is").
    pub fn is_identity(&self) -> bool {
        self.rotation_deg == [0.0; 3] && self.translation_mm == [0.0; 3]
    }
}

/// Which open end (or point) the devices enter at.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum AccessChoice {
    /// An open end by its index (ends are numbered by radius, largest first).
    End(usize),
    /// The open end nearest this LPS point (mm, after placement); for a closed surface,
    /// the point itself, which must lie in the lumen near a vessel's end.
    NearMm([f64; 3]),
}

impl Default for AccessChoice {
    fn default() -> Self {
        AccessChoice::End(0)
    }
}

/// Everything that makes a surface into anatomy.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceCase {
    /// The surface (OBJ, STL, PLY, VTP).
    pub surface: PathBuf,
    /// Its length unit.
    pub unit: LengthUnit,
    /// Its placement into LPS.
    pub placement: Placement,
    /// Centerlines: a graph (`.json`, LPS, m, as `cathlab case` writes it), curves (`.vtp`
    /// lines with a radius array, Slicer `.mrk.json`) in the surface's frame and unit, or a
    /// tree (`.swc`); `None` computes them from the surface.
    pub centerlines: Option<PathBuf>,
    /// Where the devices enter.
    pub access: AccessChoice,
    /// New names for branches (`vessel_03` → `left_ica`).
    pub names: BTreeMap<String, String>,
    /// Voxel size for computed centerlines (m); `None` picks one.
    pub voxel_m: Option<f64>,
}

/// A surface made into anatomy, with what was found on the way.
#[derive(Debug)]
pub struct SurfaceAnatomy {
    /// The graph (landmark `access`) and the capped lumen.
    pub anatomy: Anatomy,
    /// The open ends found and capped (LPS).
    pub open_ends: Vec<OpenEnd>,
    /// The access point (m, LPS).
    pub access: Point3<f64>,
}

fn field(name: &str, reason: impl Into<String>) -> ImagingError {
    ImagingError::Case {
        field: name.to_owned(),
        reason: reason.into(),
    }
}

/// Grid settings for contact queries on a surface of any size: 1 mm cells over a 3 mm band.
pub fn contact_grid() -> GridSettings {
    GridSettings {
        cell_size: Some(1e-3),
        band: 3e-3,
    }
}

/// Reads, places and caps the surface; returns it with its open ends (LPS).
pub fn placed_surface(case: &SurfaceCase) -> Result<(TriangleMesh, Vec<OpenEnd>)> {
    let mut mesh = io::load_surface(&case.surface, case.unit)?;
    if !case.placement.is_identity() {
        for v in &mut mesh.vertices {
            *v = case.placement.apply(v);
        }
        mesh.normals.clear();
    }
    let shown = case.surface.display().to_string();
    let (capped, ends) = cap_open_ends(&mesh, &shown)?;
    Ok((capped, ends))
}

/// The access point for `choice` among `ends` (LPS, m).
pub fn access_point(choice: &AccessChoice, ends: &[OpenEnd]) -> Result<Point3<f64>> {
    match *choice {
        AccessChoice::End(i) => ends.get(i).map(|e| e.centre).ok_or_else(|| {
            field(
                "access.end",
                if ends.is_empty() {
                    "the surface is closed (no open ends); give access.near_mm, a point in the \
                     access vessel near its end"
                        .to_owned()
                } else {
                    format!(
                        "end {i} does not exist: the surface has {} open ends (0–{})",
                        ends.len(),
                        ends.len() - 1
                    )
                },
            )
        }),
        AccessChoice::NearMm(p) => {
            let p = Point3::from(Vector3::from(p) * 1e-3);
            Ok(ends
                .iter()
                .min_by(|a, b| (a.centre - p).norm().total_cmp(&(b.centre - p).norm()))
                .map_or(p, |e| e.centre))
        }
    }
}

/// Moves `access` from an end's centre (on the cap) one radius into the vessel, where the
/// lumen surrounds it.
fn inside_end(access: Point3<f64>, ends: &[OpenEnd]) -> Point3<f64> {
    ends.iter()
        .find(|e| (e.centre - access).norm() < 1e-9)
        .map_or(access, |e| e.centre - e.normal * e.radius_m)
}

/// Builds the anatomy of a surface case.
pub fn load_surface_case(case: &SurfaceCase) -> Result<SurfaceAnatomy> {
    let (mesh, open_ends) = placed_surface(case)?;
    let access = access_point(&case.access, &open_ends)?;
    let shown = case.surface.display().to_string();
    let mut anatomy = match &case.centerlines {
        None => {
            let lumen = Lumen::with_grid_settings(mesh, &shown, contact_grid())?;
            let computed = centerlines_from_surface(
                &lumen,
                &inside_end(access, &open_ends),
                &SurfaceCenterlineSettings {
                    voxel_m: case.voxel_m,
                    ..SurfaceCenterlineSettings::default()
                },
            )?;
            Anatomy {
                graph: computed.graph,
                lumen,
            }
        }
        Some(path) => {
            let name = path.to_string_lossy().to_ascii_lowercase();
            let graph_file = |graph: VesselGraph, lumen: Lumen| Anatomy { graph, lumen };
            if name.ends_with(".mrk.json") || name.ends_with(".vtp") {
                let mut curves = if name.ends_with(".vtp") {
                    vtp::load(path, case.unit)?.lines
                } else {
                    let mut c = slicer::load(path)?;
                    // Slicer stores LPS millimetres: its curves are in the patient's frame
                    // already, so the placement is undone to bring them to the surface's.
                    for curve in &mut c {
                        for p in &mut curve.points {
                            *p = unplace(&case.placement, p);
                        }
                    }
                    c
                };
                if curves.is_empty() {
                    return Err(field("anatomy.centerlines", "the file holds no lines"));
                }
                for curve in &mut curves {
                    for p in &mut curve.points {
                        *p = case.placement.apply(p);
                    }
                    if curve.radii.is_empty() {
                        return Err(field(
                            "anatomy.centerlines",
                            format!("line {:?} has no radius array", curve.name),
                        ));
                    }
                }
                let access = inside_end(access, &open_ends);
                let assembled = assemble(mesh, curves, access, &shown)?;
                let lumen = assembled.lumen.with_grid(contact_grid())?;
                graph_file(assembled.graph, lumen)
            } else {
                let mut graph = if name.ends_with(".swc") {
                    let mut g = swc::load(path, case.unit)?;
                    place_graph(&mut g, &case.placement)?;
                    g
                } else if name.ends_with(".json") {
                    let text =
                        std::fs::read_to_string(path).map_err(|source| ImagingError::Io {
                            file: path.clone(),
                            source,
                        })?;
                    VesselGraph::from_json(&text, &path.display().to_string())?
                } else {
                    return Err(field(
                        "anatomy.centerlines",
                        "unknown format (expected .json graph, .vtp lines, .mrk.json curves or .swc)",
                    ));
                };
                graph
                    .landmarks
                    .entry("access".into())
                    .or_insert_with(|| inside_end(access, &open_ends));
                let lumen = Lumen::with_grid_settings(mesh, &shown, contact_grid())?;
                graph_file(graph, lumen)
            }
        }
    };
    rename(&mut anatomy.graph, &case.names)?;
    let access = anatomy
        .graph
        .landmarks
        .get("access")
        .copied()
        .unwrap_or(access);
    Ok(SurfaceAnatomy {
        anatomy,
        open_ends,
        access,
    })
}

fn unplace(placement: &Placement, p: &Point3<f64>) -> Point3<f64> {
    Point3::from(
        placement.rotation().transpose()
            * (p.coords - Vector3::from(placement.translation_mm) * 1e-3),
    )
}

fn place_graph(graph: &mut VesselGraph, placement: &Placement) -> Result<()> {
    if placement.is_identity() {
        return Ok(());
    }
    for n in &mut graph.nodes {
        *n = placement.apply(n);
    }
    for b in &mut graph.branches {
        for p in &mut b.points {
            *p = placement.apply(p);
        }
    }
    for l in graph.landmarks.values_mut() {
        *l = placement.apply(l);
    }
    *graph = std::mem::take(graph).finish()?;
    Ok(())
}

/// Renames branches; every old name must exist and new names must stay unique.
pub fn rename(graph: &mut VesselGraph, names: &BTreeMap<String, String>) -> Result<()> {
    for (old, new) in names {
        let id = graph
            .branch_id(old)
            .map_err(|_| field(&format!("anatomy.names.{old}"), "no branch has this name"))?;
        if new.is_empty() || new.len() > 64 || new.chars().any(|c| c.is_control()) {
            return Err(field(
                &format!("anatomy.names.{old}"),
                "a name is 1–64 printable characters",
            ));
        }
        if graph.branches.iter().any(|b| &b.name == new) && new != old {
            return Err(field(
                &format!("anatomy.names.{old}"),
                format!("{new:?} is already a branch's name"),
            ));
        }
        graph.branches[id].name = new.clone();
    }
    Ok(())
}

/// The free end of the graph farthest along the vessels from the access: a default target.
pub fn farthest_end(graph: &VesselGraph) -> Option<(String, f64)> {
    let access = graph.landmarks.get("access")?;
    let degree = graph.node_degrees();
    graph
        .branches
        .iter()
        .filter(|b| degree[b.end] == 1 || degree[b.start] == 1)
        .filter_map(|b| {
            let route = graph.path_to(access, &b.name).ok()?;
            Some((b.name.clone(), route.length))
        })
        .filter(|(_, length)| *length > 0.0)
        .max_by(|a, b| a.1.total_cmp(&b.1))
}

/// The branch holding the free end nearest `p` (m, LPS).
pub fn branch_at_end(graph: &VesselGraph, p: &Point3<f64>) -> Option<String> {
    let degree = graph.node_degrees();
    graph
        .branches
        .iter()
        .flat_map(|b| {
            [
                (b.start, b.points[0]),
                (b.end, b.points[b.points.len() - 1]),
            ]
            .into_iter()
            .filter(|(node, _)| degree[*node] == 1)
            .map(move |(_, q)| (b.name.clone(), (q - p).norm()))
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(name, _)| name)
}

/// The path a scene gives, resolved against its folder.
pub fn resolve(base: &Path, path: &Path) -> PathBuf {
    if path.is_absolute() {
        path.to_owned()
    } else {
        base.join(path)
    }
}
