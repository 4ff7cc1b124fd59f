//! Collision points and contact detection, shared by navigations and coaxial stacks: the
//! points along each element, detection at the predicted configuration with the bounds that
//! spare points clear of the wall their probes ([`ClearanceCache`]), and the warm start of the
//! contact solve from the last step's forces.

use nalgebra::{Vector3, Vector6};

use crate::contact::{Contact, point_displacement};
use crate::wall::Wall;

/// Material coordinate of a contact point (m from the proximal end).
pub(crate) fn material_of(material: &[f64], contact: &Contact) -> f64 {
    let (a, b) = (material[contact.element], material[contact.element + 1]);
    a + contact.t * (b - a)
}

/// The previous step's forces for contacts within `tolerance` (m, along the device) of the
/// same material point, as a Gauss–Seidel warm start; both lists are ordered along the device.
pub(crate) fn warm_start(
    contacts: &[Contact],
    material: &[f64],
    previous: &[(f64, Vector3<f64>)],
    tolerance: f64,
) -> Option<Vec<Vector3<f64>>> {
    if previous.is_empty() {
        return None;
    }
    let mut j = 0;
    let warm = contacts
        .iter()
        .map(|c| {
            let s = material_of(material, c);
            while j + 1 < previous.len()
                && (previous[j + 1].0 - s).abs() <= (previous[j].0 - s).abs()
            {
                j += 1;
            }
            if (previous[j].0 - s).abs() <= tolerance {
                previous[j].1
            } else {
                Vector3::zeros()
            }
        })
        .collect();
    Some(warm)
}

/// One collision point.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Sample {
    pub(crate) element: usize,
    pub(crate) t: f64,
    pub(crate) radius: f64,
    pub(crate) friction: f64,
    /// How far the material at this point slid this step before the solve (m): the contact's
    /// [`Contact::slip`]. Zero as laid out; the step sets it.
    pub(crate) slip: Vector3<f64>,
}

/// Appends the collision points of element `e` of `elements` (its length `length_m`, points
/// about `spacing_m` apart) with the radius and wall friction of `section`. t = 0 belongs to
/// the element (node e); the tip (t = 1) only to the last element.
pub(crate) fn push_element_samples(
    samples: &mut Vec<Sample>,
    (e, elements): (usize, usize),
    length_m: f64,
    spacing_m: f64,
    section: &crate::device::Section,
) {
    let count = (length_m / spacing_m).ceil().max(1.0) as usize;
    let last = if e + 1 == elements { count } else { count - 1 };
    // The base node is driven (held by the sheath or the hand): no contact force can move
    // it, so a contact there has no compliance and Gauss–Seidel cannot resolve it (it stalled
    // every sweep where the entry touched a segmented lumen's end).
    let first = usize::from(e == 0);
    for j in first..=last {
        samples.push(Sample {
            element: e,
            t: j as f64 / count as f64,
            radius: section.cross_section.outer_radius_m,
            friction: section.friction_coefficient,
            slip: Vector3::zeros(),
        });
    }
}

/// How far beyond its search radius a collision point's probe looks (m), so that the
/// distance it finds lets the point skip the probes of the following steps.
pub(crate) const CLEARANCE_REACH_M: f64 = 1e-3;

/// Slack on the clearance bound (m): far above rounding, far below any contact margin.
const CLEARANCE_SLACK_M: f64 = 1e-9;

/// Per collision point: where it was last probed and a lower bound on its distance to the
/// wall there (0: none known). The distance to the wall changes no faster than the point
/// moves, so a point that has moved less than its bound minus its search radius is still
/// clear of the wall and needs no probe: the contacts are exactly those of probing every
/// point (a skipped probe would have found no wall within the search radius). Most of a
/// device lies clear of the wall and moves a fraction of a millimetre a step, so most probes
/// are skipped.
#[derive(Debug, Clone, Default)]
pub(crate) struct ClearanceCache {
    points: Vec<(Vector3<f64>, f64)>,
}

impl ClearanceCache {
    /// Room for `n` collision points (a changed layout keeps the bounds: each is tied to the
    /// position it was found at, not to the sample).
    fn fit(&mut self, n: usize) {
        self.points.resize(n, (Vector3::zeros(), 0.0));
    }

    /// Whether point `i`, now at `at`, is certainly farther than `search` from the wall.
    pub(crate) fn clear_of_wall(&self, i: usize, at: &Vector3<f64>, search: f64) -> bool {
        let Some(&(at0, bound)) = self.points.get(i) else {
            return false;
        };
        bound > 0.0 && (at - at0).norm() < bound - search - CLEARANCE_SLACK_M
    }

    /// Records what a probe with search radius `reach` found at `at`: no wall within it
    /// while inside (`None`), the distance to the wall when inside, nothing when outside.
    fn remember(
        &mut self,
        i: usize,
        at: &Vector3<f64>,
        probe: Option<&crate::WallProbe>,
        reach: f64,
    ) {
        let bound = match probe {
            None => reach,
            Some(p) => p.clearance_m.max(0.0),
        };
        self.points[i] = (*at, bound);
    }
}

/// Contacts at the predicted configuration x + Δu_free: for each element the deepest collision
/// point within the margin, with its gap shifted back so that `gap + n·δ_free` is the
/// predicted gap (the contact solver linearizes about the free motion, so a fast push cannot
/// tunnel through the wall).
pub(crate) fn detect<W: Wall>(
    wall: &W,
    samples: &[Sample],
    positions: &[Vector3<f64>],
    free: &[Vector6<f64>],
    margin: f64,
    cache: &mut ClearanceCache,
) -> Vec<Contact> {
    let mut contacts: Vec<Contact> = Vec::new();
    // Predicted gaps of the contacts of the current element (parallel to its tail of
    // `contacts`): one contact per element and wall direction, the deepest.
    let mut deepest: Vec<f64> = Vec::new();
    let mut element_start = 0;
    cache.fit(samples.len());
    for (i, s) in samples.iter().enumerate() {
        let delta = point_displacement(free, s.element, s.t);
        let at = positions[s.element] * (1.0 - s.t) + positions[s.element + 1] * s.t + delta;
        let search = s.radius + margin;
        if cache.clear_of_wall(i, &at, search) {
            continue;
        }
        let probe = wall.probe(&at, search + CLEARANCE_REACH_M);
        cache.remember(i, &at, probe.as_ref(), search + CLEARANCE_REACH_M);
        let Some(probe) = probe else {
            continue;
        };
        let predicted_gap = probe.clearance_m - s.radius;
        if predicted_gap > margin {
            continue;
        }
        let contact = Contact {
            element: s.element,
            t: s.t,
            normal: probe.normal,
            gap: predicted_gap - probe.normal.dot(&delta),
            friction: s.friction,
            slip: s.slip,
        };
        if contacts.last().is_none_or(|c| c.element != s.element) {
            element_start = contacts.len();
            deepest.clear();
        }
        // One contact per element half and wall direction: an element lying along the wall
        // keeps a contact near each end.
        let same_wall = contacts[element_start..]
            .iter()
            .position(|c| c.normal.dot(&contact.normal) > 0.9 && (c.t < 0.5) == (contact.t < 0.5));
        match same_wall {
            Some(k) if predicted_gap < deepest[k] => {
                contacts[element_start + k] = contact;
                deepest[k] = predicted_gap;
            }
            Some(_) => {}
            None => {
                contacts.push(contact);
                deepest.push(predicted_gap);
            }
        }
    }
    contacts
}

#[cfg(test)]
mod clearance_tests {
    use super::*;
    use crate::WallProbe;
    use crate::wall::{CappedTube, RingTube};
    use proptest::prelude::*;

    /// A chain of `n` nodes along x through the tube, each moved by `wiggle` (m) per step.
    fn chain(n: usize, y: f64, z: f64) -> Vec<Vector3<f64>> {
        (0..n)
            .map(|i| Vector3::new(0.004 * i as f64, y, z))
            .collect()
    }

    fn samples(elements: usize, radius: f64) -> Vec<Sample> {
        (0..elements)
            .flat_map(|e| {
                (0..4).map(move |j| Sample {
                    element: e,
                    t: j as f64 / 4.0,
                    radius,
                    friction: 0.1,
                    slip: Vector3::zeros(),
                })
            })
            .collect()
    }

    proptest! {
        /// The contacts found with the bounds kept from step to step are exactly those of
        /// probing every point every step, whatever the walk (the fast path against the naive
        /// one), in a capped tube and in a ring.
        #[test]
        fn kept_bounds_find_exactly_the_contacts_of_probing_every_point(
            y in -0.0015f64..0.0015,
            z in -0.0015f64..0.0015,
            steps in prop::collection::vec((-2e-4f64..2e-4, -2e-4f64..2e-4, -1e-3f64..1e-3), 1..60),
            radius in 1e-4f64..5e-4,
            margin in 0.0f64..3e-4,
            ring in any::<bool>(),
        ) {
            let tube = CappedTube {
                start: Vector3::new(-0.01, 0.0, 0.0),
                axis: Vector3::x(),
                length_m: 0.05,
                radius_m: 0.002,
            };
            let torus = RingTube {
                center: Vector3::new(0.02, -0.03, 0.0),
                axis: Vector3::z(),
                major_radius_m: 0.03,
                minor_radius_m: 0.002,
            };
            let mut positions = chain(9, y, z);
            let layout = samples(8, radius);
            let free = vec![Vector6::zeros(); positions.len()];
            let mut kept = ClearanceCache::default();
            for (k, (dy, dz, dx)) in steps.iter().enumerate() {
                for (i, p) in positions.iter_mut().enumerate() {
                    // Each node its own drift: bends as well as translations.
                    let f = 1.0 + 0.1 * i as f64;
                    *p += Vector3::new(*dx, dy * f, dz * (2.0 - f * 0.5));
                }
                let (fast, naive) = if ring {
                    (
                        detect(&torus, &layout, &positions, &free, margin, &mut kept),
                        detect(&torus, &layout, &positions, &free, margin, &mut ClearanceCache::default()),
                    )
                } else {
                    (
                        detect(&tube, &layout, &positions, &free, margin, &mut kept),
                        detect(&tube, &layout, &positions, &free, margin, &mut ClearanceCache::default()),
                    )
                };
                prop_assert_eq!(fast, naive, "step {}", k);
            }
        }
    }

    #[test]
    fn points_clear_of_the_wall_skip_their_probes() {
        /// Counts its probes.
        struct Counting<'a>(&'a CappedTube, std::cell::Cell<usize>);
        impl Wall for Counting<'_> {
            fn probe(&self, point: &Vector3<f64>, search_m: f64) -> Option<WallProbe> {
                self.1.set(self.1.get() + 1);
                self.0.probe(point, search_m)
            }
        }
        let tube = CappedTube {
            start: Vector3::new(-0.01, 0.0, 0.0),
            axis: Vector3::x(),
            length_m: 0.05,
            radius_m: 0.002,
        };
        let wall = Counting(&tube, std::cell::Cell::new(0));
        let mut positions = chain(9, 0.0, 0.0);
        let layout = samples(8, 2e-4);
        let free = vec![Vector6::zeros(); positions.len()];
        let mut kept = ClearanceCache::default();
        for _ in 0..100 {
            for p in &mut positions {
                p.x += 4e-5; // 20 mm/s at 500 Hz
            }
            assert!(detect(&wall, &layout, &positions, &free, 1e-4, &mut kept).is_empty());
        }
        // On the axis 1.7 mm clear of the wall: a probe about every 40 steps, not 100.
        let probes = wall.1.get();
        println!("{probes} probes for {} point-steps", 100 * layout.len());
        assert!(probes < 10 * layout.len(), "{probes}");
    }
}
