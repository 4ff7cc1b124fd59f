//! Scalar volumes on a regular grid (CT, masks, distance maps) with spacing, origin and
//! direction in patient LPS coordinates; the file formats are read in [`crate::metaimage`],
//! [`crate::nifti`] and [`crate::dicom`], chosen by [`ScalarVolume::load`] (`load.rs`).

use nalgebra::{Matrix3, Point3, Vector3};

use crate::error::{ImagingError, Result};

/// A scalar volume. Voxel (i, j, k) is at `origin + direction · (i·sx, j·sy, k·sz)`;
/// `values` run with i fastest.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalarVolume {
    /// Voxels along each index axis.
    pub dims: [usize; 3],
    /// Voxel spacing along each index axis (m).
    pub spacing_m: Vector3<f64>,
    /// Patient position of voxel (0, 0, 0) (m, LPS).
    pub origin_m: Vector3<f64>,
    /// Columns: the unit directions of the index axes in patient coordinates.
    pub direction: Matrix3<f64>,
    /// The voxel values (file units, e.g. HU), i fastest.
    pub values: Vec<f32>,
}

impl ScalarVolume {
    /// Builds and checks a volume: positive dimensions and spacings, finite origin,
    /// orthonormal direction, one value per voxel.
    pub fn new(
        dims: [usize; 3],
        spacing_m: Vector3<f64>,
        origin_m: Vector3<f64>,
        direction: Matrix3<f64>,
        values: Vec<f32>,
    ) -> Result<Self> {
        check_grid(dims, &spacing_m, &origin_m, &direction, values.len())
            .map_err(ImagingError::InvalidVolume)?;
        Ok(Self {
            dims,
            spacing_m,
            origin_m,
            direction,
            values,
        })
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.values.len()
    }

    /// Whether the volume has no voxels (never, for a checked volume).
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// Linear index of voxel (i, j, k).
    pub fn linear(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// Voxel (i, j, k) of a linear index.
    pub fn ijk(&self, n: usize) -> [usize; 3] {
        let (nx, ny) = (self.dims[0], self.dims[1]);
        [n % nx, (n / nx) % ny, n / (nx * ny)]
    }

    /// Patient position (m) of a continuous voxel index.
    pub fn position_of(&self, index: &Vector3<f64>) -> Point3<f64> {
        Point3::from(self.origin_m + self.direction * index.component_mul(&self.spacing_m))
    }

    /// Continuous voxel index of a patient position (m).
    pub fn index_of(&self, p: &Point3<f64>) -> Vector3<f64> {
        (self.direction.transpose() * (p.coords - self.origin_m)).component_div(&self.spacing_m)
    }

    /// Trilinear value at a continuous voxel index, clamped to the volume's edge.
    pub fn sample_index(&self, x: &Vector3<f64>) -> f64 {
        let mut base = [0usize; 3];
        let mut frac = [0.0f64; 3];
        for a in 0..3 {
            let max = (self.dims[a] - 1) as f64;
            let c = x[a].clamp(0.0, max);
            let f = c.floor().min((max - 1.0).max(0.0));
            base[a] = f as usize;
            frac[a] = c - f;
        }
        let step = |a: usize| usize::from(self.dims[a] > 1);
        let mut sum = 0.0;
        for dk in 0..2 {
            for dj in 0..2 {
                for di in 0..2 {
                    let w = (if di == 1 { frac[0] } else { 1.0 - frac[0] })
                        * (if dj == 1 { frac[1] } else { 1.0 - frac[1] })
                        * (if dk == 1 { frac[2] } else { 1.0 - frac[2] });
                    if w == 0.0 {
                        continue;
                    }
                    let n = self.linear(
                        base[0] + di * step(0),
                        base[1] + dj * step(1),
                        base[2] + dk * step(2),
                    );
                    sum += w * f64::from(self.values[n]);
                }
            }
        }
        sum
    }

    /// Trilinear value at a patient position (m).
    pub fn sample(&self, p: &Point3<f64>) -> f64 {
        self.sample_index(&self.index_of(p))
    }

    /// The same grid with other values.
    pub fn with_values(&self, values: Vec<f32>) -> Result<Self> {
        Self::new(
            self.dims,
            self.spacing_m,
            self.origin_m,
            self.direction,
            values,
        )
    }

    /// Bytes held by the values.
    pub fn memory_bytes(&self) -> usize {
        self.values.len() * std::mem::size_of::<f32>()
    }
}

/// Checks a voxel grid: at least one voxel per axis, finite positive spacing (m), finite
/// origin (m), orthonormal direction, `count` = the number of voxels. The error says what
/// is wrong, in words.
pub fn check_grid(
    dims: [usize; 3],
    spacing_m: &Vector3<f64>,
    origin_m: &Vector3<f64>,
    direction: &Matrix3<f64>,
    count: usize,
) -> std::result::Result<(), String> {
    if let Some(axis) = dims.iter().position(|&n| n == 0) {
        return Err(format!("size along axis {axis} is 0 voxels"));
    }
    for axis in 0..3 {
        let s = spacing_m[axis];
        if !(s.is_finite() && s > 0.0) {
            return Err(format!(
                "voxel spacing along axis {axis} is {s} m (must be finite and > 0)"
            ));
        }
        if !origin_m[axis].is_finite() {
            return Err(format!("origin component {axis} is not finite"));
        }
    }
    let orthonormal = (direction.transpose() * direction - Matrix3::identity())
        .abs()
        .max();
    if orthonormal.is_nan() || orthonormal >= 1e-4 {
        return Err(format!(
            "direction matrix is not orthonormal (|DᵀD − I| = {orthonormal})"
        ));
    }
    let voxels = dims[0] * dims[1] * dims[2];
    if count != voxels {
        return Err(format!("{count} values for {voxels} voxels"));
    }
    Ok(())
}
