// Analytic layers: per pixel, density × exact chord through each mitred tube piece binned into
// the pixel's tile — the same formulas as the CPU reference (layers.rs), in f32.

struct Params {
    source: vec4<f32>,
    corner: vec4<f32>,
    step_u: vec4<f32>,
    step_v: vec4<f32>,
    // width, height, tile side, tiles per row
    size: vec4<u32>,
};

struct Piece {
    start: vec4<f32>,      // xyz, density
    end: vec4<f32>,        // xyz, channel
    radii: vec4<f32>,      // outer start, outer end, inner start, inner end
    start_cap: vec4<f32>,  // outward normal
    end_cap: vec4<f32>,
    pixel_box: vec4<i32>,  // u0, v0, u1, v1
};

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> pieces: array<Piece>;
@group(0) @binding(2) var<storage, read> offsets: array<u32>;
@group(0) @binding(3) var<storage, read> indices: array<u32>;
@group(0) @binding(4) var<storage, read_write> out: array<f32>;

// Narrows [range.x, range.y] to normal · (o + t d − point) ≤ 0.
fn clip(range: vec2<f32>, normal: vec3<f32>, point: vec3<f32>, o: vec3<f32>, d: vec3<f32>) -> vec2<f32> {
    let a = dot(normal, o - point);
    let b = dot(normal, d);
    var r = range;
    if (abs(b) < 1e-30) {
        if (a > 0.0) {
            r.y = r.x;
        }
    } else if (b > 0.0) {
        r.y = min(r.y, -a / b);
    } else {
        r.x = max(r.x, -a / b);
    }
    return r;
}

fn overlap(t0: f32, t1: f32, lo: f32, hi: f32) -> f32 {
    return max(min(t1, hi) - max(t0, lo), 0.0);
}

fn sublevel_length(a: f32, b: f32, c: f32, lo: f32, hi: f32) -> f32 {
    let big = 3.0e38;
    if (abs(a) <= 1e-7 * max(abs(b) + abs(c), 1e-37)) {
        if (abs(b) < 1e-30) {
            if (c <= 0.0) { return overlap(lo, hi, lo, hi); }
            return 0.0;
        } else if (b > 0.0) {
            return overlap(-big, -c / b, lo, hi);
        }
        return overlap(-c / b, big, lo, hi);
    }
    let disc = b * b - 4.0 * a * c;
    if (disc <= 0.0) {
        if (a > 0.0) { return 0.0; }
        return overlap(lo, hi, lo, hi);
    }
    var sign_b = 1.0;
    if (b < 0.0) { sign_b = -1.0; }
    let q = -0.5 * (b + sign_b * sqrt(disc));
    let r1 = q / a;
    let r2 = c / q;
    let t1 = min(r1, r2);
    let t2 = max(r1, r2);
    if (a > 0.0) {
        return overlap(t1, t2, lo, hi);
    }
    return overlap(-big, t1, lo, hi) + overlap(t2, big, lo, hi);
}

fn cone_chord(p: Piece, r_start: f32, r_end: f32, o: vec3<f32>, d: vec3<f32>, range: vec2<f32>) -> f32 {
    let axis = p.end.xyz - p.start.xyz;
    let len = length(axis);
    let u = axis / len;
    let slope = (r_end - r_start) / len;
    let w = o - p.start.xyz;
    let s0 = dot(u, w);
    let sd = dot(u, d);
    let p0 = w - u * s0;
    let pd = d - u * sd;
    let r0 = r_start + slope * s0;
    let rd = slope * sd;
    var lo = range.x;
    var hi = range.y;
    if (abs(rd) < 1e-30) {
        if (r0 < 0.0) { return 0.0; }
    } else if (rd > 0.0) {
        lo = max(lo, -r0 / rd);
    } else {
        hi = min(hi, -r0 / rd);
    }
    if (lo >= hi) { return 0.0; }
    let a = dot(pd, pd) - rd * rd;
    let b = 2.0 * (dot(p0, pd) - r0 * rd);
    let c = dot(p0, p0) - r0 * r0;
    return sublevel_length(a, b, c, lo, hi);
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let width = params.size.x;
    let height = params.size.y;
    if (id.x >= width || id.y >= height) {
        return;
    }
    let pixel = id.y * width + id.x;
    let tile = (id.y / params.size.z) * params.size.w + id.x / params.size.z;
    // The pixel's ray through its point on the isocenter plane (small numbers near the
    // patient; the corner and steps are scaled onto that plane).
    let o = params.corner.xyz + params.step_u.xyz * f32(id.x) + params.step_v.xyz * f32(id.y);
    let d = normalize(o - params.source.xyz);
    var sums = vec3<f32>(0.0);
    let ui = i32(id.x);
    let vi = i32(id.y);
    for (var k = offsets[tile]; k < offsets[tile + 1u]; k++) {
        let p = pieces[indices[k]];
        let b = p.pixel_box;
        if (ui < b.x || ui > b.z || vi < b.y || vi > b.w) {
            continue;
        }
        // Measure the ray from its point abreast of the piece, so that the quadratic's
        // coefficients scale with the radius, not the source distance (f32 cancellation).
        let abreast = dot(p.start.xyz - o, d);
        let near = o + d * abreast;
        var range = vec2<f32>(-3.0e38, 3.0e38);
        range = clip(range, p.start_cap.xyz, p.start.xyz, near, d);
        range = clip(range, p.end_cap.xyz, p.end.xyz, near, d);
        if (range.x >= range.y) {
            continue;
        }
        var chord = cone_chord(p, p.radii.x, p.radii.y, near, d, range);
        if (chord > 0.0 && (p.radii.z != 0.0 || p.radii.w != 0.0)) {
            chord = max(chord - cone_chord(p, p.radii.z, p.radii.w, near, d, range), 0.0);
        }
        let contribution = p.start.w * chord;
        let channel = u32(p.end.w);
        if (channel == 0u) { sums.x += contribution; }
        else if (channel == 1u) { sums.y += contribution; }
        else { sums.z += contribution; }
    }
    let plane = width * height;
    out[pixel] = sums.x;
    out[plane + pixel] = sums.y;
    out[2u * plane + pixel] = sums.z;
}
