//! Exact Euclidean distance transforms on anisotropic voxel grids (Felzenszwalb and
//! Huttenlocher's separable lower envelope of parabolas), used for the inscribed-sphere
//! radius of the skeleton and for morphology with ball-shaped structuring elements.

use rayon::prelude::*;

/// Squared distances larger than any on a real grid: "no feature voxel on this line".
const FAR: f64 = 1e30;

/// Distance (m) from each voxel centre to the nearest voxel centre where `feature` is true;
/// `f32::INFINITY` everywhere when no voxel is a feature. `dims` are the grid's voxel counts
/// (i fastest), `spacing_m` the voxel spacing per axis (m).
pub fn distance_to(feature: &[bool], dims: [usize; 3], spacing_m: [f64; 3]) -> Vec<f32> {
    let mut squared: Vec<f64> = feature
        .par_iter()
        .map(|&f| if f { 0.0 } else { FAR })
        .collect();
    transform_axis0(&mut squared, dims, spacing_m[0]);
    transform_axis1(&mut squared, dims, spacing_m[1]);
    transform_axis2(&mut squared, dims, spacing_m[2]);
    squared
        .into_par_iter()
        .map(|d| {
            if d >= FAR * 0.5 {
                f32::INFINITY
            } else {
                d.sqrt() as f32
            }
        })
        .collect()
}

/// Scratch space of the 1-D transform.
#[derive(Default)]
struct Envelope {
    hull: Vec<usize>,
    bounds: Vec<f64>,
    out: Vec<f64>,
}

impl Envelope {
    /// Replaces `f` (squared distances along one line, spacing `h`) by its 1-D transform
    /// `min_q f[q] + ((p − q)·h)²`.
    fn transform(&mut self, f: &mut [f64], h: f64) {
        let n = f.len();
        self.hull.clear();
        self.bounds.clear();
        self.out.clear();
        self.out.resize(n, FAR);
        let key = |q: usize, fq: f64| fq + (q as f64 * h).powi(2);
        for q in 0..n {
            if f[q] >= FAR * 0.5 {
                continue;
            }
            loop {
                let Some(&v) = self.hull.last() else {
                    self.hull.push(q);
                    self.bounds.push(f64::NEG_INFINITY);
                    break;
                };
                let s = (key(q, f[q]) - key(v, f[v])) / (2.0 * h * h * (q - v) as f64);
                if s <= *self.bounds.last().unwrap_or(&f64::NEG_INFINITY) {
                    self.hull.pop();
                    self.bounds.pop();
                } else {
                    self.hull.push(q);
                    self.bounds.push(s);
                    break;
                }
            }
        }
        if self.hull.is_empty() {
            return;
        }
        let mut k = 0;
        for p in 0..n {
            while k + 1 < self.hull.len() && self.bounds[k + 1] < p as f64 {
                k += 1;
            }
            let v = self.hull[k];
            self.out[p] = f[v] + ((p as f64 - v as f64) * h).powi(2);
        }
        f.copy_from_slice(&self.out);
    }
}

fn transform_axis0(data: &mut [f64], dims: [usize; 3], h: f64) {
    data.par_chunks_mut(dims[0])
        .for_each_init(Envelope::default, |env, line| env.transform(line, h));
}

fn transform_axis1(data: &mut [f64], dims: [usize; 3], h: f64) {
    let (nx, ny) = (dims[0], dims[1]);
    data.par_chunks_mut(nx * ny).for_each_init(
        || (Envelope::default(), vec![0.0; ny]),
        |(env, line), slab| {
            for i in 0..nx {
                for j in 0..ny {
                    line[j] = slab[i + nx * j];
                }
                env.transform(line, h);
                for j in 0..ny {
                    slab[i + nx * j] = line[j];
                }
            }
        },
    );
}

fn transform_axis2(data: &mut [f64], dims: [usize; 3], h: f64) {
    let (nx, ny, nz) = (dims[0], dims[1], dims[2]);
    let plane = nx * ny;
    // Each row j gathers its x–z plane, transforms along z, and the planes are scattered back.
    let rows: Vec<Vec<f64>> = (0..ny)
        .into_par_iter()
        .map_init(
            || (Envelope::default(), vec![0.0; nz]),
            |(env, line), j| {
                let mut out = vec![0.0; nx * nz];
                for i in 0..nx {
                    for k in 0..nz {
                        line[k] = data[i + nx * j + plane * k];
                    }
                    env.transform(line, h);
                    out[i * nz..(i + 1) * nz].copy_from_slice(line);
                }
                out
            },
        )
        .collect();
    for (j, row) in rows.iter().enumerate() {
        for i in 0..nx {
            for k in 0..nz {
                data[i + nx * j + plane * k] = row[i * nz + k];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn brute_force(feature: &[bool], dims: [usize; 3], h: [f64; 3]) -> Vec<f32> {
        let at = |n: usize| {
            [
                n % dims[0],
                (n / dims[0]) % dims[1],
                n / (dims[0] * dims[1]),
            ]
        };
        (0..feature.len())
            .map(|n| {
                let p = at(n);
                let mut best = f64::INFINITY;
                for (m, &f) in feature.iter().enumerate() {
                    if f {
                        let q = at(m);
                        let d2: f64 = (0..3)
                            .map(|a| ((p[a] as f64 - q[a] as f64) * h[a]).powi(2))
                            .sum();
                        best = best.min(d2);
                    }
                }
                best.sqrt() as f32
            })
            .collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// The separable transform equals the brute-force minimum over all feature voxels,
        /// on random masks and anisotropic spacings.
        #[test]
        fn separable_transform_matches_brute_force(
            nx in 1usize..9, ny in 1usize..9, nz in 1usize..7,
            hx in 0.3f64..2.0, hy in 0.3f64..2.0, hz in 0.3f64..3.0,
            density in 0.0f64..0.3, seed in any::<u64>(),
        ) {
            let dims = [nx, ny, nz];
            let n = nx * ny * nz;
            let mut state = seed | 1;
            let feature: Vec<bool> = (0..n).map(|_| {
                state ^= state << 13; state ^= state >> 7; state ^= state << 17;
                (state % 10_000) as f64 / 10_000.0 < density
            }).collect();
            let fast = distance_to(&feature, dims, [hx, hy, hz]);
            let slow = brute_force(&feature, dims, [hx, hy, hz]);
            for (a, b) in fast.iter().zip(&slow) {
                if b.is_infinite() {
                    prop_assert!(a.is_infinite());
                } else {
                    prop_assert!((a - b).abs() <= 1e-5 * (1.0 + b), "{a} vs {b}");
                }
            }
        }
    }
}
