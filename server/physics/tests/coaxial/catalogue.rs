//! The device catalogue: definition errors named by device, section and field, user devices
//! in TOML, the built-in catalogue (sourced, nesting as in the clinic), marker bands and
//! stent retriever tables.

use cathlab_physics::{Catalogue, PhysicsError, presets};
use nalgebra::Vector3;

use crate::support::free_stack;

/// A one-device catalogue whose tip section has `field = value`.
fn catalogue_with(field: &str, value: &str) -> String {
    let section = |name: &str, tip: bool| {
        let mut fields = vec![
            ("length_mm", "100.0"),
            ("outer_diameter_mm", "1.67"),
            ("inner_diameter_mm", "0.97"),
            ("young_modulus_gpa", "2.5"),
            ("poisson_ratio", "0.4"),
            ("density_kg_m3", "1150.0"),
            ("wall_friction", "0.05"),
            ("lumen_friction", "0.04"),
        ];
        if tip {
            for f in &mut fields {
                if f.0 == field {
                    f.1 = value;
                }
            }
        }
        let body: String = fields.iter().map(|(k, v)| format!("{k} = {v}\n")).collect();
        format!("[[device.section]]\nname = \"{name}\"\n{body}")
    };
    format!(
        "[[device]]\nid = \"test-catheter\"\nname = \"Test catheter\"\nkind = \"catheter\"\nsource = \"test\"\n{}{}{}",
        section("shaft", false),
        section("transition", false),
        section("tip", true)
    )
}

fn definition_error(text: &str) -> (String, String, String) {
    match Catalogue::from_toml_str(text) {
        Err(PhysicsError::DeviceDefinition {
            device,
            section,
            field,
            ..
        }) => (device, section, field),
        other => panic!("expected a device definition error, got {other:?}"),
    }
}

#[test]
fn catalogue_inner_diameter_not_below_outer_is_named() {
    let (device, section, field) = definition_error(&catalogue_with("inner_diameter_mm", "1.67"));
    assert_eq!(
        (device.as_str(), section.as_str(), field.as_str()),
        ("test-catheter", "section \"tip\"", "inner_diameter_mm")
    );
}

#[test]
fn catalogue_negative_length_is_named() {
    let (device, section, field) = definition_error(&catalogue_with("length_mm", "-5.0"));
    assert_eq!(
        (device.as_str(), section.as_str(), field.as_str()),
        ("test-catheter", "section \"tip\"", "length_mm")
    );
}

#[test]
fn catalogue_nan_is_named() {
    let text = catalogue_with("young_modulus_gpa", "nan");
    let err = Catalogue::from_toml_str(&text).unwrap_err();
    assert!(
        err.to_string()
            .contains("young_modulus_gpa: must be finite"),
        "{err}"
    );
    assert_eq!(
        definition_error(&text).2,
        "young_modulus_gpa",
        "the field is named"
    );
}

#[test]
fn catalogue_arcs_longer_than_their_section_are_named() {
    let text = catalogue_with("lumen_friction", "0.04")
        + "[[device.section.arc]]\nlength_mm = 150.0\nangle_deg = 90.0\n";
    let (_, section, field) = definition_error(&text);
    assert_eq!(
        (section.as_str(), field.as_str()),
        ("section \"tip\"", "arc")
    );
}

#[test]
fn catalogue_syntax_and_unknown_fields_are_errors() {
    let err = Catalogue::from_toml_str(&catalogue_with("length_mm", "\"long\"")).unwrap_err();
    assert!(matches!(err, PhysicsError::CatalogueSyntax(_)), "{err:?}");
    let err =
        Catalogue::from_toml_str(&(catalogue_with("length_mm", "100.0") + "colour = \"blue\"\n"))
            .unwrap_err();
    assert!(err.to_string().contains("colour"), "{err}");
    let unknown = Catalogue::builtin().device("no-such-device").unwrap_err();
    assert!(unknown.to_string().contains("no-such-device"), "{unknown}");
}

#[test]
fn a_user_device_in_toml_runs_in_a_stack() {
    let catalogue = Catalogue::from_toml_str(&catalogue_with("length_mm", "100.0")).unwrap();
    let entry = catalogue.get("test-catheter").unwrap();
    assert!((entry.device.length_m() - 0.3).abs() < 1e-12);
    let mut stack = free_stack(vec![
        (entry.device.clone(), 0.05),
        (presets::guidewire_035(), 0.07),
    ]);
    stack.step().unwrap();
    assert!((stack.tip_position(0).unwrap() - Vector3::x() * 0.05).norm() < 1e-9);
}

#[test]
fn the_builtin_catalogue_is_valid_sourced_and_nests() {
    use cathlab_physics::DeviceKind::*;
    let catalogue = Catalogue::builtin();
    assert!(catalogue.entries().len() >= 18);
    for entry in catalogue.entries() {
        assert!(
            !entry.source.trim().is_empty(),
            "{} has no source",
            entry.id
        );
        entry.device.validate().unwrap();
    }
    let of = |kind| {
        catalogue
            .entries()
            .iter()
            .filter(move |e| e.kind == kind)
            .map(|e| &e.device)
    };
    // The clinical stacks: every microwire in every microcatheter, every microcatheter in
    // every distal-access catheter, those in the long sheath, 0.035" wires in 5 F catheters.
    for (outer, inner) in [
        (Microcatheter, Microwire),
        (DistalAccess, Microcatheter),
        (Sheath, DistalAccess),
        (Guide, Catheter),
        (Catheter, Guidewire),
    ] {
        for o in of(outer) {
            for i in of(inner) {
                cathlab_physics::stack::check_fit(o, i).unwrap_or_else(|e| panic!("{e}"));
            }
        }
    }
    // Stent retrievers go through 0.021" and 0.027" microcatheters, not 0.017" ones.
    for stent in catalogue
        .entries()
        .iter()
        .filter(|e| e.kind == StentRetriever)
    {
        let spec = stent.stent.expect("a stent retriever has its stent");
        assert!(spec.from_tip_m + spec.length_m <= stent.device.length_m());
        for id in ["microcatheter-021-160", "microcatheter-027-150"] {
            let outer = catalogue.device(id).unwrap();
            cathlab_physics::stack::check_fit(&outer, &stent.device)
                .unwrap_or_else(|e| panic!("{e}"));
        }
        let small = catalogue.device("microcatheter-017-150").unwrap();
        assert!(cathlab_physics::stack::check_fit(&small, &stent.device).is_err());
    }
    // Shapes from the catalogue behave: the Simmons reverse curve turns back on itself.
    let simmons = catalogue.device("catheter-5f-simmons-2").unwrap();
    assert!(!simmons.sections.last().unwrap().rest_shape.is_straight());
}

#[test]
fn catalogue_markers_are_checked_and_named() {
    let base = catalogue_with("lumen_friction", "0.04");
    let marker = |from_tip: &str, length: &str| {
        format!("{base}\n[[device.marker]]\nfrom_tip_mm = {from_tip}\nlength_mm = {length}\n")
    };
    let (device, section, field) = definition_error(&marker("-1.0", "1.0"));
    assert_eq!(
        (device.as_str(), section.as_str(), field.as_str()),
        ("test-catheter", "marker 0", "from_tip_mm")
    );
    let (_, _, field) = definition_error(&marker("0.0", "5000.0"));
    assert_eq!(field, "length_mm");
    let ok = Catalogue::from_toml_str(&marker("0.5", "1.0")).unwrap();
    let m = ok.get("test-catheter").unwrap().markers[0];
    assert_eq!((m.from_tip_m, m.length_m, m.fill), (0.5e-3, 1e-3, 1.0));
    // Every built-in microcatheter carries its two marker bands 30 mm apart.
    for entry in Catalogue::builtin().entries() {
        if entry.kind == cathlab_physics::DeviceKind::Microcatheter {
            assert_eq!(entry.markers.len(), 2, "{}", entry.id);
        }
    }
}

/// The stent retriever's `[device.stent]` table: required for that kind, refused on any other,
/// and its fields checked by name.
#[test]
fn catalogue_stent_tables_are_checked_by_name() {
    let text = cathlab_physics::catalogue::BUILTIN_TOML;
    let stent = &text[text.find("# ---- stent-retriever-4x20").unwrap()..];
    assert!(
        Catalogue::from_toml_str(stent).unwrap().entries()[0]
            .stent
            .is_some()
    );
    let start = stent.find("[device.stent]").unwrap();
    let end = start + stent[start..].find("\n\n").unwrap();
    let without = format!("{}{}", &stent[..start], &stent[end..]);
    let (device, section, field) = definition_error(&without);
    assert_eq!(
        (device.as_str(), section.as_str(), field.as_str()),
        ("stent-retriever-4x20", "stent", "stent")
    );
    for (from, to, field) in [
        ("open_area = 0.8", "open_area = 1.5", "open_area"),
        (
            "reference_diameter_mm = 3.0",
            "reference_diameter_mm = 4.5",
            "reference_diameter_mm",
        ),
        ("rrf_ratio = 1.6", "rrf_ratio = 0.5", "rrf_ratio"),
        (
            "from_tip_mm = 5.0\ncof",
            "from_tip_mm = 1790.0\ncof",
            "from_tip_mm",
        ),
        ("cof_n_per_mm = 0.02", "cof_n_per_mm = nan", "cof_n_per_mm"),
    ] {
        assert!(stent.contains(from), "{from}");
        let (_, section, got) = definition_error(&stent.replace(from, to));
        assert_eq!((section.as_str(), got.as_str()), ("stent", field));
    }
    let table = &stent[start..end];
    let (device, _, field) =
        definition_error(&(catalogue_with("lumen_friction", "0.04") + "\n" + table + "\n"));
    assert_eq!(
        (device.as_str(), field.as_str()),
        ("test-catheter", "stent")
    );
}
