//! A discretised device: node positions and quaternion frames, the incremental
//! (co-rotational) Timoshenko formulation, assembly, and the paper and converged step modes.
//!
//! **Kinematics.** Node `i` has a position `x_i` (m) and a unit quaternion `q_i` mapping its
//! material frame (x along the device) to the world. For each element the rest configuration
//! stores the chord length `l0` and, per end node, the constant offset `O_i = R_i0ᵀ R_e0`
//! between the node frame and the element frame at rest, so a curved rest shape carries no
//! stress. In the current configuration the element frame `R_e` has its x axis along the
//! chord and its y/z axes from the mid-rotation of `R_1 O_1` and `R_2 O_2`; the local
//! deformation ū − ū0 is then (chord − l0, θ̄1, θ̄2) with θ̄_i = log(R_eᵀ R_i O_i).
//! This is the paper's Eq. (1) measured in a chord-aligned frame rather than the first node's
//! frame: it keeps every element in exact moment equilibrium in its current shape, which the
//! first-node frame does not (its error would make the scheme first-order accurate).
//!
//! **Step.** The local stiffness K̄e is rotated by Λ = diag(R_e, R_e, R_e, R_e) into
//! `K_e = Λᵀ K̄e Λ` (Eq. 3) and assembled; the elastic force `−γ Λᵀ K̄e (ū − ū0)` (Eq. 5,
//! with the sign that restores the rest shape) is added to the external forces, and one linear
//! solve (the substructure solver) gives the increments, applied as x += Δx and
//! q ← exp(Δθ) q. The *paper mode* does this once per step; the *converged mode* repeats it
//! (γ = 1) until the increments fall below a tolerance, which is a quasi-Newton solve of
//! static equilibrium. Optionally the tangent includes the geometric stiffness of the current
//! axial force, which keeps the iteration contractive under large tension.
//!
//! Note that with γ < 1 the paper's step leaves the static equilibrium at f_int = f_ext/γ, so
//! γ = 1 (the default) is the only value that reproduces applied loads exactly.

use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3, Vector6};

use crate::contact::{Contact, ContactResponse, ContactSettings, gauss_seidel, point_displacement};
use crate::device::Device;
use crate::element::{BendingCoefficients, local_geometric_stiffness, local_stiffness};
use crate::error::{DivergenceCheck, PhysicsError, Result, require_finite, require_positive};
use crate::section::BeamProperties;
use crate::substructure::{BlockTridiagonal, Flexibility, Substructure};

/// How a step is computed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StepMode {
    /// The paper's incremental method: one linear solve per step with restoring-force factor
    /// γ ∈ (0, 1].
    Incremental {
        /// γ of Eq. (5).
        gamma: f64,
    },
    /// Repeat the linearisation within the step until the largest translation increment is
    /// below `tolerance`·(device length) and the largest rotation increment below
    /// `tolerance` rad, or `max_iterations` is reached.
    Converged {
        /// Relative tolerance (dimensionless).
        tolerance: f64,
        /// Iteration cap per step.
        max_iterations: usize,
    },
}

impl StepMode {
    /// The paper mode with γ = 1.
    pub const PAPER: StepMode = StepMode::Incremental { gamma: 1.0 };
    /// Converged mode to 1e-8 relative increments, at most 100 iterations. (Slender wires,
    /// L/r ~ 10⁴, have a round-off floor near 1e-9·L in their increments.)
    pub const CONVERGED: StepMode = StepMode::Converged {
        tolerance: 1e-8,
        max_iterations: 100,
    };
}

/// Solver options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolverSettings {
    /// Paper or converged step.
    pub mode: StepMode,
    /// Add the geometric (axial-force) stiffness to the tangent.
    pub geometric_stiffness: bool,
    /// Compute the flexibility blocks (diagonal of K⁻¹ and couplings) each step.
    pub compute_flexibility: bool,
    /// Viscous drag of the surrounding fluid, which turns each quasi-static step into a step
    /// of overdamped motion: `(K + C/Δt) Δu = f_ext − f_int`. It leaves every equilibrium
    /// unchanged (Δu = 0 there) and keeps steps bounded where K is near-singular (buckling).
    pub drag: Option<ViscousDrag>,
    /// Largest node translation (m) and rotation (rad) of the free motion in a step with
    /// contacts; a larger free increment is scaled down as a whole before the contacts are
    /// solved, so a violent event such as buckling proceeds over several steps.
    pub max_step_increment: Option<(f64, f64)>,
    /// Include the geometric stiffness of compressed elements too. Off, only tension stiffens
    /// the tangent: the tangent stays positive definite however hard the device is pushed, and
    /// the step relaxes into a buckled shape instead of following an unstable straight branch
    /// (see the buckling test).
    pub geometric_stiffness_in_compression: bool,
    /// Converged mode only: when a step trips an increment guard (a rotation larger than π, a
    /// translation larger than [`MAX_TRANSLATION_INCREMENT_LENGTHS`] device lengths) or does
    /// not converge, it is redone as sub-steps that apply the change of loads and base pose
    /// since the last step in fractions, halving the fraction up to this many times before
    /// the step is reported as diverged (0: never split).
    pub max_substep_halvings: usize,
}

/// Viscous drag per unit length on the device (Levenberg–Marquardt regularization with a
/// physical meaning).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViscousDrag {
    /// Drag force per unit length per unit velocity (N·s/m²); rotations get the drag of a rod
    /// segment turning about its centre, c·ℓ³/12 per node.
    pub per_length_n_s_per_m2: f64,
    /// The time step it acts over (s).
    pub time_step_s: f64,
}

impl Default for SolverSettings {
    fn default() -> Self {
        Self {
            mode: StepMode::PAPER,
            geometric_stiffness: true,
            compute_flexibility: true,
            drag: None,
            max_step_increment: None,
            geometric_stiffness_in_compression: true,
            max_substep_halvings: 10,
        }
    }
}

/// A single linear solve that moves a node by more than this many device lengths is taken
/// as divergence: no quasi-static load a device can bear does that.
pub const MAX_TRANSLATION_INCREMENT_LENGTHS: f64 = 10.0;

/// What a step did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepReport {
    /// Linear solves performed.
    pub iterations: usize,
    /// Whether the converged mode met its tolerance (always true in paper mode).
    pub converged: bool,
    /// Largest node translation increment of the last iteration (m).
    pub last_translation_increment_m: f64,
    /// Largest node rotation increment of the last iteration (rad).
    pub last_rotation_increment_rad: f64,
}

/// A saved model state (see [`BeamModel::snapshot`]).
#[derive(Debug, Clone)]
pub struct BeamSnapshot {
    elements: Vec<Element>,
    positions: Vec<Vector3<f64>>,
    rotations: Vec<UnitQuaternion<f64>>,
    rest_positions: Vec<Vector3<f64>>,
    rest_rotations: Vec<UnitQuaternion<f64>>,
    external: Vec<Vector6<f64>>,
    last_external: Vec<Vector6<f64>>,
    last_base: (Vector3<f64>, UnitQuaternion<f64>),
    length_m: f64,
    step_count: u64,
}

/// What a step with contacts did.
#[derive(Debug, Clone, PartialEq)]
pub struct ContactStep {
    /// The beam step (one linear solve plus the contact correction).
    pub report: StepReport,
    /// The contacts detected for this step.
    pub contacts: Vec<Contact>,
    /// Their forces.
    pub response: ContactResponse,
    /// The deepest penetration the last detection saw in the solved configuration (m; 0 when
    /// none, or when only one detection round ran).
    pub penetration_m: f64,
}

/// Rest data and constant matrices of one element.
#[derive(Debug, Clone)]
struct Element {
    props: BeamProperties,
    rest_length_m: f64,
    offsets: [UnitQuaternion<f64>; 2],
    bending: BendingCoefficients,
    /// K̄e blocks (node-1/node-1, node-1/node-2, node-2/node-2) in frame-free form.
    stiffness: [AxisymmetricBlock6; 3],
    /// Geometric stiffness blocks per newton of axial force, frame-free form.
    geometric_per_newton: [AxisymmetricBlock6; 3],
}

/// A 3×3 block a·I + b·e eᵀ + c·[e]× of an axisymmetric beam: every sub-block of K̄e and of
/// the geometric stiffness has this form (Iy = Iz), so rotating it into the world frame
/// needs only the element axis e, not the full frame.
#[derive(Debug, Clone, Copy, Default)]
struct AxisymmetricBlock {
    iso: f64,
    axial: f64,
    skew: f64,
}

impl AxisymmetricBlock {
    /// Reads the coefficients off a local block (axis e = x).
    fn from_local(b: &Matrix3<f64>) -> Self {
        debug_assert!((b[(1, 1)] - b[(2, 2)]).abs() <= 1e-12 * b.abs().max());
        debug_assert!((b[(1, 2)] + b[(2, 1)]).abs() <= 1e-12 * b.abs().max());
        Self {
            iso: b[(1, 1)],
            axial: b[(0, 0)] - b[(1, 1)],
            skew: b[(2, 1)],
        }
    }

    fn scaled_add(&self, other: &Self, factor: f64) -> Self {
        Self {
            iso: self.iso + factor * other.iso,
            axial: self.axial + factor * other.axial,
            skew: self.skew + factor * other.skew,
        }
    }

    /// The block in the world frame for element axis `e` (unit).
    fn world(&self, e: &Vector3<f64>) -> Matrix3<f64> {
        let (a, b, c) = (self.iso, self.axial, self.skew);
        Matrix3::new(
            a + b * e.x * e.x,
            b * e.x * e.y - c * e.z,
            b * e.x * e.z + c * e.y,
            b * e.y * e.x + c * e.z,
            a + b * e.y * e.y,
            b * e.y * e.z - c * e.x,
            b * e.z * e.x - c * e.y,
            b * e.z * e.y + c * e.x,
            a + b * e.z * e.z,
        )
    }
}

/// A 6×6 block as four [`AxisymmetricBlock`]s (translation/rotation rows and columns).
#[derive(Debug, Clone, Copy, Default)]
struct AxisymmetricBlock6([[AxisymmetricBlock; 2]; 2]);

impl AxisymmetricBlock6 {
    fn from_local(k: &Matrix6<f64>) -> Self {
        let sub = |i: usize, j: usize| {
            AxisymmetricBlock::from_local(&k.fixed_view::<3, 3>(3 * i, 3 * j).into_owned())
        };
        Self([[sub(0, 0), sub(0, 1)], [sub(1, 0), sub(1, 1)]])
    }

    fn scaled_add(&self, other: &Self, factor: f64) -> Self {
        let f = |i: usize, j: usize| self.0[i][j].scaled_add(&other.0[i][j], factor);
        Self([[f(0, 0), f(0, 1)], [f(1, 0), f(1, 1)]])
    }

    /// Adds the world-frame block for element axis `e` into `out`.
    fn add_world_to(&self, e: &Vector3<f64>, out: &mut Matrix6<f64>) {
        for i in 0..2 {
            for j in 0..2 {
                let mut view = out.fixed_view_mut::<3, 3>(3 * i, 3 * j);
                view += self.0[i][j].world(e);
            }
        }
    }
}

impl Element {
    /// An element from its rest geometry alone (the offsets are relative, so the pose of the
    /// rest shape does not matter).
    fn from_spec(spec: &ElementSpec) -> Result<Self> {
        require_positive(|| "element length_m".into(), spec.length_m)?;
        for v in spec.curvature_per_m.iter() {
            require_finite(|| "element curvature_per_m".into(), *v)?;
        }
        let (dp, dq) = arc_increment(&spec.curvature_per_m, spec.length_m);
        let frame = element_frame(&UnitQuaternion::identity(), &dq, &dp);
        Ok(Self::new(
            spec.props,
            dp.norm(),
            [frame, dq.inverse() * frame],
        ))
    }

    fn new(props: BeamProperties, rest_length_m: f64, offsets: [UnitQuaternion<f64>; 2]) -> Self {
        let split = |k: &crate::element::Matrix12| {
            [(0, 0), (0, 6), (6, 6)].map(|(i, j)| {
                AxisymmetricBlock6::from_local(&k.fixed_view::<6, 6>(i, j).into_owned())
            })
        };
        let phi = 12.0 * props.bending_stiffness_nm2
            / (props.shear_stiffness_n * rest_length_m * rest_length_m);
        Self {
            props,
            rest_length_m,
            offsets,
            bending: BendingCoefficients::new(props.bending_stiffness_nm2, rest_length_m, phi),
            stiffness: split(&local_stiffness(&props, rest_length_m)),
            geometric_per_newton: split(&local_geometric_stiffness(&props, rest_length_m, 1.0)),
        }
    }
}

/// The element frame and local deformation in the current configuration.
#[derive(Debug, Clone, Copy)]
struct ElementState {
    frame: Matrix3<f64>,
    chord_m: f64,
    theta: [Vector3<f64>; 2],
}

/// A discretised device (or test beam) with its current configuration.
#[derive(Debug, Clone)]
pub struct BeamModel {
    elements: Vec<Element>,
    positions: Vec<Vector3<f64>>,
    rotations: Vec<UnitQuaternion<f64>>,
    rest_positions: Vec<Vector3<f64>>,
    rest_rotations: Vec<UnitQuaternion<f64>>,
    external: Vec<Vector6<f64>>,
    /// External loads and base pose at the end of the last completed step: where a split step
    /// starts from.
    last_external: Vec<Vector6<f64>>,
    last_base: (Vector3<f64>, UnitQuaternion<f64>),
    settings: SolverSettings,
    step_count: u64,
    length_m: f64,
    // Work buffers, reused every step.
    stiffness: BlockTridiagonal,
    substructure: Substructure,
    flexibility: Flexibility,
    internal: Vec<Vector6<f64>>,
    rhs: Vec<Vector6<f64>>,
    saved_positions: Vec<Vector3<f64>>,
    saved_rotations: Vec<UnitQuaternion<f64>>,
}

/// Unit vector of the material x axis (along the device).
fn axis_x() -> Vector3<f64> {
    Vector3::x()
}

/// Rest geometry of one element: properties, length (m) and rest curvature (1/m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ElementSpec {
    /// Section properties.
    pub props: BeamProperties,
    /// Arc length of the element at rest (m).
    pub length_m: f64,
    /// Rest curvature (Darboux) vector in the material frame at the element's start (1/m): x
    /// is the rest torsion rate, y and z the bending curvatures about the material y and z
    /// axes (a positive z component bends towards material +y). The element's rest shape is
    /// the helix the frame traces rotating at this constant rate.
    pub curvature_per_m: Vector3<f64>,
}

impl ElementSpec {
    /// An element bent in the material x–y plane: curvature `kappa_per_m` (1/m) about the
    /// material z axis, positive towards material +y.
    pub fn planar(props: BeamProperties, length_m: f64, kappa_per_m: f64) -> Self {
        Self {
            props,
            length_m,
            curvature_per_m: Vector3::new(0.0, 0.0, kappa_per_m),
        }
    }
}

impl BeamModel {
    /// A model from per-element specifications, clamped at `base_position` with material
    /// frame `base_rotation`; the rest shape is integrated exactly (circular arcs).
    pub fn new(
        specs: &[ElementSpec],
        base_position: Vector3<f64>,
        base_rotation: UnitQuaternion<f64>,
        settings: SolverSettings,
    ) -> Result<Self> {
        if specs.is_empty() {
            return Err(PhysicsError::TooFewElements { count: 0, min: 1 });
        }
        for (i, s) in specs.iter().enumerate() {
            require_positive(|| format!("element {i}: length_m"), s.length_m)?;
            for v in s.curvature_per_m.iter() {
                require_finite(|| format!("element {i}: curvature_per_m"), *v)?;
            }
        }
        for (i, v) in base_position.iter().enumerate() {
            require_finite(|| format!("base position component {i}"), *v)?;
        }
        let mut positions = vec![base_position];
        let mut rotations = vec![base_rotation];
        for s in specs {
            let (dp, dq) = arc_increment(&s.curvature_per_m, s.length_m);
            let (p, q) = (*positions.last().unwrap(), *rotations.last().unwrap());
            positions.push(p + q * dp);
            rotations.push(q * dq);
        }
        let elements = specs
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let (p1, p2) = (positions[i], positions[i + 1]);
                let (q1, q2) = (rotations[i], rotations[i + 1]);
                let chord = p2 - p1;
                let frame = element_frame(&q1, &q2, &chord);
                Element::new(
                    s.props,
                    chord.norm(),
                    [q1.inverse() * frame, q2.inverse() * frame],
                )
            })
            .collect::<Vec<_>>();
        let nodes = positions.len();
        Ok(Self {
            length_m: specs.iter().map(|s| s.length_m).sum(),
            elements,
            rest_positions: positions.clone(),
            rest_rotations: rotations.clone(),
            positions,
            rotations,
            external: vec![Vector6::zeros(); nodes],
            last_external: vec![Vector6::zeros(); nodes],
            last_base: (base_position, base_rotation),
            settings,
            step_count: 0,
            stiffness: BlockTridiagonal::zeros(nodes - 1),
            substructure: Substructure::default(),
            flexibility: Flexibility::default(),
            internal: vec![Vector6::zeros(); nodes],
            rhs: vec![Vector6::zeros(); nodes - 1],
            saved_positions: Vec::with_capacity(nodes),
            saved_rotations: Vec::with_capacity(nodes),
        })
    }

    /// A straight uniform beam of `elements` elements along the world x axis, clamped at the
    /// origin.
    pub fn straight(
        props: BeamProperties,
        length_m: f64,
        elements: usize,
        settings: SolverSettings,
    ) -> Result<Self> {
        if elements == 0 {
            return Err(PhysicsError::TooFewElements { count: 0, min: 1 });
        }
        let spec = ElementSpec::planar(props, length_m / elements as f64, 0.0);
        Self::new(
            &vec![spec; elements],
            Vector3::zeros(),
            UnitQuaternion::identity(),
            settings,
        )
    }

    /// A whole device in `elements` equal elements, clamped at the origin along world x.
    pub fn from_device(device: &Device, elements: usize, settings: SolverSettings) -> Result<Self> {
        Self::from_device_part(device, 0.0, device.length_m(), elements, settings)
    }

    /// The part of a device between arc lengths `start_m` and `end_m` (from its proximal end),
    /// e.g. only the inserted length, in `elements` equal elements, each with the section
    /// properties and rest curvature at its mid-point; node 0 (at `start_m`) is clamped at the
    /// origin with its material x axis along world x.
    pub fn from_device_part(
        device: &Device,
        start_m: f64,
        end_m: f64,
        elements: usize,
        settings: SolverSettings,
    ) -> Result<Self> {
        device.validate()?;
        if elements == 0 {
            return Err(PhysicsError::TooFewElements { count: 0, min: 1 });
        }
        let start = require_finite(|| "start_m".into(), start_m)?;
        let end = require_finite(|| "end_m".into(), end_m)?;
        if start < 0.0 || end > device.length_m() * (1.0 + 1e-12) || end <= start {
            return Err(PhysicsError::OutOfRange {
                what: format!("device part [{start}, {end}] m"),
                range: "0 <= start < end <= device length",
                value: end - start,
            });
        }
        let h = (end - start) / elements as f64;
        let specs: Vec<ElementSpec> = (0..elements)
            .map(|i| {
                let mid = start + (i as f64 + 0.5) * h;
                let a = start + i as f64 * h;
                ElementSpec {
                    props: device.section_at(mid).0.beam_properties(),
                    length_m: h,
                    curvature_per_m: device.mean_rest_curvature(a, a + h),
                }
            })
            .collect();
        Self::new(
            &specs,
            Vector3::zeros(),
            UnitQuaternion::identity(),
            settings,
        )
    }

    /// Number of elements.
    pub fn element_count(&self) -> usize {
        self.elements.len()
    }

    /// Number of nodes (elements + 1); node 0 is the driven base.
    pub fn node_count(&self) -> usize {
        self.positions.len()
    }

    /// Rest arc length of the whole beam (m).
    pub fn length_m(&self) -> f64 {
        self.length_m
    }

    /// Node positions (m, world frame).
    pub fn positions(&self) -> &[Vector3<f64>] {
        &self.positions
    }

    /// Node frames (material → world).
    pub fn rotations(&self) -> &[UnitQuaternion<f64>] {
        &self.rotations
    }

    /// Rest node positions (m) for the current base pose at construction.
    pub fn rest_positions(&self) -> &[Vector3<f64>] {
        &self.rest_positions
    }

    /// Rest node frames.
    pub fn rest_rotations(&self) -> &[UnitQuaternion<f64>] {
        &self.rest_rotations
    }

    /// Tip position (m).
    pub fn tip_position(&self) -> Vector3<f64> {
        *self.positions.last().expect("at least two nodes")
    }

    /// Solver settings.
    pub fn settings(&self) -> &SolverSettings {
        &self.settings
    }

    /// Replaces the solver settings.
    pub fn set_settings(&mut self, settings: SolverSettings) {
        self.settings = settings;
    }

    /// Steps taken so far.
    pub fn step_count(&self) -> u64 {
        self.step_count
    }

    /// Flexibility blocks of the unknown nodes 1..=N from the last step (empty before the
    /// first step or when disabled). Block `i` belongs to node `i + 1`.
    pub fn flexibility(&self) -> &Flexibility {
        &self.flexibility
    }

    /// Sets a constant (dead) external force (N) and moment (N·m) on `node`, world frame.
    pub fn set_load(
        &mut self,
        node: usize,
        force_n: Vector3<f64>,
        moment_nm: Vector3<f64>,
    ) -> Result<()> {
        if node >= self.node_count() {
            return Err(PhysicsError::LengthMismatch {
                what: "load node index (must be < node count)",
                expected: self.node_count(),
                actual: node,
            });
        }
        for (i, v) in force_n.iter().chain(moment_nm.iter()).enumerate() {
            require_finite(|| format!("load on node {node}, component {i}"), *v)?;
        }
        self.external[node] = Vector6::new(
            force_n.x,
            force_n.y,
            force_n.z,
            moment_nm.x,
            moment_nm.y,
            moment_nm.z,
        );
        Ok(())
    }

    /// Removes every external load.
    pub fn clear_loads(&mut self) {
        self.external.iter_mut().for_each(|f| f.fill(0.0));
    }

    /// Moves the base (node 0) to a new pose. The rest of the device follows rigidly as a
    /// predictor (exact for a free device); the next step resolves the deformation.
    pub fn set_base_pose(
        &mut self,
        position: Vector3<f64>,
        rotation: UnitQuaternion<f64>,
    ) -> Result<()> {
        require_finite_pose(&position, &rotation)?;
        let delta = rotation * self.rotations[0].inverse();
        let origin = self.positions[0];
        for (p, q) in self.positions.iter_mut().zip(self.rotations.iter_mut()) {
            *p = position + delta * (*p - origin);
            *q = delta * *q;
        }
        // The rigid move is exact for a free device: a split step does not undo it.
        self.last_base = (position, rotation);
        Ok(())
    }

    /// Pushes the base along its own axis by `insertion_m` (negative pulls) and twists it
    /// about that axis by `twist_rad`, relative to its current pose.
    pub fn drive_base(&mut self, insertion_m: f64, twist_rad: f64) -> Result<()> {
        require_finite(|| "insertion_m".into(), insertion_m)?;
        require_finite(|| "twist_rad".into(), twist_rad)?;
        let q = self.rotations[0];
        let axis = q * axis_x();
        let twist = UnitQuaternion::from_scaled_axis(axis * twist_rad);
        self.set_base_pose(self.positions[0] + axis * insertion_m, twist * q)
    }

    /// Moves only node 0 (the driven base) to a new pose, leaving every other node where it is:
    /// the next step carries the change along the device through its stiffness (a push or a
    /// twist at the entry point of a device that lies in a vessel).
    pub fn place_base(
        &mut self,
        position: Vector3<f64>,
        rotation: UnitQuaternion<f64>,
    ) -> Result<()> {
        require_finite_pose(&position, &rotation)?;
        self.positions[0] = position;
        self.rotations[0] = rotation;
        Ok(())
    }

    /// Moves every node to the given positions (m) and frames, e.g. a kinematic predictor
    /// before a step. The lengths must match the node count.
    pub fn set_nodes(
        &mut self,
        positions: &[Vector3<f64>],
        rotations: &[UnitQuaternion<f64>],
    ) -> Result<()> {
        for (what, len) in [
            ("node positions", positions.len()),
            ("node rotations", rotations.len()),
        ] {
            if len != self.node_count() {
                return Err(PhysicsError::LengthMismatch {
                    what,
                    expected: self.node_count(),
                    actual: len,
                });
            }
        }
        for (i, p) in positions.iter().enumerate() {
            for v in p.iter() {
                require_finite(|| format!("node {i} position"), *v)?;
            }
        }
        self.positions.copy_from_slice(positions);
        self.rotations.copy_from_slice(rotations);
        Ok(())
    }

    /// The model's state without its work buffers: what [`BeamModel::restore`] needs to undo
    /// the steps and discretization changes made since.
    pub fn snapshot(&self) -> BeamSnapshot {
        BeamSnapshot {
            elements: self.elements.clone(),
            positions: self.positions.clone(),
            rotations: self.rotations.clone(),
            rest_positions: self.rest_positions.clone(),
            rest_rotations: self.rest_rotations.clone(),
            external: self.external.clone(),
            last_external: self.last_external.clone(),
            last_base: self.last_base,
            length_m: self.length_m,
            step_count: self.step_count,
        }
    }

    /// Returns to a snapshot of this model.
    pub fn restore(&mut self, snapshot: BeamSnapshot) {
        self.elements = snapshot.elements;
        self.positions = snapshot.positions;
        self.rotations = snapshot.rotations;
        self.rest_positions = snapshot.rest_positions;
        self.rest_rotations = snapshot.rest_rotations;
        self.external = snapshot.external;
        self.last_external = snapshot.last_external;
        self.last_base = snapshot.last_base;
        self.length_m = snapshot.length_m;
        self.step_count = snapshot.step_count;
        self.resize_work_buffers();
    }

    /// Rest length of element `index` (m).
    pub fn element_rest_length(&self, index: usize) -> f64 {
        self.elements[index].rest_length_m
    }

    /// Replaces the rest geometry of element 0 (next to the base), e.g. as the device slides
    /// in or out through the entry point; the nodes stay where they are.
    pub fn set_base_element(&mut self, spec: ElementSpec) -> Result<()> {
        let element = Element::from_spec(&spec)?;
        self.length_m += element.rest_length_m - self.elements[0].rest_length_m;
        self.elements[0] = element;
        Ok(())
    }

    /// Splits element 0 by a new node 1 on its chord, `distal_length` (m, rest) from node 1
    /// (the old node 1 becomes node 2): the shape does not jump. `base` and `distal` are the two
    /// new elements' rest geometries.
    pub fn insert_node_after_base(&mut self, base: ElementSpec, distal: ElementSpec) -> Result<()> {
        let first = Element::from_spec(&base)?;
        let second = Element::from_spec(&distal)?;
        let fraction = first.rest_length_m / (first.rest_length_m + second.rest_length_m);
        let (p0, p1) = (self.positions[0], self.positions[1]);
        let position = p0 + (p1 - p0) * fraction;
        let rotation = self.rotations[0].slerp(&self.rotations[1], fraction);
        self.insert_node(0, first, second, position, rotation);
        Ok(())
    }

    /// Splits element `index` by a new node on the smooth curve through its two nodes: the
    /// cubic Hermite interpolant of their positions and tangents, evaluated at the rest-length
    /// fraction of `first` (the old node `index + 1` becomes `index + 2`). The frame is the
    /// slerp of the two node frames. No existing node moves, so the shape does not jump; the
    /// new node at the midpoint of a circular arc lies on it exactly. `first` and
    /// `second` are the two new elements' rest geometries.
    pub fn split_element(
        &mut self,
        index: usize,
        first: ElementSpec,
        second: ElementSpec,
    ) -> Result<()> {
        if index >= self.elements.len() {
            return Err(PhysicsError::OutOfRange {
                what: "element to split".into(),
                range: "0 to the element count − 1",
                value: index as f64,
            });
        }
        let a = Element::from_spec(&first)?;
        let b = Element::from_spec(&second)?;
        let f = a.rest_length_m / (a.rest_length_m + b.rest_length_m);
        let (position, rotation) = hermite_point(
            (&self.positions[index], &self.rotations[index]),
            (&self.positions[index + 1], &self.rotations[index + 1]),
            f,
        );
        self.insert_node(index, a, b, position, rotation);
        Ok(())
    }

    /// Replaces element `index` by `first` and `second` joined at a new node at `position`
    /// with frame `rotation`.
    fn insert_node(
        &mut self,
        index: usize,
        first: Element,
        second: Element,
        position: Vector3<f64>,
        rotation: UnitQuaternion<f64>,
    ) {
        self.length_m +=
            first.rest_length_m + second.rest_length_m - self.elements[index].rest_length_m;
        self.elements[index] = second;
        self.elements.insert(index, first);
        self.positions.insert(index + 1, position);
        self.rotations.insert(index + 1, rotation);
        self.rest_positions.insert(index + 1, position);
        self.rest_rotations.insert(index + 1, rotation);
        self.external.insert(index + 1, Vector6::zeros());
        self.last_external.insert(index + 1, Vector6::zeros());
        self.resize_work_buffers();
    }

    /// Removes node `index + 1`, joining elements `index` and `index + 1` into one with rest
    /// geometry `merged`; the other nodes stay where they are.
    pub fn merge_elements(&mut self, index: usize, merged: ElementSpec) -> Result<()> {
        if index + 1 >= self.elements.len() {
            return Err(PhysicsError::OutOfRange {
                what: "first of the two elements to merge".into(),
                range: "0 to the element count − 2",
                value: index as f64,
            });
        }
        let element = Element::from_spec(&merged)?;
        self.length_m += element.rest_length_m
            - self.elements[index].rest_length_m
            - self.elements[index + 1].rest_length_m;
        self.elements.remove(index);
        self.elements[index] = element;
        for v in [&mut self.positions, &mut self.rest_positions] {
            v.remove(index + 1);
        }
        for v in [&mut self.rotations, &mut self.rest_rotations] {
            v.remove(index + 1);
        }
        self.external.remove(index + 1);
        self.last_external.remove(index + 1);
        self.resize_work_buffers();
        Ok(())
    }

    /// Removes node 1, joining elements 0 and 1 into one with rest geometry `merged` (as the
    /// device is pulled out through the entry point). Needs at least two elements.
    pub fn remove_node_after_base(&mut self, merged: ElementSpec) -> Result<()> {
        if self.elements.len() < 2 {
            return Err(PhysicsError::TooFewElements {
                count: self.elements.len(),
                min: 2,
            });
        }
        self.merge_elements(0, merged)
    }

    /// Replaces the whole discretization at once: new rest geometries `specs`, node positions
    /// (m) and frames. Element `e` is copied from the current element `keep[e]` where that is
    /// `Some` (its rest geometry unchanged: no rebuild), else built from `specs[e]`. Loads are
    /// cleared. Used by coaxial stacks, whose nodes move along the path every step.
    pub fn remesh(
        &mut self,
        specs: &[ElementSpec],
        keep: &[Option<usize>],
        positions: &[Vector3<f64>],
        rotations: &[UnitQuaternion<f64>],
    ) -> Result<()> {
        let nodes = specs.len() + 1;
        for (what, len) in [
            ("element keep list", keep.len() + 1),
            ("node positions", positions.len()),
            ("node rotations", rotations.len()),
        ] {
            if len != nodes {
                return Err(PhysicsError::LengthMismatch {
                    what,
                    expected: nodes,
                    actual: len,
                });
            }
        }
        if specs.is_empty() {
            return Err(PhysicsError::TooFewElements { count: 0, min: 1 });
        }
        for (i, p) in positions.iter().enumerate() {
            for v in p.iter() {
                require_finite(|| format!("node {i} position"), *v)?;
            }
        }
        let mut elements = Vec::with_capacity(specs.len());
        for (spec, kept) in specs.iter().zip(keep) {
            match kept.and_then(|k| self.elements.get(k)) {
                Some(element) => elements.push(element.clone()),
                None => elements.push(Element::from_spec(spec)?),
            }
        }
        self.elements = elements;
        self.length_m = specs.iter().map(|s| s.length_m).sum();
        self.positions.clear();
        self.positions.extend_from_slice(positions);
        self.rotations.clear();
        self.rotations.extend_from_slice(rotations);
        self.rest_positions.clone_from(&self.positions);
        self.rest_rotations.clone_from(&self.rotations);
        for v in [&mut self.external, &mut self.last_external] {
            v.clear();
            v.resize(nodes, Vector6::zeros());
        }
        self.resize_work_buffers();
        Ok(())
    }

    fn resize_work_buffers(&mut self) {
        let nodes = self.positions.len();
        self.stiffness = BlockTridiagonal::zeros(nodes - 1);
        self.internal.resize(nodes, Vector6::zeros());
        self.rhs.resize(nodes - 1, Vector6::zeros());
    }

    /// Advances one step with the configured mode. In converged mode a step that trips an
    /// increment guard or does not converge is split (see
    /// [`SolverSettings::max_substep_halvings`]); the report then counts every sub-step's
    /// solves. On error the configuration is left as it was.
    pub fn step(&mut self) -> Result<StepReport> {
        self.saved_positions.clone_from(&self.positions);
        self.saved_rotations.clone_from(&self.rotations);
        let mut result = self.step_inner();
        if self.should_split(&result) {
            self.positions.clone_from(&self.saved_positions);
            self.rotations.clone_from(&self.saved_rotations);
            result = self.split_step();
        }
        self.step_count += 1;
        match result {
            Ok(_) => {
                self.last_external.clone_from(&self.external);
                self.last_base = (self.positions[0], self.rotations[0]);
            }
            Err(_) => {
                self.positions.clone_from(&self.saved_positions);
                self.rotations.clone_from(&self.saved_rotations);
            }
        }
        result
    }

    /// Whether a converged-mode step outcome calls for sub-steps.
    fn should_split(&self, result: &Result<StepReport>) -> bool {
        if self.settings.max_substep_halvings == 0
            || !matches!(self.settings.mode, StepMode::Converged { .. })
        {
            return false;
        }
        match result {
            Ok(report) => !report.converged,
            Err(PhysicsError::Diverged { check, .. }) => matches!(
                check,
                DivergenceCheck::RotationIncrement { .. }
                    | DivergenceCheck::TranslationIncrement { .. }
            ),
            Err(_) => false,
        }
    }

    /// The step again as sub-steps: loads and the base pose go from their values at the end
    /// of the last step to the requested ones in fractions, each fraction halved (up to
    /// `max_substep_halvings` times) while its sub-step trips a guard or does not converge.
    fn split_step(&mut self) -> Result<StepReport> {
        let target = self.external.clone();
        let start = self.last_external.clone();
        let (base_to, rotation_to) = (self.positions[0], self.rotations[0]);
        let (base_from, rotation_from) = self.last_base;
        let mut report = StepReport {
            iterations: 0,
            converged: true,
            last_translation_increment_m: 0.0,
            last_rotation_increment_rad: 0.0,
        };
        let (mut done, mut halvings) = (0.0f64, 1usize);
        let mut positions = self.positions.clone();
        let mut rotations = self.rotations.clone();
        let outcome = loop {
            if done >= 1.0 {
                break Ok(());
            }
            let to = (done + 0.5f64.powi(halvings as i32)).min(1.0);
            for ((f, a), b) in self.external.iter_mut().zip(&start).zip(&target) {
                *f = a + (b - a) * to;
            }
            self.positions[0] = base_from + (base_to - base_from) * to;
            self.rotations[0] = rotation_from.slerp(&rotation_to, to);
            let result = self.step_inner();
            if self.should_split(&result) && halvings < self.settings.max_substep_halvings {
                self.positions.clone_from(&positions);
                self.rotations.clone_from(&rotations);
                halvings += 1;
                continue;
            }
            match result {
                Ok(sub) => {
                    report.iterations += sub.iterations;
                    report.converged &= sub.converged;
                    report.last_translation_increment_m = sub.last_translation_increment_m;
                    report.last_rotation_increment_rad = sub.last_rotation_increment_rad;
                    positions.clone_from(&self.positions);
                    rotations.clone_from(&self.rotations);
                    done = to;
                }
                Err(e) => break Err(e),
            }
        };
        self.external = target;
        self.positions[0] = base_to;
        self.rotations[0] = rotation_to;
        outcome.map(|()| report)
    }

    fn step_inner(&mut self) -> Result<StepReport> {
        let (gamma, tolerance, max_iterations) = match self.settings.mode {
            StepMode::Incremental { gamma } => {
                require_finite(|| "gamma".into(), gamma)?;
                if !(gamma > 0.0 && gamma <= 1.0) {
                    return Err(PhysicsError::OutOfRange {
                        what: "gamma".into(),
                        range: "(0, 1]",
                        value: gamma,
                    });
                }
                (gamma, None, 1)
            }
            StepMode::Converged {
                tolerance,
                max_iterations,
            } => (
                1.0,
                Some(require_positive(|| "tolerance".into(), tolerance)?),
                max_iterations.max(1),
            ),
        };
        let mut report = StepReport {
            iterations: 0,
            converged: tolerance.is_none(),
            last_translation_increment_m: 0.0,
            last_rotation_increment_rad: 0.0,
        };
        for iteration in 0..max_iterations {
            let (dx, dtheta) =
                self.iterate(gamma, iteration == 0 && self.settings.compute_flexibility)?;
            report.iterations += 1;
            report.last_translation_increment_m = dx;
            report.last_rotation_increment_rad = dtheta;
            if let Some(tol) = tolerance
                && dx <= tol * self.length_m
                && dtheta <= tol
            {
                report.converged = true;
                break;
            }
        }
        Ok(report)
    }

    /// One linearisation and solve; returns the largest increments (m, rad).
    fn iterate(&mut self, gamma: f64, flexibility: bool) -> Result<(f64, f64)> {
        self.solve_free(gamma, flexibility)?;
        let increments = std::mem::take(&mut self.rhs);
        let result = self.apply_increments(&increments);
        self.rhs = increments;
        result
    }

    /// Assembles, factors and solves K Δu = f_ext − γ f_int: leaves the free increment of every
    /// unknown node in `self.rhs` (and the flexibility blocks, if asked).
    fn solve_free(&mut self, gamma: f64, flexibility: bool) -> Result<()> {
        self.assemble();
        for (i, rhs) in self.rhs.iter_mut().enumerate() {
            *rhs = self.external[i + 1] - gamma * self.internal[i + 1];
        }
        self.substructure.factor(&self.stiffness)?;
        self.substructure.solve_in_place(&mut self.rhs);
        if flexibility {
            self.substructure.flexibility_into(&mut self.flexibility);
        }
        Ok(())
    }

    /// Applies increments (one per unknown node) after the divergence checks; returns the
    /// largest translation (m) and rotation (rad) increment.
    fn apply_increments(&mut self, increments: &[Vector6<f64>]) -> Result<(f64, f64)> {
        let mut max_dx: f64 = 0.0;
        let mut max_dtheta: f64 = 0.0;
        for (i, du) in increments.iter().enumerate() {
            let dx = du.fixed_rows::<3>(0).into_owned();
            let dtheta = du.fixed_rows::<3>(3).into_owned();
            let diverged = |check| PhysicsError::Diverged {
                check,
                node: i + 1,
                step: self.step_count + 1,
            };
            if !du.iter().all(|v| v.is_finite()) {
                return Err(diverged(DivergenceCheck::NonFinite("increment")));
            }
            let limit_m = MAX_TRANSLATION_INCREMENT_LENGTHS * self.length_m;
            if dx.norm() > limit_m {
                return Err(diverged(DivergenceCheck::TranslationIncrement {
                    increment_m: dx.norm(),
                    limit_m,
                }));
            }
            if dtheta.norm() > std::f64::consts::PI {
                return Err(diverged(DivergenceCheck::RotationIncrement {
                    increment_rad: dtheta.norm(),
                }));
            }
            max_dx = max_dx.max(dx.norm());
            max_dtheta = max_dtheta.max(dtheta.norm());
        }
        for (i, du) in increments.iter().enumerate() {
            self.positions[i + 1] += du.fixed_rows::<3>(0).into_owned();
            let q = UnitQuaternion::from_scaled_axis(du.fixed_rows::<3>(3).into_owned())
                * self.rotations[i + 1];
            self.rotations[i + 1] = UnitQuaternion::new_normalize(q.into_inner());
        }
        Ok((max_dx, max_dtheta))
    }

    /// One paper-mode step with contact: the free increment is solved, `detect` turns the
    /// configuration and the free increment into contacts (positions, rotations, free increment
    /// per unknown node), Gauss–Seidel finds the contact forces through the flexibility blocks,
    /// and one more O(N) solve adds their effect. The contact forces are totals, not increments:
    /// the next step's residual no longer contains them, and its contact solve finds them again
    /// (warm-started from what `warm_start` returns for the detected contacts: local forces per
    /// contact). With `settings.detection_rounds` > 1, detection runs again at the solved
    /// configuration, and if it finds a wall penetrated by more than
    /// `settings.penetration_tolerance_m` that the contact set lacks, the contacts are solved
    /// again with it (the report's `iterations` counts the rounds). Nothing changes on error.
    pub fn step_with_contacts(
        &mut self,
        detect: impl FnMut(
            &[Vector3<f64>],
            &[UnitQuaternion<f64>],
            &[Vector6<f64>],
        ) -> Result<Vec<Contact>>,
        settings: &ContactSettings,
        warm_start: impl FnOnce(&[Contact]) -> Option<Vec<Vector3<f64>>>,
    ) -> Result<ContactStep> {
        self.saved_positions.clone_from(&self.positions);
        self.saved_rotations.clone_from(&self.rotations);
        let mut result = self.step_with_contacts_inner(detect, settings, warm_start);
        if let Err(PhysicsError::Diverged { step, .. }) = &mut result
            && *step == 0
        {
            *step = self.step_count + 1;
        }
        self.step_count += 1;
        if result.is_err() {
            self.positions.clone_from(&self.saved_positions);
            self.rotations.clone_from(&self.saved_rotations);
        }
        result
    }

    fn step_with_contacts_inner(
        &mut self,
        mut detect: impl FnMut(
            &[Vector3<f64>],
            &[UnitQuaternion<f64>],
            &[Vector6<f64>],
        ) -> Result<Vec<Contact>>,
        settings: &ContactSettings,
        warm_start: impl FnOnce(&[Contact]) -> Option<Vec<Vector3<f64>>>,
    ) -> Result<ContactStep> {
        // Step-size control on the free motion only: the contact solve then makes the end
        // state feasible whatever the scale.
        let free = self.begin_coupled_step()?;
        let mut contacts = detect(&self.positions, &self.rotations, &free)?;
        let mut warm = if contacts.is_empty() {
            None
        } else {
            warm_start(&contacts)
        };
        let rounds = settings.detection_rounds.max(1);
        let mut increments;
        let mut response;
        let mut round = 0;
        let mut penetration: f64 = 0.0;
        loop {
            response = if contacts.is_empty() {
                ContactResponse {
                    nodal_loads: vec![Vector6::zeros(); free.len()],
                    converged: true,
                    ..Default::default()
                }
            } else {
                gauss_seidel(
                    &self.flexibility,
                    &free,
                    &contacts,
                    settings,
                    warm.as_deref(),
                )?
            };
            increments = response.nodal_loads.clone();
            if !contacts.is_empty() {
                self.substructure.solve_in_place(&mut increments);
            }
            for (du, f) in increments.iter_mut().zip(&free) {
                *du += f;
            }
            round += 1;
            if rounds == 1 || contacts.is_empty() {
                break;
            }
            // Look again where the contact forces moved the device: a wall it now penetrates
            // (one the contact set lacks, such as a corner's other wall, or one whose
            // linearization went stale as the device slid along a curved wall) means another
            // round with fresh contacts there.
            let mut next = detect(&self.positions, &self.rotations, &increments)?;
            let depth = |c: &Contact| {
                -(c.gap
                    + c.normal
                        .dot(&point_displacement(&increments, c.element, c.t)))
            };
            penetration = next.iter().map(depth).fold(0.0, f64::max);
            if penetration <= settings.penetration_tolerance_m || round >= rounds {
                break;
            }
            // Keep the earlier rounds' contacts too (a wall the contact forces pushed the device
            // away from still bounds it), ordered along the device.
            for old in &contacts {
                if !next.iter().any(|c| same_contact(c, old)) {
                    next.push(*old);
                }
            }
            next.sort_by(|a, b| {
                (a.element, a.t)
                    .partial_cmp(&(b.element, b.t))
                    .unwrap_or(std::cmp::Ordering::Equal)
            });
            warm = Some(carry_forces(&next, &contacts, &response.local));
            contacts = next;
        }
        let (dx, dtheta) = self.apply_increments(&increments)?;
        Ok(ContactStep {
            report: StepReport {
                iterations: round,
                converged: response.converged,
                last_translation_increment_m: dx,
                last_rotation_increment_rad: dtheta,
            },
            contacts,
            response,
            penetration_m: penetration,
        })
    }

    /// The first half of a step whose contacts couple this chain to others (nested coaxial
    /// instruments): assembles, factors, and returns the free increment of every unknown node
    /// (step-size controlled as in [`Self::step_with_contacts`]), leaving the flexibility
    /// blocks for the coupled contact solve. Nothing moves until [`Self::finish_coupled_step`].
    pub(crate) fn begin_coupled_step(&mut self) -> Result<Vec<Vector6<f64>>> {
        let gamma = match self.settings.mode {
            StepMode::Incremental { gamma } => gamma,
            StepMode::Converged { .. } => 1.0,
        };
        self.solve_free(gamma, true)?;
        let mut free = self.rhs.clone();
        if let Some((max_dx, max_dtheta)) = self.settings.max_step_increment {
            let (dx, dtheta) = free.iter().fold((0.0f64, 0.0f64), |(a, b), du| {
                (
                    a.max(du.fixed_rows::<3>(0).norm()),
                    b.max(du.fixed_rows::<3>(3).norm()),
                )
            });
            let scale = (max_dx / dx).min(max_dtheta / dtheta).min(1.0);
            if scale < 1.0 {
                free.iter_mut().for_each(|du| *du *= scale);
            }
        }
        Ok(free)
    }

    /// The increments of a coupled step: `free` plus K⁻¹ `loads` (contact loads per unknown
    /// node, N and N·m), by one O(N) solve with the factorization of
    /// [`Self::begin_coupled_step`].
    pub(crate) fn coupled_increments(
        &mut self,
        free: &[Vector6<f64>],
        loads: &[Vector6<f64>],
    ) -> Vec<Vector6<f64>> {
        let mut increments = loads.to_vec();
        self.substructure.solve_in_place(&mut increments);
        for (du, f) in increments.iter_mut().zip(free) {
            *du += f;
        }
        increments
    }

    /// The second half of a coupled step: applies `increments` after the divergence checks
    /// (nothing moves if one trips) and counts the step.
    pub(crate) fn finish_coupled_step(
        &mut self,
        increments: &[Vector6<f64>],
    ) -> Result<StepReport> {
        let result = self.apply_increments(increments);
        self.step_count += 1;
        let (dx, dtheta) = result?;
        Ok(StepReport {
            iterations: 1,
            converged: true,
            last_translation_increment_m: dx,
            last_rotation_increment_rad: dtheta,
        })
    }

    /// Internal forces f_int = Λᵀ K̄e(ū − ū0) and the tangent stiffness of the unknown nodes.
    fn assemble(&mut self) {
        self.stiffness.clear();
        self.internal.iter_mut().for_each(|f| f.fill(0.0));
        let geometric = self.settings.geometric_stiffness;
        for (e, element) in self.elements.iter().enumerate() {
            let state = self.element_state(e);
            let (f1, f2, axial_force) = element_forces(element, &state);
            let r = &state.frame;
            self.internal[e] += rotate_wrench(r, &f1);
            self.internal[e + 1] += rotate_wrench(r, &f2);

            let mut k = element.stiffness;
            if geometric {
                let force = if self.settings.geometric_stiffness_in_compression {
                    axial_force
                } else {
                    axial_force.max(0.0)
                };
                for (block, g) in k.iter_mut().zip(&element.geometric_per_newton) {
                    *block = block.scaled_add(g, force);
                }
            }
            let axis = r.column(0).into_owned();
            k[2].add_world_to(&axis, &mut self.stiffness.diagonal[e]);
            if e > 0 {
                k[0].add_world_to(&axis, &mut self.stiffness.diagonal[e - 1]);
                k[1].add_world_to(&axis, &mut self.stiffness.upper[e - 1]);
            }
        }
        if let Some(drag) = self.settings.drag {
            let rate = drag.per_length_n_s_per_m2 / drag.time_step_s;
            let elements = self.elements.len();
            for (i, block) in self.stiffness.diagonal.iter_mut().enumerate() {
                // Unknown i is node i + 1: half of each adjacent element.
                let node = i + 1;
                let mut share = 0.5 * self.elements[node - 1].rest_length_m;
                if node < elements {
                    share += 0.5 * self.elements[node].rest_length_m;
                }
                let translational = rate * share;
                let rotational = rate * share.powi(3) / 12.0;
                for d in 0..3 {
                    block[(d, d)] += translational;
                    block[(d + 3, d + 3)] += rotational;
                }
            }
        }
    }

    fn element_state(&self, e: usize) -> ElementState {
        let element = &self.elements[e];
        let s1 = self.rotations[e] * element.offsets[0];
        let s2 = self.rotations[e + 1] * element.offsets[1];
        let chord = self.positions[e + 1] - self.positions[e];
        let frame_q = element_frame(&s1, &s2, &chord);
        let inv = frame_q.inverse();
        ElementState {
            frame: frame_q.to_rotation_matrix().into_inner(),
            chord_m: chord.norm(),
            theta: [rotation_vector(&(inv * s1)), rotation_vector(&(inv * s2))],
        }
    }

    /// Residual f_ext − f_int on the unknown nodes (N and N·m), for convergence checks.
    pub fn residual(&mut self) -> Vec<Vector6<f64>> {
        self.assemble();
        (1..self.node_count())
            .map(|i| self.external[i] - self.internal[i])
            .collect()
    }

    /// The tangent stiffness of the unknown nodes in the current configuration.
    pub fn tangent_stiffness(&mut self) -> &BlockTridiagonal {
        self.assemble();
        &self.stiffness
    }

    /// Elastic energy stored in the device (J): ½ Σ ū·K̄e ū over the elements, with the local
    /// deformation ū measured from the rest shape.
    pub fn elastic_energy(&self) -> f64 {
        (0..self.elements.len())
            .map(|e| {
                let element = &self.elements[e];
                let state = self.element_state(e);
                let (f1, f2, axial) = element_forces(element, &state);
                let [t1, t2] = state.theta;
                let torsion = f1[3];
                0.5 * (axial * (state.chord_m - element.rest_length_m)
                    + torsion * (t1.x - t2.x)
                    + f1[4] * t1.y
                    + f2[4] * t2.y
                    + f1[5] * t1.z
                    + f2[5] * t2.z)
            })
            .sum()
    }

    /// Reaction wrench at the base (force N, moment N·m, world frame): what the operator's
    /// hand must apply to hold the device where it is.
    pub fn base_reaction(&mut self) -> Vector6<f64> {
        self.assemble();
        self.internal[0] - self.external[0]
    }
}

/// Whether two contacts are the same wall touching the same point: same element and
/// parameter, normals within about 25°.
fn same_contact(a: &Contact, b: &Contact) -> bool {
    a.element == b.element && (a.t - b.t).abs() <= 1e-9 && a.normal.dot(&b.normal) > 0.9
}

/// Forces of `old` contacts carried over to the same `new` ones (zero for the rest): the
/// warm start of a repeated detection round.
fn carry_forces(new: &[Contact], old: &[Contact], forces: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    new.iter()
        .map(|c| {
            old.iter()
                .zip(forces)
                .filter(|(o, _)| same_contact(o, c))
                .map(|(_, f)| *f)
                .next()
                .unwrap_or_else(Vector3::zeros)
        })
        .collect()
}

/// Checks that a base pose is finite, naming the first bad component.
fn require_finite_pose(position: &Vector3<f64>, rotation: &UnitQuaternion<f64>) -> Result<()> {
    for (i, v) in position.iter().chain(rotation.coords.iter()).enumerate() {
        require_finite(|| format!("base pose component {i}"), *v)?;
    }
    Ok(())
}

/// Rotation vector (axis × angle, rad) of a unit quaternion, accurate near the identity.
///
/// nalgebra's `scaled_axis` computes the angle as 2·acos(w), which loses half the digits
/// near w = 1 (an error of ~1e-8 rad on an exact rest state); 2·atan2(|v|, w) does not.
pub fn rotation_vector(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let (w, v) = (q.scalar(), q.vector());
    let (w, v) = if w < 0.0 {
        (-w, -v)
    } else {
        (w, v.into_owned())
    };
    let sin_half = v.norm();
    if sin_half < 1e-300 {
        return Vector3::zeros();
    }
    let angle = 2.0 * sin_half.atan2(w);
    v * (angle / sin_half)
}

/// Element frame: mid-rotation of the two corrected node frames, turned so x lies on the chord.
fn element_frame(
    s1: &UnitQuaternion<f64>,
    s2: &UnitQuaternion<f64>,
    chord: &Vector3<f64>,
) -> UnitQuaternion<f64> {
    let half = UnitQuaternion::from_scaled_axis(rotation_vector(&(s1.inverse() * s2)) * 0.5);
    let mid = s1 * half;
    let tangent = mid * axis_x();
    minimal_rotation(&tangent, &chord.normalize()) * mid
}

/// The smallest rotation taking unit vector `a` to unit vector `b`: the normalised
/// quaternion (1 + a·b, a×b). Accurate for nearly parallel vectors, unlike nalgebra's
/// `rotation_between`, whose acos of the dot product is only good to ~1e-8 rad there.
/// Anti-parallel inputs (never met by an element frame) give the identity.
pub fn minimal_rotation(a: &Vector3<f64>, b: &Vector3<f64>) -> UnitQuaternion<f64> {
    let w = 1.0 + a.dot(b);
    if w <= 1e-12 {
        return UnitQuaternion::identity();
    }
    let v = a.cross(b);
    UnitQuaternion::new_normalize(nalgebra::Quaternion::new(w, v.x, v.y, v.z))
}

/// Local end wrenches of an element (node 1, node 2) and its axial force (N), from the
/// condensed stiffness: exact element equilibrium in the current chord length.
fn element_forces(element: &Element, state: &ElementState) -> (Vector6<f64>, Vector6<f64>, f64) {
    let p = &element.props;
    let l0 = element.rest_length_m;
    let b = &element.bending;
    let [t1, t2] = state.theta;
    let axial = p.axial_stiffness_n / l0 * (state.chord_m - l0);
    let torsion = p.torsional_stiffness_nm2 / l0 * (t1.x - t2.x);
    let m1y = b.k_tt_near * t1.y + b.k_tt_far * t2.y;
    let m2y = b.k_tt_far * t1.y + b.k_tt_near * t2.y;
    let m1z = b.k_tt_near * t1.z + b.k_tt_far * t2.z;
    let m2z = b.k_tt_far * t1.z + b.k_tt_near * t2.z;
    let shear_y = -(m1z + m2z) / state.chord_m;
    let shear_z = (m1y + m2y) / state.chord_m;
    let f2 = Vector6::new(axial, shear_y, shear_z, -torsion, m2y, m2z);
    let f1 = Vector6::new(-axial, -shear_y, -shear_z, torsion, m1y, m1z);
    (f1, f2, axial)
}

/// The point at fraction `f` ∈ [0, 1] of the smooth curve between two nodes (position m,
/// frame): the cubic Hermite interpolant of their positions and tangents, with the tangent
/// length chord / cos²(θ/4) (θ the angle between the end tangents) that puts it exactly on a
/// circular arc; the frame is the slerp of the two node frames.
pub(crate) fn hermite_point(
    (p0, q0): (&Vector3<f64>, &UnitQuaternion<f64>),
    (p1, q1): (&Vector3<f64>, &UnitQuaternion<f64>),
    f: f64,
) -> (Vector3<f64>, UnitQuaternion<f64>) {
    let (d0, d1) = (q0 * Vector3::x(), q1 * Vector3::x());
    let scale = (p1 - p0).norm() / (0.25 * d0.angle(&d1).min(3.0)).cos().powi(2);
    let (t0, t1) = (d0 * scale, d1 * scale);
    let (f2, f3) = (f * f, f * f * f);
    let position = p0 * (2.0 * f3 - 3.0 * f2 + 1.0)
        + t0 * (f3 - 2.0 * f2 + f)
        + p1 * (-2.0 * f3 + 3.0 * f2)
        + t1 * (f3 - f2);
    (position, q0.slerp(q1, f))
}

fn rotate_wrench(r: &Matrix3<f64>, w: &Vector6<f64>) -> Vector6<f64> {
    let f = r * w.fixed_rows::<3>(0);
    let m = r * w.fixed_rows::<3>(3);
    Vector6::new(f.x, f.y, f.z, m.x, m.y, m.z)
}

/// Position and rotation increment along a helix of constant material curvature vector
/// `kappa` (1/m, see [`ElementSpec::curvature_per_m`]) and arc length `length` (m), in the
/// frame at its start: the frame turns by exp(s·κ̂), and the position is
/// ∫₀ᴸ exp(s·κ̂)·x ds = (L·I + (1 − cos θ)/|κ|²·κ̂ + (L − sin θ/|κ|)/|κ|²·κ̂²)·x, θ = |κ|L.
fn arc_increment(kappa: &Vector3<f64>, length: f64) -> (Vector3<f64>, UnitQuaternion<f64>) {
    let k = kappa.norm();
    let theta = k * length;
    // Coefficients of κ̂ and κ̂², with their series near θ = 0.
    let (c1, c2) = if theta < 1e-4 {
        let t2 = theta * theta;
        (
            length * length / 2.0 * (1.0 - t2 / 12.0),
            length * length * length / 6.0 * (1.0 - t2 / 20.0),
        )
    } else {
        (
            (1.0 - theta.cos()) / (k * k),
            (length - theta.sin() / k) / (k * k),
        )
    };
    let x = Vector3::x();
    let kx = kappa.cross(&x);
    let kkx = kappa.cross(&kx);
    (
        x * length + kx * c1 + kkx * c2,
        UnitQuaternion::from_scaled_axis(kappa * length),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed-form helix increment against a fine midpoint integration of the frame ODE
    /// (planar, torsion only, and a general 3D curvature, small and large angles).
    #[test]
    fn helix_increment_matches_integrated_frame() {
        for kappa in [
            Vector3::new(0.0, 0.0, 300.0),
            Vector3::new(50.0, 0.0, 0.0),
            Vector3::new(40.0, -120.0, 250.0),
            Vector3::new(1e-5, 2e-5, -3e-5),
        ] {
            let length = 0.02;
            let n = 20_000;
            let ds = length / n as f64;
            let mut p = Vector3::zeros();
            for i in 0..n {
                let q = UnitQuaternion::from_scaled_axis(kappa * ((i as f64 + 0.5) * ds));
                p += q * Vector3::x() * ds;
            }
            let (dp, dq) = arc_increment(&kappa, length);
            assert!(
                (dp - p).norm() < 1e-9 * length,
                "{kappa:?}: {dp:?} vs {p:?}"
            );
            let exact = UnitQuaternion::from_scaled_axis(kappa * length);
            assert!(dq.angle_to(&exact) < 1e-12);
        }
    }

    #[test]
    fn rotation_vector_is_accurate_near_identity() {
        // Regression: nalgebra's acos-based angle gave ~1e-8 rad for rotations of 1e-12 rad.
        for angle in [1e-15, 1e-12, 1e-9, 1e-4, 1.0, 3.0] {
            let axis = Vector3::new(1.0, -2.0, 0.5).normalize();
            let q = UnitQuaternion::from_scaled_axis(axis * angle);
            let back = rotation_vector(&q);
            assert!(
                (back - axis * angle).norm() <= 1e-15 * angle.max(1e-15) * 4.0,
                "{angle}: {back:?}"
            );
        }
    }

    #[test]
    fn minimal_rotation_is_accurate_for_nearly_parallel_vectors() {
        // Regression: nalgebra's rotation_between returned 1.5e-8 rad for vectors 1e-16 apart.
        let a = Vector3::new(0.6, 0.8, 0.0);
        for tilt in [0.0, 1e-16, 1e-12, 1e-6, 0.5] {
            let b = (a + Vector3::z() * tilt).normalize();
            let q = minimal_rotation(&a, &b);
            assert!((q * a - b).norm() < 1e-15, "{tilt}");
            assert!(
                (rotation_vector(&q).norm() - tilt.atan()).abs() < 1e-15,
                "{tilt}"
            );
        }
    }

    #[test]
    fn frame_free_blocks_equal_the_full_rotation() {
        // Fast path vs naive R₆ K R₆ᵀ for a random frame and every element block.
        let props = BeamProperties::new(
            &crate::section::CircularSection {
                outer_radius_m: 1e-3,
                inner_radius_m: 4e-4,
            },
            &crate::section::Material {
                young_modulus_pa: 3e9,
                poisson_ratio: 0.4,
                density_kg_m3: 1e3,
            },
        );
        let k = crate::element::local_stiffness(&props, 0.01)
            + crate::element::local_geometric_stiffness(&props, 0.01, -0.7);
        let frame =
            UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -1.1, 0.7)).to_rotation_matrix();
        let r = frame.matrix();
        let mut r6 = Matrix6::zeros();
        r6.fixed_view_mut::<3, 3>(0, 0).copy_from(r);
        r6.fixed_view_mut::<3, 3>(3, 3).copy_from(r);
        for (i, j) in [(0, 0), (0, 6), (6, 6), (6, 0)] {
            let local = k.fixed_view::<6, 6>(i, j).into_owned();
            let naive = r6 * local * r6.transpose();
            let mut fast = Matrix6::zeros();
            AxisymmetricBlock6::from_local(&local)
                .add_world_to(&r.column(0).into_owned(), &mut fast);
            assert!(
                (fast - naive).abs().max() <= 1e-12 * naive.abs().max(),
                "block ({i},{j})"
            );
        }
    }

    #[test]
    fn curved_rest_shape_is_stress_free() {
        // Regression: the acos errors above left forces of ~1e-4·EI/l² in a J tip at rest.
        let props = BeamProperties::new(
            &crate::section::CircularSection::solid(0.4e-3),
            &crate::section::Material {
                young_modulus_pa: 2e9,
                poisson_ratio: 0.33,
                density_kg_m3: 6450.0,
            },
        );
        let specs: Vec<ElementSpec> = (0..40)
            .map(|i| ElementSpec::planar(props, 1e-3, if i >= 20 { 1.0 / 3e-3 } else { 0.0 }))
            .collect();
        let mut model = BeamModel::new(
            &specs,
            Vector3::zeros(),
            UnitQuaternion::identity(),
            SolverSettings::default(),
        )
        .unwrap();
        let scale = props.bending_stiffness_nm2 / 1e-6;
        let worst = model
            .residual()
            .iter()
            .map(|r| r.abs().max())
            .fold(0.0, f64::max);
        assert!(worst < 1e-12 * scale, "{worst} vs {scale}");
    }
}
