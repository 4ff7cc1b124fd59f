//! Steady Poiseuille flow on a network: nodal analysis (Kirchhoff's current law with R = 8ηL/πr⁴
//! per vessel), one sparse Cholesky factorization per network, cheap re-solves, catheter
//! narrowings as a low-rank (Woodbury) update of that factorization, clots as porous plugs
//! in the factorized matrix, and a catheter-tip injection as an exact point source of volume
//! inside a vessel.

use faer::prelude::Solve;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMat, Triplet};
use faer::{MatMut, Side};
use nalgebra::{DMatrix, DVector};

use crate::clot::Occlusion;
use crate::error::{HemoError, Result, require_finite, require_non_negative, require_positive};
use crate::network::{FlowNetwork, InletCondition, Vessel};

/// A catheter lying in part of a vessel: the lumen there is an annulus, which raises the
/// vessel's resistance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Narrowing {
    /// The vessel.
    pub vessel: usize,
    /// Arc length where the catheter enters the vessel (m from the vessel's start).
    pub from_arc: f64,
    /// Arc length where it leaves (m), greater than `from_arc`.
    pub to_arc: f64,
    /// Catheter outer radius (m).
    pub catheter_radius: f64,
}

/// A contrast injection through the catheter tip: a point source of volume and iodine.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Injection {
    /// The vessel the tip is in.
    pub vessel: usize,
    /// The tip's arc length along that vessel (m from its start).
    pub arc: f64,
    /// Injected volume flow (m³/s; 1 mL/s = 1e-6 m³/s). Zero stops the injection.
    pub rate: f64,
    /// Iodine concentration of the injected agent (mg/mL, which is kg/m³), 270–400 typical.
    pub concentration: f64,
}

/// The flow in one vessel. Positive flow runs from the vessel's start node to its end node.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VesselFlow {
    /// Flow upstream of an injection point, or the vessel's flow when there is none (m³/s).
    pub proximal: f64,
    /// Flow downstream of the injection point (m³/s): `proximal + injection rate`.
    pub distal: f64,
    /// Where the flow changes from `proximal` to `distal` (m along the vessel); the vessel's
    /// length when there is no injection in it.
    pub split_arc: f64,
}

impl VesselFlow {
    /// Flow at arc length `arc` (m³/s).
    pub fn at(&self, arc: f64) -> f64 {
        if arc < self.split_arc {
            self.proximal
        } else {
            self.distal
        }
    }
}

/// A solved flow field.
#[derive(Debug, Clone, PartialEq)]
pub struct FlowSolution {
    /// Pressure at each node (Pa).
    pub pressure: Vec<f64>,
    /// Flow in each vessel.
    pub vessels: Vec<VesselFlow>,
    /// Flow entering at the inlet (m³/s); negative if a strong injection drives blood out there.
    pub inlet_flow: f64,
    /// Flow leaving through each outlet (m³/s), in the network's outlet order.
    pub outlet_flows: Vec<f64>,
    /// The injection this solution includes, if any.
    pub injection: Option<Injection>,
}

impl FlowSolution {
    /// For each node, the net flow leaving it through vessels and boundaries (m³/s): zero by
    /// Kirchhoff's law, so this measures the solve's conservation error.
    pub fn kirchhoff_residuals(&self, network: &FlowNetwork) -> Vec<f64> {
        let mut net = vec![0.0; network.node_count];
        for (v, f) in network.vessels.iter().zip(&self.vessels) {
            net[v.from] += f.proximal;
            net[v.to] -= f.distal;
        }
        net[network.inlet.node] -= self.inlet_flow;
        for (o, q) in network.outlets.iter().zip(&self.outlet_flows) {
            net[o.node] += q;
        }
        net
    }
}

/// The factorized flow problem of one network. Build it once per anatomy; [`FlowSolver::solve`]
/// is then two triangular solves, and narrowings cost a few more.
pub struct FlowSolver {
    network: FlowNetwork,
    /// Unknown-pressure index of each node, or `None` where the pressure is prescribed.
    unknown: Vec<Option<usize>>,
    /// Prescribed pressure of each node, where there is one (Pa).
    prescribed: Vec<Option<f64>>,
    /// Conductance of each vessel in the factorized matrix: the open lumen with its clots
    /// (m³/(Pa·s)).
    base_conductance: Vec<f64>,
    /// Conductance with the current narrowings.
    conductance: Vec<f64>,
    /// Narrowings per vessel.
    narrowings: Vec<Vec<Narrowing>>,
    /// Clots per vessel.
    occlusions: Vec<Vec<Occlusion>>,
    llt: Llt<usize, f64>,
    unknown_count: usize,
    woodbury: Option<Woodbury>,
    /// Vessels at each node: (vessel, node is its start).
    incidence: Vec<Vec<(usize, bool)>>,
    /// Outlet index at each node.
    outlet_at: Vec<Option<usize>>,
    /// A spanning tree from the inlet in breadth-first order: (node, vessel to its parent).
    tree_order: Vec<(usize, usize)>,
}

/// The low-rank correction for narrowed vessels: `(A + U D Uᵀ)⁻¹ = A⁻¹ − Z C⁻¹ Uᵀ A⁻¹` with
/// `Z = A⁻¹ U` and `C = D⁻¹ + Uᵀ Z`.
struct Woodbury {
    /// The changed vessels.
    vessels: Vec<usize>,
    /// `A⁻¹ U`, one column per changed vessel.
    z: DMatrix<f64>,
    /// LU of the capacitance matrix `C`.
    capacitance: nalgebra::LU<f64, nalgebra::Dyn, nalgebra::Dyn>,
}

impl std::fmt::Debug for FlowSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FlowSolver")
            .field("nodes", &self.network.node_count)
            .field("vessels", &self.network.vessels.len())
            .field("unknowns", &self.unknown_count)
            .field(
                "narrowed_vessels",
                &self.woodbury.as_ref().map_or(0, |w| w.vessels.len()),
            )
            .finish()
    }
}

impl FlowSolver {
    /// Assembles the nodal conductance matrix of `network` and factorizes it (sparse Cholesky
    /// with a fill-reducing ordering).
    pub fn new(network: FlowNetwork) -> Result<Self> {
        let n = network.node_count;
        let mut prescribed = vec![None; n];
        if let InletCondition::Pressure(p) = network.inlet.condition {
            prescribed[network.inlet.node] = Some(p);
        }
        for o in &network.outlets {
            if o.resistance == 0.0 {
                prescribed[o.node] = Some(o.pressure);
            }
        }
        let mut unknown = vec![None; n];
        let mut unknown_count = 0;
        for (node, slot) in unknown.iter_mut().enumerate() {
            if prescribed[node].is_none() {
                *slot = Some(unknown_count);
                unknown_count += 1;
            }
        }
        let eta = network.blood.viscosity;
        let base_conductance: Vec<f64> = network
            .vessels
            .iter()
            .map(|v| 1.0 / v.resistance_between(eta, 0.0, v.length()))
            .collect();
        let llt = factorize(&network, &unknown, unknown_count, &base_conductance)?;
        let incidence = network.incidence();
        let mut outlet_at = vec![None; n];
        for (i, o) in network.outlets.iter().enumerate() {
            outlet_at[o.node] = Some(i);
        }
        let mut tree_order = Vec::with_capacity(n);
        let mut seen = vec![false; n];
        seen[network.inlet.node] = true;
        let mut queue = std::collections::VecDeque::from([network.inlet.node]);
        while let Some(node) = queue.pop_front() {
            for &(v, is_start) in &incidence[node] {
                let vessel = &network.vessels[v];
                let other = if is_start { vessel.to } else { vessel.from };
                if !std::mem::replace(&mut seen[other], true) {
                    tree_order.push((other, v));
                    queue.push_back(other);
                }
            }
        }
        Ok(Self {
            incidence,
            outlet_at,
            tree_order,
            narrowings: vec![Vec::new(); network.vessels.len()],
            occlusions: vec![Vec::new(); network.vessels.len()],
            conductance: base_conductance.clone(),
            network,
            unknown,
            prescribed,
            base_conductance,
            llt,
            unknown_count,
            woodbury: None,
        })
    }

    /// The network this solver was built for.
    pub fn network(&self) -> &FlowNetwork {
        &self.network
    }

    /// Number of unknown node pressures (the size of the factorized matrix).
    pub fn unknown_count(&self) -> usize {
        self.unknown_count
    }

    /// Current conductance of each vessel, narrowings included (m³/(Pa·s)).
    pub fn conductances(&self) -> &[f64] {
        &self.conductance
    }

    /// Replaces the catheter narrowings (an empty slice restores the open lumen). The
    /// factorization is kept; the change enters as a rank-k update, k = the number of narrowed
    /// vessels, costing k re-solves here and a k×k solve per [`FlowSolver::solve`].
    pub fn set_narrowings(&mut self, narrowings: &[Narrowing]) -> Result<()> {
        let mut per_vessel = vec![Vec::new(); self.network.vessels.len()];
        for n in narrowings {
            let vessel = self.network.vessel_at(n.vessel)?;
            require_non_negative(|| "narrowing catheter radius (m)".into(), n.catheter_radius)?;
            require_finite(|| "narrowing start arc (m)".into(), n.from_arc)?;
            require_finite(|| "narrowing end arc (m)".into(), n.to_arc)?;
            if n.to_arc < n.from_arc {
                return Err(HemoError::InvalidParameter {
                    name: format!("narrowing in vessel {:?} end arc (m)", vessel.name),
                    value: n.to_arc,
                    requirement: "at least its start arc",
                });
            }
            per_vessel[n.vessel].push(*n);
        }
        self.narrowings = per_vessel;
        self.apply_narrowings()
    }

    /// Replaces the clots (an empty slice removes them all). Clots change the factorized
    /// matrix itself (they are placed and removed rarely, and a low-rank update of a vessel
    /// losing nearly all its conductance would cancel digits): the network is refactorized,
    /// then the narrowings are applied on top.
    pub fn set_occlusions(&mut self, occlusions: &[Occlusion]) -> Result<()> {
        let mut per_vessel = vec![Vec::new(); self.network.vessels.len()];
        for o in occlusions {
            let vessel = self.network.vessel_at(o.vessel)?;
            o.validate(&vessel.name, vessel.length())?;
            per_vessel[o.vessel].push(*o);
        }
        let eta = self.network.blood.viscosity;
        let base: Vec<f64> = self
            .network
            .vessels
            .iter()
            .zip(&per_vessel)
            .map(|(v, clots)| 1.0 / part_resistance(v, eta, &[], clots, 0.0, v.length()))
            .collect();
        self.llt = factorize(&self.network, &self.unknown, self.unknown_count, &base)?;
        self.base_conductance = base;
        self.occlusions = per_vessel;
        self.apply_narrowings()
    }

    /// The clots in place, per vessel.
    pub fn occlusions(&self) -> impl Iterator<Item = &Occlusion> {
        self.occlusions.iter().flatten()
    }

    /// Conductances with the narrowings and clots, and the low-rank update for the vessels
    /// whose conductance differs from the factorized one.
    fn apply_narrowings(&mut self) -> Result<()> {
        let eta = self.network.blood.viscosity;
        let mut changed = Vec::new();
        for (i, v) in self.network.vessels.iter().enumerate() {
            if self.narrowings[i].is_empty() {
                self.conductance[i] = self.base_conductance[i];
                continue;
            }
            let r = part_resistance(
                v,
                eta,
                &self.narrowings[i],
                &self.occlusions[i],
                0.0,
                v.length(),
            );
            self.conductance[i] = 1.0 / r;
            if self.conductance[i] != self.base_conductance[i] {
                changed.push(i);
            }
        }
        self.woodbury = if changed.is_empty() {
            None
        } else {
            Some(self.woodbury_for(changed)?)
        };
        Ok(())
    }

    fn woodbury_for(&self, vessels: Vec<usize>) -> Result<Woodbury> {
        let k = vessels.len();
        let m = self.unknown_count;
        let mut z = DMatrix::zeros(m, k);
        let mut d_inv = DVector::zeros(k);
        for (c, &v) in vessels.iter().enumerate() {
            let vessel = &self.network.vessels[v];
            if let Some(i) = self.unknown[vessel.from] {
                z[(i, c)] += 1.0;
            }
            if let Some(i) = self.unknown[vessel.to] {
                z[(i, c)] -= 1.0;
            }
            d_inv[c] = 1.0 / (self.conductance[v] - self.base_conductance[v]);
        }
        let u = z.clone();
        // Z = A⁻¹ U, column by column through the factorization.
        for c in 0..k {
            let mut column: Vec<f64> = z.column(c).iter().copied().collect();
            self.llt
                .solve_in_place(MatMut::from_column_major_slice_mut(&mut column, m, 1));
            z.column_mut(c).copy_from_slice(&column);
        }
        let mut capacitance = u.transpose() * &z;
        for c in 0..k {
            capacitance[(c, c)] += d_inv[c];
        }
        Ok(Woodbury {
            vessels,
            z,
            capacitance: capacitance.lu(),
        })
    }

    /// Solves for node pressures and vessel flows, with an optional injection (a point source of
    /// volume at the catheter tip; the flow upstream of it can reverse when it exceeds the
    /// vessel's resting flow).
    pub fn solve(&self, injection: Option<&Injection>) -> Result<FlowSolution> {
        let network = &self.network;
        let m = self.unknown_count;
        let mut rhs = vec![0.0; m];
        if let InletCondition::Flow(q) = network.inlet.condition
            && let Some(i) = self.unknown[network.inlet.node]
        {
            rhs[i] += q;
        }
        for o in &network.outlets {
            if o.resistance > 0.0
                && let Some(i) = self.unknown[o.node]
            {
                rhs[i] += o.pressure / o.resistance;
            }
        }
        for (v, g) in network.vessels.iter().zip(&self.conductance) {
            match (self.unknown[v.from], self.unknown[v.to]) {
                (Some(i), None) => rhs[i] += g * self.prescribed[v.to].unwrap_or(0.0),
                (None, Some(j)) => rhs[j] += g * self.prescribed[v.from].unwrap_or(0.0),
                _ => {}
            }
        }
        // An injection at arc s splits its vessel into R1 = R(0, s) and R2 = R(s, L). Eliminating
        // the point leaves the vessel's conductance unchanged and injects J·R2/(R1+R2) at the
        // start node and J·R1/(R1+R2) at the end node: only the right-hand side changes.
        let split = match injection {
            Some(inj) => Some(self.injection_split(inj)?),
            None => None,
        };
        if let Some((inj, r1, r2)) = split {
            let vessel = &network.vessels[inj.vessel];
            if let Some(i) = self.unknown[vessel.from] {
                rhs[i] += inj.rate * r2 / (r1 + r2);
            }
            if let Some(j) = self.unknown[vessel.to] {
                rhs[j] += inj.rate * r1 / (r1 + r2);
            }
        }
        self.llt
            .solve_in_place(MatMut::from_column_major_slice_mut(&mut rhs, m, 1));
        if let Some(w) = &self.woodbury {
            // x = y − Z C⁻¹ Uᵀ y.
            let uty = DVector::from_iterator(
                w.vessels.len(),
                w.vessels.iter().map(|&v| {
                    let vessel = &network.vessels[v];
                    self.unknown[vessel.from].map_or(0.0, |i| rhs[i])
                        - self.unknown[vessel.to].map_or(0.0, |j| rhs[j])
                }),
            );
            let coefficients = w
                .capacitance
                .solve(&uty)
                .ok_or_else(|| HemoError::Solver("singular narrowing update".into()))?;
            let correction = &w.z * coefficients;
            for (x, c) in rhs.iter_mut().zip(correction.iter()) {
                *x -= c;
            }
        }
        let pressure: Vec<f64> = (0..network.node_count)
            .map(|n| match self.unknown[n] {
                Some(i) => rhs[i],
                None => self.prescribed[n].unwrap_or(0.0),
            })
            .collect();
        if let Some(bad) = pressure.iter().position(|p| !p.is_finite()) {
            return Err(HemoError::Solver(format!(
                "node {bad} pressure is not finite"
            )));
        }
        let mut vessels: Vec<VesselFlow> = network
            .vessels
            .iter()
            .zip(&self.conductance)
            .map(|(v, g)| {
                let q = g * (pressure[v.from] - pressure[v.to]);
                VesselFlow {
                    proximal: q,
                    distal: q,
                    split_arc: v.length(),
                }
            })
            .collect();
        if let Some((inj, r1, r2)) = split {
            let f = &mut vessels[inj.vessel];
            f.proximal -= inj.rate * r2 / (r1 + r2);
            f.distal = f.proximal + inj.rate;
            f.split_arc = inj.arc;
        }
        self.conserve_along_tree(&pressure, &mut vessels);
        // Boundary flows from the node balances (exact at prescribed-pressure nodes).
        let mut leaving = vec![0.0; network.node_count];
        for (v, f) in network.vessels.iter().zip(&vessels) {
            leaving[v.from] += f.proximal;
            leaving[v.to] -= f.distal;
        }
        let inlet_flow = match network.inlet.condition {
            InletCondition::Flow(q) => q,
            InletCondition::Pressure(_) => leaving[network.inlet.node],
        };
        let outlet_flows = network
            .outlets
            .iter()
            .map(|o| {
                if o.resistance > 0.0 {
                    (pressure[o.node] - o.pressure) / o.resistance
                } else {
                    -leaving[o.node]
                }
            })
            .collect();
        Ok(FlowSolution {
            pressure,
            vessels,
            inlet_flow,
            outlet_flows,
            injection: injection.copied(),
        })
    }

    /// Flows from pressure differences lose digits where a large vessel carries a small drop
    /// (ΔP ≪ P): each is right to ~ε·P·g, which leaves junction imbalances of ~1e-12 of the
    /// flow. Recomputing the spanning tree's vessels from the node balances, leaves first, makes
    /// every junction (except the inlet and fixed-pressure outlets, which take the balance as
    /// their boundary flow) conserve flow to rounding.
    fn conserve_along_tree(&self, pressure: &[f64], vessels: &mut [VesselFlow]) {
        let network = &self.network;
        for &(node, tree_vessel) in self.tree_order.iter().rev() {
            let terminal_out = match self.outlet_at[node] {
                Some(o) => {
                    let outlet = &network.outlets[o];
                    if outlet.resistance == 0.0 {
                        continue;
                    }
                    (pressure[node] - outlet.pressure) / outlet.resistance
                }
                None => 0.0,
            };
            let mut others = terminal_out;
            for &(v, is_start) in &self.incidence[node] {
                if v != tree_vessel {
                    others += if is_start {
                        vessels[v].proximal
                    } else {
                        -vessels[v].distal
                    };
                }
            }
            let f = &mut vessels[tree_vessel];
            let added = f.distal - f.proximal;
            if network.vessels[tree_vessel].to == node {
                f.distal = others;
                f.proximal = others - added;
            } else {
                f.proximal = -others;
                f.distal = -others + added;
            }
        }
    }

    /// Validates an injection and returns it with the resistances upstream and downstream of
    /// its point.
    fn injection_split(&self, inj: &Injection) -> Result<(Injection, f64, f64)> {
        let vessel = self.network.vessel_at(inj.vessel)?;
        require_non_negative(|| "injection rate (m³/s)".into(), inj.rate)?;
        require_non_negative(
            || "injection iodine concentration (mg/mL)".into(),
            inj.concentration,
        )?;
        require_finite(|| "injection arc (m)".into(), inj.arc)?;
        let length = vessel.length();
        if !(0.0..=length).contains(&inj.arc) {
            return Err(HemoError::InvalidParameter {
                name: format!("injection arc (m) in vessel {:?}", vessel.name),
                value: inj.arc,
                requirement: "within the vessel's length",
            });
        }
        let eta = self.network.blood.viscosity;
        let narrowings = &self.narrowings[inj.vessel];
        let clots = &self.occlusions[inj.vessel];
        let r1 = part_resistance(vessel, eta, narrowings, clots, 0.0, inj.arc);
        let r2 = part_resistance(vessel, eta, narrowings, clots, inj.arc, length);
        require_positive(|| "vessel resistance (Pa·s/m³)".into(), r1 + r2)?;
        Ok((*inj, r1, r2))
    }
}

/// Resistance of `[a, b]` of a vessel with its narrowings and clots (Pa·s/m³). A clot's
/// stretch is its Darcy resistance instead of the open lumen's (a catheter through a clot
/// adds its narrowing on top, negligible beside the clot).
fn part_resistance(
    vessel: &Vessel,
    viscosity: f64,
    narrowings: &[Narrowing],
    clots: &[Occlusion],
    a: f64,
    b: f64,
) -> f64 {
    let mut r = vessel.resistance_between(viscosity, a, b);
    for n in narrowings {
        let (lo, hi) = (n.from_arc.max(a), n.to_arc.min(b));
        if hi > lo {
            r += vessel.annular_resistance_between(viscosity, lo, hi, n.catheter_radius)
                - vessel.resistance_between(viscosity, lo, hi);
        }
    }
    for c in clots {
        let (lo, hi) = (c.from_arc.max(a), c.to_arc.min(b));
        if hi > lo {
            r += vessel.darcy_resistance_between(viscosity, c.permeability_m2, lo, hi)
                - vessel.resistance_between(viscosity, lo, hi);
        }
    }
    r
}

fn factorize(
    network: &FlowNetwork,
    unknown: &[Option<usize>],
    m: usize,
    conductance: &[f64],
) -> Result<Llt<usize, f64>> {
    if m == 0 {
        return Err(HemoError::Solver(
            "every node has a prescribed pressure: nothing to solve".into(),
        ));
    }
    let mut triplets = Vec::with_capacity(3 * network.vessels.len() + network.outlets.len());
    for (v, &g) in network.vessels.iter().zip(conductance) {
        let (a, b) = (unknown[v.from], unknown[v.to]);
        if let Some(i) = a {
            triplets.push(Triplet::new(i, i, g));
        }
        if let Some(j) = b {
            triplets.push(Triplet::new(j, j, g));
        }
        if let (Some(i), Some(j)) = (a, b) {
            let (row, col) = if i > j { (i, j) } else { (j, i) };
            triplets.push(Triplet::new(row, col, -g));
        }
    }
    for o in &network.outlets {
        if o.resistance > 0.0
            && let Some(i) = unknown[o.node]
        {
            triplets.push(Triplet::new(i, i, 1.0 / o.resistance));
        }
    }
    let matrix = SparseColMat::<usize, f64>::try_new_from_triplets(m, m, &triplets)
        .map_err(|e| HemoError::Solver(format!("assembly: {e:?}")))?;
    let symbolic = SymbolicLlt::try_new(matrix.symbolic(), Side::Lower)
        .map_err(|e| HemoError::Solver(format!("symbolic factorization: {e:?}")))?;
    Llt::try_new_with_symbolic(symbolic, matrix.as_ref(), Side::Lower).map_err(|e| {
        HemoError::Solver(format!(
            "the conductance matrix is not positive definite ({e:?}): is every part of the \
             network connected to an outlet?"
        ))
    })
}
