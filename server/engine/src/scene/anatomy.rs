//! The scene's `[anatomy]`: the vessels (an imported arch-to-circle-of-Willis folder, a CT
//! segmented at load, any vessel surface, or the seeded neuro phantom), and its checks.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::field::{range, scene_error};
use crate::error::Result;

/// The vessels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum AnatomySpec {
    /// Imported files in the layout of the bundled arch-to-circle-of-Willis anatomy:
    /// `vessels.obj` (mm) and `centerlines/*.mrk.json`; placed into LPS by
    /// [`cathlab_xray::scene::ARCH_TO_COW_TO_LPS`].
    ArchToCow {
        /// The directory (relative to the scene file).
        dir: PathBuf,
        /// Adds the circle of Willis computed from the surface
        /// (`cathlab_imaging::circle_of_willis`, about 2 s): the given curves end 20 mm
        /// earlier and the named head arteries (`left_internal_carotid`,
        /// `left_middle_cerebral`, `basilar`, …) continue them.
        #[serde(default)]
        circle_of_willis: bool,
    },
    /// Vessels segmented from a CT angiography volume at load (`cathlab segment`'s
    /// pipeline with its default settings): the vessel tree that holds the seed, its
    /// centerlines and lumen surface; the access point is the tree's end farthest from the
    /// seed, branches are named `vessel_00`, `vessel_01`, … breadth-first from there.
    CtSegmentation {
        /// The volume (MetaImage or NIfTI, relative to the scene file).
        volume: PathBuf,
        /// A voxel (i, j, k) inside a contrast-filled vessel.
        seed_voxel: [usize; 3],
    },
    /// Any vessel surface (OBJ, STL, PLY, VTP; open ends are capped at load) with optional
    /// centerlines (else computed from the surface), its unit, its placement into patient
    /// LPS, the access end, and branch names. `cathlab case` writes such scenes.
    Surface {
        /// The surface file (relative to the scene file).
        file: PathBuf,
        /// Its length unit: "mm" (default), "cm", "m" or "um".
        #[serde(default = "default_unit")]
        unit: cathlab_anatomy::io::LengthUnit,
        /// Rotation then translation into LPS; absent: the file is in LPS already.
        #[serde(default)]
        placement: cathlab_imaging::case::Placement,
        /// Centerlines: a graph `.json` (as `cathlab case` writes), `.vtp` lines with a
        /// radius array, Slicer `.mrk.json` curves, or `.swc`; absent: computed at load.
        #[serde(default)]
        centerlines: Option<PathBuf>,
        /// Where the devices enter: `{ end = 0 }` (open ends by radius, largest first) or
        /// `{ near_mm = [x, y, z] }` (the open end nearest an LPS point).
        #[serde(default)]
        access: cathlab_imaging::case::AccessChoice,
        /// New branch names: `{ vessel_03 = "left_ica" }`.
        #[serde(default)]
        names: std::collections::BTreeMap<String, String>,
        /// Voxel size for centerlines computed at load (mm), 0.1–5; chosen from the size
        /// of the surface when absent.
        #[serde(default)]
        voxel_mm: Option<f64>,
    },
    /// The seeded neuro phantom (aortic arch to circle of Willis), meshed into a lumen
    /// surface at load.
    NeuroPhantom {
        /// Seed of its variations.
        #[serde(default)]
        seed: u64,
        /// Tortuosity 0–1.
        #[serde(default = "default_tortuosity")]
        tortuosity: f64,
    },
}

fn default_unit() -> cathlab_anatomy::io::LengthUnit {
    cathlab_anatomy::io::LengthUnit::Mm
}

fn default_tortuosity() -> f64 {
    0.3
}

impl AnatomySpec {
    /// Checks the phantom's tortuosity, and a surface's voxel size, placement and names.
    pub(super) fn validate(&self) -> Result<()> {
        if let AnatomySpec::NeuroPhantom { tortuosity, .. } = self {
            range("anatomy.tortuosity", *tortuosity, 0.0, 1.0)?;
        }
        if let AnatomySpec::Surface {
            placement,
            voxel_mm,
            names,
            ..
        } = self
        {
            if let Some(v) = voxel_mm {
                range("anatomy.voxel_mm", *v, 0.1, 5.0)?;
            }
            for (a, r) in placement.rotation_deg.iter().enumerate() {
                range(
                    &format!("anatomy.placement.rotation_deg[{a}]"),
                    *r,
                    -360.0,
                    360.0,
                )?;
            }
            for (a, t) in placement.translation_mm.iter().enumerate() {
                range(
                    &format!("anatomy.placement.translation_mm[{a}]"),
                    *t,
                    -5000.0,
                    5000.0,
                )?;
            }
            if names.len() > 1000 {
                return Err(scene_error("anatomy.names", "more than 1000 names"));
            }
        }
        Ok(())
    }
}
