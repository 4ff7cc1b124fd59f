//! Changes of a beam model's discretization: elements grown, split and merged at the base
//! or anywhere along the device, and the whole discretization swapped at once (a coaxial
//! stack's per-step update). The shape never jumps.

use nalgebra::{UnitQuaternion, Vector3, Vector6};

use super::element::{Element, ElementSpec};
use super::kinematics::hermite_point;
use super::model::BeamModel;
use crate::error::{PhysicsError, Result, require_finite};
use crate::substructure::BlockTridiagonal;

impl BeamModel {
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

    /// Splits element 0 by a new node 1 on its chord, at the rest-length fraction of `base`
    /// (the old node 1 becomes node 2). The chord keeps both halves' axial strain. `base`
    /// and `distal` are the two new elements' rest geometries.
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

    /// The point at fraction `fraction` ∈ [0, 1] of the smooth curve through nodes 0 and 1
    /// (position m, frame), where [`Self::split_element`] would put a new node.
    pub fn base_curve_point(&self, fraction: f64) -> (Vector3<f64>, UnitQuaternion<f64>) {
        hermite_point(
            (&self.positions[0], &self.rotations[0]),
            (&self.positions[1], &self.rotations[1]),
            fraction,
        )
    }

    /// Splits element 0 by a new node 1 at `position` (m) with frame `rotation` (the old node
    /// 1 becomes node 2). `base` and `distal` are the two new elements' rest geometries.
    pub fn insert_node_after_base_at(
        &mut self,
        base: ElementSpec,
        distal: ElementSpec,
        position: Vector3<f64>,
        rotation: UnitQuaternion<f64>,
    ) -> Result<()> {
        for &x in position.iter() {
            require_finite(|| "the new node's position".into(), x)?;
        }
        let first = Element::from_spec(&base)?;
        let second = Element::from_spec(&distal)?;
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
    ///
    /// The element measures its stretch on its chord, and one chord across a bend at node 1 is
    /// shorter than the two it replaces: joined as they lie, a 0.035" wire bent by 0.08 rad
    /// there went from 8 to 36 N of compression in one step. So the nodes beyond are first
    /// carried along the new chord by the difference (micrometres), and the joined element is
    /// as long as the two were: the stretch does not jump.
    pub fn remove_node_after_base(&mut self, merged: ElementSpec) -> Result<()> {
        if self.elements.len() < 2 {
            return Err(PhysicsError::TooFewElements {
                count: self.elements.len(),
                min: 2,
            });
        }
        let (p0, p1, p2) = (self.positions[0], self.positions[1], self.positions[2]);
        let chord = p2 - p0;
        let shortfall = (p1 - p0).norm() + (p2 - p1).norm() - chord.norm();
        if let Some(direction) = chord.try_normalize(1e-15) {
            let carry = direction * shortfall;
            for p in &mut self.positions[2..] {
                *p += carry;
            }
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
                Some(element) if !element.series => elements.push(element.clone()),
                _ => elements.push(Element::from_spec(spec)?),
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

    pub(super) fn resize_work_buffers(&mut self) {
        let nodes = self.positions.len();
        self.stiffness = BlockTridiagonal::zeros(nodes - 1);
        self.internal.resize(nodes, Vector6::zeros());
        self.rhs.resize(nodes - 1, Vector6::zeros());
    }
}
