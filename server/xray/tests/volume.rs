//! Volumes: analytic phantoms' line integrals against exact chords, MetaImage and NIfTI
//! readers (written here byte by byte), the real CT, and bad files.

use std::io::Write;
use std::path::PathBuf;

use cathlab_xray::XrayError;
use cathlab_xray::volume::{Volume, read_metaimage, read_nifti};
use nalgebra::{Point3, Vector3};

/// μ of water (1/m) at 60 keV; HU → μ scales linearly from air (−1000) to water (0).
const MU_WATER: f64 = 2.06;

fn mu(hu: f64) -> f64 {
    MU_WATER * (1.0 + hu / 1000.0).max(0.0)
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("cathlab-xray-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// 1 mm voxels, 128³, centred on the origin, HU 1000 inside `inside` (μ = 2 μ_water).
fn phantom(inside: impl Fn(&Point3<f64>) -> bool + Sync) -> Volume {
    Volume::from_fn([128; 3], Vector3::repeat(1e-3), Vector3::zeros(), 4, |p| {
        if inside(p) { 1000.0 } else { -1000.0 }
    })
    .unwrap()
}

#[test]
fn sphere_line_integrals_match_exact_chords_within_half_a_percent() {
    let radius = 0.04;
    let volume = phantom(|p| p.coords.norm() < radius);
    let mut worst: f64 = 0.0;
    for k in 0..9 {
        let offset = radius * 0.8 * k as f64 / 8.0;
        // Oblique rays, not aligned with the grid.
        let direction = Vector3::new(1.0, 0.3, 0.2).normalize();
        let normal = direction.cross(&Vector3::z()).normalize();
        let origin = Point3::from(normal * offset - direction * 0.5);
        let got = volume.line_integral(&origin, &direction, 0.25e-3, mu);
        let exact = 2.0 * (radius * radius - offset * offset).sqrt() * 2.0 * MU_WATER;
        worst = worst.max((got / exact - 1.0).abs());
    }
    println!("sphere: worst relative error {worst:.2e}");
    assert!(worst < 5e-3, "{worst}");
}

#[test]
fn cylinder_line_integrals_match_exact_chords_within_half_a_percent() {
    let radius = 0.03;
    let volume = phantom(|p| p.x * p.x + p.y * p.y < radius * radius && p.z.abs() < 0.05);
    let mut worst: f64 = 0.0;
    for k in 0..9 {
        let offset = radius * 0.8 * k as f64 / 8.0;
        // Across the axis, tilted 20° out of the cross-section.
        let tilt = 20f64.to_radians();
        let direction = Vector3::new(tilt.cos(), 0.0, tilt.sin());
        let origin = Point3::new(0.0, offset, 0.01) - direction * 0.5;
        let got = volume.line_integral(&origin, &direction, 0.25e-3, mu);
        let exact = 2.0 * (radius * radius - offset * offset).sqrt() / tilt.cos() * 2.0 * MU_WATER;
        worst = worst.max((got / exact - 1.0).abs());
    }
    println!("cylinder: worst relative error {worst:.2e}");
    assert!(worst < 5e-3, "{worst}");
}

fn metaimage_header(extra: &str, element: &str) -> String {
    format!(
        "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n\
         TransformMatrix = -1 0 0 0 -1 0 0 0 1\nOffset = 10 20 30\nElementSpacing = 0.5 0.75 2\n\
         DimSize = 3 2 2\nElementType = {element}\n{extra}ElementDataFile = LOCAL\n"
    )
}

fn values() -> Vec<i16> {
    (0..12).map(|i| i * 100 - 1000).collect()
}

#[test]
fn metaimage_raw_and_zlib_read_back_with_geometry() {
    let raw: Vec<u8> = values().iter().flat_map(|v| v.to_le_bytes()).collect();
    let plain = scratch("plain.mha");
    let mut f = std::fs::File::create(&plain).unwrap();
    f.write_all(metaimage_header("", "MET_SHORT").as_bytes())
        .unwrap();
    f.write_all(&raw).unwrap();
    drop(f);
    let v = read_metaimage(&plain).unwrap();
    assert_eq!(v.dims, [3, 2, 2]);
    assert_eq!(v.hu, values());
    assert!((v.spacing_m - Vector3::new(0.5e-3, 0.75e-3, 2e-3)).norm() < 1e-15);
    // Voxel (1, 0, 0) lies 0.5 mm along −x from the origin (TransformMatrix flips x and y).
    let p = v.position_of(&Vector3::new(1.0, 1.0, 0.0));
    assert!(
        (p.coords - Vector3::new(9.5e-3, 19.25e-3, 30e-3)).norm() < 1e-12,
        "{p}"
    );
    assert!((v.index_of(&p) - Vector3::new(1.0, 1.0, 0.0)).norm() < 1e-9);
    // Trilinear midway between voxels 0 and 1 along i.
    assert_eq!(v.sample_index(&Vector3::new(0.5, 0.0, 0.0)), -950.0);

    let floats: Vec<u8> = values()
        .iter()
        .flat_map(|&v| (f32::from(v)).to_le_bytes())
        .collect();
    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    z.write_all(&floats).unwrap();
    let compressed = z.finish().unwrap();
    let packed = scratch("packed.mha");
    let mut f = std::fs::File::create(&packed).unwrap();
    f.write_all(
        metaimage_header(
            &format!(
                "CompressedData = True\nCompressedDataSize = {}\n",
                compressed.len()
            ),
            "MET_FLOAT",
        )
        .as_bytes(),
    )
    .unwrap();
    f.write_all(&compressed).unwrap();
    drop(f);
    assert_eq!(Volume::load(&packed).unwrap().hu, values());
}

#[test]
fn bad_metaimages_give_named_errors() {
    let raw: Vec<u8> = values().iter().flat_map(|v| v.to_le_bytes()).collect();
    let cases: Vec<(&str, String, Vec<u8>, &str)> = vec![
        (
            "truncated.mha",
            metaimage_header("", "MET_SHORT"),
            raw[..10].to_vec(),
            "truncated",
        ),
        (
            "type.mha",
            metaimage_header("", "MET_LONG_ARRAY"),
            raw.clone(),
            "ElementType",
        ),
        (
            "spacing.mha",
            metaimage_header("", "MET_SHORT").replace("0.5 0.75 2", "0.5 0 2"),
            raw.clone(),
            "ElementSpacing",
        ),
        (
            "dims.mha",
            metaimage_header("", "MET_SHORT").replace("DimSize = 3 2 2", "DimSize = 3 2"),
            raw.clone(),
            "DimSize",
        ),
        (
            "nan.mha",
            metaimage_header("", "MET_SHORT").replace("Offset = 10 20 30", "Offset = 10 nan 30"),
            raw.clone(),
            "Offset",
        ),
        ("noheader.mha", "just some text\n".into(), Vec::new(), "'='"),
        (
            "size.mha",
            metaimage_header("", "MET_SHORT")
                .replace("ElementSpacing = 0.5 0.75 2", "ElementSize = 0.5 x 2"),
            raw.clone(),
            "ElementSize",
        ),
    ];
    for (name, header, data, expected) in cases {
        let path = scratch(name);
        let mut f = std::fs::File::create(&path).unwrap();
        f.write_all(header.as_bytes()).unwrap();
        f.write_all(&data).unwrap();
        drop(f);
        let message = read_metaimage(&path).unwrap_err().to_string();
        assert!(message.contains(expected), "{name}: {message}");
    }
    assert!(matches!(
        Volume::load(&scratch("volume.vtk")),
        Err(XrayError::Unsupported { .. })
    ));
    assert!(matches!(
        Volume::load(&scratch("missing.mha")),
        Err(XrayError::Io { .. })
    ));
}

/// A minimal NIfTI-1 file: int16 voxels, sform = diag(spacing) + offset (RAS, mm).
fn nifti_bytes(dims: [i16; 3], spacing: [f32; 3], offset: [f32; 3], datatype: i16) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    let dim = [3i16, dims[0], dims[1], dims[2], 1, 1, 1, 1];
    for (i, d) in dim.iter().enumerate() {
        h[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
    }
    h[70..72].copy_from_slice(&datatype.to_le_bytes());
    h[72..74].copy_from_slice(&16i16.to_le_bytes());
    let pixdim = [
        1.0f32, spacing[0], spacing[1], spacing[2], 1.0, 1.0, 1.0, 1.0,
    ];
    for (i, p) in pixdim.iter().enumerate() {
        h[76 + 4 * i..80 + 4 * i].copy_from_slice(&p.to_le_bytes());
    }
    h[108..112].copy_from_slice(&352f32.to_le_bytes());
    h[123] = 2; // mm
    h[254..256].copy_from_slice(&1i16.to_le_bytes());
    for r in 0..3 {
        let mut row = [0f32; 4];
        row[r] = spacing[r];
        row[3] = offset[r];
        for (c, v) in row.iter().enumerate() {
            let o = 280 + 16 * r + 4 * c;
            h[o..o + 4].copy_from_slice(&v.to_le_bytes());
        }
    }
    h[344..348].copy_from_slice(b"n+1\0");
    h.extend(values().iter().flat_map(|v| v.to_le_bytes()));
    h
}

#[test]
fn nifti_plain_and_gzip_read_back_in_lps() {
    let bytes = nifti_bytes([3, 2, 2], [0.5, 0.75, 2.0], [10.0, 20.0, 30.0], 4);
    let plain = scratch("plain.nii");
    std::fs::write(&plain, &bytes).unwrap();
    let v = read_nifti(&plain).unwrap();
    assert_eq!(v.dims, [3, 2, 2]);
    assert_eq!(v.hu, values());
    // RAS (10, 20, 30) mm is LPS (−10, −20, 30) mm; index i runs along R = −L.
    let p = v.position_of(&Vector3::new(1.0, 0.0, 0.0));
    assert!(
        (p.coords - Vector3::new(-10.5e-3, -20e-3, 30e-3)).norm() < 1e-12,
        "{p}"
    );
    let mut z = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    z.write_all(&bytes).unwrap();
    let gz = scratch("packed.nii.gz");
    std::fs::write(&gz, z.finish().unwrap()).unwrap();
    assert_eq!(Volume::load(&gz).unwrap().hu, values());
}

#[test]
fn bad_niftis_give_named_errors() {
    let good = nifti_bytes([3, 2, 2], [0.5, 0.75, 2.0], [0.0; 3], 4);
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("short.nii", good[..200].to_vec(), "348-byte"),
        (
            "truncated.nii",
            good[..good.len() - 4].to_vec(),
            "truncated",
        ),
        (
            "type.nii",
            nifti_bytes([3, 2, 2], [0.5, 0.75, 2.0], [0.0; 3], 32),
            "datatype",
        ),
        (
            "spacing.nii",
            nifti_bytes([3, 2, 2], [0.5, 0.0, 2.0], [0.0; 3], 4),
            "pixdim[2]",
        ),
        ("notnifti.nii", vec![7u8; 400], "sizeof_hdr"),
    ];
    for (name, bytes, expected) in cases {
        let path = scratch(name);
        std::fs::write(&path, bytes).unwrap();
        let message = read_nifti(&path).unwrap_err().to_string();
        assert!(message.contains(expected), "{name}: {message}");
    }
}

#[test]
fn the_real_aorta_ct_loads_with_its_geometry() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data/ct/aorta.mha");
    let v = Volume::load(&path).unwrap();
    assert_eq!(v.dims, [157, 393, 34]);
    assert!((v.spacing_m.x - 0.878906e-3).abs() < 1e-9);
    assert!((v.spacing_m.z - 1.50009e-3).abs() < 1e-9);
    assert_eq!(v.memory_bytes(), 157 * 393 * 34 * 2);
    let mut sorted = v.hu.clone();
    sorted.sort_unstable();
    let at = |q: f64| sorted[((sorted.len() - 1) as f64 * q) as usize];
    println!(
        "aorta.mha: values {}..{}, median {}, 99th percentile {}",
        at(0.0),
        at(1.0),
        at(0.5),
        at(0.99)
    );
    // A contrast CT: the contrast-filled lumen (about 1 % of this crop) is far brighter than
    // the surrounding tissue.
    assert!(f64::from(at(0.99)) > 3.0 * f64::from(at(0.5)));
    // The direction flips x and y (TransformMatrix −1 0 0 0 −1 0 0 0 1).
    let p = v.position_of(&Vector3::new(1.0, 0.0, 0.0));
    assert!(p.x < v.origin_m.x);
}
