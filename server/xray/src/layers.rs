//! The dynamic layers of a frame, drawn analytically because they are thinner than a voxel:
//! contrast-filled lumen and devices as chains of mitred truncated cones (hollow for
//! catheters), their exact chord lengths along a ray, and their binning into screen tiles.
//!
//! A chain of pieces along a polyline meets at bisector planes ("mitred pipe"), so pieces
//! neither overlap nor leave gaps at bends and chords simply add up along a ray.

use nalgebra::{Point3, Vector3};

use crate::error::{Result, XrayError, require_finite};
use crate::geometry::CArm;

/// The path channel a layer piece adds to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LayerMaterial {
    /// Iodinated contrast; density is the concentration over 300 mg/mL.
    Iodine,
    /// Nitinol; density is the metal fill fraction of the cross-section.
    Nitinol,
    /// Platinum; density is the metal fill fraction of the cross-section.
    Platinum,
}

impl LayerMaterial {
    /// Index among the layer channels (iodine 0, nitinol 1, platinum 2).
    pub fn channel(self) -> usize {
        match self {
            LayerMaterial::Iodine => 0,
            LayerMaterial::Nitinol => 1,
            LayerMaterial::Platinum => 2,
        }
    }
}

/// Sharpest bend between a chain's segments that still gets a mitre joint (degrees); the
/// joint's plane then makes at most half this angle with the axes' normal plane.
pub const MITRE_LIMIT_DEG: f64 = 120.0;

/// One truncated cone between two cap planes, possibly hollow: the unit all layers are made of.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TubePiece {
    /// Axis start (m, LPS).
    pub start: Point3<f64>,
    /// Axis end (m, LPS).
    pub end: Point3<f64>,
    /// Outer radius at the start and end (m).
    pub outer_radius_m: [f64; 2],
    /// Inner (lumen) radius at the start and end (m); 0 for a solid piece.
    pub inner_radius_m: [f64; 2],
    /// Outward unit normal of the cap plane through `start` (−axis for a square end).
    pub start_cap: Vector3<f64>,
    /// Outward unit normal of the cap plane through `end` (+axis for a square end).
    pub end_cap: Vector3<f64>,
    /// Which channel it adds to.
    pub material: LayerMaterial,
    /// Concentration over 300 mg/mL (iodine) or metal fill fraction (devices).
    pub density: f64,
}

impl TubePiece {
    /// Exact length (m) of the ray `origin + t·direction`, t ≥ 0, inside the piece's wall
    /// (the whole cross-section when solid); `direction` is a unit vector.
    pub fn chord(&self, origin: &Point3<f64>, direction: &Vector3<f64>) -> f64 {
        // Measure the ray from its point abreast of the piece: the quadratic's coefficients
        // then scale with the radius, not with the source distance (no cancellation).
        let abreast = direction.dot(&(self.start - origin));
        let origin = &(origin + direction * abreast);
        let (mut lo, mut hi) = (-abreast, f64::INFINITY);
        clip_half_space(
            &mut lo,
            &mut hi,
            &self.start_cap,
            &self.start,
            origin,
            direction,
        );
        clip_half_space(
            &mut lo,
            &mut hi,
            &self.end_cap,
            &self.end,
            origin,
            direction,
        );
        if lo >= hi {
            return 0.0;
        }
        let outer = cone_chord(self, self.outer_radius_m, origin, direction, lo, hi);
        if outer == 0.0 || self.inner_radius_m == [0.0, 0.0] {
            return outer;
        }
        (outer - cone_chord(self, self.inner_radius_m, origin, direction, lo, hi)).max(0.0)
    }

    /// Whether a point lies inside the wall (for brute-force checks of [`Self::chord`]).
    pub fn contains(&self, p: &Point3<f64>) -> bool {
        if self.start_cap.dot(&(p - self.start)) > 0.0 || self.end_cap.dot(&(p - self.end)) > 0.0 {
            return false;
        }
        let axis = self.end - self.start;
        let length = axis.norm();
        let u = axis / length;
        let s = u.dot(&(p - self.start));
        let radial = ((p - self.start) - u * s).norm();
        let radius = |r: [f64; 2]| r[0] + (r[1] - r[0]) * s / length;
        let inner = radius(self.inner_radius_m);
        radial <= radius(self.outer_radius_m) && (inner <= 0.0 || radial >= inner)
    }

    /// A sphere around each end that holds the piece: centre and radius (m). The piece is
    /// the convex hull of its two cap ellipses, and each ellipse reaches r / cos φ from the
    /// axis, φ the angle between cap normal and axis.
    fn end_spheres(&self) -> [(Point3<f64>, f64); 2] {
        let u = (self.end - self.start).normalize();
        let reach = |radius: f64, cap: &Vector3<f64>| radius / cap.dot(&u).abs().max(0.05);
        [
            (self.start, reach(self.outer_radius_m[0], &self.start_cap)),
            (self.end, reach(self.outer_radius_m[1], &self.end_cap)),
        ]
    }
}

/// Narrows [lo, hi] to the ray parameters with `normal · (x − point) ≤ 0`.
#[inline]
fn clip_half_space(
    lo: &mut f64,
    hi: &mut f64,
    normal: &Vector3<f64>,
    point: &Point3<f64>,
    origin: &Point3<f64>,
    direction: &Vector3<f64>,
) {
    let a = normal.dot(&(origin - point));
    let b = normal.dot(direction);
    if b.abs() < 1e-300 {
        if a > 0.0 {
            *hi = *lo;
        }
    } else if b > 0.0 {
        *hi = hi.min(-a / b);
    } else {
        *lo = lo.max(-a / b);
    }
}

/// Length of the ray inside the (infinite, r ≥ 0 nappe of the) cone of the piece's axis with
/// radii `radius` at its ends, within [lo, hi].
fn cone_chord(
    piece: &TubePiece,
    radius: [f64; 2],
    origin: &Point3<f64>,
    direction: &Vector3<f64>,
    mut lo: f64,
    mut hi: f64,
) -> f64 {
    let axis = piece.end - piece.start;
    let length = axis.norm();
    let u = axis / length;
    let slope = (radius[1] - radius[0]) / length;
    let w = origin - piece.start;
    let (s0, sd) = (u.dot(&w), u.dot(direction));
    let (p0, pd) = (w - u * s0, direction - u * sd);
    // r(t) = r0 + rd t must stay ≥ 0 (one nappe).
    let (r0, rd) = (radius[0] + slope * s0, slope * sd);
    if rd.abs() < 1e-300 {
        if r0 < 0.0 {
            return 0.0;
        }
    } else if rd > 0.0 {
        lo = lo.max(-r0 / rd);
    } else {
        hi = hi.min(-r0 / rd);
    }
    if lo >= hi {
        return 0.0;
    }
    let a = pd.norm_squared() - rd * rd;
    let b = 2.0 * (p0.dot(&pd) - r0 * rd);
    let c = p0.norm_squared() - r0 * r0;
    sublevel_length(a, b, c, lo, hi)
}

/// Length of {t ∈ [lo, hi] : a t² + b t + c ≤ 0}.
fn sublevel_length(a: f64, b: f64, c: f64, lo: f64, hi: f64) -> f64 {
    let overlap = |t0: f64, t1: f64| (t1.min(hi) - t0.max(lo)).max(0.0);
    if a.abs() <= 1e-14 * (b.abs() + c.abs()).max(f64::MIN_POSITIVE) || a == 0.0 {
        // Linear: b t + c ≤ 0.
        return if b.abs() < 1e-300 {
            if c <= 0.0 { overlap(lo, hi) } else { 0.0 }
        } else if b > 0.0 {
            overlap(f64::NEG_INFINITY, -c / b)
        } else {
            overlap(-c / b, f64::INFINITY)
        };
    }
    let disc = b * b - 4.0 * a * c;
    if disc <= 0.0 {
        return if a > 0.0 { 0.0 } else { overlap(lo, hi) };
    }
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    let (r1, r2) = (q / a, c / q);
    let (t1, t2) = (r1.min(r2), r1.max(r2));
    if a > 0.0 {
        overlap(t1, t2)
    } else {
        overlap(f64::NEG_INFINITY, t1) + overlap(t2, f64::INFINITY)
    }
}

/// A contrast-filled piece of lumen as the hemo crate reports it (plain data): a truncated
/// cone along the centerline with one concentration. Consecutive tubes whose ends meet form
/// one mitred chain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContrastTube {
    /// Centerline start (m, LPS).
    pub start: Point3<f64>,
    /// Centerline end (m, LPS).
    pub end: Point3<f64>,
    /// Lumen radius at the start (m).
    pub start_radius_m: f64,
    /// Lumen radius at the end (m).
    pub end_radius_m: f64,
    /// Iodine concentration (mg/mL).
    pub concentration_mg_per_ml: f64,
}

/// A stretch of a device measured from its distal tip, made of another material: a
/// platinum tip coil, a marker band.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DeviceBand {
    /// Distance from the distal tip to the band's distal edge (m).
    pub from_tip_m: f64,
    /// Band length (m).
    pub length_m: f64,
    /// Its material.
    pub material: LayerMaterial,
    /// Metal fill fraction of the wall cross-section in the band.
    pub fill: f64,
}

/// What a device looks like to X-rays: the cross-section and materials of a wire or catheter.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DeviceAppearance {
    /// Outer radius (m).
    pub outer_radius_m: f64,
    /// Lumen radius (m); 0 for a solid wire.
    #[serde(default)]
    pub inner_radius_m: f64,
    /// Material of the shaft.
    pub material: LayerMaterial,
    /// Metal fill fraction of the shaft wall (a braid is a fraction of its wall).
    pub fill: f64,
    /// Tip coils and markers.
    #[serde(default)]
    pub bands: Vec<DeviceBand>,
}

impl DeviceAppearance {
    /// A 0.035" (0.89 mm) nitinol guidewire with a 30 mm platinum tip coil (coil fill 0.6).
    pub fn guidewire_035() -> Self {
        Self {
            outer_radius_m: 0.445e-3,
            inner_radius_m: 0.0,
            material: LayerMaterial::Nitinol,
            fill: 1.0,
            bands: vec![DeviceBand {
                from_tip_m: 0.0,
                length_m: 0.03,
                material: LayerMaterial::Platinum,
                fill: 0.6,
            }],
        }
    }

    /// A 0.014" (0.36 mm) microwire with a 30 mm platinum coil.
    pub fn microwire_014() -> Self {
        Self {
            outer_radius_m: 0.178e-3,
            ..Self::guidewire_035()
        }
    }

    /// A 5 F catheter (1.67 mm outer, 1.0 mm lumen) with a nitinol braid filling 15 % of the
    /// wall and a 1 mm platinum marker band 2 mm from the tip.
    pub fn catheter_5f() -> Self {
        Self {
            outer_radius_m: 0.835e-3,
            inner_radius_m: 0.5e-3,
            material: LayerMaterial::Nitinol,
            fill: 0.15,
            bands: vec![DeviceBand {
                from_tip_m: 0.002,
                length_m: 0.001,
                material: LayerMaterial::Platinum,
                fill: 1.0,
            }],
        }
    }
}

/// Everything drawn analytically over the background in one frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Layers {
    pieces: Vec<TubePiece>,
}

/// One straight stretch of a chain before mitring.
#[derive(Debug, Clone, Copy)]
struct ChainSegment {
    start: Point3<f64>,
    end: Point3<f64>,
    outer: [f64; 2],
    inner: [f64; 2],
    material: LayerMaterial,
    density: f64,
}

impl Layers {
    /// No layers.
    pub fn new() -> Self {
        Self::default()
    }

    /// The pieces, in insertion order.
    pub fn pieces(&self) -> &[TubePiece] {
        &self.pieces
    }

    /// Adds a piece as given (caps included); checked.
    pub fn push_piece(&mut self, piece: TubePiece) -> Result<()> {
        validate_piece(&piece)?;
        self.pieces.push(piece);
        Ok(())
    }

    /// Adds contrast-filled lumen; tubes below `threshold_mg_per_ml` are skipped, tubes
    /// whose ends meet are mitred together.
    pub fn add_contrast(&mut self, tubes: &[ContrastTube], threshold_mg_per_ml: f64) -> Result<()> {
        let mut chain: Vec<ChainSegment> = Vec::new();
        for (i, tube) in tubes.iter().enumerate() {
            for (what, value) in [
                ("start radius (m)", tube.start_radius_m),
                ("end radius (m)", tube.end_radius_m),
                ("concentration (mg/mL)", tube.concentration_mg_per_ml),
            ] {
                if !(value.is_finite() && value >= 0.0) {
                    return Err(XrayError::OutOfRange {
                        what: format!("contrast tube {i} {what}"),
                        range: "finite and ≥ 0",
                        value,
                    });
                }
            }
            check_point(|| format!("contrast tube {i} start"), &tube.start)?;
            check_point(|| format!("contrast tube {i} end"), &tube.end)?;
            if tube.concentration_mg_per_ml < threshold_mg_per_ml
                || tube.concentration_mg_per_ml == 0.0
                || (tube.end - tube.start).norm() < 1e-9
            {
                self.push_chain(&std::mem::take(&mut chain));
                continue;
            }
            let joined = chain
                .last()
                .is_some_and(|last| (last.end - tube.start).norm() < 1e-9);
            if !joined {
                self.push_chain(&std::mem::take(&mut chain));
            }
            chain.push(ChainSegment {
                start: tube.start,
                end: tube.end,
                outer: [tube.start_radius_m, tube.end_radius_m],
                inner: [0.0, 0.0],
                material: LayerMaterial::Iodine,
                density: tube.concentration_mg_per_ml / 300.0,
            });
        }
        self.push_chain(&chain);
        Ok(())
    }

    /// Adds a device along its node positions, proximal first and distal tip last.
    pub fn add_device(&mut self, points: &[Point3<f64>], look: &DeviceAppearance) -> Result<()> {
        require_radius("device outer radius (m)", look.outer_radius_m, false)?;
        require_radius("device inner radius (m)", look.inner_radius_m, true)?;
        if look.inner_radius_m >= look.outer_radius_m {
            return Err(XrayError::OutOfRange {
                what: "device inner radius (m)".into(),
                range: "below the outer radius",
                value: look.inner_radius_m,
            });
        }
        require_fill("device shaft fill", look.fill)?;
        for (i, band) in look.bands.iter().enumerate() {
            require_radius("device band distance from tip (m)", band.from_tip_m, true)?;
            require_radius("device band length (m)", band.length_m, false)?;
            require_fill(&format!("device band {i} fill"), band.fill)?;
        }
        for (i, p) in points.iter().enumerate() {
            check_point(|| format!("device node {i}"), p)?;
        }
        // Distance from the tip of each node.
        let mut from_tip = vec![0.0; points.len()];
        for i in (0..points.len().saturating_sub(1)).rev() {
            from_tip[i] = from_tip[i + 1] + (points[i + 1] - points[i]).norm();
        }
        let mut cuts: Vec<f64> = look
            .bands
            .iter()
            .flat_map(|b| [b.from_tip_m, b.from_tip_m + b.length_m])
            .collect();
        cuts.sort_by(f64::total_cmp);
        // A band that starts where another ends gives the same cut twice: once is enough (a
        // zero-length piece between them had no axis and drew a square of metal).
        cuts.dedup_by(|a, b| (*a - *b).abs() < 1e-12);
        let material_at = |d: f64| {
            look.bands
                .iter()
                .rev()
                .find(|b| d >= b.from_tip_m && d < b.from_tip_m + b.length_m)
                .map_or((look.material, look.fill), |b| (b.material, b.fill))
        };
        let radii = ([look.outer_radius_m; 2], [look.inner_radius_m; 2]);
        let mut chain = Vec::new();
        for i in 0..points.len().saturating_sub(1) {
            let (a, b) = (points[i], points[i + 1]);
            let (da, db) = (from_tip[i], from_tip[i + 1]);
            if da - db < 1e-9 {
                continue;
            }
            // Split at band edges inside this segment (da > d > db).
            let mut stops = vec![da];
            stops.extend(
                cuts.iter()
                    .rev()
                    .copied()
                    .filter(|&d| d < da - 1e-9 && d > db + 1e-9),
            );
            stops.push(db);
            for w in stops.windows(2) {
                if w[0] - w[1] < 1e-12 {
                    continue;
                }
                let at = |d: f64| a + (b - a) * ((da - d) / (da - db));
                let (material, fill) = material_at(0.5 * (w[0] + w[1]));
                chain.push(ChainSegment {
                    start: at(w[0]),
                    end: at(w[1]),
                    outer: radii.0,
                    inner: radii.1,
                    material,
                    density: fill,
                });
            }
        }
        self.push_chain(&chain);
        Ok(())
    }

    /// Mitres a chain: neighbours share the bisector plane of their axes, up to a bend of
    /// [`MITRE_LIMIT_DEG`]; sharper kinks (a device folded back on itself) get square ends.
    /// A mitre plane nearly along the axis would clip the piece's cone far beyond its
    /// segment: a fold drew a square of metal over the piece's whole bounding box.
    fn push_chain(&mut self, chain: &[ChainSegment]) {
        let axis = |s: &ChainSegment| (s.end - s.start).normalize();
        let limit = (0.5 * MITRE_LIMIT_DEG).to_radians().cos();
        for (i, s) in chain.iter().enumerate() {
            let u = axis(s);
            let joint = |other: &ChainSegment| {
                let sum = u + axis(other);
                if sum.norm() < 1e-6 {
                    return u;
                }
                let n = sum.normalize();
                if n.dot(&u) < limit { u } else { n }
            };
            let start_cap = if i > 0 { -joint(&chain[i - 1]) } else { -u };
            let end_cap = if i + 1 < chain.len() {
                joint(&chain[i + 1])
            } else {
                u
            };
            self.pieces.push(TubePiece {
                start: s.start,
                end: s.end,
                outer_radius_m: s.outer,
                inner_radius_m: s.inner,
                start_cap,
                end_cap,
                material: s.material,
                density: s.density,
            });
        }
    }

    /// Sum over pieces of density × chord, per layer channel (iodine, nitinol, platinum), m.
    pub fn paths_along(&self, origin: &Point3<f64>, direction: &Vector3<f64>) -> [f64; 3] {
        let mut out = [0.0; 3];
        for piece in &self.pieces {
            out[piece.material.channel()] += piece.density * piece.chord(origin, direction);
        }
        out
    }
}

fn check_point(what: impl Fn() -> String, p: &Point3<f64>) -> Result<()> {
    for c in p.iter() {
        require_finite(&what, *c)?;
    }
    Ok(())
}

fn require_radius(what: &str, value: f64, zero_ok: bool) -> Result<()> {
    if value.is_finite() && (value > 0.0 || (zero_ok && value == 0.0)) {
        Ok(())
    } else {
        Err(XrayError::OutOfRange {
            what: what.into(),
            range: if zero_ok {
                "finite and ≥ 0"
            } else {
                "finite and > 0"
            },
            value,
        })
    }
}

fn require_fill(what: &str, value: f64) -> Result<()> {
    if value.is_finite() && (0.0..=1.0).contains(&value) {
        Ok(())
    } else {
        Err(XrayError::OutOfRange {
            what: what.into(),
            range: "between 0 and 1",
            value,
        })
    }
}

fn validate_piece(piece: &TubePiece) -> Result<()> {
    check_point(|| "piece start".into(), &piece.start)?;
    check_point(|| "piece end".into(), &piece.end)?;
    let length = (piece.end - piece.start).norm();
    if length.is_nan() || length <= 1e-12 {
        return Err(XrayError::OutOfRange {
            what: "piece length (m)".into(),
            range: "> 0",
            value: length,
        });
    }
    for r in piece.outer_radius_m {
        require_radius("piece outer radius (m)", r, true)?;
    }
    for r in piece.inner_radius_m {
        require_radius("piece inner radius (m)", r, true)?;
    }
    for (what, n) in [("start cap", piece.start_cap), ("end cap", piece.end_cap)] {
        let norm = n.norm();
        if norm.is_nan() || (norm - 1.0).abs() >= 1e-6 {
            return Err(XrayError::OutOfRange {
                what: format!("piece {what} normal length"),
                range: "1 (a unit vector)",
                value: norm,
            });
        }
    }
    if !(piece.density.is_finite() && piece.density >= 0.0) {
        return Err(XrayError::OutOfRange {
            what: "piece density".into(),
            range: "finite and ≥ 0",
            value: piece.density,
        });
    }
    Ok(())
}

/// Pieces sorted into square screen tiles by their projected bounding boxes, so that each
/// pixel tests only the pieces that can cover it. Flat arrays, ready for a GPU.
#[derive(Debug, Clone, PartialEq)]
pub struct TileBins {
    /// Tile side (pixels).
    pub tile_px: u32,
    /// Tiles per row and per column.
    pub tiles: [u32; 2],
    /// Piece indices of tile t are `indices[offsets[t]..offsets[t + 1]]`.
    pub offsets: Vec<u32>,
    /// Piece indices, tile by tile.
    pub indices: Vec<u32>,
    /// Per piece, the inclusive pixel box it can cover: [u0, v0, u1, v1]; empty when u0 > u1.
    pub boxes: Vec<[i32; 4]>,
}

impl TileBins {
    /// Bins the layers for a pose.
    pub fn build(layers: &Layers, carm: &CArm, tile_px: u32) -> Self {
        let (w, h) = (carm.detector.width_px, carm.detector.height_px);
        let tiles = [w.div_ceil(tile_px), h.div_ceil(tile_px)];
        let p = carm.projection_matrix();
        let boxes: Vec<[i32; 4]> = layers
            .pieces
            .iter()
            .map(|piece| {
                let (mut u0, mut v0, mut u1, mut v1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
                let mut behind = false;
                for (centre, r) in piece.end_spheres() {
                    for corner in 0..8 {
                        let sign = |bit: usize| if corner >> bit & 1 == 1 { r } else { -r };
                        let q = centre + Vector3::new(sign(0), sign(1), sign(2));
                        let hq = p * q.to_homogeneous();
                        if hq.z <= 1e-6 {
                            behind = true;
                            continue;
                        }
                        let (u, v) = (hq.x / hq.z, hq.y / hq.z);
                        u0 = u0.min(u);
                        u1 = u1.max(u);
                        v0 = v0.min(v);
                        v1 = v1.max(v);
                    }
                }
                if behind {
                    return [0, 0, w as i32 - 1, h as i32 - 1];
                }
                let clamp_u = |x: f64| x.clamp(-1.0, f64::from(w)) as i32;
                let clamp_v = |x: f64| x.clamp(-1.0, f64::from(h)) as i32;
                let b = [
                    clamp_u(u0.floor() - 1.0).max(0),
                    clamp_v(v0.floor() - 1.0).max(0),
                    clamp_u(u1.ceil() + 1.0).min(w as i32 - 1),
                    clamp_v(v1.ceil() + 1.0).min(h as i32 - 1),
                ];
                if b[0] > b[2] || b[1] > b[3] {
                    [1, 1, 0, 0]
                } else {
                    b
                }
            })
            .collect();
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); (tiles[0] * tiles[1]) as usize];
        for (i, b) in boxes.iter().enumerate() {
            if b[0] > b[2] {
                continue;
            }
            let t = tile_px as i32;
            for ty in b[1] / t..=b[3] / t {
                for tx in b[0] / t..=b[2] / t {
                    lists[(ty as u32 * tiles[0] + tx as u32) as usize].push(i as u32);
                }
            }
        }
        let mut offsets = Vec::with_capacity(lists.len() + 1);
        let mut indices = Vec::new();
        offsets.push(0);
        for list in &lists {
            indices.extend_from_slice(list);
            offsets.push(indices.len() as u32);
        }
        Self {
            tile_px,
            tiles,
            offsets,
            indices,
            boxes,
        }
    }

    /// The pieces binned into the tile holding pixel (u, v).
    pub fn pieces_at(&self, u: u32, v: u32) -> &[u32] {
        let t = (v / self.tile_px * self.tiles[0] + u / self.tile_px) as usize;
        &self.indices[self.offsets[t] as usize..self.offsets[t + 1] as usize]
    }
}
