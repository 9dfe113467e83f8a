// Debug view: the basis points of one level (for the flat basis: the level of the
// hierarchical point each one is) as small disks coloured by the luminance of their flat
// coefficient's irradiance (normal component), on a log scale. Every point is drawn; those
// of other levels collapse to nothing.

struct Point {
    pos_r: vec4<f32>,
    normal_level: vec4<f32>,
    weight_params: vec4<f32>,
};

struct PointsParams {
    // x: the level shown; y: disk radius as a fraction of r_j; z: log10 of the colour scale's
    // top; w: 1 to encode sRGB.
    params: vec4<f32>,
};

@group(0) @binding(0) var<uniform> g: Globals;
@group(0) @binding(1) var<storage, read> points: array<Point>;
@group(0) @binding(2) var<storage, read> coeffs: array<f32>;
@group(0) @binding(3) var<uniform> pp: PointsParams;

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) color: vec3<f32>,
    @location(1) corner: vec2<f32>,
};

@vertex
fn vs(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> VsOut {
    let j = ii;
    let p = points[j];
    if abs(p.normal_level.w - pp.params.x) > 0.5 {
        var none: VsOut;
        none.clip = vec4<f32>(0.0);
        return none;
    }
    let corner = vec2<f32>(f32(vi & 1u), f32((vi >> 1u) & 1u)) * 2.0 - 1.0;
    let n = p.normal_level.xyz;
    var t = cross(n, vec3<f32>(0.0, 1.0, 0.0));
    if length(t) < 1e-3 {
        t = cross(n, vec3<f32>(1.0, 0.0, 0.0));
    }
    let u = normalize(t);
    let v = cross(n, u);
    // The disk scales with the level's own radius.
    let s = pp.params.y * p.pos_r.w;
    // Lifted off the surface a little so the depth test keeps it visible.
    let w = p.pos_r.xyz + n * (0.02 * p.pos_r.w) + (u * corner.x + v * corner.y) * s;
    let b = j * 9u;
    let e = vec3<f32>(
        dot(vec3<f32>(coeffs[b], coeffs[b + 1u], coeffs[b + 2u]), n),
        dot(vec3<f32>(coeffs[b + 3u], coeffs[b + 4u], coeffs[b + 5u]), n),
        dot(vec3<f32>(coeffs[b + 6u], coeffs[b + 7u], coeffs[b + 8u]), n));
    let l = max(dot(e, vec3<f32>(0.2126, 0.7152, 0.0722)), 1e-30);
    let t01 = clamp((log(l) / log(10.0) - (pp.params.z - 4.0)) / 4.0, 0.0, 1.0);
    var out: VsOut;
    out.clip = g.view_proj * vec4<f32>(w, 1.0);
    out.color = vec3<f32>(t01, 1.0 - abs(2.0 * t01 - 1.0), 1.0 - t01);
    out.corner = corner;
    return out;
}

@fragment
fn fs(v: VsOut) -> @location(0) vec4<f32> {
    if dot(v.corner, v.corner) > 1.0 {
        discard;
    }
    return vec4<f32>(v.color, 1.0);
}
