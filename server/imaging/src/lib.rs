//! Medical images for cathlab: scalar volumes and their readers (MetaImage, NIfTI, DICOM
//! series), filters, and the segmentation of CT angiography into the vessel graph and lumen
//! surface that `cathlab-anatomy` defines.
//!
//! Units: metres throughout; coordinates in the patient LPS frame (x to the patient's left,
//! y posterior, z superior), as DICOM uses.

pub mod case;
pub mod circle_of_willis;
pub mod dicom;
pub mod dicom_lengths;
pub mod error;
pub mod instruments;
mod load;
pub mod metaimage;
pub mod nifti;
pub mod preview;
pub mod segment;
pub mod surface_centerlines;
pub mod volume;
mod voxels;

pub use error::{ImagingError, Result};
pub use metaimage::read_metaimage;
pub use nifti::read_nifti;
pub use volume::ScalarVolume;
