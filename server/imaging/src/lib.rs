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
pub mod preview;
pub mod segment;
pub mod surface_centerlines;
pub mod volume;

pub use error::{ImagingError, Result};
pub use volume::ScalarVolume;
