// Background ray-march: per pixel, water and bone paths (m) through a 16-bit (f16) HU volume
// by the trapezoid rule — the same samples and HU model as the CPU reference, with the
// texture unit's trilinear filter.

struct Params {
    // Patient frame relative to the isocenter (m): focal spot, detector point of pixel
    // (0, 0), per-pixel steps.
    source: vec4<f32>,
    corner: vec4<f32>,
    step_u: vec4<f32>,
    step_v: vec4<f32>,
    // Patient → index directions: columns of m; offset: the focal spot's continuous index.
    m0: vec4<f32>,
    m1: vec4<f32>,
    m2: vec4<f32>,
    offset: vec4<f32>,
    // Volume size in voxels (xyz), image width, height.
    dims: vec4<u32>,
    size: vec4<u32>,
    // step (m), bone HU, unused, unused
    settings: vec4<f32>,
};

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var volume: texture_3d<f32>;
@group(0) @binding(2) var volume_sampler: sampler;
// 1 where an 8³ brick (dilated by the trilinear footprint) is pure air: skipped.
@group(0) @binding(3) var air_bricks: texture_3d<u32>;
@group(0) @binding(4) var<storage, read_write> out: array<f32>;

// Trilinear HU at a continuous voxel index inside the box of voxel centres.
fn sample_hu(x: vec3<f32>) -> f32 {
    let n = vec3<f32>(params.dims.xyz);
    return textureSampleLevel(volume, volume_sampler, (x + vec3<f32>(0.5)) / n, 0.0).x;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let width = params.size.x;
    let height = params.size.y;
    if (id.x >= width || id.y >= height) {
        return;
    }
    let pixel = id.y * width + id.x;
    let target_point = params.corner.xyz + params.step_u.xyz * f32(id.x) + params.step_v.xyz * f32(id.y);
    let d_patient = normalize(target_point - params.source.xyz);
    let m = mat3x3<f32>(params.m0.xyz, params.m1.xyz, params.m2.xyz);
    let o = params.offset.xyz;
    let d = m * d_patient;
    // Clip to the box of voxel centres.
    var t0 = 0.0;
    var t1 = 3.0e38;
    var hit = true;
    for (var axis = 0; axis < 3; axis++) {
        let hi = f32(params.dims[axis]) - 1.0;
        if (abs(d[axis]) < 1e-30) {
            if (o[axis] < 0.0 || o[axis] > hi) {
                hit = false;
            }
        } else {
            let a = (0.0 - o[axis]) / d[axis];
            let b = (hi - o[axis]) / d[axis];
            t0 = max(t0, min(a, b));
            t1 = min(t1, max(a, b));
        }
    }
    var water = 0.0;
    var bone = 0.0;
    if (hit && t0 < t1) {
        let n = max(ceil((t1 - t0) / params.settings.x), 1.0);
        let h = (t1 - t0) / n;
        let samples = u32(n) + 1u;
        let start = o + d * t0;
        let step = d * h;
        let bone_hu = params.settings.y;
        let bricks = vec3<i32>(textureDimensions(air_bricks));
        let last = vec3<f32>(params.dims.xyz) - vec3<f32>(1.0);
        var s = 0u;
        loop {
            if (s >= samples) {
                break;
            }
            // Clamped into the box: rounding at the clipped ends must not read air.
            let x = clamp(start + step * f32(s), vec3<f32>(0.0), last);
            let brick = min(vec3<i32>(x / 8.0), bricks - vec3<i32>(1));
            if (textureLoad(air_bricks, brick, 0).x == 1u) {
                // Every sample left in this brick's closed box adds nothing: jump past them.
                let lo = vec3<f32>(brick) * 8.0;
                var t_exit = 3.0e38;
                for (var a = 0; a < 3; a++) {
                    if (step[a] > 1e-30) {
                        t_exit = min(t_exit, (lo[a] + 8.0 - x[a]) / step[a]);
                    } else if (step[a] < -1e-30) {
                        t_exit = min(t_exit, (lo[a] - x[a]) / step[a]);
                    }
                }
                s += u32(max(t_exit, 0.0)) + 1u;
                continue;
            }
            let hu = sample_hu(x);
            var w = h;
            if (s == 0u || s + 1u == samples) {
                w = 0.5 * h;
            }
            if (hu <= 0.0) {
                water += w * max(1.0 + hu * 1e-3, 0.0);
            } else {
                water += w;
                bone += w * hu / bone_hu;
            }
            s++;
        }
    }
    out[pixel] = water;
    out[width * height + pixel] = bone;
}
