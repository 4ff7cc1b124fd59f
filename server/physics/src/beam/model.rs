//! The beam model's data and its handling between steps: node positions and frames, rest
//! geometry, loads and base pose, construction from element specifications or a device,
//! accessors, and snapshots.

use nalgebra::{UnitQuaternion, Vector3, Vector6};

use super::element::{Element, ElementSpec};
use super::kinematics::{arc_increment, axis_x, element_frame};
use super::settings::SolverSettings;
use crate::device::Device;
use crate::error::{PhysicsError, Result, require_finite, require_positive};
use crate::section::BeamProperties;
use crate::substructure::{BlockTridiagonal, Flexibility, Substructure};

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

/// A discretised device (or test beam) with its current configuration.
#[derive(Debug, Clone)]
pub struct BeamModel {
    pub(super) elements: Vec<Element>,
    pub(super) positions: Vec<Vector3<f64>>,
    pub(super) rotations: Vec<UnitQuaternion<f64>>,
    pub(super) rest_positions: Vec<Vector3<f64>>,
    pub(super) rest_rotations: Vec<UnitQuaternion<f64>>,
    pub(super) external: Vec<Vector6<f64>>,
    /// External loads and base pose at the end of the last completed step: where a split step
    /// starts from.
    pub(super) last_external: Vec<Vector6<f64>>,
    pub(super) last_base: (Vector3<f64>, UnitQuaternion<f64>),
    pub(super) settings: SolverSettings,
    pub(super) step_count: u64,
    pub(super) length_m: f64,
    // Work buffers, reused every step.
    pub(super) stiffness: BlockTridiagonal,
    pub(super) substructure: Substructure,
    pub(super) flexibility: Flexibility,
    pub(super) internal: Vec<Vector6<f64>>,
    pub(super) rhs: Vec<Vector6<f64>>,
    pub(super) saved_positions: Vec<Vector3<f64>>,
    pub(super) saved_rotations: Vec<UnitQuaternion<f64>>,
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
}

/// Checks that a base pose is finite, naming the first bad component.
fn require_finite_pose(position: &Vector3<f64>, rotation: &UnitQuaternion<f64>) -> Result<()> {
    for (i, v) in position.iter().chain(rotation.coords.iter()).enumerate() {
        require_finite(|| format!("base pose component {i}"), *v)?;
    }
    Ok(())
}
