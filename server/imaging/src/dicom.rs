//! DICOM CT series: a folder of single-frame slices (or one file) read with dicom-rs into a
//! [`ScalarVolume`] in HU: slices grouped by SeriesInstanceUID, ordered by their position
//! along the slice normal, spacing from the positions, rescale slope and intercept applied.
//!
//! Transfer syntaxes decoded (all in pure Rust, no system library): implicit and explicit VR
//! little endian, deflated explicit VR little endian, RLE lossless, JPEG baseline, extended
//! and lossless, JPEG 2000 (lossless and lossy). JPEG-LS and JPEG XL are refused by name.

use std::path::{Path, PathBuf};

use dicom_dictionary_std::tags;
use dicom_object::{DefaultDicomObject, OpenFileOptions};
use dicom_pixeldata::PixelDecoder;
use nalgebra::{Matrix3, Vector3};

use crate::error::{ImagingError, Result};
use crate::volume::ScalarVolume;

/// Most files a series folder may hold (a CT rarely has more than a few thousand slices).
pub const MAX_FILES: usize = 20_000;

/// Relative tolerance on slice gaps: a gap more than this far from the series' spacing is a
/// missing (or extra) slice.
const GAP_TOLERANCE: f64 = 0.2;

/// One series in a folder, as listed by [`list_series`].
#[derive(Debug, Clone, PartialEq)]
pub struct SeriesInfo {
    /// SeriesInstanceUID (0020,000E).
    pub uid: String,
    /// SeriesDescription (0008,103E), empty when absent.
    pub description: String,
    /// Files (slices) in the folder that belong to it.
    pub files: usize,
}

/// The header of one slice: what ordering and the grid need.
#[derive(Debug, Clone)]
struct Slice {
    file: PathBuf,
    series: String,
    description: String,
    rows: usize,
    columns: usize,
    /// Row direction (along a row, the column index grows), then column direction (LPS).
    orientation: [Vector3<f64>; 2],
    /// ImagePositionPatient (m, LPS): the centre of the first voxel.
    position: Vector3<f64>,
    /// PixelSpacing: between rows, between columns (m).
    pixel_spacing: [f64; 2],
    frames: u32,
}

fn error(dir: &Path, reason: impl Into<String>) -> ImagingError {
    ImagingError::Dicom {
        dir: dir.to_owned(),
        reason: reason.into(),
    }
}

fn file_name(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.display().to_string())
}

/// The DICOM files of `path`: the file itself, or the regular files of the folder (sorted by
/// name; hidden files and `DICOMDIR` skipped). Non-DICOM files are skipped when reading.
fn candidate_files(path: &Path) -> Result<Vec<PathBuf>> {
    let meta = std::fs::metadata(path).map_err(|source| ImagingError::Io {
        file: path.to_owned(),
        source,
    })?;
    if meta.is_file() {
        return Ok(vec![path.to_owned()]);
    }
    if !meta.is_dir() {
        return Err(error(path, "neither a regular file nor a folder"));
    }
    let mut files = Vec::new();
    let entries = std::fs::read_dir(path).map_err(|source| ImagingError::Io {
        file: path.to_owned(),
        source,
    })?;
    for entry in entries {
        let entry = entry.map_err(|source| ImagingError::Io {
            file: path.to_owned(),
            source,
        })?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.starts_with('.') || name.eq_ignore_ascii_case("DICOMDIR") {
            continue;
        }
        if entry.file_type().map(|t| t.is_file()).unwrap_or(false) {
            files.push(entry.path());
            if files.len() > MAX_FILES {
                return Err(error(
                    path,
                    format!("more than {MAX_FILES} files; point at one series' folder"),
                ));
            }
        }
    }
    files.sort();
    Ok(files)
}

fn text(obj: &DefaultDicomObject, tag: dicom_core::Tag) -> Option<String> {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .and_then(|e| e.to_str().ok())
        .map(|s| s.trim().trim_end_matches('\0').to_owned())
}

fn numbers(obj: &DefaultDicomObject, tag: dicom_core::Tag) -> Option<Vec<f64>> {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .and_then(|e| e.to_multi_float64().ok())
}

fn integer(obj: &DefaultDicomObject, tag: dicom_core::Tag) -> Option<i64> {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .and_then(|e| e.to_int::<i64>().ok())
}

/// Reads `file` once, checks every element's declared length against it (dicom-rs reserves
/// a value's declared length before reading it, [`crate::dicom_lengths`]) and opens it with
/// dicom-rs from those bytes, up to `until` when given; `Ok(None)` for a file that is not
/// DICOM, `Ok(Some(Err))` for one dicom-rs cannot parse.
fn open(
    dir: &Path,
    file: &Path,
    until: Option<dicom_core::Tag>,
) -> Result<Option<std::result::Result<DefaultDicomObject, dicom_object::ReadError>>> {
    let bytes = cathlab_anatomy::io::limits::read_regular_file(file)
        .map_err(|e| error(dir, format!("{}: cannot be read: {e}", file_name(file))))?;
    let stream = crate::dicom_lengths::checked(&bytes).map_err(|why| {
        error(
            dir,
            format!(
                "{}: {}{why}",
                file_name(file),
                cathlab_anatomy::io::limits::REFUSED
            ),
        )
    })?;
    let Some(stream) = stream else {
        return Ok(None);
    };
    let options = match until {
        Some(tag) => OpenFileOptions::new().read_until(tag),
        None => OpenFileOptions::new(),
    };
    Ok(Some(options.from_reader(stream)))
}

/// Reads one slice's header; `Ok(None)` for a file that is not DICOM or holds no image.
fn read_header(dir: &Path, file: &Path) -> Result<Option<Slice>> {
    let Some(Ok(obj)) = open(dir, file, Some(tags::PIXEL_DATA))? else {
        return Ok(None);
    };
    let name = file_name(file);
    let Some(rows) = integer(&obj, tags::ROWS) else {
        return Ok(None); // not an image (a report, a presentation state, ...)
    };
    let columns = integer(&obj, tags::COLUMNS)
        .ok_or_else(|| error(dir, format!("{name}: Columns (0028,0011) missing")))?;
    if !(1..=16_384).contains(&rows) || !(1..=16_384).contains(&columns) {
        return Err(error(
            dir,
            format!("{name}: {rows}×{columns} pixels is not a CT slice (1–16384 each)"),
        ));
    }
    let series = text(&obj, tags::SERIES_INSTANCE_UID).unwrap_or_default();
    let description = text(&obj, tags::SERIES_DESCRIPTION).unwrap_or_default();
    let frames = integer(&obj, tags::NUMBER_OF_FRAMES).unwrap_or(1);
    let frames = u32::try_from(frames)
        .ok()
        .filter(|&f| f >= 1)
        .ok_or_else(|| error(dir, format!("{name}: NumberOfFrames {frames} is not ≥ 1")))?;
    let need = |tag, what: &str, count: usize| -> Result<Vec<f64>> {
        let values = numbers(&obj, tag).ok_or_else(|| {
            error(
                dir,
                format!("{name}: {what} missing (a CT slice needs it to be placed)"),
            )
        })?;
        if values.len() < count || values.iter().take(count).any(|v| !v.is_finite()) {
            return Err(error(
                dir,
                format!("{name}: {what} needs {count} finite numbers, has {values:?}"),
            ));
        }
        Ok(values)
    };
    if frames > 1 && numbers(&obj, tags::IMAGE_POSITION_PATIENT).is_none() {
        return Err(error(
            dir,
            format!(
                "{name}: an enhanced multi-frame image ({frames} frames with per-frame \
                 positions) is not supported; export the series as single-frame slices"
            ),
        ));
    }
    let iop = need(
        tags::IMAGE_ORIENTATION_PATIENT,
        "ImageOrientationPatient (0020,0037)",
        6,
    )?;
    let ipp = need(
        tags::IMAGE_POSITION_PATIENT,
        "ImagePositionPatient (0020,0032)",
        3,
    )?;
    let spacing = need(tags::PIXEL_SPACING, "PixelSpacing (0028,0030)", 2)?;
    if spacing[0] <= 0.0 || spacing[1] <= 0.0 {
        return Err(error(
            dir,
            format!("{name}: PixelSpacing {spacing:?} must be > 0"),
        ));
    }
    let row = Vector3::new(iop[0], iop[1], iop[2]);
    let col = Vector3::new(iop[3], iop[4], iop[5]);
    if (row.norm() - 1.0).abs() > 1e-3
        || (col.norm() - 1.0).abs() > 1e-3
        || row.dot(&col).abs() > 1e-3
    {
        return Err(error(
            dir,
            format!("{name}: ImageOrientationPatient {iop:?} is not two orthogonal unit vectors"),
        ));
    }
    Ok(Some(Slice {
        file: file.to_owned(),
        series,
        description,
        rows: rows as usize,
        columns: columns as usize,
        orientation: [row.normalize(), col.normalize()],
        position: Vector3::new(ipp[0], ipp[1], ipp[2]) * 1e-3,
        pixel_spacing: [spacing[0] * 1e-3, spacing[1] * 1e-3],
        frames,
    }))
}

fn headers(path: &Path) -> Result<Vec<Slice>> {
    let mut slices = Vec::new();
    for file in candidate_files(path)? {
        if let Some(slice) = read_header(path, &file)? {
            slices.push(slice);
        }
    }
    if slices.is_empty() {
        return Err(error(path, "no DICOM image found"));
    }
    Ok(slices)
}

fn group(slices: &[Slice]) -> Vec<SeriesInfo> {
    let mut series: Vec<SeriesInfo> = Vec::new();
    for s in slices {
        match series.iter_mut().find(|x| x.uid == s.series) {
            Some(x) => x.files += 1,
            None => series.push(SeriesInfo {
                uid: s.series.clone(),
                description: s.description.clone(),
                files: 1,
            }),
        }
    }
    series
}

/// The image series in a folder (or file), in order of first appearance.
pub fn list_series(path: &Path) -> Result<Vec<SeriesInfo>> {
    Ok(group(&headers(path)?))
}

/// Reads a CT series from a folder of slices or one file into a volume in HU (m, LPS). A
/// folder with several series needs `series` (a SeriesInstanceUID); the error lists them.
pub fn read_series(path: &Path, series: Option<&str>) -> Result<ScalarVolume> {
    let all = headers(path)?;
    let listed = group(&all);
    let uid = match (series, listed.as_slice()) {
        (Some(uid), _) => {
            if !listed.iter().any(|s| s.uid == uid) {
                return Err(error(
                    path,
                    format!("no series {uid:?} here (found: {})", describe(&listed)),
                ));
            }
            uid.to_owned()
        }
        (None, [one]) => one.uid.clone(),
        (None, _) => {
            return Err(error(
                path,
                format!(
                    "{} series in one folder ({}); choose one by SeriesInstanceUID",
                    listed.len(),
                    describe(&listed)
                ),
            ));
        }
    };
    let mut slices: Vec<Slice> = all.into_iter().filter(|s| s.series == uid).collect();
    let first = slices[0].clone();
    let name0 = file_name(&first.file);
    for s in &slices {
        let name = file_name(&s.file);
        if (s.rows, s.columns) != (first.rows, first.columns) {
            return Err(error(
                path,
                format!(
                    "{name} is {}×{} pixels but {name0} is {}×{}",
                    s.rows, s.columns, first.rows, first.columns
                ),
            ));
        }
        let tilt = (s.orientation[0] - first.orientation[0]).norm()
            + (s.orientation[1] - first.orientation[1]).norm();
        if tilt > 1e-3 {
            return Err(error(
                path,
                format!("{name} and {name0} differ in ImageOrientationPatient"),
            ));
        }
        if (s.pixel_spacing[0] - first.pixel_spacing[0]).abs() > 1e-6
            || (s.pixel_spacing[1] - first.pixel_spacing[1]).abs() > 1e-6
        {
            return Err(error(
                path,
                format!("{name} and {name0} differ in PixelSpacing"),
            ));
        }
    }
    if slices.len() == 1 && first.frames > 1 {
        return Err(error(
            path,
            format!(
                "{name0}: a multi-frame image with one position for {} frames cannot be \
                 placed as a volume",
                first.frames
            ),
        ));
    }
    if slices.len() < 2 {
        return Err(error(
            path,
            "one slice is not a volume (a series needs at least 2)",
        ));
    }
    let [row, col] = first.orientation;
    let normal = row.cross(&col);
    slices.sort_by(|a, b| a.position.dot(&normal).total_cmp(&b.position.dot(&normal)));
    let along: Vec<f64> = slices.iter().map(|s| s.position.dot(&normal)).collect();
    let gaps: Vec<f64> = along.windows(2).map(|w| w[1] - w[0]).collect();
    let mut sorted = gaps.clone();
    sorted.sort_by(f64::total_cmp);
    let spacing = sorted[sorted.len() / 2];
    for (i, &gap) in gaps.iter().enumerate() {
        let (a, b) = (file_name(&slices[i].file), file_name(&slices[i + 1].file));
        if gap < 1e-6 {
            return Err(error(
                path,
                format!("{a} and {b} are at the same position (duplicate slice)"),
            ));
        }
        if (gap - spacing).abs() > GAP_TOLERANCE * spacing {
            return Err(error(
                path,
                format!(
                    "gap of {:.3} mm between {a} and {b} where the series' spacing is {:.3} mm: \
                     {}",
                    gap * 1e3,
                    spacing * 1e3,
                    if gap > spacing {
                        format!(
                            "about {} slice(s) missing",
                            (gap / spacing).round() as i64 - 1
                        )
                    } else {
                        "an extra slice or uneven spacing".into()
                    }
                ),
            ));
        }
        // Slices must stack along the normal: in-plane drift means a tilted (gantry) series.
        let drift = (slices[i + 1].position - slices[i].position) - normal * gap;
        if drift.norm() > 0.1 * spacing.max(first.pixel_spacing[0]) {
            return Err(error(
                path,
                format!(
                    "{b} is shifted {:.2} mm in-plane from {a}: a gantry-tilted series is not \
                     supported",
                    drift.norm() * 1e3
                ),
            ));
        }
    }
    let (nx, ny, nz) = (first.columns, first.rows, slices.len());
    let voxels = cathlab_anatomy::io::limits::checked_voxels(&[nx as u64, ny as u64, nz as u64])
        .map_err(|e| error(path, format!("Rows × Columns × slices: {e}")))?;
    let mut values = Vec::with_capacity(voxels);
    for s in &slices {
        values.extend(decode(path, s, nx * ny)?);
    }
    // Index i runs along a row (the row direction), j down the columns, k along the normal.
    let direction = Matrix3::from_columns(&[row, col, normal]);
    let spacing_m = Vector3::new(first.pixel_spacing[1], first.pixel_spacing[0], spacing);
    ScalarVolume::new(
        [nx, ny, nz],
        spacing_m,
        slices[0].position,
        direction,
        values,
    )
}

fn describe(series: &[SeriesInfo]) -> String {
    series
        .iter()
        .map(|s| {
            let uid: String = s.uid.chars().take(64).collect();
            if s.description.is_empty() {
                format!("{uid} ({} files)", s.files)
            } else {
                format!("{uid} \"{}\" ({} files)", s.description, s.files)
            }
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// One slice's pixels in HU (rescale slope and intercept applied), row by row.
fn decode(dir: &Path, slice: &Slice, count: usize) -> Result<Vec<f32>> {
    let name = file_name(&slice.file);
    let obj = open(dir, &slice.file, None)?
        .ok_or_else(|| error(dir, format!("{name}: no longer reads as DICOM")))?
        .map_err(|e| error(dir, format!("{name}: cannot be read: {e}")))?;
    let syntax = obj
        .meta()
        .transfer_syntax()
        .trim_end_matches('\0')
        .to_owned();
    // The pixel format dicom-rs's rescale table asserts on (it panics otherwise).
    let allocated = integer(&obj, tags::BITS_ALLOCATED).unwrap_or(0);
    let stored = integer(&obj, tags::BITS_STORED).unwrap_or(allocated);
    if ![8, 16, 32].contains(&allocated) || !(1..=allocated).contains(&stored) {
        return Err(error(
            dir,
            format!(
                "{name}: BitsAllocated {allocated} and BitsStored {stored}: a CT slice has \
                 8, 16 or 32 bits allocated and 1 to that many stored"
            ),
        ));
    }
    // The codecs are third-party code run on the file's bytes: a panic in one (dicom-rs
    // 0.10's RLE decoder indexes past a short segment) is this file's error, not the
    // process's end.
    let decoded =
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| obj.decode_pixel_data()))
            .map_err(|_| {
                error(
                    dir,
                    format!(
                        "{name}: pixel data in transfer syntax {syntax}: the decoder failed on it"
                    ),
                )
            })?
            .map_err(|e| {
                error(
                    dir,
                    format!(
                        "{name}: pixel data in transfer syntax {syntax} cannot be decoded ({e}); \
                 supported: uncompressed, deflate, RLE, JPEG, JPEG 2000"
                    ),
                )
            })?;
    if decoded.samples_per_pixel() != 1 {
        return Err(error(
            dir,
            format!(
                "{name}: {} samples per pixel; a CT slice has 1 (grey)",
                decoded.samples_per_pixel()
            ),
        ));
    }
    let values: Vec<f32> =
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| decoded.to_vec()))
            .map_err(|_| error(dir, format!("{name}: pixel values: the conversion failed")))?
            .map_err(|e| error(dir, format!("{name}: pixel values: {e}")))?;
    if values.len() != count {
        return Err(error(
            dir,
            format!(
                "{name}: {} pixel values where Rows × Columns is {count}",
                values.len()
            ),
        ));
    }
    Ok(values)
}
