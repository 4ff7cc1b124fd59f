//! The vessel graph: named branches (centerline polylines with a radius per point,
//! arc-length parameterised) joined at junction nodes; point-on-graph queries and path finding.

use std::collections::{BTreeMap, BinaryHeap};

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::components::count_components;
use crate::error::{AnatomyError, Result};

/// How many times its length a communicating artery counts in [`VesselGraph::path_to`].
pub const COMMUNICATING_ROUTE_WEIGHT: f64 = 20.0;

/// Distance (m) within which branch end points are taken to be the same junction.
pub const NODE_MERGE_TOLERANCE_M: f64 = 1e-6;

/// Which side of the body a vessel is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Side {
    /// Patient's left.
    Left,
    /// Patient's right.
    Right,
    /// Unpaired vessels (aorta, basilar, anterior communicating).
    Midline,
}

/// Anatomical identity of a branch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VesselKind {
    /// Ascending aorta, arch or descending aorta.
    Aorta,
    /// Brachiocephalic trunk.
    Brachiocephalic,
    /// Subclavian artery.
    Subclavian,
    /// Common carotid artery.
    CommonCarotid,
    /// Internal carotid artery (including the siphon).
    InternalCarotid,
    /// External carotid artery.
    ExternalCarotid,
    /// Vertebral artery.
    Vertebral,
    /// Basilar artery.
    Basilar,
    /// Anterior cerebral artery.
    AnteriorCerebral,
    /// Middle cerebral artery.
    MiddleCerebral,
    /// Posterior cerebral artery.
    PosteriorCerebral,
    /// Anterior communicating artery.
    AnteriorCommunicating,
    /// Posterior communicating artery.
    PosteriorCommunicating,
    /// Anything else (test phantoms, unnamed imports).
    Other,
}

/// Index of a junction node.
pub type NodeId = usize;
/// Index of a branch.
pub type BranchId = usize;

/// A vessel segment between two junction nodes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Branch {
    /// Unique name, e.g. `left_common_carotid`.
    pub name: String,
    /// Anatomical identity.
    pub kind: VesselKind,
    /// Body side.
    pub side: Side,
    /// Node at the first centerline point.
    pub start: NodeId,
    /// Node at the last centerline point.
    pub end: NodeId,
    /// Centerline points (m), at least two, no two consecutive points equal.
    pub points: Vec<Point3<f64>>,
    /// Lumen radius at each centerline point (m).
    pub radii: Vec<f64>,
    /// Cumulative arc length at each point (m); first is 0.
    #[serde(skip)]
    arc: Vec<f64>,
}

/// What a new branch is made of.
#[derive(Debug, Clone, PartialEq)]
pub struct BranchSpec {
    /// Unique name.
    pub name: String,
    /// Anatomical identity.
    pub kind: VesselKind,
    /// Body side.
    pub side: Side,
    /// Centerline points (m).
    pub points: Vec<Point3<f64>>,
    /// Radius per point (m).
    pub radii: Vec<f64>,
}

impl Branch {
    /// Total centerline length (m).
    pub fn length(&self) -> f64 {
        *self.arc.last().unwrap_or(&0.0)
    }

    /// Cumulative arc length per point (m).
    pub fn arc_lengths(&self) -> &[f64] {
        &self.arc
    }

    /// Segment index and fraction for arc length `s` (clamped to the branch).
    fn locate(&self, s: f64) -> (usize, f64) {
        let s = s.clamp(0.0, self.length());
        let i = match self.arc.binary_search_by(|a| a.total_cmp(&s)) {
            Ok(i) => i.min(self.points.len() - 2),
            Err(i) => i.saturating_sub(1).min(self.points.len() - 2),
        };
        let len = self.arc[i + 1] - self.arc[i];
        (
            i,
            if len > 0.0 {
                (s - self.arc[i]) / len
            } else {
                0.0
            },
        )
    }

    /// Centerline point at arc length `s` (m), linearly interpolated.
    pub fn point_at(&self, s: f64) -> Point3<f64> {
        let (i, t) = self.locate(s);
        self.points[i] + (self.points[i + 1] - self.points[i]) * t
    }

    /// Radius at arc length `s` (m), linearly interpolated.
    pub fn radius_at(&self, s: f64) -> f64 {
        let (i, t) = self.locate(s);
        self.radii[i] + (self.radii[i + 1] - self.radii[i]) * t
    }

    /// Unit tangent (towards increasing arc length) at `s`.
    pub fn direction_at(&self, s: f64) -> Vector3<f64> {
        let (i, _) = self.locate(s);
        (self.points[i + 1] - self.points[i]).normalize()
    }

    fn rebuild_arc(&mut self) {
        self.arc.clear();
        self.arc.push(0.0);
        for w in self.points.windows(2) {
            let last = *self.arc.last().unwrap_or(&0.0);
            self.arc.push(last + (w[1] - w[0]).norm());
        }
    }
}

/// A place on the graph: the closest centerline point to a query.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GraphLocation {
    /// The branch.
    pub branch: BranchId,
    /// Arc length along it (m).
    pub arc_length: f64,
    /// The centerline point (m).
    pub position: Point3<f64>,
    /// Distance from the query to the centerline (m).
    pub distance: f64,
    /// Lumen radius there (m).
    pub radius: f64,
    /// Unit centerline direction there.
    pub direction: Vector3<f64>,
}

/// One stretch of a path: a branch walked from one arc length to another.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathLeg {
    /// The branch.
    pub branch: BranchId,
    /// Where the leg enters the branch (m of arc length).
    pub from_arc: f64,
    /// Where it leaves (m); smaller than `from_arc` when walked against the branch direction.
    pub to_arc: f64,
}

/// A route through the vessel tree.
#[derive(Debug, Clone, PartialEq)]
pub struct VesselPath {
    /// The legs in order.
    pub legs: Vec<PathLeg>,
    /// Total length (m).
    pub length: f64,
}

/// Named branches joined at junctions, plus named landmarks (access point, targets).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct VesselGraph {
    /// Junction and end node positions (m).
    pub nodes: Vec<Point3<f64>>,
    /// The branches.
    pub branches: Vec<Branch>,
    /// Named points (m), e.g. `access` where devices enter.
    pub landmarks: BTreeMap<String, Point3<f64>>,
}

impl VesselGraph {
    /// An empty graph.
    pub fn new() -> Self {
        Self::default()
    }

    /// The node at `position`, reusing one within [`NODE_MERGE_TOLERANCE_M`].
    pub fn node_at(&mut self, position: Point3<f64>) -> NodeId {
        if let Some(i) = self
            .nodes
            .iter()
            .position(|n| (n - position).norm() <= NODE_MERGE_TOLERANCE_M)
        {
            return i;
        }
        self.nodes.push(position);
        self.nodes.len() - 1
    }

    /// Adds a branch; its end points join existing nodes within [`NODE_MERGE_TOLERANCE_M`].
    pub fn add_branch(&mut self, spec: BranchSpec) -> Result<BranchId> {
        let BranchSpec {
            name,
            kind,
            side,
            points,
            radii,
        } = spec;
        if self.branches.iter().any(|b| b.name == name) {
            return Err(AnatomyError::InvalidGraph(format!(
                "two branches named {name:?}"
            )));
        }
        if points.len() < 2 {
            return Err(AnatomyError::InvalidGraph(format!(
                "branch {name:?} has {} centerline points (at least 2 needed)",
                points.len()
            )));
        }
        if radii.len() != points.len() {
            return Err(AnatomyError::InvalidGraph(format!(
                "branch {name:?} has {} points but {} radii",
                points.len(),
                radii.len()
            )));
        }
        if let Some(i) = points
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            return Err(AnatomyError::InvalidGraph(format!(
                "branch {name:?} point {i} is not finite"
            )));
        }
        if let Some(i) = radii.iter().position(|r| !(r.is_finite() && *r > 0.0)) {
            return Err(AnatomyError::InvalidGraph(format!(
                "branch {name:?} radius {i} is {} (must be finite and > 0)",
                radii[i]
            )));
        }
        // Drop repeated points (zero-length segments), keeping the first radius.
        let mut clean_points: Vec<Point3<f64>> = Vec::with_capacity(points.len());
        let mut clean_radii = Vec::with_capacity(points.len());
        for (p, r) in points.into_iter().zip(radii) {
            if clean_points.last().is_some_and(|q| (p - q).norm() <= 1e-12) {
                continue;
            }
            clean_points.push(p);
            clean_radii.push(r);
        }
        if clean_points.len() < 2 {
            return Err(AnatomyError::InvalidGraph(format!(
                "branch {name:?} has zero length"
            )));
        }
        let start = self.node_at(clean_points[0]);
        let end = self.node_at(*clean_points.last().unwrap_or(&clean_points[0]));
        if start == end && clean_points.len() < 3 {
            return Err(AnatomyError::InvalidGraph(format!(
                "branch {name:?} starts and ends at the same node"
            )));
        }
        let mut branch = Branch {
            name,
            kind,
            side,
            start,
            end,
            points: clean_points,
            radii: clean_radii,
            arc: Vec::new(),
        };
        branch.rebuild_arc();
        self.branches.push(branch);
        Ok(self.branches.len() - 1)
    }

    /// Recomputes derived data (arc lengths) after deserialisation or direct edits, and
    /// checks the graph's invariants.
    pub fn finish(mut self) -> Result<Self> {
        let specs: Vec<_> = std::mem::take(&mut self.branches);
        let nodes = std::mem::take(&mut self.nodes);
        let landmarks = std::mem::take(&mut self.landmarks);
        let mut graph = VesselGraph {
            nodes: Vec::new(),
            branches: Vec::new(),
            landmarks,
        };
        for b in specs {
            if b.start >= nodes.len() || b.end >= nodes.len() {
                return Err(AnatomyError::InvalidGraph(format!(
                    "branch {:?} refers to node {} but there are {} nodes",
                    b.name,
                    b.start.max(b.end),
                    nodes.len()
                )));
            }
            let (first, last) = (b.points.first().copied(), b.points.last().copied());
            for (node, point, which) in [(b.start, first, "start"), (b.end, last, "end")] {
                if point.is_some_and(|p| (nodes[node] - p).norm() > 1e-6 * (1.0 + p.coords.norm()))
                {
                    return Err(AnatomyError::InvalidGraph(format!(
                        "branch {:?}: its {which} node {node} is not at its {which} point",
                        b.name
                    )));
                }
            }
            graph.add_branch(BranchSpec {
                name: b.name,
                kind: b.kind,
                side: b.side,
                points: b.points,
                radii: b.radii,
            })?;
        }
        Ok(graph)
    }

    /// The branch with this name.
    pub fn branch_id(&self, name: &str) -> Result<BranchId> {
        self.branches
            .iter()
            .position(|b| b.name == name)
            .ok_or_else(|| AnatomyError::UnknownBranch(name.to_owned()))
    }

    /// The branch with this name.
    pub fn branch(&self, name: &str) -> Result<&Branch> {
        Ok(&self.branches[self.branch_id(name)?])
    }

    /// Branches meeting at each node (1 at free ends, 3 or more at branch points).
    pub fn node_degrees(&self) -> Vec<usize> {
        let mut degree = vec![0; self.nodes.len()];
        for b in &self.branches {
            degree[b.start] += 1;
            degree[b.end] += 1;
        }
        degree
    }

    /// Total centerline length of all branches (m).
    pub fn total_length(&self) -> f64 {
        self.branches.iter().map(Branch::length).sum()
    }

    /// Number of independent cycles (edges − nodes + connected components).
    pub fn cycle_rank(&self) -> usize {
        let used: Vec<NodeId> = {
            let mut u: Vec<_> = self
                .branches
                .iter()
                .flat_map(|b| [b.start, b.end])
                .collect();
            u.sort_unstable();
            u.dedup();
            u
        };
        (self.branches.len() + self.connected_components()).saturating_sub(used.len())
    }

    /// Connected components among nodes used by branches.
    pub fn connected_components(&self) -> usize {
        count_components(
            self.nodes.len(),
            self.branches.iter().map(|b| (b.start, b.end)),
        )
    }

    /// The closest centerline point to `point` over all branches (brute force over segments,
    /// pruned by distance bounds).
    pub fn nearest(&self, point: &Point3<f64>) -> Option<GraphLocation> {
        let mut best: Option<GraphLocation> = None;
        for (id, b) in self.branches.iter().enumerate() {
            for i in 0..b.points.len() - 1 {
                let (a, c) = (b.points[i], b.points[i + 1]);
                let ab = c - a;
                let t = ((point - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
                let q = a + ab * t;
                let d = (point - q).norm();
                if best.as_ref().is_none_or(|x| d < x.distance) {
                    best = Some(GraphLocation {
                        branch: id,
                        arc_length: b.arc[i] + t * (b.arc[i + 1] - b.arc[i]),
                        position: q,
                        distance: d,
                        radius: b.radii[i] + t * (b.radii[i + 1] - b.radii[i]),
                        direction: ab.normalize(),
                    });
                }
            }
        }
        best
    }

    /// Shortest route along centerlines from the graph point nearest `from` to the distal
    /// end of the branch named `target` (Dijkstra over junctions). A communicating artery
    /// counts [`COMMUNICATING_ROUTE_WEIGHT`] times its length, so that routes into the head
    /// go up the artery that feeds the target, as catheters do, and cross the circle of
    /// Willis only where nothing else leads.
    pub fn path_to(&self, from: &Point3<f64>, target: &str) -> Result<VesselPath> {
        let target_id = self.branch_id(target)?;
        let start = self.nearest(from).ok_or_else(|| AnatomyError::NoPath {
            from: format!("{from:?}"),
            to: target.to_owned(),
        })?;
        let describe = || AnatomyError::NoPath {
            from: format!(
                "{} at {:.4} m",
                self.branches[start.branch].name, start.arc_length
            ),
            to: target.to_owned(),
        };
        let target_branch = &self.branches[target_id];
        if start.branch == target_id {
            let length = target_branch.length() - start.arc_length;
            return Ok(VesselPath {
                legs: vec![PathLeg {
                    branch: target_id,
                    from_arc: start.arc_length,
                    to_arc: target_branch.length(),
                }],
                length,
            });
        }
        // Dijkstra from the two ends of the start branch; the target is reached by entering
        // its start node and walking it forwards (to its distal end).
        let n = self.nodes.len();
        let mut dist = vec![f64::INFINITY; n];
        let mut via: Vec<Option<(BranchId, NodeId)>> = vec![None; n];
        let mut heap = BinaryHeap::new();
        let sb = &self.branches[start.branch];
        for (node, d) in [
            (sb.start, start.arc_length),
            (sb.end, sb.length() - start.arc_length),
        ] {
            if d < dist[node] {
                dist[node] = d;
                heap.push(QueueEntry { cost: -d, node });
            }
        }
        while let Some(QueueEntry { cost, node }) = heap.pop() {
            if -cost > dist[node] {
                continue;
            }
            for (id, b) in self.branches.iter().enumerate() {
                let other = if b.start == node {
                    b.end
                } else if b.end == node {
                    b.start
                } else {
                    continue;
                };
                let weight = match b.kind {
                    VesselKind::AnteriorCommunicating | VesselKind::PosteriorCommunicating => {
                        COMMUNICATING_ROUTE_WEIGHT
                    }
                    _ => 1.0,
                };
                let d = dist[node] + b.length() * weight;
                if d < dist[other] {
                    dist[other] = d;
                    via[other] = Some((id, node));
                    heap.push(QueueEntry {
                        cost: -d,
                        node: other,
                    });
                }
            }
        }
        let entry = target_branch.start;
        if !dist[entry].is_finite() {
            return Err(describe());
        }
        // Walk back from the target's start node.
        let mut legs = vec![PathLeg {
            branch: target_id,
            from_arc: 0.0,
            to_arc: target_branch.length(),
        }];
        let mut node = entry;
        while let Some((id, previous)) = via[node] {
            let b = &self.branches[id];
            let (from_arc, to_arc) = if b.start == previous {
                (0.0, b.length())
            } else {
                (b.length(), 0.0)
            };
            legs.push(PathLeg {
                branch: id,
                from_arc,
                to_arc,
            });
            node = previous;
        }
        let to_arc = if node == sb.start { 0.0 } else { sb.length() };
        legs.push(PathLeg {
            branch: start.branch,
            from_arc: start.arc_length,
            to_arc,
        });
        legs.reverse();
        legs.retain(|l| (l.to_arc - l.from_arc).abs() > 0.0 || l.branch == target_id);
        let length = legs.iter().map(|l| (l.to_arc - l.from_arc).abs()).sum();
        Ok(VesselPath { legs, length })
    }

    /// Points (m) and radii (m) along a path, every `spacing` metres at most.
    pub fn sample_path(&self, path: &VesselPath, spacing: f64) -> Vec<(Point3<f64>, f64)> {
        let mut out = Vec::new();
        for leg in &path.legs {
            let b = &self.branches[leg.branch];
            let len = (leg.to_arc - leg.from_arc).abs();
            let count = (len / spacing.max(1e-9)).ceil().max(1.0) as usize;
            let first = usize::from(!out.is_empty());
            for k in first..=count {
                let s = leg.from_arc + (leg.to_arc - leg.from_arc) * k as f64 / count as f64;
                out.push((b.point_at(s), b.radius_at(s)));
            }
        }
        out
    }

    /// The JSON form of the graph (metres).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_default()
    }

    /// Reads the JSON form written by [`VesselGraph::to_json`]; `file` names the source.
    pub fn from_json(text: &str, file: &str) -> Result<Self> {
        let graph: VesselGraph = serde_json::from_str(text).map_err(|e| AnatomyError::Parse {
            file: file.to_owned(),
            line: Some(e.line()),
            message: e.to_string(),
        })?;
        if let Some(i) = graph
            .nodes
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            return Err(AnatomyError::Parse {
                file: file.to_owned(),
                line: None,
                message: format!("node {i} is not finite"),
            });
        }
        graph.finish().map_err(|e| AnatomyError::Parse {
            file: file.to_owned(),
            line: None,
            message: e.to_string(),
        })
    }
}

#[derive(PartialEq)]
struct QueueEntry {
    cost: f64,
    node: NodeId,
}

impl Eq for QueueEntry {}

impl PartialOrd for QueueEntry {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for QueueEntry {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.cost.total_cmp(&other.cost)
    }
}
