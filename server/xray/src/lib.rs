//! Synthetic X-ray (fluoroscopy) for cathlab: C-arm geometry in DICOM XA conventions, CT
//! volumes loaded from MetaImage and NIfTI, and Beer–Lambert line integrals through them.
//! Plain library: no threads of its own beyond rayon, no networking. Lengths are metres,
//! attenuation coefficients 1/m, unless a name says otherwise.

pub mod error;
pub mod geometry;
pub mod volume;

pub use error::{Result, XrayError};
pub use geometry::{CArm, DetectorGeometry};
pub use volume::Volume;
