// The direct light at the sender points (section 3.3, step 1), as the CPU relighter computes
// it: the light's irradiance at the point (or, within a few support radii of the light, the
// support average the CPU computed and listed), times the fraction of jittered shadow rays
// that reach the light. The rays end on a disk around the light facing the point, of half the
// sender level's disk radius (at most a quarter of the distance, and at most half-way to the
// surface nearest the light); half of them go first and, where they agree, decide alone. The
// rays walk a bounding volume hierarchy of the scene's triangles (any hit).

struct Params {
    // xyz: the light's position; w: its cone: 0 none, 1 hard, 2 smooth.
    light: vec4<f32>,
    // rgb: intensity; w: the ray epsilon.
    intensity: vec4<f32>,
    // xyz: the cone's axis; w: cos of the hard half angle, or of the smooth inner one.
    axis: vec4<f32>,
    // xyz: the normal of the surface nearest the light; w: the light's height over it (< 0:
    // none).
    clearance: vec4<f32>,
    // x: sender points; y: shadow rays per point; z: invocations per row of the grid;
    // w: 1 when the rays are adaptive.
    counts: vec4<u32>,
    // x: listed support averages; y: the smooth cone's outer cosine's bits.
    more: vec4<u32>,
};

// Node k: nodes[2k] = (min, first as bits), nodes[2k + 1] = (max, count as bits).
@group(0) @binding(0) var<storage, read> nodes: array<vec4<f32>>;
@group(0) @binding(1) var<storage, read> corners: array<f32>;
// Per sender point: (position, support radius), (normal, its level's disk radius).
@group(0) @binding(2) var<storage, read> points: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> normals: array<vec4<f32>>;
// Per sender point: 1 where its sample is used (the pull replaces the others).
@group(0) @binding(4) var<storage, read> used: array<u32>;
// The support averages near the light: (sample, point index as bits).
@group(0) @binding(5) var<storage, read> near: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> out: array<f32>;
@group(0) @binding(7) var<uniform> params: Params;
// The shadow rays cast this frame (cleared before the pass).
@group(0) @binding(8) var<storage, read_write> rays: atomic<u32>;

const NEAR_FULL: f32 = 2.0;
const NEAR_NONE: f32 = 3.0;
const LOW_FULL: f32 = 0.5;
const LOW_NONE: f32 = 1.0;
const TAU: f32 = 6.283185307179586;

fn cone_factor(dir: vec3<f32>) -> f32 {
    let kind = params.light.w;
    let c = dot(params.axis.xyz, dir);
    if kind == 1.0 {
        return select(0.0, 1.0, c >= params.axis.w);
    }
    if kind == 2.0 {
        let outer = bitcast<f32>(params.more.y);
        let scale = 1.0 / max(params.axis.w - outer, 1e-3);
        let t = clamp((c - outer) * scale, 0.0, 1.0);
        return t * t;
    }
    return 1.0;
}

fn near_weight(dist: f32, height: f32, r: f32) -> f32 {
    if !(r > 0.0) {
        return 0.0;
    }
    let a = clamp((NEAR_NONE - dist / r) / (NEAR_NONE - NEAR_FULL), 0.0, 1.0);
    let b = clamp((LOW_NONE - height / r) / (LOW_NONE - LOW_FULL), 0.0, 1.0);
    return a * b;
}

fn slab(lo: vec3<f32>, hi: vec3<f32>, o: vec3<f32>, inv: vec3<f32>, t0: f32, t1: f32) -> bool {
    let a = (lo - o) * inv;
    let b = (hi - o) * inv;
    let mn = min(a, b);
    let mx = max(a, b);
    let near_t = max(max(max(mn.x, mn.y), mn.z), t0);
    let far_t = min(min(min(mx.x, mx.y), mx.z), t1);
    return near_t <= far_t;
}

fn corner(t: u32, k: u32) -> vec3<f32> {
    let o = 9u * t + 3u * k;
    return vec3<f32>(corners[o], corners[o + 1u], corners[o + 2u]);
}

// Whether the segment from `a` to `b`, less `eps` at each end, meets a triangle.
fn occluded(a: vec3<f32>, b: vec3<f32>, eps: f32) -> bool {
    let d = b - a;
    let len = length(d);
    if !(len > 2.0 * eps) || arrayLength(&nodes) < 2u {
        return false;
    }
    let dir = d / len;
    let t0 = eps;
    let t1 = len - eps;
    let inv = 1.0 / dir;
    var stack: array<u32, 64>;
    var top = 1u;
    stack[0] = 0u;
    while top > 0u {
        top -= 1u;
        let k = stack[top];
        let lo = nodes[2u * k];
        let hi = nodes[2u * k + 1u];
        if !slab(lo.xyz, hi.xyz, a, inv, t0, t1) {
            continue;
        }
        let first = bitcast<u32>(lo.w);
        let count = bitcast<u32>(hi.w);
        if count == 0u {
            if top + 2u <= 64u {
                stack[top] = first;
                stack[top + 1u] = first + 1u;
                top += 2u;
            }
            continue;
        }
        for (var t = first; t < first + count; t++) {
            let v0 = corner(t, 0u);
            let e1 = corner(t, 1u) - v0;
            let e2 = corner(t, 2u) - v0;
            let p = cross(dir, e2);
            let det = dot(e1, p);
            if abs(det) < 1e-12 {
                continue;
            }
            let inv_det = 1.0 / det;
            let s = a - v0;
            let u = dot(s, p) * inv_det;
            if u < 0.0 || u > 1.0 {
                continue;
            }
            let q = cross(s, e1);
            let v = dot(dir, q) * inv_det;
            if v < 0.0 || u + v > 1.0 {
                continue;
            }
            let th = dot(e2, q) * inv_det;
            if th > t0 && th < t1 {
                return true;
            }
        }
    }
    return false;
}

// glam's `any_orthonormal_pair`.
fn orthonormal_pair(n: vec3<f32>) -> array<vec3<f32>, 2> {
    let sign = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    return array<vec3<f32>, 2>(
        vec3<f32>(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        vec3<f32>(b, sign + n.y * n.y * a, -n.y),
    );
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let j = id.x + id.y * params.counts.z;
    if j >= params.counts.x {
        return;
    }
    var e = vec3<f32>(0.0);
    let pr = points[j];
    let nd = normals[j];
    let x = pr.xyz;
    let n = nd.xyz;
    let lp = params.light.xyz;
    if used[j] == 1u {
        let d = lp - x;
        let d2 = dot(d, d);
        if d2 > 0.0 {
            let l = d / sqrt(d2);
            e = params.intensity.rgb * (max(dot(n, l), 0.0) * cone_factor(-l) / d2);
        }
        if near_weight(sqrt(d2), dot(d, n), pr.w) > 0.0 {
            for (var k = 0u; k < params.more.x; k++) {
                let s = near[k];
                if bitcast<u32>(s.w) == j {
                    e = s.xyz;
                    break;
                }
            }
        }
    }
    if any(e != vec3<f32>(0.0)) {
        let eps = params.intensity.w;
        let k = params.counts.y;
        let to_light = lp - x;
        let dist = length(to_light);
        let l = to_light / max(dist, 1.17549435e-38);
        var radius = min(0.5 * nd.w, 0.25 * dist);
        let h = params.clearance.w;
        if h >= 0.0 {
            let nc = params.clearance.xyz;
            let sin = sqrt(max(1.0 - dot(l, nc) * dot(l, nc), 0.0));
            if radius * sin > 0.5 * h {
                radius = 0.5 * h / sin;
            }
        }
        let frame = orthonormal_pair(l);
        let origin = x + n * eps;
        let turn = f32(j * 0x9E3779B9u) / 4294967296.0;
        var even = 0u;
        for (var s = 0u; s < k; s += 2u) {
            even += select(1u, 0u, occluded(origin, lp + ray_offset(s, k, radius, turn, frame), eps));
        }
        let half = (k + 1u) / 2u;
        var v = 0.0;
        if params.counts.w == 1u && k >= 4u && (even == 0u || even == half) {
            v = select(1.0, 0.0, even == 0u);
            atomicAdd(&rays, half);
        } else {
            atomicAdd(&rays, k);
            var odd = 0u;
            for (var s = 1u; s < k; s += 2u) {
                odd += select(1u, 0u, occluded(origin, lp + ray_offset(s, k, radius, turn, frame), eps));
            }
            v = f32(even + odd) / f32(k);
        }
        e *= v;
    }
    out[3u * j] = e.x;
    out[3u * j + 1u] = e.y;
    out[3u * j + 2u] = e.z;
}

fn ray_offset(s: u32, k: u32, radius: f32, turn: f32, frame: array<vec3<f32>, 2>) -> vec3<f32> {
    if k == 1u {
        return vec3<f32>(0.0);
    }
    let r = radius * sqrt((f32(s) + 0.5) / f32(k));
    let phi = TAU * (f32(s) * 0.618034 + turn);
    return frame[0] * (r * cos(phi)) + frame[1] * (r * sin(phi));
}
