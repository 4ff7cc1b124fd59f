//! DICOM series: the real JPEG 2000 CT series against values decoded independently (pydicom
//! with the C OpenJPEG library, `tests/data/dicom_reference.py`), and synthetic series written
//! here slice by slice (oblique, shuffled, rescaled) against the same volume written as
//! MetaImage; every bad series gives an error naming what is wrong.

use std::path::{Path, PathBuf};

use cathlab_imaging::dicom::{list_series, read_series};
use cathlab_imaging::{ImagingError, ScalarVolume};
use dicom_core::value::PrimitiveValue;
use dicom_core::{DataElement, VR};
use dicom_dictionary_std::{tags, uids};
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
use nalgebra::{Matrix3, Rotation3, Vector3};

fn real_series() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/ct/totalsegmentator-example/dicom")
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("cathlab-dicom-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn the_real_jpeg2000_series_reads_with_the_reference_hu_spacing_and_orientation() {
    let reference: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/dicom_reference.json"),
        )
        .unwrap(),
    )
    .unwrap();
    let volume = read_series(&real_series(), None).unwrap();
    let slices = reference["slices"].as_array().unwrap();
    assert_eq!(volume.dims, [512, 512, slices.len()]);
    let spacing = &reference["pixel_spacing_mm"];
    assert!((volume.spacing_m.x * 1e3 - spacing[1].as_f64().unwrap()).abs() < 1e-9);
    assert!((volume.spacing_m.y * 1e3 - spacing[0].as_f64().unwrap()).abs() < 1e-9);
    let iop: Vec<f64> = reference["image_orientation_patient"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let row = Vector3::new(iop[0], iop[1], iop[2]);
    let col = Vector3::new(iop[3], iop[4], iop[5]);
    assert!((volume.direction.column(0) - row).norm() < 1e-9);
    assert!((volume.direction.column(1) - col).norm() < 1e-9);
    assert!((volume.direction.column(2) - row.cross(&col)).norm() < 1e-9);
    for (k, slice) in slices.iter().enumerate() {
        let ipp: Vec<f64> = slice["image_position_patient_mm"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap() * 1e-3)
            .collect();
        // Each slice lies where its ImagePositionPatient says.
        let centre = volume.position_of(&Vector3::new(0.0, 0.0, k as f64));
        assert!(
            (centre.coords - Vector3::new(ipp[0], ipp[1], ipp[2])).norm() < 1e-6,
            "slice {k} at {centre:?}, the file says {ipp:?}"
        );
        let plane = &volume.values[k * 512 * 512..(k + 1) * 512 * 512];
        let sum: f64 = plane.iter().map(|&v| f64::from(v)).sum();
        assert_eq!(
            sum,
            slice["sum_hu"].as_f64().unwrap(),
            "slice {k}: lossless decoding"
        );
        let min = plane.iter().copied().fold(f32::MAX, f32::min);
        let max = plane.iter().copied().fold(f32::MIN, f32::max);
        assert_eq!(f64::from(min), slice["min_hu"].as_f64().unwrap());
        assert_eq!(f64::from(max), slice["max_hu"].as_f64().unwrap());
        for probe in slice["probes"].as_array().unwrap() {
            let (i, j, hu) = (
                probe[0].as_u64().unwrap() as usize,
                probe[1].as_u64().unwrap() as usize,
                probe[2].as_f64().unwrap(),
            );
            assert_eq!(
                f64::from(volume.values[volume.linear(i, j, k)]),
                hu,
                "({i},{j},{k})"
            );
        }
    }
    // Physically: air outside the patient reads −1000 HU, not the stored 0.
    let corner = volume.values[volume.linear(5, 5, 0)];
    assert!((-1030.0..=-990.0).contains(&corner), "air is {corner} HU");
    // The folder is also what ScalarVolume::load reads.
    assert_eq!(ScalarVolume::load(&real_series()).unwrap(), volume);
    println!(
        "real series: {:?} voxels, spacing {:.4}×{:.4}×{:.4} mm, HU {min}..{max}",
        volume.dims,
        volume.spacing_m.x * 1e3,
        volume.spacing_m.y * 1e3,
        volume.spacing_m.z * 1e3,
        min = volume.values.iter().copied().fold(f32::MAX, f32::min),
        max = volume.values.iter().copied().fold(f32::MIN, f32::max),
    );
}

/// A synthetic CT (HU: a bright tube in soft tissue, air around) on an oblique grid.
fn synthetic_volume() -> ScalarVolume {
    let dims = [24, 20, 9];
    let rotation = Rotation3::from_euler_angles(0.3, -0.2, 0.7);
    let direction: Matrix3<f64> = *rotation.matrix();
    let spacing = Vector3::new(0.7e-3, 0.8e-3, 1.25e-3);
    let origin = Vector3::new(-0.012, 0.034, -0.101);
    let mut values = Vec::new();
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let (x, y) = (i as f64 - 11.0, j as f64 - 9.0);
                let r2 = x * x + y * y;
                let hu = if r2 < 16.0 {
                    400.0 + (k * 3) as f64
                } else if r2 < 64.0 {
                    40.0 + ((i * 7 + j * 3) % 11) as f64
                } else {
                    -1000.0
                };
                values.push(hu as f32);
            }
        }
    }
    ScalarVolume::new(dims, spacing, origin, direction, values).unwrap()
}

/// Writes slice `k` of `volume` as an explicit-VR little-endian DICOM file: stored unsigned
/// values with RescaleSlope `slope` and RescaleIntercept `intercept`.
fn write_slice(
    volume: &ScalarVolume,
    k: usize,
    series: &str,
    file: &Path,
    slope: f64,
    intercept: f64,
) {
    let [nx, ny, _] = volume.dims;
    let d = volume.direction;
    let ipp = volume.position_of(&Vector3::new(0.0, 0.0, k as f64)).coords * 1e3;
    let stored: Vec<u16> = volume.values[k * nx * ny..(k + 1) * nx * ny]
        .iter()
        .map(|&hu| ((f64::from(hu) - intercept) / slope).round() as u16)
        .collect();
    let ds = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:.10}"))
            .collect::<Vec<_>>()
            .join("\\")
    };
    let sop = format!("{series}.{k}");
    let obj = InMemDicomObject::from_element_iter([
        DataElement::new(
            tags::SOP_CLASS_UID,
            VR::UI,
            PrimitiveValue::from(uids::CT_IMAGE_STORAGE),
        ),
        DataElement::new(
            tags::SOP_INSTANCE_UID,
            VR::UI,
            PrimitiveValue::from(sop.as_str()),
        ),
        DataElement::new(tags::MODALITY, VR::CS, PrimitiveValue::from("CT")),
        DataElement::new(
            tags::SERIES_INSTANCE_UID,
            VR::UI,
            PrimitiveValue::from(series),
        ),
        DataElement::new(
            tags::IMAGE_POSITION_PATIENT,
            VR::DS,
            PrimitiveValue::from(ds(&[ipp.x, ipp.y, ipp.z])),
        ),
        DataElement::new(
            tags::IMAGE_ORIENTATION_PATIENT,
            VR::DS,
            PrimitiveValue::from(ds(&[
                d[(0, 0)],
                d[(1, 0)],
                d[(2, 0)],
                d[(0, 1)],
                d[(1, 1)],
                d[(2, 1)],
            ])),
        ),
        DataElement::new(tags::SAMPLES_PER_PIXEL, VR::US, PrimitiveValue::from(1_u16)),
        DataElement::new(
            tags::PHOTOMETRIC_INTERPRETATION,
            VR::CS,
            PrimitiveValue::from("MONOCHROME2"),
        ),
        DataElement::new(tags::ROWS, VR::US, PrimitiveValue::from(ny as u16)),
        DataElement::new(tags::COLUMNS, VR::US, PrimitiveValue::from(nx as u16)),
        DataElement::new(
            tags::PIXEL_SPACING,
            VR::DS,
            PrimitiveValue::from(ds(&[volume.spacing_m.y * 1e3, volume.spacing_m.x * 1e3])),
        ),
        DataElement::new(tags::BITS_ALLOCATED, VR::US, PrimitiveValue::from(16_u16)),
        DataElement::new(tags::BITS_STORED, VR::US, PrimitiveValue::from(16_u16)),
        DataElement::new(tags::HIGH_BIT, VR::US, PrimitiveValue::from(15_u16)),
        DataElement::new(
            tags::PIXEL_REPRESENTATION,
            VR::US,
            PrimitiveValue::from(0_u16),
        ),
        DataElement::new(
            tags::RESCALE_INTERCEPT,
            VR::DS,
            PrimitiveValue::from(ds(&[intercept])),
        ),
        DataElement::new(
            tags::RESCALE_SLOPE,
            VR::DS,
            PrimitiveValue::from(ds(&[slope])),
        ),
        DataElement::new(tags::PIXEL_DATA, VR::OW, PrimitiveValue::U16(stored.into())),
    ]);
    obj.with_meta(
        FileMetaTableBuilder::new()
            .transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN)
            .media_storage_sop_class_uid(uids::CT_IMAGE_STORAGE)
            .media_storage_sop_instance_uid(sop.as_str()),
    )
    .unwrap()
    .write_to_file(file)
    .unwrap();
}

/// Writes the whole volume as a series, the files named in a shuffled order.
fn write_series(
    volume: &ScalarVolume,
    dir: &Path,
    series: &str,
    prefix: &str,
    skip: Option<usize>,
) {
    let order = [4, 0, 7, 2, 8, 5, 1, 6, 3];
    for (n, &k) in order.iter().enumerate() {
        if Some(k) == skip {
            continue;
        }
        write_slice(
            volume,
            k,
            series,
            &dir.join(format!("{prefix}{n:03}.dcm")),
            0.5,
            -1024.0,
        );
    }
}

#[test]
fn a_shuffled_oblique_synthetic_series_matches_the_same_volume_written_as_metaimage() {
    let volume = synthetic_volume();
    let dir = scratch("shuffled");
    write_series(&volume, &dir, "1.2.826.0.1.3680043.9.7777.1", "IM", None);
    // A stray non-DICOM file does not stop the reading.
    std::fs::write(dir.join("notes.txt"), "not an image").unwrap();
    let from_dicom = read_series(&dir, None).unwrap();
    let mha = dir.join("same.mha");
    volume.write_metaimage(&mha).unwrap();
    let from_mha = ScalarVolume::load(&mha).unwrap();
    assert_eq!(from_dicom.dims, from_mha.dims);
    assert!(
        (from_dicom.spacing_m - from_mha.spacing_m).norm() < 1e-9,
        "spacing"
    );
    assert!(
        (from_dicom.origin_m - from_mha.origin_m).norm() < 1e-9,
        "origin"
    );
    assert!(
        (from_dicom.direction - from_mha.direction).norm() < 1e-7,
        "direction"
    );
    assert_eq!(from_dicom.values, from_mha.values, "voxel for voxel");
    let _ = std::fs::remove_dir_all(&dir);
}

fn dicom_error(result: Result<ScalarVolume, ImagingError>) -> String {
    match result {
        Err(e @ ImagingError::Dicom { .. }) => e.to_string(),
        other => panic!("expected a DICOM error, got {other:?}"),
    }
}

#[test]
fn a_missing_slice_is_named() {
    let dir = scratch("missing");
    write_series(&synthetic_volume(), &dir, "1.2.3.4", "IM", Some(5));
    let message = dicom_error(read_series(&dir, None));
    println!("{message}");
    assert!(message.contains("1 slice(s) missing"), "{message}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn mixed_series_are_refused_unless_one_is_chosen() {
    let dir = scratch("mixed");
    let volume = synthetic_volume();
    write_series(&volume, &dir, "1.2.3.100", "A", None);
    write_series(&volume, &dir, "1.2.3.200", "B", Some(0));
    let message = dicom_error(read_series(&dir, None));
    println!("{message}");
    assert!(
        message.contains("2 series")
            && message.contains("1.2.3.100")
            && message.contains("1.2.3.200"),
        "{message}"
    );
    let listed = list_series(&dir).unwrap();
    assert_eq!(
        listed.iter().map(|s| s.files).collect::<Vec<_>>(),
        vec![9, 8]
    );
    let chosen = read_series(&dir, Some("1.2.3.100")).unwrap();
    assert_eq!(chosen.values, volume.values);
    let message = dicom_error(read_series(&dir, Some("9.9.9")));
    assert!(message.contains("no series \"9.9.9\""), "{message}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn duplicate_slices_empty_folders_and_lone_slices_are_refused() {
    let volume = synthetic_volume();
    let dir = scratch("duplicate");
    write_series(&volume, &dir, "1.2.3.4", "IM", None);
    write_slice(&volume, 3, "1.2.3.4", &dir.join("again.dcm"), 0.5, -1024.0);
    let message = dicom_error(read_series(&dir, None));
    assert!(message.contains("duplicate slice"), "{message}");

    let empty = scratch("empty");
    std::fs::write(empty.join("readme.txt"), "nothing here").unwrap();
    let message = dicom_error(read_series(&empty, None));
    assert!(message.contains("no DICOM image found"), "{message}");

    let lone = scratch("lone");
    write_slice(&volume, 0, "1.2.3.4", &lone.join("one.dcm"), 1.0, -1024.0);
    let message = dicom_error(read_series(&lone, None));
    assert!(message.contains("at least 2"), "{message}");
    for d in [dir, empty, lone] {
        let _ = std::fs::remove_dir_all(d);
    }
}
