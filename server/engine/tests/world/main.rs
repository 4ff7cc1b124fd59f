//! The engine on the real arch-to-cow scene: scene errors name their field, the world is
//! deterministic (digests), a live threaded session replays bit for bit from what it
//! recorded, a coarse scene that really diverges is reset and reported, frames encode.
//!
//! One test binary, by topic: `scenes` (scene errors name their field, the asset cache),
//! `replay` (determinism, a live session replayed, divergence, the fidelity governor),
//! `hands` (the target, push limits, stacks and exchanges) and `imaging` (frames, the DSA
//! run's injector, contrast, a wire inside a catheter). The helpers below are shared.

mod hands;
mod imaging;
mod replay;
mod scenes;

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use cathlab_engine::*;

fn scenes() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes")
}

fn default_text() -> String {
    std::fs::read_to_string(scenes().join("arch_to_cow_lcca.toml")).unwrap()
}

fn cache() -> &'static AssetCache {
    static CACHE: OnceLock<AssetCache> = OnceLock::new();
    // Built anatomies (the stroke scenes' neuro phantom: ~45 s) are kept on disk for the
    // other suites that load them.
    CACHE.get_or_init(|| {
        AssetCache::default()
            .with_disk_cache(&Path::new(env!("CARGO_TARGET_TMPDIR")).join("asset-cache"))
    })
}

fn assets(text: &str) -> Arc<SceneAssets> {
    let spec = SceneSpec::parse(text, SceneFormat::Toml).unwrap();
    cache().load(&spec, &scenes()).unwrap()
}

/// The coarse, loose scene that diverges when pushed and twisted hard: 100 Hz steps, 10 mm
/// tip and 50 mm shaft elements, no refinement, contact tolerance 0.5.
pub fn coarse_text() -> String {
    default_text().replace(
        "step_rate_hz = 500",
        "step_rate_hz = 100\ntip_element_mm = 10\nshaft_element_mm = 50\n\
         contact_tolerance = 0.5\nrefine = false",
    )
}

/// The coarse scene with a 180° hook over 10 mm on 2 mm tip elements (each bent by 36°),
/// which diverges when pushed and twisted hard. (The 90°-over-30 mm wire stopped diverging
/// once elements took the exact mean of the rest curvature instead of its mid-point value;
/// the hook on one 10 mm element once the hand's limit held within the step; on 5 mm
/// elements once a hand at its strength gave way within the step.) Its hand
/// pushes and twists through anything: the 10 N default holds the push back, and the
/// 0.1 N·m default the twist, before the hook breaks the coarse elements (as in the server's
/// diverging-session test).
fn fragile_text() -> String {
    coarse_text()
        .replace("tip_element_mm = 10", "tip_element_mm = 2")
        .replace("bend_deg = 90.0", "bend_deg = 180.0")
        .replace("bend_length_mm = 30.0", "bend_length_mm = 10.0")
        + "\n[limits]\npush_force_n = 10000.0\nunsupported_mm = 5.0\ntwist_torque_nm = 10.0\n"
}

/// The default scene with `stack` (TOML `[[stack]]` tables, outermost first) instead of its
/// selectable devices.
fn stack_text(stack: &[(&str, f64)]) -> String {
    let text = default_text();
    let from = text.find("[[devices]]").unwrap();
    let to = text.find("[start]").unwrap();
    let tables: String = stack
        .iter()
        .map(|(id, mm)| format!("[[stack]]\ndevice = \"{id}\"\ninserted_mm = {mm}\n\n"))
        .collect();
    format!("{}{tables}{}", &text[..from], &text[to..])
}

fn drive(world: &mut World, script: &[(u64, Command)], steps: u64) -> Vec<u64> {
    let mut digests = Vec::new();
    let mut next = 0;
    for _ in 0..steps {
        while next < script.len() && script[next].0 == world.step_index() {
            world.apply(next as u64 + 1, &script[next].1).unwrap();
            next += 1;
        }
        world.step().unwrap();
        digests.push(world.digest());
    }
    digests
}

/// Each case's scene (a changed copy of `base`) fails to load with an error naming the
/// field path it starts with.
fn assert_scene_errors(base: &str, cases: &[(String, &str)]) {
    for (text, path) in cases {
        assert_ne!(text, base, "{path}: the case changed the scene");
        let outcome = SceneSpec::parse(text, SceneFormat::Toml)
            .and_then(|spec| cache().load(&spec, &scenes()).map(|_| ()));
        match outcome {
            Err(EngineError::Scene { path: p, reason }) => {
                println!("{p}: {reason}");
                assert!(p.starts_with(path), "{path}: got {p} ({reason})");
                assert!(!reason.is_empty());
            }
            other => panic!("{path}: {other:?}"),
        }
    }
}
