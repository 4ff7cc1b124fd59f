//! Lumen (vessel wall) queries for contact: signed distance, closest wall point and outward
//! normal, over a closed triangle surface or a vessel graph's implicit lumen.
//!
//! A surface's queries are exact, by either of two indexes: parry's BVH over the triangles,
//! and a narrow-band cell grid that lists, per cell, every triangle that can be closest to a
//! point in that cell (falling back to the BVH away from the wall). The grid is the default:
//! see the `lumen` benchmark for both. A generated anatomy, whose graph is the lumen, is
//! queried through its implicit field instead ([`crate::field_wall`]), with a light tube mesh
//! to show.

use nalgebra::{Point3, Vector3};
use parry3d_f64::query::{PointQuery, PointQueryWithLocation};
use parry3d_f64::shape::{TriMesh, TriMeshFlags};
use rayon::prelude::*;

use crate::error::{AnatomyError, Result};
use crate::field_wall::{FieldWall, FieldWallSettings};
use crate::glam_conv::{to_glam, to_point};
use crate::graph::VesselGraph;
use crate::mesh::TriangleMesh;
pub use crate::wall_query::{Proximity, WallQuery};

/// A lumen prepared for queries: a closed surface, or a vessel graph's implicit lumen with a
/// mesh to show.
pub struct Lumen {
    walls: Walls,
}

enum Walls {
    Surface(Box<MeshWall>),
    Field {
        wall: Box<FieldWall>,
        /// What is shown of it (not queried).
        display: TriangleMesh,
    },
}

/// A closed surface with its per-triangle tables and query indexes.
struct MeshWall {
    mesh: TriangleMesh,
    /// Vertex normals for interpolation (known normals if the mesh carries them).
    normals: Vec<Vector3<f64>>,
    /// Angle-weighted vertex pseudo-normals, for the inside test at vertices.
    pseudo_normals: Vec<Vector3<f64>>,
    /// Unit face normals.
    face_normals: Vec<Vector3<f64>>,
    /// Neighbouring triangle across edge k (corner k to corner k+1) of each triangle.
    neighbours: Vec<[u32; 3]>,
    /// Triangle corners stored contiguously for the candidate loop.
    corners: Vec<[Point3<f64>; 3]>,
    /// Edge pseudo-normals (sum of the two adjacent unit face normals), per triangle edge.
    edge_normals: Vec<[Vector3<f64>; 3]>,
    trimesh: TriMesh,
    grid: CellGrid,
}

/// How the narrow-band grid is laid out.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridSettings {
    /// Cell edge (m); `None` picks a quarter of the median triangle edge, kept between 0.1 and
    /// 2 mm.
    pub cell_size: Option<f64>,
    /// Cells whose centre is within this distance of the wall (m) keep a candidate list; the
    /// rest answer through the BVH (or as "far" for [`Lumen::proximity`]).
    pub band: f64,
}

impl Default for GridSettings {
    fn default() -> Self {
        Self {
            cell_size: None,
            band: 3e-3,
        }
    }
}

/// Cells along each edge of a grid block.
pub(crate) const BLOCK: usize = 8;

/// Most cells the default cell size allows near the wall (each a few µs to build).
const CELL_BUDGET: f64 = 400_000.0;
/// Most blocks a grid's box may have (its block table is allocated whole).
const MAX_BLOCKS: usize = 1 << 26;
/// `block_of` entry of a block that holds no cells.
pub(crate) const NO_BLOCK: u32 = u32::MAX;

/// One grid cell: its candidate triangles (a range of `CellGrid::candidates`) and how far
/// the wall is at least.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct CellEntry {
    pub(crate) start: u32,
    pub(crate) count: u32,
    /// A lower bound on the distance to the wall from any point of the cell (m), negative
    /// inside.
    pub(crate) far_bound: f32,
}

/// The narrow-band grid: blocks of `BLOCK`³ cells where the wall is near, each cell listing
/// the triangles that can be closest to a point in it.
#[derive(Debug, Default, PartialEq)]
pub(crate) struct CellGrid {
    pub(crate) origin: Point3<f64>,
    /// Cells per metre.
    pub(crate) inverse_cell: f64,
    pub(crate) blocks: [usize; 3],
    /// Per block of the box (x fastest), its slot in `cells` or `NO_BLOCK`.
    pub(crate) block_of: Vec<u32>,
    pub(crate) cells: Vec<CellEntry>,
    pub(crate) candidates: Vec<u32>,
    /// Distance from its cell's centre to each candidate, less the cell's half diagonal: a
    /// lower bound on the distance to it from any point of the cell (m, ascending per cell).
    pub(crate) candidate_bounds: Vec<f32>,
}

impl CellGrid {
    #[inline]
    fn entry(&self, p: &Point3<f64>) -> Option<&CellEntry> {
        let f = (p - self.origin) * self.inverse_cell;
        if !(f.x >= 0.0 && f.y >= 0.0 && f.z >= 0.0) {
            return None;
        }
        let (i, j, k) = (f.x as usize, f.y as usize, f.z as usize);
        let (bi, bj, bk) = (i / BLOCK, j / BLOCK, k / BLOCK);
        if bi >= self.blocks[0] || bj >= self.blocks[1] || bk >= self.blocks[2] {
            return None;
        }
        let block = self.block_of[(bk * self.blocks[1] + bj) * self.blocks[0] + bi];
        if block == NO_BLOCK {
            return None;
        }
        let local = ((k % BLOCK) * BLOCK + (j % BLOCK)) * BLOCK + (i % BLOCK);
        self.cells
            .get(block as usize * BLOCK * BLOCK * BLOCK + local)
    }
}

impl std::fmt::Debug for Lumen {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mesh = self.mesh();
        f.debug_struct("Lumen")
            .field("implicit", &matches!(self.walls, Walls::Field { .. }))
            .field("vertices", &mesh.vertices.len())
            .field("triangles", &mesh.triangles.len())
            .finish()
    }
}

impl Lumen {
    /// Heap bytes held (an estimate from the lengths of its arrays; a surface's BVH counted at
    /// two nodes per triangle): what the server's asset cache charges for it.
    pub fn memory_bytes(&self) -> usize {
        match &self.walls {
            Walls::Surface(m) => m.memory_bytes(),
            Walls::Field { wall, display } => {
                wall.memory_bytes()
                    + display.vertices.len() * 2 * std::mem::size_of::<Vector3<f64>>()
                    + display.triangles.len() * std::mem::size_of::<[u32; 3]>()
            }
        }
    }

    /// The implicit lumen of `graph` (a generated anatomy, whose graph is the lumen) as the
    /// wall, shown as tubes of `sides` vertices round.
    pub fn implicit(
        graph: &VesselGraph,
        settings: &FieldWallSettings,
        sides: usize,
    ) -> Result<Self> {
        Ok(Self {
            walls: Walls::Field {
                wall: Box::new(FieldWall::new(graph, settings)?),
                display: crate::tubes::tube_mesh(graph, sides),
            },
        })
    }

    /// True when the wall is a graph's implicit lumen (its mesh only shown).
    pub fn is_implicit(&self) -> bool {
        matches!(self.walls, Walls::Field { .. })
    }

    /// Prepares `mesh`, which must be a closed, consistently oriented 2-manifold; a surface
    /// whose faces all point into the lumen is flipped. `source` names it in errors. The query
    /// grid uses [`GridSettings::default`].
    pub fn new(mesh: TriangleMesh, source: &str) -> Result<Self> {
        Self::with_grid_settings(mesh, source, GridSettings::default())
    }

    /// As [`Lumen::new`] with the query grid built to `settings` (for example a narrower band
    /// for contact queries only, which builds much faster on finely meshed surfaces).
    pub fn with_grid_settings(
        mesh: TriangleMesh,
        source: &str,
        settings: GridSettings,
    ) -> Result<Self> {
        let mut wall = MeshWall::prepared(mesh, source)?;
        wall.grid = wall.build_grid(settings)?;
        Ok(Self::surface(wall))
    }

    fn surface(wall: MeshWall) -> Self {
        Self {
            walls: Walls::Surface(Box::new(wall)),
        }
    }

    /// `mesh` checked and its per-triangle tables built, with an empty grid (every query
    /// through the BVH).
    pub(crate) fn prepared(mesh: TriangleMesh, source: &str) -> Result<Self> {
        Ok(Self::surface(MeshWall::prepared(mesh, source)?))
    }

    /// The surface's narrow-band grid (for the stored form); `None` for an implicit wall.
    pub(crate) fn grid(&self) -> Option<&CellGrid> {
        match &self.walls {
            Walls::Surface(m) => Some(&m.grid),
            Walls::Field { .. } => None,
        }
    }

    /// Puts in a grid read back from the stored form, refusing one that does not fit this
    /// surface (an index past its arrays): a query never reads out of bounds.
    pub(crate) fn set_grid(&mut self, grid: CellGrid) -> std::result::Result<(), String> {
        match &mut self.walls {
            Walls::Surface(m) => m.set_grid(grid),
            Walls::Field { .. } => Err("an implicit wall has no grid".into()),
        }
    }

    /// Rebuilds a surface's narrow-band grid with other settings (an implicit wall has none:
    /// it is returned as it is).
    pub fn with_grid(mut self, settings: GridSettings) -> Result<Self> {
        if let Walls::Surface(m) = &mut self.walls {
            m.grid = m.build_grid(settings)?;
        }
        Ok(self)
    }

    /// Number of candidate triangles the grid holds for `point`'s cell (`None`: the query
    /// falls back to the BVH there, or the wall is implicit).
    pub fn grid_candidates(&self, point: &Point3<f64>) -> Option<usize> {
        match &self.walls {
            Walls::Surface(m) => m.grid_candidates(point),
            Walls::Field { .. } => None,
        }
    }

    /// Memory held by a surface's narrow-band grid (bytes; 0 for an implicit wall).
    pub fn grid_bytes(&self) -> usize {
        match &self.walls {
            Walls::Surface(m) => m.grid_bytes(),
            Walls::Field { .. } => 0,
        }
    }

    /// The query index in words: a surface's grid (cell size, cells, cells with candidates,
    /// candidates), or an implicit wall's cells and segments.
    pub fn grid_summary(&self) -> String {
        match &self.walls {
            Walls::Surface(m) => m.grid_summary(),
            Walls::Field { wall, .. } => {
                let (cells, listed, cell) = wall.field().index_summary();
                format!(
                    "implicit: cell {:.3} mm, {cells} cells, {listed} segments listed",
                    cell * 1e3
                )
            }
        }
    }

    /// The wall query for a point: exact on a surface (the grid's candidate triangles near
    /// the wall, the BVH elsewhere), the implicit field's Newton step on an implicit wall.
    #[inline]
    pub fn query(&self, point: &Point3<f64>) -> WallQuery {
        match &self.walls {
            Walls::Surface(m) => m.query(point),
            Walls::Field { wall, .. } => wall.query(point),
        }
    }

    /// The wall query if the wall is within `max_distance` (m) of `point`, else which side
    /// of the wall the point is on. Cheaper than [`Lumen::query`] far from the wall.
    #[inline]
    pub fn proximity(&self, point: &Point3<f64>, max_distance: f64) -> Proximity {
        match &self.walls {
            Walls::Surface(m) => m.proximity(point, max_distance),
            Walls::Field { wall, .. } => wall.proximity(point, max_distance),
        }
    }

    /// The surface (of an implicit wall, the mesh shown).
    pub fn mesh(&self) -> &TriangleMesh {
        match &self.walls {
            Walls::Surface(m) => &m.mesh,
            Walls::Field { display, .. } => display,
        }
    }

    /// Wall query for a point through parry's BVH (an implicit wall: [`Lumen::query`]).
    pub fn query_bvh(&self, point: &Point3<f64>) -> WallQuery {
        match &self.walls {
            Walls::Surface(m) => m.query_bvh(point),
            Walls::Field { wall, .. } => wall.query(point),
        }
    }
}

impl MeshWall {
    fn memory_bytes(&self) -> usize {
        use std::mem::size_of;
        let triangles = self.mesh.triangles.len();
        let vertices = self.mesh.vertices.len();
        vertices * (size_of::<Point3<f64>>() + 3 * size_of::<Vector3<f64>>())
            + triangles
                * (size_of::<[u32; 3]>() * 2
                    + size_of::<Vector3<f64>>()
                    + size_of::<[Point3<f64>; 3]>()
                    + size_of::<[Vector3<f64>; 3]>()
                    + 2 * 64)
            + self.grid.block_of.len() * size_of::<u32>()
            + self.grid.cells.len() * size_of::<CellEntry>()
            + self.grid.candidates.len() * size_of::<u32>()
            + self.grid.candidate_bounds.len() * size_of::<f32>()
    }

    /// `mesh` checked and its per-triangle tables built, with an empty grid (every query
    /// through the BVH).
    fn prepared(mut mesh: TriangleMesh, source: &str) -> Result<Self> {
        mesh.require_closed_manifold(source)?;
        let volume = mesh.enclosed_volume();
        if volume < 0.0 {
            mesh.flip();
        } else if volume == 0.0 {
            return Err(AnatomyError::NotManifold {
                file: source.to_owned(),
                message: "encloses no volume".into(),
            });
        }
        let vertices = mesh.vertices.iter().map(to_glam).collect();
        let trimesh = TriMesh::with_flags(vertices, mesh.triangles.clone(), TriMeshFlags::ORIENTED)
            .map_err(|e| AnatomyError::NotManifold {
                file: source.to_owned(),
                message: format!("parry rejected the surface: {e:?}"),
            })?;
        // Interpolation uses the best normals known; the sign test needs true pseudo-normals.
        let normals = mesh.best_vertex_normals();
        let pseudo_normals = mesh.vertex_normals();
        let face_normals: Vec<Vector3<f64>> = mesh
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = mesh.corners(t);
                (b - a)
                    .cross(&(c - a))
                    .try_normalize(0.0)
                    .unwrap_or_else(Vector3::zeros)
            })
            .collect();
        let mut edge_faces: std::collections::HashMap<(u32, u32), Vec<usize>> =
            std::collections::HashMap::with_capacity(mesh.triangles.len() * 2);
        for (f, t) in mesh.triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                edge_faces.entry((a.min(b), a.max(b))).or_default().push(f);
            }
        }
        let edge_normals = mesh
            .triangles
            .iter()
            .map(|t| {
                std::array::from_fn(|k| {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    edge_faces[&(a.min(b), a.max(b))]
                        .iter()
                        .map(|&f| face_normals[f])
                        .sum::<Vector3<f64>>()
                })
            })
            .collect();
        let corners = mesh.triangles.iter().map(|t| mesh.corners(t)).collect();
        let neighbours = mesh
            .triangles
            .iter()
            .enumerate()
            .map(|(f, t)| {
                std::array::from_fn(|k| {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    edge_faces[&(a.min(b), a.max(b))]
                        .iter()
                        .find(|&&g| g != f)
                        .map_or(u32::MAX, |&g| g as u32)
                })
            })
            .collect();
        Ok(Self {
            mesh,
            normals,
            pseudo_normals,
            face_normals,
            neighbours,
            corners,
            edge_normals,
            trimesh,
            grid: CellGrid::default(),
        })
    }

    /// Puts in a grid read back from the stored form, refusing one that does not fit this
    /// surface (an index past its arrays): a query never reads out of bounds.
    fn set_grid(&mut self, grid: CellGrid) -> std::result::Result<(), String> {
        let per_block = BLOCK * BLOCK * BLOCK;
        let finite = grid.inverse_cell.is_finite()
            && grid.inverse_cell > 0.0
            && grid.origin.iter().all(|c| c.is_finite());
        if !finite {
            return Err("grid origin or cell size not finite".into());
        }
        let total = grid
            .blocks
            .iter()
            .try_fold(1usize, |a, &b| a.checked_mul(b));
        if total != Some(grid.block_of.len()) || grid.block_of.len() > MAX_BLOCKS {
            return Err("grid block table does not match its dimensions".into());
        }
        if !grid.cells.len().is_multiple_of(per_block) {
            return Err("grid cells are not whole blocks".into());
        }
        let slots = grid.cells.len() / per_block;
        if grid
            .block_of
            .iter()
            .any(|&b| b != NO_BLOCK && b as usize >= slots)
        {
            return Err("grid block table names a block past the cells".into());
        }
        if grid.candidate_bounds.len() != grid.candidates.len() {
            return Err("grid candidate bounds do not match the candidates".into());
        }
        if grid
            .cells
            .iter()
            .any(|c| c.start as usize + c.count as usize > grid.candidates.len())
        {
            return Err("grid cell lists run past the candidates".into());
        }
        let triangles = self.mesh.triangles.len();
        if grid.candidates.iter().any(|&t| t as usize >= triangles) {
            return Err("grid names a triangle past the surface".into());
        }
        self.grid = grid;
        Ok(())
    }

    fn build_grid(&self, settings: GridSettings) -> Result<CellGrid> {
        let band = crate::error::require_positive("band", settings.band)?;
        let cell = match settings.cell_size {
            Some(c) => crate::error::require_positive("cell_size", c)?,
            None => {
                let mut edges: Vec<f64> = self
                    .mesh
                    .triangles
                    .iter()
                    .map(|t| {
                        let [a, b, _] = self.mesh.corners(t);
                        (b - a).norm()
                    })
                    .collect();
                edges.sort_by(f64::total_cmp);
                // A quarter of the median edge, but no finer than keeps the cells within
                // the band of the wall (about area · 2 · (band + a block) / cell³) under
                // the budget: a finely meshed surface does not need a finer grid, only
                // longer candidate lists.
                let area = self.mesh.surface_area();
                let mut by_budget = 1e-4_f64;
                while by_budget < 2e-3
                    && area * 2.0 * (band + BLOCK as f64 * by_budget) / by_budget.powi(3)
                        > CELL_BUDGET
                {
                    by_budget *= 1.05;
                }
                (0.25 * edges[edges.len() / 2])
                    .max(by_budget)
                    .clamp(1e-4, 2e-3)
            }
        };
        let (lo, hi) = self.mesh.bounding_box();
        let pad = Vector3::repeat(band + cell);
        let origin = lo - pad;
        let extent = (hi + pad) - origin;
        let block_size = cell * BLOCK as f64;
        let blocks = [
            (extent.x / block_size).ceil() as usize,
            (extent.y / block_size).ceil() as usize,
            (extent.z / block_size).ceil() as usize,
        ];
        let total_blocks = blocks[0] * blocks[1] * blocks[2];
        if total_blocks > MAX_BLOCKS {
            return Err(AnatomyError::InvalidParameter {
                name: "cell_size",
                value: cell,
                requirement: "large enough that the grid has at most 2^26 blocks",
            });
        }
        // Blocks touched by any triangle's box grown by the band.
        let mut block_of = vec![NO_BLOCK; total_blocks];
        let mut allocated = 0u32;
        for t in &self.mesh.triangles {
            let [a, b, c] = self.mesh.corners(t);
            let tlo = a.inf(&b).inf(&c) - Vector3::repeat(band);
            let thi = a.sup(&b).sup(&c) + Vector3::repeat(band);
            let b0 = ((tlo - origin) / block_size).map(|v| v.max(0.0) as usize);
            let b1 = ((thi - origin) / block_size).map(|v| v.max(0.0) as usize);
            for bk in b0.z..=b1.z.min(blocks[2] - 1) {
                for bj in b0.y..=b1.y.min(blocks[1] - 1) {
                    for bi in b0.x..=b1.x.min(blocks[0] - 1) {
                        let slot = &mut block_of[(bk * blocks[1] + bj) * blocks[0] + bi];
                        if *slot == NO_BLOCK {
                            *slot = allocated;
                            allocated += 1;
                        }
                    }
                }
            }
        }
        let per_block = BLOCK * BLOCK * BLOCK;
        let half_diagonal = 0.5 * cell * 3f64.sqrt();
        // The allocated blocks in slot order, each built on its own (in parallel).
        let mut slots = vec![0usize; allocated as usize];
        for (linear, &slot) in block_of.iter().enumerate() {
            if slot != NO_BLOCK {
                slots[slot as usize] = linear;
            }
        }
        // Blocks are built in parallel a chunk at a time and appended in slot order, so that
        // only one chunk's lists are held twice and the lists grow to their exact size.
        let build_block = |&linear: &usize| {
            let (bi, bj, bk) = (
                linear % blocks[0],
                (linear / blocks[0]) % blocks[1],
                linear / (blocks[0] * blocks[1]),
            );
            let mut cells = vec![CellEntry::default(); per_block];
            let mut candidates = Vec::new();
            let mut candidate_bounds = Vec::new();
            for (local, entry) in cells.iter_mut().enumerate() {
                let (i, j, k) = (
                    local % BLOCK,
                    (local / BLOCK) % BLOCK,
                    local / (BLOCK * BLOCK),
                );
                let center = origin
                    + Vector3::new(
                        (bi * BLOCK + i) as f64 + 0.5,
                        (bj * BLOCK + j) as f64 + 0.5,
                        (bk * BLOCK + k) as f64 + 0.5,
                    ) * cell;
                let signed = self.signed_distance_bvh(&center);
                let d = signed.abs();
                // A lower bound on the wall distance anywhere in the cell, rounded down.
                entry.far_bound = (((d - half_diagonal).max(0.0) * (1.0 - 1e-6)) as f32)
                    * if signed < 0.0 { -1.0 } else { 1.0 };
                if d > band {
                    continue;
                }
                let reach = d + 2.0 * half_diagonal;
                let g = to_glam(&center);
                // Block-local start; made global when the blocks are joined.
                entry.start = candidates.len() as u32;
                // Nearest first, so that the query's plane test culls the rest early.
                let mut near: Vec<(f64, u32)> = self
                    .trimesh
                    .bvh()
                    .leaves(|node| node.aabb().distance_to_local_point(g, true) <= reach)
                    .filter_map(|leaf| {
                        let [a, b, c] = self.corners[leaf as usize];
                        let (q, _) = closest_on_triangle(&center, &a, &b, &c);
                        let d = (center - q).norm();
                        (d <= reach).then_some((d, leaf))
                    })
                    .collect();
                near.sort_by(|x, y| x.0.total_cmp(&y.0));
                candidates.extend(near.iter().map(|&(_, leaf)| leaf));
                // Rounded down, so that it stays a lower bound in f32.
                candidate_bounds.extend(
                    near.iter()
                        .map(|&(d, _)| ((d - half_diagonal).max(0.0) * (1.0 - 1e-6)) as f32),
                );
                entry.count = candidates.len() as u32 - entry.start;
            }
            (cells, candidates, candidate_bounds)
        };
        let mut cells = Vec::with_capacity(allocated as usize * per_block);
        let mut candidates: Vec<u32> = Vec::new();
        let mut candidate_bounds: Vec<f32> = Vec::new();
        for chunk in slots.chunks(64) {
            let built: Vec<(Vec<CellEntry>, Vec<u32>, Vec<f32>)> =
                chunk.par_iter().map(build_block).collect();
            let more: usize = built.iter().map(|b| b.1.len()).sum();
            candidates.reserve_exact(more);
            candidate_bounds.reserve_exact(more);
            for (block_cells, block_candidates, block_bounds) in built {
                if candidates.len() + block_candidates.len() > u32::MAX as usize {
                    return Err(AnatomyError::InvalidParameter {
                        name: "cell_size",
                        value: cell,
                        requirement: "large enough that the grid holds at most 2^32 candidates",
                    });
                }
                let offset = candidates.len() as u32;
                cells.extend(block_cells.into_iter().map(|mut e| {
                    if e.count > 0 {
                        e.start += offset;
                    }
                    e
                }));
                candidates.extend(block_candidates);
                candidate_bounds.extend(block_bounds);
            }
        }
        Ok(CellGrid {
            origin,
            inverse_cell: 1.0 / cell,
            blocks,
            block_of,
            cells,
            candidates,
            candidate_bounds,
        })
    }

    /// Number of candidate triangles the grid holds for `point`'s cell (`None`: the query
    /// falls back to the BVH there).
    fn grid_candidates(&self, point: &Point3<f64>) -> Option<usize> {
        self.grid
            .entry(point)
            .filter(|e| e.count > 0)
            .map(|e| e.count as usize)
    }

    /// Memory held by the narrow-band grid (bytes).
    fn grid_bytes(&self) -> usize {
        self.grid.block_of.len() * 4
            + self.grid.cells.len() * std::mem::size_of::<CellEntry>()
            + self.grid.candidates.len() * 8
    }

    /// The grid in words: cell size, cells, cells with candidates, candidates.
    fn grid_summary(&self) -> String {
        let listed = self.grid.cells.iter().filter(|c| c.count > 0).count();
        format!(
            "cell {:.3} mm, {} cells ({} with candidates), {} candidates ({:.1} per listed cell)",
            1e3 / self.grid.inverse_cell,
            self.grid.cells.len(),
            listed,
            self.grid.candidates.len(),
            self.grid.candidates.len() as f64 / listed.max(1) as f64
        )
    }

    /// Exact wall query for a point: the grid's candidate triangles near the wall, the BVH
    /// elsewhere.
    #[inline]
    fn query(&self, point: &Point3<f64>) -> WallQuery {
        match self.grid.entry(point) {
            Some(e) if e.count > 0 => {
                let range = e.start as usize..(e.start + e.count) as usize;
                let list = &self.grid.candidates[range.clone()];
                let bounds = &self.grid.candidate_bounds[range];
                self.query_candidates(point, list, bounds)
            }
            _ => self.query_bvh(point),
        }
    }

    /// The wall query if the wall is within `max_distance` (m) of `point`, else which side
    /// of the wall the point is on.
    #[inline]
    fn proximity(&self, point: &Point3<f64>, max_distance: f64) -> Proximity {
        if let Some(e) = self.grid.entry(point)
            && f64::from(e.far_bound.abs()) > max_distance
        {
            return Proximity::Far {
                inside: e.far_bound < 0.0,
            };
        }
        let q = self.query(point);
        if q.signed_distance.abs() <= max_distance {
            Proximity::Near(q)
        } else {
            Proximity::Far { inside: q.inside() }
        }
    }

    fn query_candidates(&self, point: &Point3<f64>, list: &[u32], bounds: &[f32]) -> WallQuery {
        let mut best = (f64::INFINITY, Point3::origin(), Feature::Face, 0u32);
        for (&t, &bound) in list.iter().zip(bounds) {
            // Ascending lower bounds: no later candidate can be nearer.
            let bound = f64::from(bound);
            if bound * bound >= best.0 {
                break;
            }
            let [a, b, c] = &self.corners[t as usize];
            // The distance to the triangle's plane bounds the distance to the triangle.
            let plane = (point - a).dot(&self.face_normals[t as usize]);
            if plane * plane >= best.0 {
                continue;
            }
            let (q, feature) = closest_on_triangle(point, a, b, c);
            let d2 = (point - q).norm_squared();
            if d2 < best.0 {
                best = (d2, q, feature, t);
            }
        }
        let (d2, closest, feature, t) = best;
        let tri = self.mesh.triangles[t as usize];
        let pseudo = match feature {
            Feature::Face => self.face_normals[t as usize],
            Feature::Edge(k) => self.edge_normals[t as usize][k as usize],
            Feature::Vertex(k) => self.pseudo_normals[tri[k as usize] as usize],
        };
        let inside = (point - closest).dot(&pseudo) <= 0.0;
        let distance = d2.sqrt();
        WallQuery {
            signed_distance: if inside { -distance } else { distance },
            closest_wall_point: closest,
            outward_normal: self.smooth_normal(t, point, &closest),
            triangle: t,
        }
    }

    /// Wall query for a point through parry's BVH.
    fn query_bvh(&self, point: &Point3<f64>) -> WallQuery {
        let (projection, (triangle, _)) = self
            .trimesh
            .project_local_point_and_get_location(to_glam(point), false);
        let closest = to_point(projection.point);
        let distance = (point - closest).norm();
        WallQuery {
            signed_distance: if projection.is_inside {
                -distance
            } else {
                distance
            },
            closest_wall_point: closest,
            outward_normal: self.smooth_normal(triangle, point, &closest),
            triangle,
        }
    }

    /// Signed distance (m, negative inside) from `point` to the wall through parry's BVH:
    /// [`Self::query_bvh`] without the smoothed normal, which most of a query's time goes to
    /// near the wall and which the grid's build, asking at every cell, does not use.
    fn signed_distance_bvh(&self, point: &Point3<f64>) -> f64 {
        let projection = self.trimesh.project_local_point(to_glam(point), false);
        let distance = (point - to_point(projection.point)).norm();
        if projection.is_inside {
            -distance
        } else {
            distance
        }
    }

    /// Unit outward normal for a query at `point` whose closest wall point lies on
    /// `triangle`: the vertex normals interpolated at the spot of the wall whose interpolated
    /// normal passes through `point` (Phong projection), so the normal follows the smooth
    /// wall rather than the facets. Newton's method on the spot's barycentric coordinates
    /// and the distance along the normal, walking across triangle edges: 2–3 iterations near
    /// the wall, where the fixed point it replaced (step to where the line along the normal
    /// meets the triangle's plane) took 6–12 and was a fifth of a step held against a dead
    /// end.
    fn smooth_normal(
        &self,
        triangle: u32,
        point: &Point3<f64>,
        closest: &Point3<f64>,
    ) -> Vector3<f64> {
        let mut tri = triangle as usize;
        let mut x = *closest;
        let mut normal = self.face_normals[tri];
        for _ in 0..12 {
            let Some((bary, interpolated)) = self.phong_at(tri, &x) else {
                break;
            };
            // Outside this triangle: step across the edge facing the most negative weight.
            let (worst, most_negative) =
                bary.iter().enumerate().fold(
                    (0, 0.0),
                    |acc, (k, &b)| if b < acc.1 { (k, b) } else { acc },
                );
            if most_negative < -1e-9 {
                let next = self.neighbours[tri][(worst + 1) % 3];
                if next == u32::MAX {
                    break;
                }
                tri = next as usize;
                continue;
            }
            let Some(n) = interpolated.try_normalize(0.0) else {
                break;
            };
            normal = n;
            if n.dot(&self.face_normals[tri]).abs() < 0.5 {
                break;
            }
            // F(v, w, s) = a + v·e0 + w·e1 + s·ñ(v, w) − point, with ñ the unnormalized
            // interpolated normal (linear in v, w), from the s that best fits the current spot.
            let t = self.mesh.triangles[tri];
            let [a, b, c] = self.corners[tri];
            let n0 = self.normals[t[0] as usize];
            let (d1, d2) = (
                self.normals[t[1] as usize] - n0,
                self.normals[t[2] as usize] - n0,
            );
            let (e0, e1) = (b - a, c - a);
            // The spot in this triangle's plane (after a walk across an edge it lay in the
            // last one's).
            let spot = a + e0 * bary[1] + e1 * bary[2];
            let along = (point - spot).dot(&interpolated) / interpolated.norm_squared();
            let residual = spot + interpolated * along - point;
            // The Newton step J·δ = −F by Cramer's rule (δ's first two entries: the spot's).
            let (jv, jw) = (e0 + d1 * along, e1 + d2 * along);
            let det = jv.dot(&jw.cross(&interpolated));
            if !det.is_normal() {
                break;
            }
            let delta_v = -residual.dot(&jw.cross(&interpolated)) / det;
            let delta_w = -jv.dot(&residual.cross(&interpolated)) / det;
            let step = e0 * delta_v + e1 * delta_w;
            x = spot + step;
            if step.norm_squared() < 1e-24 {
                break;
            }
        }
        normal
    }

    /// The barycentric coordinates in `triangle` of `x` (projected onto its plane) and the
    /// vertex normals interpolated there (unnormalized); None for a degenerate triangle.
    fn phong_at(&self, triangle: usize, x: &Point3<f64>) -> Option<([f64; 3], Vector3<f64>)> {
        let t = self.mesh.triangles[triangle];
        let [a, b, c] = self.corners[triangle];
        let (v0, v1, v2) = (b - a, c - a, x - a);
        let (d00, d01, d11) = (v0.dot(&v0), v0.dot(&v1), v1.dot(&v1));
        let denom = d00 * d11 - d01 * d01;
        if denom <= 0.0 || self.face_normals[triangle] == Vector3::zeros() {
            return None;
        }
        let (d20, d21) = (v2.dot(&v0), v2.dot(&v1));
        let v = (d11 * d20 - d01 * d21) / denom;
        let w = (d00 * d21 - d01 * d20) / denom;
        let bary = [1.0 - v - w, v, w];
        let interpolated = self.normals[t[0] as usize] * bary[0]
            + self.normals[t[1] as usize] * bary[1]
            + self.normals[t[2] as usize] * bary[2];
        Some((bary, interpolated))
    }
}

/// Which feature of a triangle a closest point lies on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Feature {
    /// Interior of the face.
    Face,
    /// Edge k runs from corner k to corner (k+1) mod 3.
    Edge(u8),
    /// Corner k.
    Vertex(u8),
}

/// Closest point on triangle (a, b, c) to p and the feature it lies on
/// (Ericson, *Real-Time Collision Detection*, §5.1.5).
pub(crate) fn closest_on_triangle(
    p: &Point3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> (Point3<f64>, Feature) {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (*a, Feature::Vertex(0));
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (*b, Feature::Vertex(1));
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (a + ab * v, Feature::Edge(0));
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (*c, Feature::Vertex(2));
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (a + ac * w, Feature::Edge(2));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (b + (c - b) * w, Feature::Edge(1));
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    (a + ab * v + ac * w, Feature::Face)
}

#[cfg(test)]
mod tests;
