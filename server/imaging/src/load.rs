//! Reading a volume file of any supported format: the reader chosen by extension.

use std::path::Path;

use crate::error::{ImagingError, Result};
use crate::volume::ScalarVolume;

impl ScalarVolume {
    /// Reads a volume, choosing the format by extension: `.mha`, `.mhd`, `.nii`, `.nii.gz`;
    /// a folder (or a `.dcm` file) is read as one DICOM series (see [`crate::dicom`]).
    pub fn load(path: &Path) -> Result<Self> {
        let name = path.to_string_lossy().to_ascii_lowercase();
        if path.is_dir() || name.ends_with(".dcm") {
            crate::dicom::read_series(path, None)
        } else if name.ends_with(".mha") || name.ends_with(".mhd") {
            crate::metaimage::read_metaimage(path)
        } else if name.ends_with(".nii") || name.ends_with(".nii.gz") {
            crate::nifti::read_nifti(path)
        } else {
            Err(ImagingError::UnsupportedVolume {
                file: path.to_owned(),
                what: "volume format (expected .mha, .mhd, .nii, .nii.gz, .dcm or a DICOM folder)"
                    .into(),
            })
        }
    }
}
