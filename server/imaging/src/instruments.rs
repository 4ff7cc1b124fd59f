//! The instruments `cathlab case` writes into a scene: the catheter-and-wire pair that fits
//! the route's narrow lumen (a 5 F catheter over a 0.035" wire in the neck, a 0.017"
//! microcatheter over a 0.014" microwire in small vessels), and how far each starts
//! inserted, so that both lie inside the straight first stretch of the access vessel.

use cathlab_physics::Catalogue;
use nalgebra::{Point3, Vector3};

use crate::error::{ImagingError, Result};

/// The largest share of the lumen's diameter a catheter may fill (–): a 5 F catheter
/// (1.67 mm) then needs a vessel of 2.8 mm or more (a vertebral, an ICA), a 0.8 mm
/// microcatheter one of 1.3 mm (an M2); one filling more wedges and cannot be steered.
pub const FIT_FRACTION: f64 = 0.6;

/// The share of the route's samples narrower than the "narrow lumen" (–): its 10th
/// percentile, so that one pinched sample of a segmentation does not decide.
pub const NARROW_QUANTILE: f64 = 0.1;

/// Clearance kept between a starting instrument and the wall (m), beyond its radius.
pub const START_CLEARANCE_M: f64 = 0.2e-3;

/// Most an instrument starts inserted (mm): the catheter, then the wire.
pub const MOST_INSERTED_MM: [f64; 2] = [10.0, 30.0];

/// Least an instrument starts inserted (mm): one tip element (the scene's lower bound).
pub const LEAST_INSERTED_MM: f64 = 2.0;

/// A catheter and the wire inside it, as a scene's `[[stack]]` names them.
#[derive(Debug, Clone, PartialEq)]
pub struct InstrumentPair {
    /// What the scene's comment calls the pair.
    pub label: &'static str,
    /// The catheter's `[[stack]]` line (`device = "…"`).
    pub catheter: &'static str,
    /// The catheter's catalogue identifier.
    pub catheter_id: &'static str,
    /// The wire's `[[stack]]` line (`device = "…"` or `custom = {…}`).
    pub wire: &'static str,
    /// The wire's largest outer diameter (mm).
    pub wire_outer_mm: f64,
    /// The wire's shaped tip: the angle it turns through (deg) over its last length (mm).
    pub wire_bend: (f64, f64),
    /// A straight wire of the same size (`device = "…"`) for where the shaped tip's bend does
    /// not fit beside the catheter at the start.
    pub straight_wire: Option<&'static str>,
}

/// The first quoted name of a `[[stack]]` line (the catalogue identifier or preset name).
fn quoted_name(line: &'static str) -> &'static str {
    line.split('"').nth(1).unwrap_or(line)
}

impl InstrumentPair {
    /// The wire's catalogue identifier or preset name.
    pub fn wire_name(&self) -> &'static str {
        quoted_name(self.wire)
    }
}

/// The pairs `cathlab case` chooses from, largest first.
pub fn pairs() -> [InstrumentPair; 2] {
    [
        InstrumentPair {
            label: "a 5 F catheter in the left hand, a shaped 0.035\" wire in the right",
            catheter: "device = \"catheter-5f-vertebral\"",
            catheter_id: "catheter-5f-vertebral",
            wire: "custom = { preset = \"guidewire_035_shaped\", bend_deg = 90.0, \
                   bend_length_mm = 30.0 }",
            wire_outer_mm: 0.889,
            wire_bend: (90.0, 30.0),
            straight_wire: None,
        },
        InstrumentPair {
            label: "a 0.017\" microcatheter in the left hand, an angled 0.014\" microwire in \
                    the right (the vessels are small)",
            catheter: "device = \"microcatheter-017-150\"",
            catheter_id: "microcatheter-017-150",
            wire: "device = \"microwire-014-angled\"",
            wire_outer_mm: 0.3556,
            wire_bend: (45.0, 5.0),
            straight_wire: Some("device = \"microwire-014-straight\""),
        },
    ]
}

/// The largest outer diameter of a catalogue device (mm).
pub fn catalogue_outer_mm(id: &str) -> Result<f64> {
    let device = Catalogue::builtin()
        .device(id)
        .map_err(|e| ImagingError::Case {
            field: "instruments".into(),
            reason: e.to_string(),
        })?;
    Ok(device
        .sections
        .iter()
        .map(|s| s.cross_section.outer_radius_m * 2e3)
        .fold(0.0, f64::max))
}

/// The narrow lumen radius of a route (m): the [`NARROW_QUANTILE`] of its samples' radii.
pub fn narrow_radius_m(route: &[(Point3<f64>, f64)]) -> f64 {
    let mut radii: Vec<f64> = route.iter().map(|(_, r)| *r).collect();
    if radii.is_empty() {
        return 0.0;
    }
    radii.sort_by(f64::total_cmp);
    radii[((radii.len() - 1) as f64 * NARROW_QUANTILE).round() as usize]
}

/// The first pair whose catheter fills at most [`FIT_FRACTION`] of the diameter
/// `2 × narrow_radius_m`, with the catheter's outer diameter (mm); an error naming the
/// lumen when none fits.
pub fn choose_pair(narrow_radius_m: f64) -> Result<(InstrumentPair, f64)> {
    let diameter_mm = 2e3 * narrow_radius_m;
    let mut smallest = f64::INFINITY;
    for pair in pairs() {
        let outer = catalogue_outer_mm(pair.catheter_id)?;
        if outer <= FIT_FRACTION * diameter_mm {
            return Ok((pair, outer));
        }
        smallest = smallest.min(outer);
    }
    Err(ImagingError::Case {
        field: "instruments".into(),
        reason: format!(
            "the route's narrow lumen is {diameter_mm:.2} mm across; the smallest catheter \
             (outer {smallest:.2} mm) needs {:.2} mm",
            smallest / FIT_FRACTION
        ),
    })
}

/// How far a straight instrument of outer radius `outer_radius_m`, entering at the route's
/// start along its direction 10 samples ahead (as the engine places a scene's devices),
/// stays inside the vessels with [`START_CLEARANCE_M`] to spare (m): the lumen is taken as
/// the frustums of the route's radii about its segments.
pub fn straight_reach_m(route: &[(Point3<f64>, f64)], outer_radius_m: f64) -> f64 {
    let Some(&(start, _)) = route.first() else {
        return 0.0;
    };
    let ahead = route[10.min(route.len() - 1)].0;
    let Some(direction) = (ahead - start).try_normalize(1e-12) else {
        return 0.0;
    };
    let step = 0.25e-3;
    // Inside the frustum of some segment of the route.
    let inside = |p: &Point3<f64>| {
        route.windows(2).any(|w| {
            let ((a, ra), (b, rb)) = (w[0], w[1]);
            let ab = b - a;
            let t = ((p - a).dot(&ab) / ab.norm_squared().max(1e-24)).clamp(0.0, 1.0);
            let d = (p - (a + ab * t)).norm();
            d + outer_radius_m + START_CLEARANCE_M <= ra + (rb - ra) * t
        })
    };
    let length: f64 = route.windows(2).map(|w| (w[1].0 - w[0].0).norm()).sum();
    let mut reach = 0.0;
    while reach + step <= length {
        let p: Point3<f64> = start + Vector3::from(direction) * (reach + step);
        if !inside(&p) {
            break;
        }
        reach += step;
    }
    reach
}

/// The longest a shaped wire tip may stand out of its catheter (m) so that its bend (`angle`
/// rad over its last `length` m, a circular arc leaving the catheter tangentially) stays
/// [`START_CLEARANCE_M`] off the wall of a lumen of radius `lumen_radius_m` around the
/// catheter's axis: the arc's sideways offset (1 − cos κL)/κ, κ = angle/length, within
/// lumen radius − wire radius − clearance. Infinite when the whole bend fits.
pub fn max_lead_m(angle: f64, length: f64, wire_radius_m: f64, lumen_radius_m: f64) -> f64 {
    let room = lumen_radius_m - wire_radius_m - START_CLEARANCE_M;
    if room <= 0.0 {
        return 0.0;
    }
    if angle <= 0.0 || length <= 0.0 {
        return f64::INFINITY;
    }
    let kappa = angle / length;
    if (1.0 - angle.cos()) / kappa <= room {
        return f64::INFINITY;
    }
    (1.0 - room * kappa).clamp(-1.0, 1.0).acos() / kappa
}

/// How far the catheter and the wire start inserted (mm): the catheter 40 % of the straight
/// reach, the wire 80 % of it but at most `max_lead_m` ahead of the catheter's tip (its
/// shaped tip stays off the wall); each within [`LEAST_INSERTED_MM`] and
/// [`MOST_INSERTED_MM`].
pub fn start_inserted_mm(reach_m: f64, max_lead_m: f64) -> [f64; 2] {
    let reach_mm = reach_m * 1e3;
    let catheter = (0.4 * reach_mm).clamp(LEAST_INSERTED_MM, MOST_INSERTED_MM[0]);
    let wire = (0.8 * reach_mm)
        .min(catheter + max_lead_m * 1e3)
        .clamp(LEAST_INSERTED_MM, MOST_INSERTED_MM[1]);
    [catheter, wire]
}

/// The instruments' start: the wire's `[[stack]]` line and name, and how far each starts
/// inserted (mm).
#[derive(Debug, Clone, PartialEq)]
pub struct StartPlan {
    /// The wire's `[[stack]]` line.
    pub wire: &'static str,
    /// The wire's catalogue identifier or preset name.
    pub wire_name: &'static str,
    /// Catheter, then wire (mm).
    pub inserted_mm: [f64; 2],
}

/// How `pair` starts on a route whose first `reach_m` run straight in a lumen of radius
/// `start_lumen_m` (at its narrowest there): the shaped wire standing out of the catheter as
/// far as its bend clears the wall ([`max_lead_m`]); where its bend cannot stand out at all
/// beside the catheter and the pair has a straight wire, that one (a soft catheter over a
/// shaped wire takes the wire's shape, so a shaped wire kept inside bends the catheter's tip
/// into the wall as well).
pub fn start_plan(pair: &InstrumentPair, reach_m: f64, start_lumen_m: f64) -> StartPlan {
    let lead = max_lead_m(
        pair.wire_bend.0.to_radians(),
        pair.wire_bend.1 * 1e-3,
        pair.wire_outer_mm * 0.5e-3,
        start_lumen_m,
    );
    match pair.straight_wire {
        Some(straight) if lead.is_finite() => StartPlan {
            wire: straight,
            wire_name: quoted_name(straight),
            inserted_mm: start_inserted_mm(reach_m, f64::INFINITY),
        },
        _ => StartPlan {
            wire: pair.wire,
            wire_name: pair.wire_name(),
            inserted_mm: start_inserted_mm(reach_m, lead),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn straight(radius: f64, length_mm: usize) -> Vec<(Point3<f64>, f64)> {
        (0..=length_mm)
            .map(|i| (Point3::new(i as f64 * 1e-3, 0.0, 0.0), radius))
            .collect()
    }

    #[test]
    fn the_pairs_name_their_catalogue_devices_and_wires_of_the_catalogues_size() {
        for pair in pairs() {
            let outer = catalogue_outer_mm(pair.catheter_id).unwrap();
            assert!(outer > pair.wire_outer_mm, "{}", pair.label);
            assert!(pair.catheter.contains(pair.catheter_id));
        }
        // The microwire's diameter and bend are the catalogue's.
        let micro = &pairs()[1];
        let id = micro.wire_name();
        assert!((catalogue_outer_mm(id).unwrap() - micro.wire_outer_mm).abs() < 1e-9);
        let device = Catalogue::builtin().device(id).unwrap();
        let arcs = &device.sections.last().unwrap().rest_shape.arcs;
        assert_eq!(arcs.len(), 1);
        assert!((arcs[0].length_m * 1e3 - micro.wire_bend.1).abs() < 1e-9);
        let angle = arcs[0].curvature_per_m * arcs[0].length_m;
        assert!(
            (angle.to_degrees() - micro.wire_bend.0).abs() < 1e-6,
            "{angle}"
        );
    }

    #[test]
    fn a_carotid_takes_the_5f_pair_a_2_mm_vessel_the_micro_pair_and_a_thread_none() {
        assert_eq!(
            choose_pair(3e-3).unwrap().0.catheter_id,
            "catheter-5f-vertebral"
        );
        let (pair, outer) = choose_pair(1e-3).unwrap();
        assert_eq!(pair.catheter_id, "microcatheter-017-150");
        assert!(outer <= FIT_FRACTION * 2.0);
        // A 2.6 mm vessel is too narrow for the 5 F catheter.
        assert_eq!(
            choose_pair(1.3e-3).unwrap().0.catheter_id,
            "microcatheter-017-150"
        );
        let error = choose_pair(0.3e-3).unwrap_err().to_string();
        assert!(
            error.contains("0.60 mm across") && error.contains("1.33 mm"),
            "{error}"
        );
    }

    #[test]
    fn the_straight_reach_is_the_tube_or_where_the_route_turns() {
        // A straight tube: the whole route (to the last quarter-millimetre step).
        let tube = straight(1e-3, 40);
        let reach = straight_reach_m(&tube, 0.4e-3);
        assert!((reach - 40e-3).abs() <= 0.25e-3, "{reach}");
        // Turning by 90° after 12 mm: a ray of radius 0.4 mm in a 1 mm vessel leaves the
        // lumen about 12 + (1 − 0.4 − 0.2) mm along.
        let mut bent = straight(1e-3, 12);
        bent.extend((1..=30).map(|i| (Point3::new(12e-3, i as f64 * 1e-3, 0.0), 1e-3)));
        let reach = straight_reach_m(&bent, 0.4e-3);
        assert!(reach > 12.2e-3 && reach < 12.6e-3, "{reach}");
        let [catheter, wire] = start_inserted_mm(reach, f64::INFINITY);
        assert!(catheter < wire && wire < reach * 1e3, "{catheter} {wire}");
        assert_eq!(start_inserted_mm(1.0, f64::INFINITY), MOST_INSERTED_MM);
        assert_eq!(start_inserted_mm(0.0, 0.0), [LEAST_INSERTED_MM; 2]);
        // A wire held back to 1 mm ahead of the catheter.
        assert_eq!(start_inserted_mm(1.0, 1e-3), [10.0, 11.0]);
    }

    #[test]
    fn a_narrow_start_takes_the_straight_microwire_and_a_wide_one_the_shaped() {
        let [five_f, micro] = pairs();
        let narrow = start_plan(&micro, 20e-3, 1e-3);
        assert_eq!(narrow.wire_name, "microwire-014-straight");
        assert_eq!(narrow.inserted_mm, [8.0, 16.0]);
        let wide = start_plan(&micro, 20e-3, 3e-3);
        assert_eq!(wide.wire_name, "microwire-014-angled");
        // The 0.035" wire's 90° over 30 mm never fits whole in a carotid: it stands out as
        // far as its bend clears the wall.
        let carotid = start_plan(&five_f, 40e-3, 3e-3);
        assert_eq!(carotid.wire_name, "guidewire_035_shaped");
        let [catheter, wire] = carotid.inserted_mm;
        assert!(
            wire - catheter > 5.0 && wire - catheter < 15.0,
            "{catheter} {wire}"
        );
    }

    #[test]
    fn a_shaped_tip_stands_out_only_as_far_as_its_bend_clears_the_wall() {
        let (angle, length) = (45f64.to_radians(), 5e-3);
        let (wire, lumen) = (0.1778e-3, 1e-3);
        let lead = max_lead_m(angle, length, wire, lumen);
        // The arc of that length is offset by exactly the room left, a little more is not.
        let offset = |l: f64| (1.0 - (angle / length * l).cos()) / (angle / length);
        let room = lumen - wire - START_CLEARANCE_M;
        assert!((offset(lead) - room).abs() < 1e-12, "{lead}");
        assert!(lead > 2.5e-3 && lead < 3.0e-3, "{lead}");
        // In a carotid the whole 45° bend fits; with no room nothing may stand out.
        assert_eq!(max_lead_m(angle, length, wire, 3e-3), f64::INFINITY);
        assert_eq!(max_lead_m(angle, length, wire, 0.3e-3), 0.0);
    }

    #[test]
    fn the_narrow_radius_ignores_one_pinched_sample() {
        let mut route = straight(1e-3, 40);
        route[20].1 = 0.1e-3;
        assert_eq!(narrow_radius_m(&route), 1e-3);
        route[0].1 = 0.5e-3;
        route[1].1 = 0.5e-3;
        route[2].1 = 0.5e-3;
        route[3].1 = 0.5e-3;
        route[4].1 = 0.5e-3;
        assert_eq!(narrow_radius_m(&route), 0.5e-3);
    }
}
