//! Distances along a scene's route (its polyline sampled at a fixed spacing, in the anatomy's
//! frame) and the way back along it that a retrieved clot is pulled.

use cathlab_thrombectomy::RetrievalPath;
use nalgebra::Point3;

/// Distance along the route polyline of the point nearest `p` (m), the samples `spacing_m`
/// apart.
pub fn route_arc(samples: &[Point3<f64>], spacing_m: f64, p: &Point3<f64>) -> f64 {
    let mut best = (f64::MAX, 0.0);
    for i in 0..samples.len().saturating_sub(1) {
        let (a, b) = (samples[i], samples[i + 1]);
        let ab = b - a;
        let t = ((p - a).dot(&ab) / ab.norm_squared().max(1e-30)).clamp(0.0, 1.0);
        let d = (a + ab * t - p).norm_squared();
        if d < best.0 {
            best = (d, (i as f64 + t) * spacing_m);
        }
    }
    best.1
}

/// The way back along the route (samples `spacing_m` apart, with their radii) from a clot's
/// proximal end at `from` to a tip at `to` (m).
pub(super) fn way_back(
    route: &[Point3<f64>],
    radii: &[f64],
    spacing_m: f64,
    from: f64,
    to: f64,
) -> Option<RetrievalPath> {
    let (a, b) = (
        (to / spacing_m).floor().max(0.0) as usize,
        ((from / spacing_m).ceil() as usize).min(route.len() - 1),
    );
    if b <= a + 1 {
        return Some(RetrievalPath::straight(spacing_m, radii[b]));
    }
    let points: Vec<_> = route[a..=b].iter().rev().copied().collect();
    let r: Vec<_> = radii[a..=b].iter().rev().copied().collect();
    RetrievalPath::from_centerline(&points, &r).ok()
}
