//! The flow network: vessels (Poiseuille tubes with a piecewise-linear radius profile) between
//! junction nodes, blood properties, and the inlet and outlet boundary conditions.
//!
//! Units: metres, pascals, seconds; flows in m³/s; resistances in Pa·s/m³.

use std::collections::VecDeque;

use nalgebra::Point3;

use crate::error::{HemoError, Result, require_finite, require_non_negative, require_positive};

/// One millimetre of mercury in pascals.
pub const MMHG: f64 = 133.322_387_415;
/// One millilitre per second in m³/s.
pub const ML_PER_S: f64 = 1e-6;
/// One millilitre per minute in m³/s.
pub const ML_PER_MIN: f64 = 1e-6 / 60.0;

/// Blood as a Newtonian fluid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Blood {
    /// Dynamic viscosity (Pa·s); 3.5–4 mPa·s for whole blood.
    pub viscosity: f64,
    /// Density (kg/m³).
    pub density: f64,
}

impl Default for Blood {
    /// 4.0 mPa·s and 1060 kg/m³, as in the circle-of-Willis network data.
    fn default() -> Self {
        Self {
            viscosity: 4.0e-3,
            density: 1060.0,
        }
    }
}

/// A point of a vessel's radius profile.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Station {
    /// Arc length from the vessel's start node (m).
    pub arc: f64,
    /// Lumen radius there (m); linear in between stations.
    pub radius: f64,
}

/// A vessel segment: a straight or curved tube from node `from` to node `to`, whose radius is
/// piecewise linear in arc length. Positive flow goes from `from` to `to`.
#[derive(Debug, Clone, PartialEq)]
pub struct Vessel {
    /// Name (unique within a network).
    pub name: String,
    /// Start node.
    pub from: usize,
    /// End node.
    pub to: usize,
    /// Radius profile, from arc 0 to arc = length, at least two stations, arcs increasing.
    pub stations: Vec<Station>,
    /// Optional centerline points in space (m, LPS), one per station (for rendering contrast).
    pub centerline: Option<Vec<Point3<f64>>>,
}

impl Vessel {
    /// A uniform or linearly tapered vessel of `length` (m) from radius `proximal` to `distal` (m).
    pub fn tapered(
        name: impl Into<String>,
        from: usize,
        to: usize,
        length: f64,
        proximal: f64,
        distal: f64,
    ) -> Self {
        Self {
            name: name.into(),
            from,
            to,
            stations: vec![
                Station {
                    arc: 0.0,
                    radius: proximal,
                },
                Station {
                    arc: length,
                    radius: distal,
                },
            ],
            centerline: None,
        }
    }

    /// A uniform vessel of `length` and `radius` (m).
    pub fn uniform(
        name: impl Into<String>,
        from: usize,
        to: usize,
        length: f64,
        radius: f64,
    ) -> Self {
        Self::tapered(name, from, to, length, radius, radius)
    }

    /// Length along the centerline (m).
    pub fn length(&self) -> f64 {
        self.stations.last().map_or(0.0, |s| s.arc)
    }

    /// Lumen radius at arc length `arc` (m), clamped to the vessel.
    pub fn radius_at(&self, arc: f64) -> f64 {
        let s = &self.stations;
        let k = s.partition_point(|st| st.arc <= arc).clamp(1, s.len() - 1);
        let (a, b) = (s[k - 1], s[k]);
        let span = b.arc - a.arc;
        let t = if span > 0.0 {
            ((arc - a.arc) / span).clamp(0.0, 1.0)
        } else {
            0.0
        };
        a.radius + t * (b.radius - a.radius)
    }

    /// Position of arc length `arc` on the centerline, where the vessel has one.
    pub fn point_at(&self, arc: f64) -> Option<Point3<f64>> {
        let points = self.centerline.as_ref()?;
        let s = &self.stations;
        let k = s.partition_point(|st| st.arc <= arc).clamp(1, s.len() - 1);
        let span = s[k].arc - s[k - 1].arc;
        let t = if span > 0.0 {
            ((arc - s[k - 1].arc) / span).clamp(0.0, 1.0)
        } else {
            0.0
        };
        Some(points[k - 1] + (points[k] - points[k - 1]) * t)
    }

    /// Lumen volume between arc lengths `a` and `b` (m³), exact for the piecewise-linear radius.
    pub fn volume_between(&self, a: f64, b: f64) -> f64 {
        self.integrate_pieces(a, b, |r0, r1, len| {
            // ∫ π r² over a linear piece (Simpson is exact for the quadratic integrand).
            let rm = 0.5 * (r0 + r1);
            std::f64::consts::PI * len * (r0 * r0 + 4.0 * rm * rm + r1 * r1) / 6.0
        })
    }

    /// Poiseuille resistance of the lumen between arc lengths `a` and `b` (Pa·s/m³):
    /// `8η ∫ ds / (π r(s)⁴)`, exact for the piecewise-linear radius.
    pub fn resistance_between(&self, viscosity: f64, a: f64, b: f64) -> f64 {
        self.integrate_pieces(a, b, |r0, r1, len| {
            // ∫ ds / r⁴ over a linear taper = len (r0² + r0 r1 + r1²) / (3 r0³ r1³).
            8.0 * viscosity / std::f64::consts::PI * len * (r0 * r0 + r0 * r1 + r1 * r1)
                / (3.0 * r0.powi(3) * r1.powi(3))
        })
    }

    /// Darcy resistance of a porous plug (a clot) of hydraulic permeability `permeability`
    /// (m²) filling the lumen between arc lengths `a` and `b` (Pa·s/m³):
    /// `η/(π k) ∫ ds / r(s)²`, exact for the piecewise-linear radius.
    pub fn darcy_resistance_between(
        &self,
        viscosity: f64,
        permeability: f64,
        a: f64,
        b: f64,
    ) -> f64 {
        self.integrate_pieces(a, b, |r0, r1, len| {
            // ∫ ds / r² over a linear taper = len / (r0 r1).
            viscosity / (std::f64::consts::PI * permeability) * len / (r0 * r1)
        })
    }

    /// Resistance between `a` and `b` (Pa·s/m³) with a catheter of radius `catheter_radius` (m)
    /// lying concentrically in the lumen: the annular Poiseuille law
    /// `Q = π ΔP r⁴ (1 − κ⁴ − (1 − κ²)² / ln(1/κ)) / (8 η L)`, κ = r_c / r, integrated along the
    /// taper (the open lumen exactly, the excess by 5-point Gauss–Legendre on sub-pieces
    /// whose radii and gaps differ by at most 10 %). κ is capped at 0.99 (a wedged catheter still
    /// leaks a little), which keeps the network solvable.
    pub fn annular_resistance_between(
        &self,
        viscosity: f64,
        a: f64,
        b: f64,
        catheter_radius: f64,
    ) -> f64 {
        if catheter_radius <= 0.0 {
            return self.resistance_between(viscosity, a, b);
        }
        const NODES: [f64; 5] = [
            0.0,
            -0.538_469_310_105_683,
            0.538_469_310_105_683,
            -0.906_179_845_938_664,
            0.906_179_845_938_664,
        ];
        const WEIGHTS: [f64; 5] = [
            0.568_888_888_888_889,
            0.478_628_670_499_366,
            0.478_628_670_499_366,
            0.236_926_885_056_189,
            0.236_926_885_056_189,
        ];
        // The open lumen's part is integrated exactly and only the catheter's excess
        // `(1/f(κ) − 1) / r⁴ ≥ 0` by quadrature, so a catheter never lowers the resistance
        // (integrating `1 / (r⁴ f)` whole under-counts `∫ r⁻⁴` on a steep taper, and a thin
        // catheter there came out below the open vessel).
        // Sub-pieces whose radii and annular gaps differ by at most 10 % keep the quadrature to
        // ~1e-4 on any taper.
        let excess = self.integrate_pieces(a, b, |r0, r1, len| {
            let gap = |r: f64| (r - catheter_radius).max(0.01 * r);
            let spread = (r1 / r0).ln().abs().max((gap(r1) / gap(r0)).ln().abs());
            let parts = (spread / 0.1).ceil().clamp(1.0, 1000.0) as usize;
            let mut sum = 0.0;
            for part in 0..parts {
                let (t0, t1) = (part as f64 / parts as f64, (part + 1) as f64 / parts as f64);
                for (x, w) in NODES.iter().zip(WEIGHTS) {
                    let t = t0 + 0.5 * (1.0 + x) * (t1 - t0);
                    let r = r0 + t * (r1 - r0);
                    let kappa = (catheter_radius / r).min(0.99);
                    sum += w * (1.0 / annulus_factor(kappa) - 1.0) / r.powi(4) / parts as f64;
                }
            }
            8.0 * viscosity / std::f64::consts::PI * 0.5 * len * sum
        });
        self.resistance_between(viscosity, a, b) + excess
    }

    /// Sums `piece(r_start, r_end, length)` over the linear pieces of `[a, b]` (clamped).
    fn integrate_pieces(&self, a: f64, b: f64, piece: impl Fn(f64, f64, f64) -> f64) -> f64 {
        let (a, b) = (a.max(0.0), b.min(self.length()));
        if b <= a {
            return 0.0;
        }
        let mut total = 0.0;
        for w in self.stations.windows(2) {
            let lo = w[0].arc.max(a);
            let hi = w[1].arc.min(b);
            if hi > lo {
                total += piece(
                    self.radius_at_piece(w, lo),
                    self.radius_at_piece(w, hi),
                    hi - lo,
                );
            }
        }
        total
    }

    fn radius_at_piece(&self, w: &[Station], arc: f64) -> f64 {
        let span = w[1].arc - w[0].arc;
        let t = ((arc - w[0].arc) / span).clamp(0.0, 1.0);
        w[0].radius + t * (w[1].radius - w[0].radius)
    }

    fn validate(&self, nodes: usize) -> Result<()> {
        let bad = |message: String| HemoError::InvalidVessel {
            vessel: self.name.clone(),
            message,
        };
        if self.from >= nodes || self.to >= nodes {
            return Err(bad(format!(
                "node {} or {} does not exist (the network has {nodes} nodes)",
                self.from, self.to
            )));
        }
        if self.from == self.to {
            return Err(bad(format!("both ends are node {}", self.from)));
        }
        if self.stations.len() < 2 {
            return Err(bad("needs at least two radius stations".into()));
        }
        if let Some(points) = &self.centerline
            && points.len() != self.stations.len()
        {
            return Err(bad(format!(
                "{} centerline points for {} stations",
                points.len(),
                self.stations.len()
            )));
        }
        for (i, s) in self.stations.iter().enumerate() {
            require_positive(
                || format!("vessel {:?} radius (m) at station {i}", self.name),
                s.radius,
            )?;
            require_finite(
                || format!("vessel {:?} arc (m) at station {i}", self.name),
                s.arc,
            )?;
        }
        if self.stations[0].arc != 0.0 {
            return Err(bad("the first station must be at arc 0".into()));
        }
        if self.stations.windows(2).any(|w| w[1].arc <= w[0].arc) {
            return Err(bad("station arcs must increase strictly".into()));
        }
        require_positive(
            || format!("vessel {:?} length (m)", self.name),
            self.length(),
        )?;
        Ok(())
    }
}

/// The annular Poiseuille factor `1 − κ⁴ − (1 − κ²)² / ln(1/κ)` for 0 < κ < 1: the flow through
/// an annulus relative to the open tube at the same pressure drop (1 at κ → 0, 0 at κ → 1).
pub fn annulus_factor(kappa: f64) -> f64 {
    if kappa <= 0.0 {
        return 1.0;
    }
    let k2 = kappa * kappa;
    1.0 - k2 * k2 - (1.0 - k2).powi(2) / (1.0 / kappa).ln()
}

/// How blood enters the network at the inlet node.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum InletCondition {
    /// A prescribed pressure (Pa).
    Pressure(f64),
    /// A prescribed inflow (m³/s).
    Flow(f64),
}

/// The inlet: a node and its condition.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Inlet {
    /// The node.
    pub node: usize,
    /// Pressure or flow.
    pub condition: InletCondition,
}

/// An outlet: blood leaves node `node` through a terminal (peripheral) resistance into a
/// reservoir at `pressure`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outlet {
    /// The node.
    pub node: usize,
    /// Terminal resistance (Pa·s/m³); 0 means the node is held at `pressure` directly.
    pub resistance: f64,
    /// Reservoir (venous) pressure beyond the resistance (Pa).
    pub pressure: f64,
}

/// A validated flow network: vessels between nodes, one inlet, at least one outlet.
#[derive(Debug, Clone, PartialEq)]
pub struct FlowNetwork {
    /// Number of nodes (junctions and ends), indexed `0..node_count`.
    pub node_count: usize,
    /// The vessels.
    pub vessels: Vec<Vessel>,
    /// The inlet.
    pub inlet: Inlet,
    /// The outlets.
    pub outlets: Vec<Outlet>,
    /// Blood properties.
    pub blood: Blood,
}

impl FlowNetwork {
    /// Validates and builds a network. Errors name the first problem: a vessel with a bad
    /// radius or zero length, a node that does not exist, a network in several pieces, no
    /// outlet, or a boundary condition on the same node twice.
    pub fn new(
        node_count: usize,
        vessels: Vec<Vessel>,
        inlet: Inlet,
        outlets: Vec<Outlet>,
        blood: Blood,
    ) -> Result<Self> {
        require_positive(|| "blood viscosity (Pa·s)".into(), blood.viscosity)?;
        require_positive(|| "blood density (kg/m³)".into(), blood.density)?;
        if vessels.is_empty() {
            return Err(HemoError::InvalidParameter {
                name: "vessel count".into(),
                value: 0.0,
                requirement: "at least 1",
            });
        }
        for v in &vessels {
            v.validate(node_count)?;
        }
        let mut names: Vec<&str> = vessels.iter().map(|v| v.name.as_str()).collect();
        names.sort_unstable();
        if let Some(w) = names.windows(2).find(|w| w[0] == w[1]) {
            return Err(HemoError::InvalidVessel {
                vessel: w[0].to_string(),
                message: "two vessels have this name".into(),
            });
        }
        if outlets.is_empty() {
            return Err(HemoError::NoOutlet);
        }
        let mut boundary = vec![false; node_count];
        let mut claim = |node: usize, what: &str| -> Result<()> {
            if node >= node_count {
                return Err(HemoError::InvalidBoundary {
                    node,
                    message: format!("{what} on a node that does not exist ({node_count} nodes)"),
                });
            }
            if std::mem::replace(&mut boundary[node], true) {
                return Err(HemoError::InvalidBoundary {
                    node,
                    message: format!("{what} on a node that already has a boundary condition"),
                });
            }
            Ok(())
        };
        claim(inlet.node, "the inlet")?;
        match inlet.condition {
            InletCondition::Pressure(p) => {
                require_finite(|| "inlet pressure (Pa)".into(), p)?;
            }
            InletCondition::Flow(q) => {
                require_finite(|| "inlet flow (m³/s)".into(), q)?;
            }
        }
        for o in &outlets {
            claim(o.node, "an outlet")?;
            require_non_negative(
                || format!("outlet at node {} resistance (Pa·s/m³)", o.node),
                o.resistance,
            )?;
            require_finite(
                || format!("outlet at node {} pressure (Pa)", o.node),
                o.pressure,
            )?;
        }
        let network = Self {
            node_count,
            vessels,
            inlet,
            outlets,
            blood,
        };
        network.check_connected()?;
        Ok(network)
    }

    /// Index of the vessel called `name`.
    pub fn vessel_id(&self, name: &str) -> Result<usize> {
        self.vessels
            .iter()
            .position(|v| v.name == name)
            .ok_or_else(|| HemoError::UnknownVessel(name.to_string()))
    }

    /// The vessel called `name`.
    pub fn vessel(&self, name: &str) -> Result<&Vessel> {
        Ok(&self.vessels[self.vessel_id(name)?])
    }

    /// The vessel at `index`, or an error naming the index and the vessel count.
    pub fn vessel_at(&self, index: usize) -> Result<&Vessel> {
        self.vessels.get(index).ok_or(HemoError::VesselIndex {
            index,
            count: self.vessels.len(),
        })
    }

    /// For each node, the vessels attached to it and whether the node is that vessel's start.
    pub fn incidence(&self) -> Vec<Vec<(usize, bool)>> {
        let mut incidence = vec![Vec::new(); self.node_count];
        for (i, v) in self.vessels.iter().enumerate() {
            incidence[v.from].push((i, true));
            incidence[v.to].push((i, false));
        }
        incidence
    }

    /// Total lumen volume of all vessels (m³).
    pub fn volume(&self) -> f64 {
        self.vessels
            .iter()
            .map(|v| v.volume_between(0.0, v.length()))
            .sum()
    }

    fn check_connected(&self) -> Result<()> {
        let incidence = self.incidence();
        let mut seen = vec![false; self.node_count];
        let mut queue = VecDeque::from([self.inlet.node]);
        seen[self.inlet.node] = true;
        while let Some(n) = queue.pop_front() {
            for &(v, is_start) in &incidence[n] {
                let vessel = &self.vessels[v];
                let other = if is_start { vessel.to } else { vessel.from };
                if !std::mem::replace(&mut seen[other], true) {
                    queue.push_back(other);
                }
            }
        }
        if let Some(example_node) = seen.iter().position(|s| !s) {
            // Count the pieces for the message.
            let mut component = vec![usize::MAX; self.node_count];
            let mut components = 0;
            for start in 0..self.node_count {
                if component[start] != usize::MAX {
                    continue;
                }
                let mut stack = vec![start];
                component[start] = components;
                while let Some(n) = stack.pop() {
                    for &(v, is_start) in &incidence[n] {
                        let vessel = &self.vessels[v];
                        let other = if is_start { vessel.to } else { vessel.from };
                        if component[other] == usize::MAX {
                            component[other] = components;
                            stack.push(other);
                        }
                    }
                }
                components += 1;
            }
            return Err(HemoError::Disconnected {
                components,
                example_node,
            });
        }
        Ok(())
    }
}

/// Seeded random networks for tests and benchmarks: a random tree of `nodes` nodes (node 0 is
/// the inlet, at 100 mmHg) with `extra` loop-closing vessels, radii 0.5–4 mm, lengths 5–100 mm,
/// and an outlet (terminal resistance 0–5·10⁹ Pa·s/m³, venous 0–10 mmHg) at every third node.
pub fn random_network(seed: u64, nodes: usize, extra: usize) -> Result<FlowNetwork> {
    use rand::{RngExt, SeedableRng, rngs::StdRng};
    if nodes < 4 {
        return Err(HemoError::InvalidParameter {
            name: "random network node count".into(),
            value: nodes as f64,
            requirement: "at least 4",
        });
    }
    let mut rng = StdRng::seed_from_u64(seed);
    let mut vessels = Vec::with_capacity(nodes + extra);
    for node in 1..nodes {
        let parent = rng.random_range(0..node);
        vessels.push(Vessel::tapered(
            format!("t{node}"),
            parent,
            node,
            rng.random_range(0.005..0.1),
            rng.random_range(0.5e-3..4e-3),
            rng.random_range(0.5e-3..4e-3),
        ));
    }
    for e in 0..extra {
        let a = rng.random_range(0..nodes);
        let b = (a + 1 + rng.random_range(0..nodes - 1)) % nodes;
        vessels.push(Vessel::uniform(
            format!("x{e}"),
            a,
            b,
            rng.random_range(0.005..0.1),
            rng.random_range(0.5e-3..3e-3),
        ));
    }
    let outlets = (1..nodes)
        .filter(|n| n % 3 == 0)
        .map(|node| Outlet {
            node,
            resistance: rng.random_range(0.0..5e9),
            pressure: rng.random_range(0.0..10.0 * MMHG),
        })
        .collect();
    FlowNetwork::new(
        nodes,
        vessels,
        Inlet {
            node: 0,
            condition: InletCondition::Pressure(100.0 * MMHG),
        },
        outlets,
        Blood::default(),
    )
}
