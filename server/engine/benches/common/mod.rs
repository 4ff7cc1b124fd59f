//! What the engine's scene benchmarks share: the bundled scenes by name, and a scene's spec
//! read with its contact solve and physics options overridden from the environment.

use std::path::Path;

use cathlab_engine::{SceneFormat, SceneSpec, scene};

/// The scenes `variable` names (comma-separated), or `None` when it is not set.
pub fn picked(variable: &str) -> Option<Vec<String>> {
    std::env::var(variable)
        .ok()
        .map(|s| s.split(',').map(str::to_owned).collect())
}

/// The names of the scene files (`*.toml`) in `dir` that `keep` keeps, sorted.
pub fn bundled_scenes(dir: &Path, keep: impl Fn(&str) -> bool) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| {
            let path = e.ok()?.path();
            (path.extension()? == "toml").then(|| path.file_stem()?.to_str().map(str::to_owned))?
        })
        .filter(|n| keep(n))
        .collect();
    names.sort();
    names
}

/// Scene `name` of `dir`, its contact solve replaced by the one `variable` names (`newton` or
/// `gauss_seidel`; anything else leaves the scene's own), with the physics options
/// `PHYSICS_OPTIONS` names turned on (comma-separated: `slide_friction`,
/// `cap_with_held_contacts`, `axial_slide`; an unknown name panics).
pub fn scene_spec(dir: &Path, name: &str, variable: &str) -> SceneSpec {
    let text = std::fs::read_to_string(dir.join(format!("{name}.toml"))).unwrap();
    let mut spec = SceneSpec::parse(&text, SceneFormat::Toml).unwrap();
    match std::env::var(variable).as_deref() {
        Ok("gauss_seidel") => spec.fidelity.contact_solver = scene::ContactSolver::GaussSeidel,
        Ok("newton") => spec.fidelity.contact_solver = scene::ContactSolver::Newton,
        _ => {}
    }
    // `PHYSICS_OPTIONS=slide_friction,cap_with_held_contacts` turns those physics options on.
    let options = std::env::var("PHYSICS_OPTIONS").unwrap_or_default();
    for option in options.split(',').filter(|o| !o.is_empty()) {
        match option {
            "slide_friction" => spec.fidelity.slide_friction = true,
            "cap_with_held_contacts" => spec.fidelity.cap_with_held_contacts = true,
            "axial_slide" => spec.fidelity.axial_slide = true,
            other => panic!("PHYSICS_OPTIONS: unknown option {other:?}"),
        }
    }
    spec
}
