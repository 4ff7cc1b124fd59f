//! A case's preview: the lumen surface's silhouette seen from the front (patient's left on
//! the right of the image, head up), its centerlines, each branch labelled with its name, the
//! open ends numbered, the access in green and the target in blue, so that a user can name
//! branches and choose a target before serving the case.

use cathlab_anatomy::capping::OpenEnd;
use cathlab_anatomy::{TriangleMesh, VesselGraph};
use image::{Rgb, RgbImage};
use nalgebra::Point3;

/// The longer side of the preview (px).
pub const PREVIEW_PX: u32 = 1000;

/// 5×7 glyphs (rows top to bottom, 5 bits each) for digits, letters (upper case), `_ - .`.
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_uppercase() {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        'A' => [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'B' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'F' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'G' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'H' => [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'J' => [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C],
        'K' => [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'Q' => [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'U' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'V' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'W' => [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A],
        'X' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        'Y' => [0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04],
        'Z' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F],
        '_' => [0, 0, 0, 0, 0, 0, 0x1F],
        '-' => [0, 0, 0, 0x1F, 0, 0, 0],
        '.' => [0, 0, 0, 0, 0, 0x0C, 0x0C],
        ' ' => [0; 7],
        _ => [0x1F, 0x11, 0x11, 0x11, 0x11, 0x11, 0x1F],
    }
}

fn put(img: &mut RgbImage, x: i64, y: i64, colour: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, colour);
    }
}

/// Writes `text` with its top-left corner at (x, y), each font pixel `scale` image pixels,
/// on a dark outline so that it reads over any background.
pub fn text(img: &mut RgbImage, x: i64, y: i64, text: &str, scale: i64, colour: Rgb<u8>) {
    for (pass, paint) in [(0, Rgb([0, 0, 0])), (1, colour)] {
        for (n, c) in text.chars().enumerate() {
            let rows = glyph(c);
            for (r, bits) in rows.iter().enumerate() {
                for col in 0..5 {
                    if bits & (0x10 >> col) == 0 {
                        continue;
                    }
                    let px = x + (n as i64 * 6 + col) * scale;
                    let py = y + r as i64 * scale;
                    let grow = if pass == 0 { 1 } else { 0 };
                    for dy in -grow..scale + grow {
                        for dx in -grow..scale + grow {
                            put(img, px + dx, py + dy, paint);
                        }
                    }
                }
            }
        }
    }
}

fn line(img: &mut RgbImage, a: (f64, f64), b: (f64, f64), width: i64, colour: Rgb<u8>) {
    let steps = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
    for s in 0..=steps {
        let t = s as f64 / steps as f64;
        let (x, y) = (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t);
        for dy in -(width / 2)..=(width / 2) {
            for dx in -(width / 2)..=(width / 2) {
                put(img, x.round() as i64 + dx, y.round() as i64 + dy, colour);
            }
        }
    }
}

fn disc(img: &mut RgbImage, c: (f64, f64), r: f64, colour: Rgb<u8>) {
    let ri = r.ceil() as i64;
    for dy in -ri..=ri {
        for dx in -ri..=ri {
            if (dx * dx + dy * dy) as f64 <= r * r {
                put(
                    img,
                    c.0.round() as i64 + dx,
                    c.1.round() as i64 + dy,
                    colour,
                );
            }
        }
    }
}

/// Draws the preview of a case (all positions in m, LPS).
pub fn preview(
    mesh: &TriangleMesh,
    graph: &VesselGraph,
    ends: &[OpenEnd],
    access: &Point3<f64>,
    target: Option<&str>,
) -> RgbImage {
    let (lo, hi) = mesh.bounding_box();
    let margin = 0.05 * (hi.x - lo.x).max(hi.z - lo.z);
    let (w_m, h_m) = (hi.x - lo.x + 2.0 * margin, hi.z - lo.z + 2.0 * margin);
    let scale = f64::from(PREVIEW_PX) / w_m.max(h_m);
    let (w, h) = (
        ((w_m * scale).ceil() as u32).max(64),
        ((h_m * scale).ceil() as u32).max(64),
    );
    let project = |p: &Point3<f64>| ((p.x - lo.x + margin) * scale, (hi.z + margin - p.z) * scale);
    let mut img = RgbImage::from_pixel(w, h, Rgb([16, 16, 20]));
    // The silhouette: every triangle filled.
    for t in &mesh.triangles {
        let [a, b, c] = mesh.corners(t).map(|p| project(&p));
        let (x0, x1) = (
            a.0.min(b.0).min(c.0).floor() as i64,
            a.0.max(b.0).max(c.0).ceil() as i64,
        );
        let (y0, y1) = (
            a.1.min(b.1).min(c.1).floor() as i64,
            a.1.max(b.1).max(c.1).ceil() as i64,
        );
        let area = (b.0 - a.0) * (c.1 - a.1) - (c.0 - a.0) * (b.1 - a.1);
        if area.abs() < 1e-9 {
            continue;
        }
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                let w0 = ((b.0 - px) * (c.1 - py) - (c.0 - px) * (b.1 - py)) / area;
                let w1 = ((c.0 - px) * (a.1 - py) - (a.0 - px) * (c.1 - py)) / area;
                if w0 >= 0.0 && w1 >= 0.0 && w0 + w1 <= 1.0 {
                    put(&mut img, x, y, Rgb([90, 90, 100]));
                }
            }
        }
    }
    for b in &graph.branches {
        let colour = if Some(b.name.as_str()) == target {
            Rgb([80, 140, 255])
        } else {
            Rgb([230, 80, 60])
        };
        for pair in b.points.windows(2) {
            line(&mut img, project(&pair[0]), project(&pair[1]), 3, colour);
        }
    }
    for b in &graph.branches {
        let mid = b.point_at(0.5 * b.length());
        let (x, y) = project(&mid);
        let colour = if Some(b.name.as_str()) == target {
            Rgb([140, 190, 255])
        } else {
            Rgb([255, 240, 170])
        };
        text(&mut img, x as i64 + 4, y as i64 - 7, &b.name, 2, colour);
    }
    for e in ends {
        let (x, y) = project(&e.centre);
        disc(&mut img, (x, y), 6.0, Rgb([255, 255, 255]));
        text(
            &mut img,
            x as i64 + 8,
            y as i64 + 4,
            &format!("end {}", e.index),
            2,
            Rgb([255, 255, 255]),
        );
    }
    disc(&mut img, project(access), 8.0, Rgb([60, 220, 90]));
    text(
        &mut img,
        project(access).0 as i64 + 10,
        project(access).1 as i64 - 20,
        "access",
        2,
        Rgb([60, 220, 90]),
    );
    text(
        &mut img,
        10,
        10,
        "AP view  patient left is image right  head up",
        2,
        Rgb([200, 200, 200]),
    );
    img
}
