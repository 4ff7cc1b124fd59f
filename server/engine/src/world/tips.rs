//! Which tip counts for what: the tip the target and the path metrics follow, the tip
//! contrast leaves from, and how far outside the lumen a tip may be before the step counts as
//! diverged (anatomy frame, m).

use nalgebra::Vector3;

use crate::assets::SceneAssets;
use crate::strand::Strand;

/// The tip the target and the path metrics follow: the scene's `target.instrument` of a stack
/// (while it is beyond the entry), else the leading tip (anatomy frame, m).
pub(super) fn tracked_tip(assets: &SceneAssets, strand: &Strand) -> Vector3<f64> {
    assets
        .spec
        .target
        .instrument
        .filter(|_| !assets.spec.stack.is_empty())
        .and_then(|i| strand.tip_position(i))
        .unwrap_or_else(|| strand.leading_tip())
}

/// Where contrast leaves the devices: the tip of the innermost instrument with a lumen that is
/// beyond the entry (contrast goes in at its hub, around any wire inside), else the leading
/// tip (anatomy frame, m).
pub(super) fn injection_tip(strand: &Strand) -> Vector3<f64> {
    (0..strand.len())
        .rev()
        .filter(|&i| {
            strand.device(i).is_some_and(|d| {
                d.sections
                    .last()
                    .is_some_and(|s| s.cross_section.inner_radius_m > 0.0)
            })
        })
        .find_map(|i| strand.tip_position(i))
        .unwrap_or_else(|| strand.leading_tip())
}

/// A tip farther than this outside the lumen surface (m), or any instrument's node whose
/// surface is this far past it, counts as divergence: the device has gone through the wall,
/// which the contact solver never allows on a sound step.
pub const MAX_ESCAPE_M: f64 = 3e-3;
