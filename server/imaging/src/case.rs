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
    /// Most voxels for computed centerlines (about 20 bytes each).
    pub max_voxels: usize,
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
    // A graph file brings its own access; otherwise the choice must fit the surface.
    let chosen = access_point(&case.access, &open_ends);
    let shown = case.surface.display().to_string();
    let mut anatomy = match &case.centerlines {
        None => {
            let access = chosen?;
            let lumen = Lumen::with_grid_settings(mesh, &shown, contact_grid())?;
            let computed = centerlines_from_surface(
                &lumen,
                &inside_end(access, &open_ends),
                &SurfaceCenterlineSettings {
                    voxel_m: case.voxel_m,
                    max_voxels: case.max_voxels,
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
                let access = inside_end(chosen?, &open_ends);
                let assembled = assemble(mesh, curves, access, &shown)?;
                let lumen = assembled.lumen.with_grid(contact_grid())?;
                Anatomy {
                    graph: assembled.graph,
                    lumen,
                }
            } else {
                let mut graph = if name.ends_with(".swc") {
                    let mut g = swc::load(path, case.unit)?;
                    place_graph(&mut g, &case.placement)?;
                    g
                } else if name.ends_with(".json") {
                    let text =
                        cathlab_anatomy::io::limits::read_regular_text(path).map_err(|source| {
                            ImagingError::Io {
                                file: path.clone(),
                                source,
                            }
                        })?;
                    VesselGraph::from_json(&text, &path.display().to_string())?
                } else {
                    return Err(field(
                        "anatomy.centerlines",
                        "unknown format (expected .json graph, .vtp lines, .mrk.json curves or .swc)",
                    ));
                };
                if !graph.landmarks.contains_key("access") {
                    let access = inside_end(chosen?, &open_ends);
                    graph.landmarks.insert("access".into(), access);
                }
                let lumen = Lumen::with_grid_settings(mesh, &shown, contact_grid())?;
                Anatomy { graph, lumen }
            }
        }
    };
    rename(&mut anatomy.graph, &case.names)?;
    let access = anatomy
        .graph
        .landmarks
        .get("access")
        .copied()
        .ok_or_else(|| field("anatomy.access", "the centerlines have no access end"))?;
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

/// What `cathlab case` is asked to do besides reading its input.
#[derive(Debug, Clone, PartialEq)]
pub struct CaseOptions {
    /// The surface's length unit (volumes carry their own).
    pub unit: Option<LengthUnit>,
    /// The surface's placement into LPS.
    pub placement: Placement,
    /// Where devices enter a surface.
    pub access: AccessChoice,
    /// The target: the vessel whose free end is nearest this LPS point (mm); by default the
    /// free end farthest along the vessels from the access.
    pub target_near_mm: Option<[f64; 3]>,
    /// A volume's seed inside a contrast-filled vessel.
    pub seed: Option<crate::segment::Seed>,
    /// A DICOM folder's series (SeriesInstanceUID) when it holds several.
    pub series: Option<String>,
    /// Voxel size for centerlines computed from a surface (m).
    pub voxel_m: Option<f64>,
    /// Most voxels for centerlines computed from a surface (about 20 bytes each).
    pub max_voxels: usize,
    /// The scene's name (default: the output folder's name).
    pub name: Option<String>,
}

impl Default for CaseOptions {
    fn default() -> Self {
        Self {
            unit: None,
            placement: Placement::default(),
            access: AccessChoice::default(),
            target_near_mm: None,
            seed: None,
            series: None,
            voxel_m: None,
            max_voxels: SurfaceCenterlineSettings::default().max_voxels,
            name: None,
        }
    }
}

/// One open end as the report lists it (mm).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EndReport {
    /// Its index (`access = { end = i }`).
    pub index: usize,
    /// Centre (mm, LPS).
    pub centre_mm: [f64; 3],
    /// Mean radius (mm).
    pub radius_mm: f64,
}

/// One branch as the report lists it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BranchReport {
    /// Its name (`target.branch`, `anatomy.names`).
    pub name: String,
    /// Centerline length (mm).
    pub length_mm: f64,
    /// Median radius (mm).
    pub radius_mm: f64,
}

/// What `cathlab case` wrote.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CaseReport {
    /// The scene's name (its file is `<name>.toml`).
    pub name: String,
    /// "surface" or "volume".
    pub input_kind: String,
    /// Open ends found and capped.
    pub open_ends: Vec<EndReport>,
    /// The branches.
    pub branches: Vec<BranchReport>,
    /// The access point (mm, LPS).
    pub access_mm: [f64; 3],
    /// The target branch.
    pub target: String,
    /// The route from the access to the target's start (mm).
    pub route_mm: f64,
    /// The instruments written, outermost first (catalogue identifier or preset).
    pub instruments: [String; 2],
    /// The route's narrow lumen diameter the instruments were chosen for (mm).
    pub narrow_lumen_mm: f64,
    /// How far each instrument starts inserted (mm).
    pub inserted_mm: [f64; 2],
}

const SURFACE_EXTENSIONS: [&str; 4] = ["obj", "stl", "ply", "vtp"];

fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    std::fs::write(path, bytes).map_err(|source| ImagingError::Io {
        file: path.to_owned(),
        source,
    })
}

/// Turns `input` (a surface file, a volume file or a DICOM folder) into a scene in the
/// scenes folder `out`, which `cathlab-server --scenes out` serves unchanged: `<name>.toml`,
/// and in `<name>/` the surface, `graph.json` (the centerlines the scene loads),
/// `centerlines.vtp`, `preview.png`, `report.json`, and for a volume `ct.mha` (HU). The
/// name is the input's (sanitized) unless given.
pub fn write_case(input: &Path, options: &CaseOptions, out: &Path) -> Result<CaseReport> {
    let name = options.name.clone().unwrap_or_else(|| {
        let stem = input
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let stem = stem.split('.').next().unwrap_or_default();
        let clean: String = stem
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '-' {
                    c
                } else {
                    '_'
                }
            })
            .take(64)
            .collect();
        if clean.is_empty() {
            "case".into()
        } else {
            clean
        }
    });
    if name.is_empty()
        || name.len() > 64
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
    {
        return Err(field(
            "name",
            format!("{name:?}: a scene name is 1–64 letters, digits, '_' or '-'"),
        ));
    }
    let files = out.join(&name);
    std::fs::create_dir_all(&files).map_err(|source| ImagingError::Io {
        file: files.clone(),
        source,
    })?;
    let extension = input
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let is_surface = SURFACE_EXTENSIONS.contains(&extension.as_str());
    let (surface_file, unit, placement, mesh, ends, graph, ct) = if is_surface {
        let unit = options.unit.unwrap_or(LengthUnit::Mm);
        let file = format!("{name}/surface.{extension}");
        std::fs::copy(input, out.join(&file)).map_err(|source| ImagingError::Io {
            file: input.to_owned(),
            source,
        })?;
        let loaded = load_surface_case(&SurfaceCase {
            surface: input.to_owned(),
            unit,
            placement: options.placement,
            centerlines: None,
            access: options.access,
            names: BTreeMap::new(),
            voxel_m: options.voxel_m,
            max_voxels: options.max_voxels,
        })?;
        let mesh = loaded.anatomy.lumen.mesh().clone();
        (
            file,
            unit,
            options.placement,
            mesh,
            loaded.open_ends,
            loaded.anatomy.graph,
            None,
        )
    } else {
        let volume = if input.is_dir() {
            crate::dicom::read_series(input, options.series.as_deref())?
        } else {
            crate::ScalarVolume::load(input)?
        };
        let seed = options.seed.ok_or_else(|| {
            field(
                "seed",
                "a volume needs a seed inside a contrast-filled vessel (--seed-voxel i,j,k or --seed x,y,z)",
            )
        })?;
        let segmentation =
            crate::segment::segment(&volume, &seed, &crate::segment::SegmentSettings::default())?;
        volume.write_metaimage(&files.join("ct.mha"))?;
        write_file(
            &files.join("surface.stl"),
            &io::stl::to_binary(&segmentation.surface, LengthUnit::Mm),
        )?;
        (
            format!("{name}/surface.stl"),
            LengthUnit::Mm,
            Placement::default(),
            segmentation.surface,
            Vec::new(),
            segmentation.graph,
            Some(format!("{name}/ct.mha")),
        )
    };
    let access = graph
        .landmarks
        .get("access")
        .copied()
        .ok_or_else(|| field("access", "the centerlines have no access end"))?;
    let target = match options.target_near_mm {
        Some(p) => branch_at_end(&graph, &Point3::from(Vector3::from(p) * 1e-3)),
        None => farthest_end(&graph).map(|(name, _)| name),
    }
    .ok_or_else(|| field("target", "the vessels have no free end to aim at"))?;
    let route = graph
        .path_to(&access, &target)
        .map_err(|e| field("target", e.to_string()))?;
    let target_length = graph.branch(&target)?.length() * 1e3;
    write_file(&files.join("graph.json"), graph.to_json().as_bytes())?;
    let lines: Vec<slicer::Centerline> = graph
        .branches
        .iter()
        .map(|b| slicer::Centerline {
            name: b.name.clone(),
            points: b.points.clone(),
            radii: b.radii.clone(),
        })
        .collect();
    write_file(
        &files.join("centerlines.vtp"),
        vtp::to_string(None, &lines, LengthUnit::Mm).as_bytes(),
    )?;
    let picture = crate::preview::preview(&mesh, &graph, &ends, &access, Some(&target));
    let png = files.join("preview.png");
    picture.save(&png).map_err(|e| ImagingError::Io {
        file: png,
        source: std::io::Error::other(e),
    })?;
    // Instruments that fit the route's narrow lumen, starting inside its first straight
    // stretch.
    let samples = graph.sample_path(&route, 1e-3);
    let narrow_m = crate::instruments::narrow_radius_m(&samples);
    let (pair, catheter_outer_mm) = crate::instruments::choose_pair(narrow_m)?;
    let reach_m = crate::instruments::straight_reach_m(&samples, catheter_outer_mm * 0.5e-3);
    // The shaped wire stands out of the catheter only as far as its bend clears the wall of
    // the narrowest lumen along that straight stretch (or a straight wire where it cannot).
    let start_lumen_m = samples
        .iter()
        .take((reach_m * 1e3) as usize + 1)
        .map(|(_, r)| *r)
        .fold(f64::INFINITY, f64::min);
    let plan = crate::instruments::start_plan(&pair, reach_m, start_lumen_m);
    let [catheter_in, wire_in] = plan.inserted_mm;
    // The scripted operator's distances fit the target branch: the wire 80 % of the way
    // in, the catheter tracked half-way between the target depth and the wire's tip.
    let reach = (0.25 * target_length).clamp(1.0, 20.0);
    let wire_reach = (0.8 * target_length).clamp(reach + 2.0, 50.0);
    let track = (0.5 * (wire_reach - reach)).clamp(1.0, 15.0);
    let unit_name = match unit {
        LengthUnit::M => "m",
        LengthUnit::Cm => "cm",
        LengthUnit::Mm => "mm",
        LengthUnit::Um => "um",
    };
    let ct_section = match ct {
        Some(path) => format!("kind = \"file\"\npath = \"{path}\""),
        None => "kind = \"phantom\"\nspacing_mm = 2.0".to_owned(),
    };
    let input_name = input
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
        .replace(['"', '\\', '\n'], "_");
    let scene = format!(
        "# Written by `cathlab case` from {input_name}: {branches} branches, {ends} open ends \
         capped.\n# {name}/preview.png shows the branch names; rename branches under [anatomy.names] \
         (vessel_03 = \"left_ica\")\n# and choose another target with [target] branch or \
         end_near_mm.\ndescription = \"{name}: a case from {input_name}\"\n\n[anatomy]\n\
         kind = \"surface\"\nfile = \"{surface_file}\"\nunit = \"{unit_name}\"\n\
         placement = {{ rotation_deg = [{r0:?}, {r1:?}, {r2:?}], translation_mm = [{t0:?}, \
         {t1:?}, {t2:?}] }}\ncenterlines = \"{name}/graph.json\"\n\n[anatomy.names]\n\n[ct]\n\
         {ct_section}\n\n# Outermost first: {label}.\n# The route's narrow lumen is \
         {narrow_mm:.1} mm across; the first {reach_mm:.0} mm from the access are straight.\n\
         [[stack]]\n{catheter}\ninserted_mm = {catheter_in:.1}\n\n[[stack]]\n{wire}\n\
         inserted_mm = {wire_in:.1}\n\n[target]\nbranch = \"{target}\"\n\
         reach_mm = {reach:.1}\ninstrument = 0\n\n[autopilot]\nlookahead_mm = 20.0\n\
         wire_reach_mm = {wire_reach:.1}\ncatheter_lag_mm = 50.0\ncatheter_track_mm = \
         {track:.1}\n\n[fidelity]\nstep_rate_hz = 500\nframe_px = 512\n",
        label = pair.label,
        narrow_mm = 2e3 * narrow_m,
        reach_mm = reach_m * 1e3,
        catheter = pair.catheter,
        wire = plan.wire,
        branches = graph.branches.len(),
        ends = ends.len(),
        r0 = placement.rotation_deg[0],
        r1 = placement.rotation_deg[1],
        r2 = placement.rotation_deg[2],
        t0 = placement.translation_mm[0],
        t1 = placement.translation_mm[1],
        t2 = placement.translation_mm[2],
    );
    write_file(&out.join(format!("{name}.toml")), scene.as_bytes())?;
    let mm = |p: &Point3<f64>| [p.x * 1e3, p.y * 1e3, p.z * 1e3];
    let report = CaseReport {
        name,
        input_kind: if is_surface { "surface" } else { "volume" }.into(),
        open_ends: ends
            .iter()
            .map(|e| EndReport {
                index: e.index,
                centre_mm: mm(&e.centre),
                radius_mm: e.radius_m * 1e3,
            })
            .collect(),
        branches: graph
            .branches
            .iter()
            .map(|b| {
                let mut r = b.radii.clone();
                r.sort_by(f64::total_cmp);
                BranchReport {
                    name: b.name.clone(),
                    length_mm: b.length() * 1e3,
                    radius_mm: r[r.len() / 2] * 1e3,
                }
            })
            .collect(),
        access_mm: mm(&access),
        target,
        route_mm: route.length * 1e3,
        instruments: [pair.catheter_id.to_owned(), plan.wire_name.to_owned()],
        narrow_lumen_mm: 2e3 * narrow_m,
        inserted_mm: [catheter_in, wire_in],
    };
    write_file(
        &files.join("report.json"),
        serde_json::to_string_pretty(&report)
            .unwrap_or_default()
            .as_bytes(),
    )?;
    Ok(report)
}
