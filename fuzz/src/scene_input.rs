//! What the scene fuzz target does with one input (only with the `scene` feature: the engine
//! is a much longer build than the readers).

use super::{report, start};

/// Scene files, TOML and JSON: `cathlab_engine::SceneSpec::parse` (which validates), each
/// input read as both formats; a scene that parses has its memory estimate taken and its
/// stack and spares resolved against the device catalogue, as loading a scene does.
pub fn scene(data: &[u8]) {
    use cathlab_engine::{SceneFormat, SceneSpec};
    start();
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    for format in [SceneFormat::Toml, SceneFormat::Json] {
        let result = SceneSpec::parse(text, format);
        report(
            if format == SceneFormat::Toml {
                "scene toml"
            } else {
                "scene json"
            },
            &result,
        );
        if let Ok(scene) = result {
            let _ = scene.estimated_bytes();
            for (i, entry) in scene.stack.iter().enumerate() {
                let _ = entry.resolve(i);
            }
            for (i, spare) in scene.spares.iter().enumerate() {
                let _ = spare.resolve(i);
            }
        }
    }
}
