//! What sessions on the same scene share, loaded once: the anatomy (lumen surface and vessel
//! graph), the CT volume, the flow network, the devices and the start pose. Sessions hold
//! `Arc`s to these; nothing here is copied per session.
//!
//! `scene_assets` holds a loaded scene and the lumen as a wall; `cache` the asset cache and
//! the files a scene may name; `disk` the anatomies kept on disk between runs; `loader` how a scene's assets are built; `errors` the errors a
//! load gives.

mod cache;
mod disk;
mod errors;
mod loader;
mod scene_assets;

pub use cache::{AssetCache, DEFAULT_ASSET_BUDGET_BYTES, DEFAULT_DISK_CACHE_BYTES};
pub use scene_assets::{ROUTE_SPACING_M, SceneAssets, SharedWall};
// A preset's device and a catalogue entry's look are the scene's; re-exported here, where
// they were first.
pub use crate::scene::{appearance_of_entry, device_of};
