// The indirect pass (section 4.1): every flat basis function whose support meets the view is
// drawn as a screen-space footprint bounding its support sphere; each covered pixel evaluates
// the weight of Eq. 8 at its G-buffer position and normal and accumulates, with additive
// blending, the weight and the weighted irradiance `w (n . c)` per colour: the pixel's normal
// `n` is the same for every function there, so `sum w (n . c) = n . sum w c`, and dotting here
// blends 5 floats per fragment instead of the 10 of the vector sums (the software rasteriser
// pays per blended float). The resolve pass divides.

struct Point {
    // xyz: position; w: support radius r_j.
    pos_r: vec4<f32>,
    // xyz: normal; w: level.
    normal_level: vec4<f32>,
    // x: 1 (a weight factor; the flat basis has one level).
    factor: vec4<f32>,
};

@group(0) @binding(0) var<uniform> g: Globals;
@group(0) @binding(1) var<storage, read> points: array<Point>;
@group(0) @binding(2) var<storage, read> coeffs: array<f32>;
@group(0) @binding(3) var<storage, read> visible: array<u32>;
@group(0) @binding(4) var gbuf_position: texture_2d<f32>;
@group(0) @binding(5) var gbuf_normal: texture_2d<f32>;

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) index: u32,
};

@vertex
fn vs(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> VsOut {
    let j = visible[ii];
    let p = points[j];
    let corner = vec2<f32>(f32(vi & 1u), f32((vi >> 1u) & 1u)) * 2.0 - 1.0;
    let c = p.pos_r.xyz;
    let r = p.pos_r.w;
    let to_c = c - g.cam_pos.xyz;
    let d = length(to_c);
    // By default the whole screen, at the near plane (reversed depth 1: never rejected by the
    // depth test): for supports that reach the camera or its near plane.
    var clip = vec4<f32>(corner, 1.0, 1.0);
    if d > r * 1.001 {
        let dir = to_c / d;
        // The cone of rays tangent to the support sphere cuts the plane through its centre,
        // perpendicular to `dir`, in a disk of this radius; the quad bounds that disk.
        let s = r * d / sqrt(d * d - r * r);
        let depth = dot(to_c, g.cam_forward.xyz);
        if depth - 1.4143 * s > 2.0 * g.cam_pos.w {
            var side = cross(dir, g.cam_up.xyz);
            if length(side) < 1e-4 {
                side = cross(dir, vec3<f32>(1.0, 0.0, 0.0));
            }
            let u = normalize(side);
            let v = cross(u, dir);
            let w = c + (u * corner.x + v * corner.y) * s;
            let q = g.view_proj * vec4<f32>(w, 1.0);
            // The depth of the sphere's nearest point (view depth `depth - r`), the same over
            // the whole footprint, for the depth test against the G-buffer.
            let f = g.view_proj * vec4<f32>(c - g.cam_forward.xyz * r, 1.0);
            clip = vec4<f32>(q.xy, min(f.z / f.w, 1.0) * q.w, q.w);
        }
    }
    var out: VsOut;
    out.clip = clip;
    out.index = j;
    return out;
}

struct AccOut {
    // rgb: sum w (n . c) per colour; a: sum w.
    @location(0) sums: vec4<f32>,
    // sum w level (the level view).
    @location(1) level: f32,
};

@fragment
fn fs(v: VsOut) -> AccOut {
    let px = vec2<i32>(v.clip.xy);
    let x = textureLoad(gbuf_position, px, 0);
    if x.w == 0.0 {
        discard;
    }
    let n = textureLoad(gbuf_normal, px, 0).xyz;
    let p = points[v.index];
    let raw = basis_weight(x.xyz, n, p.pos_r.xyz, p.normal_level.xyz, p.pos_r.w);
    if raw <= 0.0 {
        discard;
    }
    let w = raw * p.factor.x;
    let b = v.index * 9u;
    let e = vec3<f32>(
        dot(n, vec3<f32>(coeffs[b], coeffs[b + 1u], coeffs[b + 2u])),
        dot(n, vec3<f32>(coeffs[b + 3u], coeffs[b + 4u], coeffs[b + 5u])),
        dot(n, vec3<f32>(coeffs[b + 6u], coeffs[b + 7u], coeffs[b + 8u])),
    );
    var out: AccOut;
    out.sums = vec4<f32>(w * e, w);
    out.level = w * p.normal_level.w;
    return out;
}
