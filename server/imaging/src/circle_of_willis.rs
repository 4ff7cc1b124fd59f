//! The circle of Willis in a vessel surface: the head's centerlines computed from the surface
//! in a box around the circle, the loops that the skeleton's tree broke rejoined through the
//! lumen, and the arteries named from shortest paths between the four inflows (both internal
//! carotids and vertebrals) and the free ends of the middle, anterior and posterior cerebral
//! arteries.
//!
//! The naming needs no atlas: the terminus of an internal carotid is where its paths to its
//! own middle and anterior cerebral ends part, the vertebrobasilar junction is where the
//! vertebrals' paths to a posterior cerebral end meet, the basilar top is where the paths
//! from there to both posterior cerebral ends part, and the communicating arteries are what
//! joins those paths. Names follow the neuro phantom's (`left_middle_cerebral`,
//! `basilar`, …), so scenes written for one anatomy name the same vessels in the other.

use std::collections::BTreeMap;

use cathlab_anatomy::Lumen;
use cathlab_anatomy::graph::{BranchSpec, Side, VesselGraph, VesselKind};
use cathlab_anatomy::real::ARCH_TO_COW_LEFT_SUPERIOR;
use nalgebra::{Point3, Vector3};
use petgraph::algo::{astar, dijkstra};
use petgraph::graph::{NodeIndex, UnGraph};
use petgraph::unionfind::UnionFind;
use petgraph::visit::EdgeRef;

use crate::error::{ImagingError, Result};
use crate::surface_centerlines::{SurfaceCenterlineSettings, centerlines_from_surface};

/// Where blood enters the circle and which way the head faces, in the surface's frame (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CircleInflows {
    /// A point on the left internal carotid's centerline, below its terminus and below the
    /// origin of its posterior communicating artery.
    pub left_internal_carotid: Point3<f64>,
    /// The same on the right.
    pub right_internal_carotid: Point3<f64>,
    /// A point on the left vertebral's centerline, below the vertebrobasilar junction.
    pub left_vertebral: Point3<f64>,
    /// The same on the right.
    pub right_vertebral: Point3<f64>,
    /// The patient's left (any length).
    pub left: Vector3<f64>,
    /// The patient's superior (any length).
    pub superior: Vector3<f64>,
}

impl CircleInflows {
    /// The inflows of the bundled arch-to-cow anatomy: the ends of its LCCA, RCCA, LVA and
    /// RVA curves (as `cathlab_anatomy::real::load_arch_to_cow_trimmed` gives them) and its
    /// axes.
    pub fn arch_to_cow(ends: &BTreeMap<String, Point3<f64>>) -> Result<Self> {
        let end = |name: &str| {
            ends.get(name).copied().ok_or_else(|| {
                fail(format!(
                    "the anatomy has no {name} curve for the circle to continue"
                ))
            })
        };
        let [left, superior] = ARCH_TO_COW_LEFT_SUPERIOR.map(Vector3::from);
        Ok(Self {
            left_internal_carotid: end("LCCA")?,
            right_internal_carotid: end("RCCA")?,
            left_vertebral: end("LVA")?,
            right_vertebral: end("RVA")?,
            left,
            superior,
        })
    }
}

/// How finely the circle is computed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CircleSettings {
    /// Voxel edge of the centerline computation (m).
    pub voxel_m: f64,
    /// The box extends this far beyond the inflow points (m).
    pub margin_m: f64,
}

impl Default for CircleSettings {
    fn default() -> Self {
        Self {
            voxel_m: 0.4e-3,
            margin_m: 35e-3,
        }
    }
}

/// The named arteries of the circle and what was found on the way.
#[derive(Debug, Clone)]
pub struct CircleOfWillis {
    /// Named arteries, each from its proximal end (m); the carotid and vertebral pieces start
    /// exactly at the inflow points, so that they join curves ending there.
    pub branches: Vec<BranchSpec>,
    /// Junctions (m): `left_ica_terminus`, `basilar_top`, `vertebrobasilar_junction`,
    /// `left_acom_junction`, `left_pcom_origin`, `left_p1_p2_junction`, … (right alike).
    pub landmarks: BTreeMap<String, Point3<f64>>,
    /// Loops of the skeleton's tree rejoined through the lumen.
    pub loops_closed: usize,
    /// Centerline in the box that no named artery uses (m): side branches, stubs, and the
    /// vessels beyond the inflow points.
    pub unnamed_length_m: f64,
    /// The voxel edge used (m).
    pub voxel_m: f64,
}

#[derive(Debug, Clone, Copy)]
struct Vertex {
    p: Point3<f64>,
    r: f64,
}

type Points = UnGraph<Vertex, f64>;

fn fail(message: impl Into<String>) -> ImagingError {
    ImagingError::Segmentation(format!("circle of Willis: {}", message.into()))
}

/// One vertex per centerline point, the branches' end points shared.
fn point_graph(graph: &VesselGraph) -> Points {
    let mut points = Points::new_undirected();
    let nodes: Vec<NodeIndex> = graph
        .nodes
        .iter()
        .map(|&p| points.add_node(Vertex { p, r: 0.0 }))
        .collect();
    for b in &graph.branches {
        let n = b.points.len();
        for (node, r) in [(b.start, b.radii[0]), (b.end, b.radii[n - 1])] {
            let v = &mut points[nodes[node]];
            v.r = v.r.max(r);
        }
        let mut previous = nodes[b.start];
        for i in 1..n {
            let next = if i == n - 1 {
                nodes[b.end]
            } else {
                points.add_node(Vertex {
                    p: b.points[i],
                    r: b.radii[i],
                })
            };
            let length = (points[next].p - points[previous].p).norm();
            points.add_edge(previous, next, length);
            previous = next;
        }
    }
    points
}

/// Whether the straight segment `a`–`b` stays inside the lumen by `clearance` (m).
fn inside(lumen: &Lumen, a: &Point3<f64>, b: &Point3<f64>, clearance: f64) -> bool {
    let steps = ((b - a).norm() / 0.1e-3).ceil().max(1.0) as usize;
    (0..=steps).all(|k| {
        let p = a + (b - a) * (k as f64 / steps as f64);
        lumen.query(&p).signed_distance < -clearance
    })
}

/// Joins each free end of the tree to the nearest vertex it reaches in a straight line
/// through the lumen that the tree only reaches the long way round (the skeleton grows a tree,
/// so every loop of the circle ends as two free ends facing each other or a vessel).
fn close_loops(points: &mut Points, lumen: &Lumen) -> usize {
    let mut closed = 0;
    let ends: Vec<NodeIndex> = points
        .node_indices()
        .filter(|&v| points.edges(v).count() == 1)
        .collect();
    for e in ends {
        if points.edges(e).count() != 1 {
            continue; // joined as the other end of a loop already
        }
        let (pe, re) = (points[e].p, points[e].r);
        let along = dijkstra(&*points, e, None, |edge| *edge.weight());
        let mut best: Option<(f64, NodeIndex)> = None;
        for v in points.node_indices() {
            let (pv, rv) = (points[v].p, points[v].r);
            let d = (pv - pe).norm();
            if v == e || d > 3.0 * (re + rv) + 1e-3 || best.is_some_and(|(b, _)| d >= b) {
                continue;
            }
            let round = along.get(&v).copied().unwrap_or(f64::INFINITY);
            if round < 2.0 * d + 2.0 * (re + rv) {
                continue; // the tree already goes there directly
            }
            if inside(lumen, &pe, &pv, 0.1 * re.min(rv)) {
                best = Some((d, v));
            }
        }
        if let Some((d, v)) = best {
            points.add_edge(e, v, d);
            closed += 1;
        }
    }
    closed
}

/// The vertex of degree 2 nearest `p`, within `reach` (m).
fn snap(points: &Points, p: &Point3<f64>, what: &str) -> Result<NodeIndex> {
    let (v, d) = points
        .node_indices()
        .filter(|&v| points.edges(v).count() == 2)
        .map(|v| (v, (points[v].p - p).norm()))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .ok_or_else(|| fail("no centerline in the box"))?;
    if d > 2.0 * points[v].r.max(1e-3) {
        return Err(fail(format!(
            "the {what} point ({:.1}, {:.1}, {:.1}) mm is {:.1} mm from the computed \
             centerlines",
            p.x * 1e3,
            p.y * 1e3,
            p.z * 1e3,
            d * 1e3
        )));
    }
    Ok(v)
}

/// The shortest path from `a` to `b` (vertices, both ends included).
fn path(points: &Points, a: NodeIndex, b: NodeIndex, what: &str) -> Result<Vec<NodeIndex>> {
    astar(points, a, |v| v == b, |e| *e.weight(), |_| 0.0)
        .map(|(_, p)| p)
        .ok_or_else(|| fail(format!("no path for the {what}")))
}

/// The last vertex that two paths from the same start share before they part.
fn parting(a: &[NodeIndex], b: &[NodeIndex]) -> NodeIndex {
    let shared = a.iter().zip(b).take_while(|(x, y)| x == y).count();
    a[shared.max(1) - 1]
}

/// The first vertex from which two paths to the same end run together.
fn meeting(a: &[NodeIndex], b: &[NodeIndex]) -> NodeIndex {
    let shared = a
        .iter()
        .rev()
        .zip(b.iter().rev())
        .take_while(|(x, y)| x == y)
        .count();
    a[a.len() - shared.max(1)]
}

/// The part of `path` from `from` to `to` (both on it, in that order).
fn between(path: &[NodeIndex], from: NodeIndex, to: NodeIndex) -> Option<Vec<NodeIndex>> {
    let i = path.iter().position(|&v| v == from)?;
    let j = path.iter().position(|&v| v == to)?;
    (i < j).then(|| path[i..=j].to_vec())
}

/// Computes the circle of Willis of `lumen` around `inflows` and names its arteries.
pub fn circle_of_willis(
    lumen: &Lumen,
    inflows: &CircleInflows,
    settings: &CircleSettings,
) -> Result<CircleOfWillis> {
    let left = inflows.left.try_normalize(1e-12);
    let superior = inflows.superior.try_normalize(1e-12);
    let (Some(left), Some(superior)) = (left, superior) else {
        return Err(fail("the left and superior directions must be non-zero"));
    };
    let anterior = left.cross(&superior);
    if anterior.norm() < 0.5 {
        return Err(fail(
            "the left and superior directions must be about perpendicular",
        ));
    }
    let anterior = anterior.normalize();
    let entries = [
        inflows.left_internal_carotid,
        inflows.right_internal_carotid,
        inflows.left_vertebral,
        inflows.right_vertebral,
    ];
    let mut lo = entries[0];
    let mut hi = entries[0];
    for p in &entries {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a] - settings.margin_m);
            hi[a] = hi[a].max(p[a] + settings.margin_m);
        }
    }
    let computed = centerlines_from_surface(
        lumen,
        &inflows.left_vertebral,
        &SurfaceCenterlineSettings {
            voxel_m: Some(settings.voxel_m),
            region: Some([lo, hi]),
            ..SurfaceCenterlineSettings::default()
        },
    )?;
    let mut points = point_graph(&computed.graph);
    let loops_closed = close_loops(&mut points, lumen);

    let names = [
        "left internal carotid",
        "right internal carotid",
        "left vertebral",
        "right vertebral",
    ];
    let mut inflow = [NodeIndex::end(); 4];
    for k in 0..4 {
        inflow[k] = snap(&points, &entries[k], names[k])?;
    }
    // The circle: what stays joined to all four inflows once they are cut.
    let mut joined = UnionFind::<usize>::new(points.node_count());
    for e in points.edge_references() {
        if !inflow.contains(&e.source()) && !inflow.contains(&e.target()) {
            joined.union(e.source().index(), e.target().index());
        }
    }
    let component = |v: NodeIndex| joined.find(v.index());
    let circle = points
        .neighbors(inflow[0])
        .map(component)
        .find(|&c| {
            inflow
                .iter()
                .all(|&v| points.neighbors(v).any(|w| component(w) == c))
        })
        .ok_or_else(|| {
            fail(
                "the four inflows are not joined by one circle (is a communicating artery or \
                 the basilar missing, or an inflow point beyond a junction?)",
            )
        })?;
    let centre = Point3::from(entries.iter().map(|p| p.coords).sum::<Vector3<f64>>() / 4.0);
    let mut ends: Vec<NodeIndex> = points
        .node_indices()
        .filter(|&v| component(v) == circle && points.edges(v).count() == 1)
        .collect();
    let offset = |v: NodeIndex| points[v].p - centre;
    let mut take = |score: &dyn Fn(NodeIndex) -> f64, what: &str| -> Result<NodeIndex> {
        let (i, _) = ends
            .iter()
            .enumerate()
            .max_by(|a, b| score(*a.1).total_cmp(&score(*b.1)))
            .ok_or_else(|| fail(format!("no free end left for the {what}")))?;
        Ok(ends.remove(i))
    };
    let m1_left = take(&|v| offset(v).dot(&left), "left middle cerebral")?;
    let m1_right = take(&|v| -offset(v).dot(&left), "right middle cerebral")?;
    if offset(m1_left).dot(&left) <= 0.0 || offset(m1_right).dot(&left) >= 0.0 {
        return Err(fail("the middle cerebral ends are not on either side"));
    }
    let mut pair = |score: &dyn Fn(NodeIndex) -> f64, what: &str| -> Result<[NodeIndex; 2]> {
        let a = take(score, what)?;
        let b = take(score, what)?;
        Ok(if offset(a).dot(&left) >= offset(b).dot(&left) {
            [a, b]
        } else {
            [b, a]
        })
    };
    let aca = pair(&|v| offset(v).dot(&anterior), "anterior cerebral arteries")?;
    let pca = pair(
        &|v| -offset(v).dot(&anterior),
        "posterior cerebral arteries",
    )?;

    let [ica_l, ica_r, va_l, va_r] = inflow;
    let ica = [ica_l, ica_r];
    let va = [va_l, va_r];
    let m1 = [m1_left, m1_right];
    let sides = [("left", Side::Left), ("right", Side::Right)];
    let mut landmarks = BTreeMap::new();
    let mut named: Vec<(String, VesselKind, Side, Vec<NodeIndex>)> = Vec::new();

    // Carotid termini, middle and anterior cerebral arteries.
    let mut terminus = [NodeIndex::end(); 2];
    let mut to_aca = Vec::new();
    for s in 0..2 {
        let to_m1 = path(&points, ica[s], m1[s], "middle cerebral")?;
        let to_a = path(&points, ica[s], aca[s], "anterior cerebral")?;
        terminus[s] = parting(&to_m1, &to_a);
        if terminus[s] == ica[s] {
            return Err(fail(format!(
                "the {} internal carotid point is at or beyond its terminus",
                sides[s].0
            )));
        }
        to_aca.push(to_a);
    }
    let mut acom = [NodeIndex::end(); 2];
    for s in 0..2 {
        let mine = path(&points, terminus[s], aca[s], "anterior cerebral")?;
        let across = path(&points, terminus[1 - s], aca[s], "anterior communicating")?;
        acom[s] = meeting(&mine, &across);
        let (prefix, side) = sides[s];
        named.push((
            format!("{prefix}_middle_cerebral"),
            VesselKind::MiddleCerebral,
            side,
            path(&points, terminus[s], m1[s], "middle cerebral")?,
        ));
        let a1 = between(&mine, terminus[s], acom[s])
            .ok_or_else(|| fail(format!("the {prefix} A1 segment has no length")))?;
        let a2 = between(&mine, acom[s], aca[s])
            .ok_or_else(|| fail(format!("the {prefix} A2 segment has no length")))?;
        named.push((
            format!("{prefix}_anterior_cerebral_a1"),
            VesselKind::AnteriorCerebral,
            side,
            a1,
        ));
        named.push((
            format!("{prefix}_anterior_cerebral_a2"),
            VesselKind::AnteriorCerebral,
            side,
            a2,
        ));
        landmarks.insert(format!("{prefix}_ica_terminus"), points[terminus[s]].p);
        landmarks.insert(format!("{prefix}_acom_junction"), points[acom[s]].p);
    }
    if acom[0] != acom[1] {
        named.push((
            "anterior_communicating".into(),
            VesselKind::AnteriorCommunicating,
            Side::Midline,
            path(&points, acom[0], acom[1], "anterior communicating")?,
        ));
    }
    // Vertebrals, basilar, posterior cerebral and communicating arteries.
    let from_left = path(&points, va[0], pca[0], "left vertebral")?;
    let from_right = path(&points, va[1], pca[0], "right vertebral")?;
    let junction = meeting(&from_left, &from_right);
    let to_left = path(&points, junction, pca[0], "left posterior cerebral")?;
    let to_right = path(&points, junction, pca[1], "right posterior cerebral")?;
    let top = parting(&to_left, &to_right);
    if top == junction {
        return Err(fail("the basilar has no length"));
    }
    landmarks.insert("vertebrobasilar_junction".into(), points[junction].p);
    landmarks.insert("basilar_top".into(), points[top].p);
    let basilar = between(&to_left, junction, top).ok_or_else(|| fail("no basilar"))?;
    named.push((
        "basilar".into(),
        VesselKind::Basilar,
        Side::Midline,
        basilar.clone(),
    ));
    for s in 0..2 {
        let (prefix, side) = sides[s];
        let from_va = path(&points, va[s], junction, "vertebral")?;
        named.push((
            format!("{prefix}_vertebral"),
            VesselKind::Vertebral,
            side,
            from_va,
        ));
        let posterior = if s == 0 { &to_left } else { &to_right };
        let from_top = between(posterior, top, pca[s])
            .ok_or_else(|| fail(format!("no {prefix} posterior cerebral")))?;
        let to_terminus = path(&points, ica[s], terminus[s], "internal carotid")?;
        let through_pcom = path(&points, ica[s], pca[s], "posterior communicating")?;
        let joins = meeting(&through_pcom, &from_top);
        let origin = parting(&through_pcom, &to_terminus);
        let pcom = between(&through_pcom, origin, joins).filter(|pcom| {
            // A communicating artery runs from the carotid to the posterior cerebral, not
            // over the basilar or the other side.
            joins != top
                && pcom
                    .iter()
                    .all(|v| !basilar.contains(v) && *v != terminus[1 - s])
        });
        match pcom {
            Some(pcom) => {
                landmarks.insert(format!("{prefix}_pcom_origin"), points[origin].p);
                landmarks.insert(format!("{prefix}_p1_p2_junction"), points[joins].p);
                let p1 = between(&from_top, top, joins).unwrap_or_default();
                let p2 = between(&from_top, joins, pca[s]).unwrap_or_default();
                named.push((
                    format!("{prefix}_posterior_cerebral_p1"),
                    VesselKind::PosteriorCerebral,
                    side,
                    p1,
                ));
                named.push((
                    format!("{prefix}_posterior_cerebral_p2"),
                    VesselKind::PosteriorCerebral,
                    side,
                    p2,
                ));
                named.push((
                    format!("{prefix}_posterior_communicating"),
                    VesselKind::PosteriorCommunicating,
                    side,
                    pcom,
                ));
                let proximal = between(&to_terminus, ica[s], origin).unwrap_or_default();
                let distal = between(&to_terminus, origin, terminus[s]).unwrap_or_default();
                if proximal.len() >= 2 {
                    named.push((
                        format!("{prefix}_internal_carotid"),
                        VesselKind::InternalCarotid,
                        side,
                        proximal,
                    ));
                }
                if distal.len() >= 2 {
                    // The communicating segment (C7), when the PCOM leaves below the terminus.
                    named.push((
                        format!("{prefix}_internal_carotid_communicating"),
                        VesselKind::InternalCarotid,
                        side,
                        distal,
                    ));
                }
            }
            None => {
                named.push((
                    format!("{prefix}_posterior_cerebral"),
                    VesselKind::PosteriorCerebral,
                    side,
                    from_top,
                ));
                named.push((
                    format!("{prefix}_internal_carotid"),
                    VesselKind::InternalCarotid,
                    side,
                    to_terminus,
                ));
            }
        }
    }
    // The named arteries must not share an edge: a shared one means the paths went the
    // wrong way round (a variant this naming does not know).
    let mut used: BTreeMap<(usize, usize), &str> = BTreeMap::new();
    for (name, _, _, vs) in &named {
        if vs.len() < 2 {
            return Err(fail(format!("{name} has no length")));
        }
        for w in vs.windows(2) {
            let key = (
                w[0].index().min(w[1].index()),
                w[0].index().max(w[1].index()),
            );
            if let Some(other) = used.insert(key, name) {
                return Err(fail(format!(
                    "{name} and {other} run along the same vessel (an anatomical variant?)"
                )));
            }
        }
    }
    let named_length: f64 = named
        .iter()
        .flat_map(|(_, _, _, vs)| vs.windows(2))
        .map(|w| (points[w[1]].p - points[w[0]].p).norm())
        .sum();
    let total_length: f64 = points.edge_weights().sum();
    let branches = named
        .into_iter()
        .map(|(name, kind, side, vs)| {
            let mut pts: Vec<Point3<f64>> = vs.iter().map(|&v| points[v].p).collect();
            let radii = vs.iter().map(|&v| points[v].r).collect();
            // Inflow pieces start exactly at the given points.
            if let Some(k) = inflow.iter().position(|&v| v == vs[0]) {
                pts[0] = entries[k];
            }
            BranchSpec {
                name,
                kind,
                side,
                points: pts,
                radii,
            }
        })
        .collect();
    Ok(CircleOfWillis {
        branches,
        landmarks,
        loops_closed,
        unnamed_length_m: (total_length - named_length).max(0.0),
        voxel_m: computed.voxel_m,
    })
}
