//! Nested mode of a coaxial stack ([`super::Coupling::Nested`]): every instrument is its own chain (a one-instrument
//! [`Stack`] in free space, so insertion, refinement and twist work as in merged mode), and
//! an inner instrument touches the lumen of the one around it across the radial clearance
//! (inner diameter of the outer minus outer diameter of the inner, halved), with that lumen's
//! friction. Each step every chain makes its free motion, contacts are detected (the wall for
//! the part of a chain beyond every instrument around it, the lumen of the innermost
//! instrument around it elsewhere), and one Gauss–Seidel solve
//! ([`crate::coupled::coupled_gauss_seidel`]) finds all forces with each pair contact's
//! compliance summed over both chains.

use nalgebra::{UnitQuaternion, Vector3, Vector6};

use super::instrument::InstrumentSpec;
use super::loads::ProximalReaction;
use super::state::{NestedStep, Stack};
use super::step::StackReport;
use crate::beam::hermite_point;
use crate::contact::point_displacement;
use crate::coupled::{ChainPoint, CoupledContact, Lumen, coupled_gauss_seidel};
use crate::error::Result;
use crate::navigation::{Sample, detect};
use crate::wall::{FreeSpace, Wall};

/// A lumen contact is detected where the predicted gap is below this fraction of the
/// clearance (or the contact margin, if smaller).
const LUMEN_MARGIN_FRACTION: f64 = 0.5;
/// How far inside an outer instrument's tip (m) the inner chain gets a lumen point of its
/// own.
const TIP_INSET_M: f64 = 1e-4;

/// A lumen contact is violated by at most this fraction of its clearance before another
/// detection round runs (capped by the wall tolerance).
const LUMEN_TOLERANCE_FRACTION: f64 = 0.05;

/// A detected contact with the path coordinates of its sides (m).
struct Detected {
    contact: CoupledContact,
    sigma_first: f64,
    sigma_second: Option<f64>,
}

impl<W: Wall> Stack<W> {
    /// The contacts and local forces (N) of the last nested step, in the order solved.
    pub fn nested_contacts(&self) -> (&[CoupledContact], &[Vector3<f64>]) {
        (&self.nested_last.contacts, &self.nested_last.local)
    }

    /// Creates the chains of instruments that now reach one tip element beyond the entry (on
    /// the centre line of the innermost instrument around them) and drops those that no
    /// longer do.
    pub(super) fn update_chains(&mut self) -> Result<()> {
        let n = self.instruments.len();
        self.chains.resize_with(n, || None);
        for i in 0..n {
            let l = self.instruments[i].inserted_m;
            if i > 0 && l < self.settings.tip_element_m {
                self.chains[i] = None;
                continue;
            }
            if self.chains[i].is_some() {
                continue;
            }
            let instrument = &self.instruments[i];
            let spec = InstrumentSpec {
                device: instrument.device.clone(),
                inserted_m: l,
                twist_rad: instrument.twist_rad,
                max_insertion_speed_m_s: instrument.max_insertion_speed_m_s,
                max_twist_rate_rad_s: instrument.max_twist_rate_rad_s,
            };
            let settings = self.settings;
            let mut chain = Stack::new(
                vec![spec],
                FreeSpace,
                self.entry_position,
                self.entry_rotation * Vector3::x(),
                settings,
            )?;
            if let Some(k) = (0..i).rev().find(|&k| self.chains[k].is_some()) {
                let container = self.chain(k);
                let end = self.instruments[k].inserted_m;
                let turn = UnitQuaternion::from_axis_angle(
                    &Vector3::x_axis(),
                    instrument.twist_rad - self.instruments[k].twist_rad,
                );
                for node in &mut chain.nodes {
                    let (p, q) = container.point_at(node.sigma.min(end));
                    let beyond = (node.sigma - end).max(0.0);
                    node.position = p + q * Vector3::x() * beyond;
                    node.rotation = q * turn;
                }
                let positions: Vec<Vector3<f64>> = chain.nodes.iter().map(|n| n.position).collect();
                let rotations: Vec<UnitQuaternion<f64>> =
                    chain.nodes.iter().map(|n| n.rotation).collect();
                chain.model.set_nodes(&positions, &rotations)?;
            }
            self.chains[i] = Some(chain);
        }
        Ok(())
    }

    /// One nested solve: every chain's kinematic update and free motion, detection of wall
    /// and lumen contacts, one coupled Gauss–Seidel solve (with detection rounds as in merged
    /// mode), the increments applied to every chain or to none.
    pub(super) fn nested_step(&mut self, targets: &[(f64, f64)]) -> Result<StackReport> {
        // Nested chains slide nothing: every tip goes with its hand.
        self.place_instruments(targets);
        self.chains.truncate(self.instruments.len());
        let existed: Vec<bool> = self.chains.iter().map(Option::is_some).collect();
        self.update_chains()?;
        for (i, chain) in self.chains.iter_mut().enumerate() {
            if let Some(chain) = chain
                && existed.get(i).copied().unwrap_or(false)
            {
                chain.step_fraction = self.step_fraction;
                chain.prepare(&targets[i..=i])?;
            }
        }
        let count = self.chains.len();
        let mut free: Vec<Vec<Vector6<f64>>> = vec![Vec::new(); count];
        for (c, chain) in self.chains.iter_mut().enumerate() {
            if let Some(chain) = chain {
                free[c] = chain.model.begin_coupled_step()?;
            }
        }
        let mut detected = self.detect_nested(&free);
        let mut warm = Some(self.remembered(&detected));
        let settings = self.effort.contact(&self.settings.contact);
        let rounds = settings.detection_rounds.max(1);
        let mut round = 0;
        let mut penetration: f64 = 0.0;
        let (increments, response) = loop {
            let contacts: Vec<CoupledContact> = detected.iter().map(|d| d.contact).collect();
            let response = {
                let empty = crate::substructure::Flexibility::default();
                let flexibilities: Vec<_> = self
                    .chains
                    .iter()
                    .map(|c| c.as_ref().map_or(&empty, |c| c.model.flexibility()))
                    .collect();
                let free_slices: Vec<&[Vector6<f64>]> = free.iter().map(Vec::as_slice).collect();
                coupled_gauss_seidel(
                    &flexibilities,
                    &free_slices,
                    &contacts,
                    &settings,
                    warm.as_deref(),
                )?
            };
            // Lumen contacts come back turned to where their points settled.
            for (d, (normal, gap)) in detected.iter_mut().zip(&response.normals) {
                d.contact.normal = *normal;
                d.contact.gap = *gap;
            }
            let mut increments: Vec<Vec<Vector6<f64>>> = vec![Vec::new(); count];
            for (c, chain) in self.chains.iter_mut().enumerate() {
                if let Some(chain) = chain {
                    increments[c] = if contacts.is_empty() {
                        free[c].clone()
                    } else {
                        chain
                            .model
                            .coupled_increments(&free[c], &response.nodal_loads[c])
                    };
                }
            }
            round += 1;
            // With one round allowed the look below is still taken: its penetration decides a
            // halving of the step (as in merged mode).
            if contacts.is_empty() {
                break (increments, (detected, response));
            }
            let mut next = self.detect_nested(&increments);
            // A lumen's tolerance is at most `LUMEN_TOLERANCE_FRACTION` of its clearance.
            let mut excess: f64 = 0.0;
            penetration = 0.0;
            for d in &next {
                let v = violation(&d.contact, &increments);
                let tolerance = d
                    .contact
                    .lumen
                    .map_or(settings.penetration_tolerance_m, |l| {
                        settings
                            .penetration_tolerance_m
                            .min(LUMEN_TOLERANCE_FRACTION * l.clearance)
                    });
                penetration = penetration.max(v);
                excess = excess.max(v - tolerance);
            }
            if excess <= 0.0 || round >= rounds {
                break (increments, (detected, response));
            }
            // Keep the earlier rounds' contacts, ordered along the path, their forces carried.
            let mut carried: Vec<Vector3<f64>> = vec![Vector3::zeros(); next.len()];
            for (d, l) in detected.into_iter().zip(&response.local) {
                match next.iter().position(|n| same_place(&n.contact, &d.contact)) {
                    Some(k) => carried[k] = *l,
                    None => {
                        next.push(d);
                        carried.push(*l);
                    }
                }
            }
            let mut order: Vec<usize> = (0..next.len()).collect();
            order.sort_by(|&a, &b| along(&next[a]).total_cmp(&along(&next[b])));
            let mut slots: Vec<Option<Detected>> = next.into_iter().map(Some).collect();
            detected = order
                .iter()
                .map(|&k| slots[k].take().expect("once"))
                .collect();
            warm = Some(order.iter().map(|&k| carried[k]).collect());
        };
        let (detected, response) = response;
        // Apply every chain's increments, or none.
        let snapshots: Vec<_> = self
            .chains
            .iter()
            .map(|c| c.as_ref().map(|c| c.model.snapshot()))
            .collect();
        let mut applied = Ok(());
        for (c, chain) in self.chains.iter_mut().enumerate() {
            if let Some(chain) = chain
                && let Err(e) = chain.model.finish_coupled_step(&increments[c])
            {
                applied = Err(e);
                break;
            }
        }
        if let Err(e) = applied {
            for (chain, snapshot) in self.chains.iter_mut().zip(snapshots) {
                if let (Some(chain), Some(snapshot)) = (chain, snapshot) {
                    chain.model.restore(snapshot);
                }
            }
            return Err(e);
        }
        // Each chain remembers where it was touched (for refinement).
        for (c, chain) in self.chains.iter_mut().enumerate() {
            let Some(chain) = chain else { continue };
            let mut touched: Vec<(f64, Vector3<f64>)> = detected
                .iter()
                .zip(&response.local)
                .filter_map(|(d, l)| {
                    if d.contact.first.chain == c {
                        Some((d.sigma_first, *l))
                    } else if d.contact.second.is_some_and(|s| s.chain == c) {
                        d.sigma_second.map(|s| (s, *l))
                    } else {
                        None
                    }
                })
                .collect();
            touched.sort_by(|a, b| a.0.total_cmp(&b.0));
            chain.previous_contacts = touched;
            chain.sync_nodes();
        }
        let report = StackReport {
            contacts: detected.len(),
            active_contacts: response.local.iter().filter(|l| l.x > 0.0).count(),
            sweeps: response.iterations,
            converged: response.converged,
            inserted_m: self.instruments.iter().map(|i| i.inserted_m).collect(),
            elements: self
                .chains
                .iter()
                .flatten()
                .map(|c| c.model.element_count())
                .sum(),
            asleep: false,
        };
        self.nested_last = NestedStep {
            sigma: detected.iter().map(|d| d.sigma_first).collect(),
            contacts: detected.into_iter().map(|d| d.contact).collect(),
            local: response.local,
            penetration_m: penetration,
        };
        Ok(report)
    }

    /// The last step's forces for contacts at the same place (same chains, within a sample
    /// spacing along the path), as a warm start.
    fn remembered(&self, detected: &[Detected]) -> Vec<Vector3<f64>> {
        let last = &self.nested_last;
        let tolerance = self.settings.sample_spacing_m;
        detected
            .iter()
            .map(|d| {
                last.contacts
                    .iter()
                    .zip(&last.sigma)
                    .zip(&last.local)
                    .filter(|((c, s), _)| {
                        c.first.chain == d.contact.first.chain
                            && c.second.map(|p| p.chain) == d.contact.second.map(|p| p.chain)
                            && (**s - d.sigma_first).abs() <= tolerance
                            && c.normal.dot(&d.contact.normal) > 0.9
                    })
                    .min_by(|a, b| {
                        (a.0.1 - d.sigma_first)
                            .abs()
                            .total_cmp(&(b.0.1 - d.sigma_first).abs())
                    })
                    .map_or(Vector3::zeros(), |(_, l)| *l)
            })
            .collect()
    }

    /// Contacts of every chain under per-chain `increments` (the free motion, or a solved
    /// one), ordered along the path: the wall where no instrument is around the chain, the
    /// lumen of the innermost instrument around it elsewhere.
    fn detect_nested(&self, increments: &[Vec<Vector6<f64>>]) -> Vec<Detected> {
        let margin = self.settings.contact_margin_m;
        let mut found = Vec::new();
        for (i, chain) in self.chains.iter().enumerate() {
            let Some(chain) = chain else { continue };
            let sigma: Vec<f64> = chain.nodes.iter().map(|n| n.sigma).collect();
            let positions = chain.model.positions();
            let mut outside: Vec<Sample> = Vec::new();
            // The deepest lumen contact per element half.
            let mut lumen: Vec<(usize, bool, f64, Detected)> = Vec::new();
            let layout = chain.sample_layout(false);
            // A point just inside each outer tip the chain passes: between two samples of a
            // long inner element the outer's tip could bend off it.
            let mut tips: Vec<Sample> = Vec::new();
            for k in 0..i {
                let tip = self.instruments[k].inserted_m - TIP_INSET_M;
                let last = sigma.len() - 1;
                if self.chains[k].is_none() || tip <= 0.0 || tip >= sigma[last] {
                    continue;
                }
                let e = sigma
                    .partition_point(|&x| x <= tip)
                    .saturating_sub(1)
                    .min(last - 1);
                let t = (tip - sigma[e]) / (sigma[e + 1] - sigma[e]);
                if let Some(like) = layout.iter().find(|s| s.element == e) {
                    tips.push(Sample {
                        element: e,
                        t,
                        ..*like
                    });
                }
            }
            for (s, is_tip) in layout
                .iter()
                .map(|s| (*s, false))
                .chain(tips.into_iter().map(|s| (s, true)))
            {
                let at = sigma[s.element] + s.t * (sigma[s.element + 1] - sigma[s.element]);
                let container = (0..i)
                    .rev()
                    .find(|&k| self.chains[k].is_some() && self.instruments[k].inserted_m > at);
                let Some(k) = container else {
                    outside.push(s);
                    continue;
                };
                if at <= 0.0 {
                    continue;
                }
                let Some((d, predicted)) =
                    self.lumen_contact(i, chain, &s, at, k, increments, margin)
                else {
                    continue;
                };
                if is_tip {
                    // Its own contact, never merged with an element half's.
                    lumen.push((usize::MAX, false, predicted, d));
                    continue;
                }
                let half = s.t < 0.5;
                match lumen.iter_mut().find(|e| e.0 == s.element && e.1 == half) {
                    Some(e) if predicted < e.2 => *e = (s.element, half, predicted, d),
                    Some(_) => {}
                    None => lumen.push((s.element, half, predicted, d)),
                }
            }
            // No bounds kept across steps here (a throwaway cache probes every point).
            let mut clearance = crate::navigation::ClearanceCache::default();
            for c in detect(
                &self.wall,
                &outside,
                positions,
                &increments[i],
                margin,
                &mut clearance,
            ) {
                found.push(Detected {
                    sigma_first: sigma[c.element] + c.t * (sigma[c.element + 1] - sigma[c.element]),
                    sigma_second: None,
                    contact: CoupledContact {
                        first: ChainPoint {
                            chain: i,
                            element: c.element,
                            t: c.t,
                        },
                        second: None,
                        normal: c.normal,
                        gap: c.gap,
                        friction: c.friction,
                        lumen: None,
                    },
                });
            }
            found.extend(lumen.into_iter().map(|e| e.3));
        }
        found.sort_by(|a, b| along(a).total_cmp(&along(b)));
        found
    }

    /// The lumen contact of sample `s` of chain `i` (`chain`, at path coordinate `at`) with
    /// chain `k` around it, and its predicted gap (m), if that is below the lumen margin.
    #[allow(clippy::too_many_arguments)]
    fn lumen_contact(
        &self,
        i: usize,
        chain: &Stack<FreeSpace>,
        s: &Sample,
        at: f64,
        k: usize,
        increments: &[Vec<Vector6<f64>>],
        margin: f64,
    ) -> Option<(Detected, f64)> {
        let (e, t) = (s.element, s.t);
        let positions = chain.model.positions();
        let rotations = chain.model.rotations();
        let p = hermite_point(
            (&positions[e], &rotations[e]),
            (&positions[e + 1], &rotations[e + 1]),
            t,
        )
        .0;
        let dp = point_displacement(&increments[i], e, t);
        let outer = self.chain(k);
        let outer_sigma: Vec<f64> = outer.nodes.iter().map(|n| n.sigma).collect();
        let op = outer.model.positions();
        let oq = outer.model.rotations();
        let last = op.len() - 2;
        let guess = outer_sigma
            .partition_point(|&x| x <= at)
            .saturating_sub(1)
            .min(last);
        // The closest point on the outer chain's chords near the same path coordinate.
        let (mut element, mut tt, mut best) = (guess, 0.0, f64::INFINITY);
        for candidate in guess.saturating_sub(1)..=(guess + 1).min(last) {
            let (a, b) = (op[candidate], op[candidate + 1]);
            let ab = b - a;
            let f = ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
            let distance = (a + ab * f - p).norm();
            if distance < best {
                (element, tt, best) = (candidate, f, distance);
            }
        }
        let (q, frame) = hermite_point(
            (&op[element], &oq[element]),
            (&op[element + 1], &oq[element + 1]),
            tt,
        );
        let dq = point_displacement(&increments[k], element, tt);
        let tangent = frame * Vector3::x();
        let v = (q + dq) - (p + dp);
        let across = v - tangent * tangent.dot(&v);
        let now = q - p;
        let distance = across.norm();
        let around = &self.instruments[k];
        let (section, _) = around
            .device
            .section_at(around.length_m - around.inserted_m + at);
        let clearance = section.cross_section.inner_radius_m - s.radius;
        let predicted = clearance - distance;
        if predicted > (LUMEN_MARGIN_FRACTION * clearance).min(margin) || distance < 1e-12 {
            return None;
        }
        let normal = across / distance;
        let sigma_second =
            outer_sigma[element] + tt * (outer_sigma[element + 1] - outer_sigma[element]);
        Some((
            Detected {
                contact: CoupledContact {
                    first: ChainPoint {
                        chain: i,
                        element: e,
                        t,
                    },
                    second: Some(ChainPoint {
                        chain: k,
                        element,
                        t: tt,
                    }),
                    normal,
                    gap: predicted - normal.dot(&(dp - dq)),
                    friction: section.lumen_friction_coefficient,
                    lumen: Some(Lumen {
                        axis: tangent,
                        across: now - tangent * tangent.dot(&now),
                        clearance,
                    }),
                },
                sigma_first: at,
                sigma_second: Some(sigma_second),
            },
            predicted,
        ))
    }

    /// Nested mode's largest penetration (m) of a wall or a lumen in the current
    /// configuration.
    pub(super) fn nested_max_penetration(&self) -> f64 {
        let zero: Vec<Vec<Vector6<f64>>> = self
            .chains
            .iter()
            .map(|c| vec![Vector6::zeros(); c.as_ref().map_or(0, |c| c.model.node_count() - 1)])
            .collect();
        self.detect_nested(&zero)
            .iter()
            .map(|d| -d.contact.gap)
            .fold(0.0, f64::max)
    }

    /// Nested mode: each instrument's own chain's base reaction along and about the entry
    /// axis.
    pub(super) fn nested_proximal_reactions(&mut self) -> Vec<ProximalReaction> {
        self.chains
            .iter_mut()
            .map(|chain| match chain {
                Some(chain) => {
                    let model = chain.model_mut();
                    let wrench = model.base_reaction();
                    let axis = model.rotations()[0] * Vector3::x();
                    ProximalReaction {
                        axial_force_n: wrench.fixed_rows::<3>(0).dot(&axis),
                        torque_nm: wrench.fixed_rows::<3>(3).dot(&axis),
                    }
                }
                None => ProximalReaction {
                    axial_force_n: 0.0,
                    torque_nm: 0.0,
                },
            })
            .collect()
    }
}

/// How far (m) a contact is violated under per-chain `increments`: a lumen contact by the
/// point's offset beyond the clearance, a wall contact along its normal.
fn violation(contact: &CoupledContact, increments: &[Vec<Vector6<f64>>]) -> f64 {
    let moved = contact.relative_displacement(increments);
    match &contact.lumen {
        Some(l) => l.offset(&moved).norm() - l.clearance,
        None => -(contact.gap + contact.normal.dot(&moved)),
    }
}

/// Sort key along the path: the first side's path coordinate, then its chain.
fn along(d: &Detected) -> f64 {
    d.sigma_first + 1e-12 * d.contact.first.chain as f64
}

/// Whether two contacts act at the same place on the same chains with similar normals.
fn same_place(a: &CoupledContact, b: &CoupledContact) -> bool {
    a.first == b.first
        && a.second.map(|p| (p.chain, p.element)) == b.second.map(|p| (p.chain, p.element))
        && a.normal.dot(&b.normal) > 0.9
}
