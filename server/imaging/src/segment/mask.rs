//! Binary masks: thresholds (Otsu's), morphology with ball-shaped structuring elements of a
//! physical radius (exact, through distance transforms), the connected component of a seed,
//! and hole filling.

use std::collections::VecDeque;

use rayon::prelude::*;

use super::edt::distance_to;

/// Otsu's threshold of `values` (the one that maximises the between-class variance), on a
/// 256-bin histogram between the smallest and largest finite value.
pub fn otsu_threshold(values: &[f32]) -> Option<f64> {
    let (lo, hi) = values
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    const BINS: usize = 256;
    let width = f64::from(hi - lo) / BINS as f64;
    let mut histogram = [0u64; BINS];
    for &v in values.iter().filter(|v| v.is_finite()) {
        let b = ((f64::from(v - lo) / width) as usize).min(BINS - 1);
        histogram[b] += 1;
    }
    let total: u64 = histogram.iter().sum();
    let centre = |b: usize| f64::from(lo) + (b as f64 + 0.5) * width;
    let sum_all: f64 = (0..BINS).map(|b| histogram[b] as f64 * centre(b)).sum();
    let (mut weight_low, mut sum_low) = (0.0, 0.0);
    let mut best = (f64::NEG_INFINITY, None);
    for (b, &count) in histogram.iter().enumerate().take(BINS - 1) {
        weight_low += count as f64;
        sum_low += count as f64 * centre(b);
        let weight_high = total as f64 - weight_low;
        if weight_low == 0.0 || weight_high == 0.0 {
            continue;
        }
        let mean_low = sum_low / weight_low;
        let mean_high = (sum_all - sum_low) / weight_high;
        let between = weight_low * weight_high * (mean_low - mean_high).powi(2);
        if between > best.0 {
            best = (between, Some(f64::from(lo) + (b + 1) as f64 * width));
        }
    }
    best.1
}

/// Morphological erosion by a ball of `radius_m`: a voxel stays if no background voxel lies
/// within the radius. Outside the grid counts as neither (a vessel cut by the border keeps
/// its width there).
pub fn erode(mask: &[bool], dims: [usize; 3], spacing_m: [f64; 3], radius_m: f64) -> Vec<bool> {
    let background: Vec<bool> = mask.par_iter().map(|&m| !m).collect();
    let distance = distance_to(&background, dims, spacing_m);
    distance
        .par_iter()
        .map(|&d| f64::from(d) > radius_m * (1.0 + 1e-9))
        .collect()
}

/// Morphological dilation by a ball of `radius_m`: every voxel within the radius of the mask.
pub fn dilate(mask: &[bool], dims: [usize; 3], spacing_m: [f64; 3], radius_m: f64) -> Vec<bool> {
    let distance = distance_to(mask, dims, spacing_m);
    distance
        .par_iter()
        .map(|&d| f64::from(d) <= radius_m * (1.0 + 1e-9))
        .collect()
}

/// Opening (erosion then dilation): removes specks and threads thinner than the ball.
pub fn open(mask: &[bool], dims: [usize; 3], spacing_m: [f64; 3], radius_m: f64) -> Vec<bool> {
    dilate(
        &erode(mask, dims, spacing_m, radius_m),
        dims,
        spacing_m,
        radius_m,
    )
}

/// Closing (dilation then erosion): fills dents and gaps narrower than the ball.
pub fn close(mask: &[bool], dims: [usize; 3], spacing_m: [f64; 3], radius_m: f64) -> Vec<bool> {
    erode(
        &dilate(mask, dims, spacing_m, radius_m),
        dims,
        spacing_m,
        radius_m,
    )
}

/// Face neighbours (6-connectivity) of voxel `n` on the grid `dims`.
pub fn face_neighbours(n: usize, dims: [usize; 3]) -> impl Iterator<Item = usize> {
    let (nx, ny, nz) = (dims[0], dims[1], dims[2]);
    let (i, j, k) = (n % nx, (n / nx) % ny, n / (nx * ny));
    let plane = nx * ny;
    [
        (i > 0).then(|| n - 1),
        (i + 1 < nx).then(|| n + 1),
        (j > 0).then(|| n - nx),
        (j + 1 < ny).then(|| n + nx),
        (k > 0).then(|| n - plane),
        (k + 1 < nz).then(|| n + plane),
    ]
    .into_iter()
    .flatten()
}

/// The 6-connected component of `mask` that holds voxel `seed` (empty if the seed is not
/// in the mask).
pub fn component_of(mask: &[bool], dims: [usize; 3], seed: usize) -> Vec<bool> {
    let mut out = vec![false; mask.len()];
    if !mask.get(seed).copied().unwrap_or(false) {
        return out;
    }
    let mut queue = VecDeque::from([seed]);
    out[seed] = true;
    while let Some(n) = queue.pop_front() {
        for m in face_neighbours(n, dims) {
            if mask[m] && !out[m] {
                out[m] = true;
                queue.push_back(m);
            }
        }
    }
    out
}

/// Fills the cavities of `mask`: background voxels with no 6-connected path to the grid's
/// border become foreground.
pub fn fill_holes(mask: &[bool], dims: [usize; 3]) -> Vec<bool> {
    let (nx, ny, nz) = (dims[0], dims[1], dims[2]);
    let mut outside = vec![false; mask.len()];
    let mut queue = VecDeque::new();
    for n in 0..mask.len() {
        let (i, j, k) = (n % nx, (n / nx) % ny, n / (nx * ny));
        let border = i == 0 || j == 0 || k == 0 || i + 1 == nx || j + 1 == ny || k + 1 == nz;
        if border && !mask[n] {
            outside[n] = true;
            queue.push_back(n);
        }
    }
    while let Some(n) = queue.pop_front() {
        for m in face_neighbours(n, dims) {
            if !mask[m] && !outside[m] {
                outside[m] = true;
                queue.push_back(m);
            }
        }
    }
    outside.into_par_iter().map(|o| !o).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ball(dims: [usize; 3], centre: [f64; 3], radius: f64) -> Vec<bool> {
        (0..dims[0] * dims[1] * dims[2])
            .map(|n| {
                let p = [
                    n % dims[0],
                    (n / dims[0]) % dims[1],
                    n / (dims[0] * dims[1]),
                ];
                (0..3)
                    .map(|a| (p[a] as f64 - centre[a]).powi(2))
                    .sum::<f64>()
                    <= radius * radius
            })
            .collect()
    }

    /// Erosion and dilation by a ball equal the brute-force definitions (no background voxel
    /// within the radius; some foreground voxel within the radius), on a ball and a slab.
    #[test]
    fn erosion_and_dilation_match_their_definitions() {
        let dims = [23, 21, 19];
        let spacing = [1.0, 0.8, 1.3];
        let mut m = ball(dims, [11.0, 10.0, 9.0], 7.0);
        for (n, v) in m.iter_mut().enumerate() {
            *v |= n % 23 < 3;
        }
        let at = |n: usize| [n % 23, (n / 23) % 21, n / (23 * 21)];
        let within = |n: usize, r: f64, want: bool| {
            let p = at(n);
            (0..m.len()).any(|q| {
                let c = at(q);
                m[q] == want
                    && (0..3)
                        .map(|a| ((p[a] as f64 - c[a] as f64) * spacing[a]).powi(2))
                        .sum::<f64>()
                        <= r * r
            })
        };
        let r = 2.5;
        let e = erode(&m, dims, spacing, r);
        let d = dilate(&m, dims, spacing, r);
        for n in 0..m.len() {
            assert_eq!(e[n], m[n] && !within(n, r, false), "erosion at {:?}", at(n));
            assert_eq!(d[n], within(n, r, true), "dilation at {:?}", at(n));
        }
    }

    #[test]
    fn opening_removes_a_thin_thread_and_closing_fills_a_gap() {
        let dims = [40, 12, 12];
        let mut m = ball(dims, [8.0, 6.0, 6.0], 5.0);
        let other = ball(dims, [31.0, 6.0, 6.0], 5.0);
        for n in 0..m.len() {
            m[n] |= other[n];
        }
        // A one-voxel thread joining the balls.
        for i in 8..32 {
            m[i + 40 * (6 + 12 * 6)] = true;
        }
        let opened = open(&m, dims, [1.0; 3], 1.5);
        let seed = 8 + 40 * (6 + 12 * 6);
        let component = component_of(&opened, dims, seed);
        assert!(!component[31 + 40 * (6 + 12 * 6)], "the thread survived");
        assert!(component_of(&m, dims, seed)[31 + 40 * (6 + 12 * 6)]);
        // A one-voxel slit through a rod is closed.
        let mut rod: Vec<bool> = (0..m.len())
            .map(|n| {
                let (j, k) = ((n / 40) % 12, n / 480);
                (j as f64 - 6.0).powi(2) + (k as f64 - 6.0).powi(2) <= 9.0
            })
            .collect();
        for (n, voxel) in rod.iter_mut().enumerate() {
            if n % 40 == 20 {
                *voxel = false;
            }
        }
        let closed = close(&rod, dims, [1.0; 3], 1.5);
        assert!(component_of(&closed, dims, 5 + 40 * (6 + 12 * 6))[35 + 40 * (6 + 12 * 6)]);
    }

    #[test]
    fn fill_holes_fills_a_cavity_but_not_a_tunnel() {
        let dims = [12, 12, 12];
        let mut m = ball(dims, [6.0; 3], 5.0);
        let cavity = ball(dims, [6.0; 3], 2.0);
        for n in 0..m.len() {
            m[n] &= !cavity[n];
        }
        assert_eq!(fill_holes(&m, dims), ball(dims, [6.0; 3], 5.0));
        // A tunnel along i through the ball stays open.
        let mut t = ball(dims, [6.0; 3], 5.0);
        for i in 0..12 {
            t[i + 12 * (6 + 12 * 6)] = false;
        }
        assert_eq!(fill_holes(&t, dims), t);
    }

    #[test]
    fn otsu_separates_two_levels() {
        let mut values = vec![40.0f32; 900];
        values.extend(vec![400.0f32; 100]);
        let t = otsu_threshold(&values).unwrap();
        assert!(t > 40.0 && t < 400.0, "{t}");
        assert!(otsu_threshold(&[1.0, 1.0]).is_none());
    }
}
