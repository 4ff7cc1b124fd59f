//! Writing a segmentation out: the vessel graph (JSON), centerlines with radii and the lumen
//! surface (VTP), the surface (OBJ, binary STL), the lumen mask (MetaImage), the report
//! (JSON) and a figure (PNG: the CT's maximum-intensity projection with the centerlines).

use std::path::{Path, PathBuf};

use image::{Rgb, RgbImage};

use super::Segmentation;
use crate::error::{ImagingError, Result};
use crate::volume::ScalarVolume;
use cathlab_anatomy::io::LengthUnit;
use cathlab_anatomy::io::slicer::Centerline;

/// The files [`write_all`] writes, by name.
pub const OUTPUT_FILES: [&str; 8] = [
    "graph.json",
    "centerlines.vtp",
    "surface.vtp",
    "surface.obj",
    "surface.stl",
    "mask.mha",
    "report.json",
    "figure.png",
];

fn write(path: PathBuf, bytes: &[u8]) -> Result<()> {
    std::fs::write(&path, bytes).map_err(|source| ImagingError::Io { file: path, source })
}

/// The centerlines as polylines with radii, one per branch.
pub fn centerlines(segmentation: &Segmentation) -> Vec<Centerline> {
    segmentation
        .graph
        .branches
        .iter()
        .map(|b| Centerline {
            name: b.name.clone(),
            points: b.points.clone(),
            radii: b.radii.clone(),
        })
        .collect()
}

/// Writes every file of [`OUTPUT_FILES`] into `dir` (created if missing); coordinates in mm
/// in the exchange formats, m in `graph.json` (the anatomy crate's own form).
pub fn write_all(segmentation: &Segmentation, volume: &ScalarVolume, dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|source| ImagingError::Io {
        file: dir.to_owned(),
        source,
    })?;
    let s = segmentation;
    write(dir.join("graph.json"), s.graph.to_json().as_bytes())?;
    let lines = centerlines(s);
    write(
        dir.join("centerlines.vtp"),
        cathlab_anatomy::io::vtp::to_string(None, &lines, LengthUnit::Mm).as_bytes(),
    )?;
    write(
        dir.join("surface.vtp"),
        cathlab_anatomy::io::vtp::to_string(Some(&s.surface), &[], LengthUnit::Mm).as_bytes(),
    )?;
    write(
        dir.join("surface.obj"),
        cathlab_anatomy::io::obj::to_string(&s.surface, LengthUnit::Mm).as_bytes(),
    )?;
    write(
        dir.join("surface.stl"),
        &cathlab_anatomy::io::stl::to_binary(&s.surface, LengthUnit::Mm),
    )?;
    s.mask.write_metaimage(&dir.join("mask.mha"))?;
    write(
        dir.join("report.json"),
        serde_json::to_string_pretty(&s.report)
            .unwrap_or_default()
            .as_bytes(),
    )?;
    let path = dir.join("figure.png");
    figure(s, volume).save(&path).map_err(|e| ImagingError::Io {
        file: path,
        source: std::io::Error::other(e),
    })
}

/// The figure: the maximum-intensity projection of `volume` along its thinnest index axis
/// (window from the tissue to the lumen value), 0.5 mm per pixel, with the centerlines drawn
/// in a colour from blue (smallest radius) to red (largest), and branch points in yellow.
pub fn figure(segmentation: &Segmentation, volume: &ScalarVolume) -> RgbImage {
    let dims = volume.dims;
    let depth_axis = (0..3).min_by_key(|&a| dims[a]).unwrap_or(2);
    let (u, v) = match depth_axis {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    };
    let pixel = 0.5e-3;
    let width = ((dims[u] as f64 * volume.spacing_m[u] / pixel).ceil() as u32).max(1);
    let height = ((dims[v] as f64 * volume.spacing_m[v] / pixel).ceil() as u32).max(1);
    let mut mip = vec![f32::NEG_INFINITY; dims[u] * dims[v]];
    for n in 0..volume.len() {
        let ijk = volume.ijk(n);
        let cell = &mut mip[ijk[u] + dims[u] * ijk[v]];
        *cell = cell.max(volume.values[n]);
    }
    let report = &segmentation.report;
    let (lo, hi) = (
        report.background_value,
        report.lumen_value.max(report.background_value + 1.0),
    );
    let mut image = RgbImage::from_fn(width, height, |x, y| {
        let a = ((x as f64 + 0.5) * pixel / volume.spacing_m[u]) as usize;
        let b = ((y as f64 + 0.5) * pixel / volume.spacing_m[v]) as usize;
        let value = f64::from(mip[a.min(dims[u] - 1) + dims[u] * b.min(dims[v] - 1)]);
        let g = (((value - lo) / (hi - lo)).clamp(0.0, 1.0) * 200.0) as u8;
        Rgb([g, g, g])
    });
    let [r_min, _, r_max] = report.radius_mm;
    let to_pixel = |p: &nalgebra::Point3<f64>| {
        let index = volume.index_of(p);
        (
            index[u] * volume.spacing_m[u] / pixel,
            index[v] * volume.spacing_m[v] / pixel,
        )
    };
    let mut dot = |x: f64, y: f64, size: i64, colour: Rgb<u8>| {
        for dy in -size..=size {
            for dx in -size..=size {
                let (px, py) = (x as i64 + dx, y as i64 + dy);
                if px >= 0 && py >= 0 && (px as u32) < width && (py as u32) < height {
                    image.put_pixel(px as u32, py as u32, colour);
                }
            }
        }
    };
    for b in &segmentation.graph.branches {
        for w in 0..b.points.len().saturating_sub(1) {
            let f = ((b.radii[w] * 1e3 - r_min) / (r_max - r_min).max(1e-9)).clamp(0.0, 1.0);
            let colour = Rgb([(255.0 * f) as u8, 60, (255.0 * (1.0 - f)) as u8]);
            let (x0, y0) = to_pixel(&b.points[w]);
            let (x1, y1) = to_pixel(&b.points[w + 1]);
            let steps = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as usize).max(1);
            for s in 0..=steps {
                let t = s as f64 / steps as f64;
                dot(x0 + (x1 - x0) * t, y0 + (y1 - y0) * t, 1, colour);
            }
        }
    }
    let degree = segmentation.graph.node_degrees();
    for (n, p) in segmentation.graph.nodes.iter().enumerate() {
        if degree[n] >= 3 {
            let (x, y) = to_pixel(p);
            dot(x, y, 3, Rgb([255, 220, 0]));
        }
    }
    image
}
