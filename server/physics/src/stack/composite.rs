//! Merged mode's composite beam: the rest geometry of an element where instruments overlap
//! (stiffnesses summed, rest curvatures blended by stiffness and turned by each instrument's
//! twist), and the nominal node spacing along the strand.

use nalgebra::{UnitQuaternion, Vector3};

use super::instrument::Instrument;
use crate::beam::ElementSpec;
use crate::navigation::{NavigationSettings, spacing};
use crate::section::BeamProperties;

/// Nominal node spacing at path coordinate `sigma`: that of the outermost instrument present
/// there, fine near its own tip (an inner instrument's tip inside another changes the
/// composite's stiffness, which the tip node captures, not its shape).
pub(super) fn nominal_spacing(
    settings: &NavigationSettings,
    instruments: &[Instrument],
    sigma: f64,
) -> f64 {
    instruments
        .iter()
        .find(|i| i.inserted_m > sigma)
        .map_or(settings.tip_element_m, |i| {
            spacing(settings, i.inserted_m, sigma)
        })
}

/// Rest geometry of the composite element between path coordinates `a` < `b`: stiffnesses
/// summed over the instruments present, rest curvature blended by stiffness (bending by EI,
/// torsion by GJ), each instrument's turned by its twist relative to the outermost's. With
/// `own_axial` ([`NavigationSettings::axial_slide`]) the axial stiffness is the outermost
/// instrument's alone: those inside it slide through it with their own strain, which the
/// strand carries as loads (`stack/slide.rs`), not as its own.
pub(super) fn composite_spec(
    instruments: &[Instrument],
    a: f64,
    b: f64,
    own_axial: bool,
) -> ElementSpec {
    let mid = 0.5 * (a + b);
    let reference = instruments[0].twist_rad;
    let mut props = BeamProperties {
        axial_stiffness_n: 0.0,
        bending_stiffness_nm2: 0.0,
        torsional_stiffness_nm2: 0.0,
        shear_stiffness_n: 0.0,
        polar_gyration_m2: 0.0,
        mass_per_length_kg_m: 0.0,
    };
    let (mut area, mut polar) = (0.0, 0.0);
    let mut bending = Vector3::zeros();
    let mut torsion = 0.0;
    for (n, instrument) in instruments
        .iter()
        .filter(|i| i.inserted_m > mid)
        .enumerate()
    {
        let offset = instrument.length_m - instrument.inserted_m;
        let (section, _) = instrument.device.section_at(offset + mid);
        let p = section.beam_properties();
        let kappa = instrument
            .device
            .mean_rest_curvature(offset + a, offset + b);
        let turned =
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), instrument.twist_rad - reference)
                * kappa;
        bending += Vector3::new(0.0, turned.y, turned.z) * p.bending_stiffness_nm2;
        torsion += turned.x * p.torsional_stiffness_nm2;
        if n == 0 || !own_axial {
            props.axial_stiffness_n += p.axial_stiffness_n;
        }
        props.bending_stiffness_nm2 += p.bending_stiffness_nm2;
        props.torsional_stiffness_nm2 += p.torsional_stiffness_nm2;
        props.shear_stiffness_n += p.shear_stiffness_n;
        props.mass_per_length_kg_m += p.mass_per_length_kg_m;
        let section_area = section.cross_section.area_m2();
        area += section_area;
        polar += p.polar_gyration_m2 * section_area;
    }
    props.polar_gyration_m2 = if area > 0.0 { polar / area } else { 0.0 };
    let mut curvature = bending / props.bending_stiffness_nm2;
    curvature.x = torsion / props.torsional_stiffness_nm2;
    ElementSpec {
        props,
        length_m: b - a,
        curvature_per_m: curvature,
    }
}

/// Whether two rest geometries agree to round-off (an element carried with its material has
/// the same geometry up to the last bits of its path coordinates).
pub(super) fn same_spec(a: &ElementSpec, b: &ElementSpec) -> bool {
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-12 * x.abs().max(y.abs()).max(1e-300);
    a.props == b.props
        && close(a.length_m, b.length_m)
        && (a.curvature_per_m - b.curvature_per_m).norm()
            <= 1e-9 * a.curvature_per_m.norm().max(1.0)
}
