// The indirect pass (section 4.1): every flat basis function whose support meets the view is
// drawn as a screen rectangle bounding its support (the squashed sphere of Eq. 10); each
// covered pixel evaluates the flat weight (Eq. 8's with the flat basis' sharper normal factor,
// `mlt_format::flat_basis`) at its G-buffer position and normal and accumulates, with additive
// blending, the weight and the weighted irradiance `w (n . c)` per colour: the pixel's normal
// `n` is the same for every function there, so `sum w (n . c) = n . sum w c`, and dotting here
// blends 5 floats per fragment instead of the 10 of the vector sums. The resolve pass divides.
//
// The vertex shader reads the function's point and coefficients and hands them to its
// fragments as flat varyings, so that the fragment shader reads only the G-buffer: a software
// rasteriser runs the fragment shader a dozen times per pixel, and storage-buffer reads there
// cost it three times the rest of the pass (llvmpipe). Only a function clipped at occluders
// (`mlt_format::support_clip`) reads its planes there, and skips the pixels they cut.

struct Point {
    // xyz: position; w: support radius r_j.
    pos_r: vec4<f32>,
    // xyz: normal; w: level.
    normal_level: vec4<f32>,
    // x: the exponent p of the flat weights' normal factor; y, z: the bits of the u32 index
    // of the first clip plane and of their count; w: unused.
    weight_params: vec4<f32>,
};

// mlt_format::support_clip::ClipPlane: x is cut when plane . (x, 1) < 0, edge0 . (x, 1) >= 0
// and edge1 . (x, 1) >= 0.
struct ClipPlane {
    plane: vec4<f32>,
    edge0: vec4<f32>,
    edge1: vec4<f32>,
};

@group(0) @binding(0) var<uniform> g: Globals;
@group(0) @binding(1) var<storage, read> points: array<Point>;
@group(0) @binding(2) var<storage, read> coeffs: array<f32>;
@group(0) @binding(3) var<storage, read> visible: array<u32>;
@group(0) @binding(4) var gbuf_position: texture_2d<f32>;
@group(0) @binding(5) var gbuf_normal: texture_2d<f32>;
@group(0) @binding(6) var<storage, read> clip_planes: array<ClipPlane>;

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    // The function's centre and support radius; normal and level; its vector irradiance per
    // colour (`red.w`: the exponent of the normal factor).
    @location(0) @interpolate(flat) pos_r: vec4<f32>,
    @location(1) @interpolate(flat) normal_level: vec4<f32>,
    @location(2) @interpolate(flat) red: vec4<f32>,
    @location(3) @interpolate(flat) green: vec3<f32>,
    @location(4) @interpolate(flat) blue: vec3<f32>,
    // The first clip plane and their count.
    @location(5) @interpolate(flat) clip_range: vec2<u32>,
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
        // perpendicular to `dir`, in a disk of this radius; the sphere's footprint bounds it.
        let s = r * d / sqrt(d * d - r * r);
        let depth = dot(to_c, g.cam_forward.xyz);
        if depth - 1.4143 * s > 2.0 * g.cam_pos.w {
            var side = cross(dir, g.cam_up.xyz);
            if length(side) < 1e-4 {
                side = cross(dir, vec3<f32>(1.0, 0.0, 0.0));
            }
            let u = normalize(side);
            let v = cross(u, dir);
            var lo = vec2<f32>(1e30);
            var hi = vec2<f32>(-1e30);
            for (var k = 0u; k < 4u; k++) {
                let e = vec2<f32>(f32(k & 1u), f32(k >> 1u)) * 2.0 - 1.0;
                let q = g.view_proj * vec4<f32>(c + (u * e.x + v * e.y) * s, 1.0);
                lo = min(lo, q.xy / q.w);
                hi = max(hi, q.xy / q.w);
            }
            // The support is the squashed sphere of Eq. 10: radius r across the normal and
            // r / (1 + F) along it, inside the box of those half-extents on the point's
            // tangent frame. Seen obliquely (a floor towards the horizon) the box's
            // projection is much smaller than the sphere's; the footprint is the screen
            // rectangle bounding both, taken where all eight corners lie in front of the
            // near plane. The tangent axis follows the screen's horizontal, so the box's
            // projection fills its bounding rectangle well.
            let nj = p.normal_level.xyz;
            let right = cross(g.cam_forward.xyz, g.cam_up.xyz);
            var t1 = right - dot(right, nj) * nj;
            if length(t1) < 1e-3 {
                t1 = g.cam_up.xyz - dot(g.cam_up.xyz, nj) * nj;
            }
            t1 = normalize(t1) * r;
            let t2 = cross(nj, t1);
            let t3 = nj * (r / (1.0 + F_SQUASH));
            var blo = vec2<f32>(1e30);
            var bhi = vec2<f32>(-1e30);
            var front = true;
            for (var k = 0u; k < 8u; k++) {
                let e = vec3<f32>(f32(k & 1u), f32((k >> 1u) & 1u), f32(k >> 2u)) * 2.0 - 1.0;
                let q = g.view_proj * vec4<f32>(c + t1 * e.x + t2 * e.y + t3 * e.z, 1.0);
                front = front && q.w > g.cam_pos.w;
                blo = min(blo, q.xy / q.w);
                bhi = max(bhi, q.xy / q.w);
            }
            if front {
                lo = max(lo, blo);
                hi = min(hi, bhi);
            }
            // The depth of the sphere's nearest point (view depth `depth - r`), the same over
            // the whole footprint, for the depth test against the G-buffer.
            let f = g.view_proj * vec4<f32>(c - g.cam_forward.xyz * r, 1.0);
            let xy = mix(lo, hi, corner * 0.5 + 0.5);
            clip = vec4<f32>(xy, min(f.z / f.w, 1.0), 1.0);
        }
    }
    var out: VsOut;
    out.clip = clip;
    let b = j * 9u;
    out.pos_r = p.pos_r;
    out.normal_level = p.normal_level;
    out.red = vec4<f32>(coeffs[b], coeffs[b + 1u], coeffs[b + 2u], p.weight_params.x);
    out.green = vec3<f32>(coeffs[b + 3u], coeffs[b + 4u], coeffs[b + 5u]);
    out.blue = vec3<f32>(coeffs[b + 6u], coeffs[b + 7u], coeffs[b + 8u]);
    out.clip_range = vec2<u32>(bitcast<u32>(p.weight_params.y), bitcast<u32>(p.weight_params.z));
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
    let w = flat_weight(x.xyz, n, v.pos_r.xyz, v.normal_level.xyz, v.pos_r.w, v.red.w);
    if w <= 0.0 {
        discard;
    }
    let xh = vec4<f32>(x.xyz, 1.0);
    for (var k = v.clip_range.x; k < v.clip_range.x + v.clip_range.y; k++) {
        let c = clip_planes[k];
        if dot(c.plane, xh) < 0.0 && dot(c.edge0, xh) >= 0.0 && dot(c.edge1, xh) >= 0.0 {
            discard;
        }
    }
    let e = vec3<f32>(dot(n, v.red.xyz), dot(n, v.green), dot(n, v.blue));
    var out: AccOut;
    out.sums = vec4<f32>(w * e, w);
    out.level = w * v.normal_level.w;
    return out;
}
