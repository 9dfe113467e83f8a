// Shared declarations of the viewer's shaders (prepended to each of them).

struct Globals {
    view_proj: mat4x4<f32>,
    // xyz: camera position; w: near plane distance.
    cam_pos: vec4<f32>,
    // xyz: camera forward (unit); w: unused.
    cam_forward: vec4<f32>,
    // xyz: camera up (unit); w: unused.
    cam_up: vec4<f32>,
    // width, height, 1/width, 1/height.
    viewport: vec4<f32>,
    // xyz: light position; w: 0 point, 1 hard spot, 2 smooth spot.
    light_pos: vec4<f32>,
    // rgb: radiant intensity (W/sr); w: shadow-map far distance.
    light_intensity: vec4<f32>,
    // xyz: spot axis; w: cos of the half angle (hard) or of the outer half angle (smooth).
    light_axis: vec4<f32>,
    // x: cos of the inner half angle (smooth spot); y: shadow-map texel size per unit
    // distance; z: number of shadow faces (0 = no shadows, 1 = spot map, 6 = cube);
    // w: shadow-map resolution.
    light_params: vec4<f32>,
    // x: view mode; y: debug level; z, w: unused.
    misc: vec4<f32>,
    face_vp: array<mat4x4<f32>, 6>,
};

const PI: f32 = 3.14159265358979;
const F_SQUASH: f32 = 2.0;
const MIN_WEIGHT_SUM: f32 = 1e-12;
// mlt_format::flat_basis::FLAT_NORMAL_FLOOR.
const FLAT_NORMAL_FLOOR: f32 = 1e-3;

// Eq. 9: K(r) = 2r^3 - 3r^2 + 1 on [0, 1].
fn kernel(r: f32) -> f32 {
    if r >= 1.0 {
        return 0.0;
    }
    if r <= 0.0 {
        return 1.0;
    }
    return (2.0 * r - 3.0) * r * r + 1.0;
}

// A flat function's weight, as mlt_format's `FlatBasis::for_each_weight`: Eq. 8 with the
// squashed distance of Eq. 10 (format/src/kernel.rs `weight`) times the flat basis' sharper
// normal factor `c^(power - 2) + FLAT_NORMAL_FLOOR`, with `c = n . nj` (`flat_normal_factor`).
fn flat_weight(
    x: vec3<f32>,
    n: vec3<f32>,
    xj: vec3<f32>,
    nj: vec3<f32>,
    rj: f32,
    power: f32,
) -> f32 {
    let c = dot(n, nj);
    if c <= 0.0 || rj <= 0.0 {
        return 0.0;
    }
    let v = x - xj;
    let vn = dot(v, nj);
    let d2 = dot(v, v) + (2.0 * F_SQUASH + F_SQUASH * F_SQUASH) * vn * vn;
    let r2 = rj * rj;
    if d2 >= r2 {
        return 0.0;
    }
    return kernel(sqrt(d2 / r2)) * c * c * (pow(c, power - 2.0) + FLAT_NORMAL_FLOOR);
}

// Unshadowed direct irradiance of the light at (x, n), as view/src/light.rs.
fn light_irradiance(g: Globals, x: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let d = g.light_pos.xyz - x;
    let d2 = dot(d, d);
    if !(d2 > 0.0) {
        return vec3<f32>(0.0);
    }
    let l = d / sqrt(d2);
    let cosine = max(dot(n, l), 0.0);
    var spot = 1.0;
    let kind = g.light_pos.w;
    if kind > 0.5 && kind < 1.5 {
        spot = select(0.0, 1.0, dot(g.light_axis.xyz, -l) >= g.light_axis.w);
    } else if kind > 1.5 {
        let scale = 1.0 / max(g.light_params.x - g.light_axis.w, 1e-3);
        let t = clamp((dot(g.light_axis.xyz, -l) - g.light_axis.w) * scale, 0.0, 1.0);
        spot = t * t;
    }
    return g.light_intensity.rgb * (cosine * spot / d2);
}

// A triangle covering the screen, for vertex indices 0..3.
fn fullscreen_clip(vi: u32) -> vec4<f32> {
    let uv = vec2<f32>(f32((vi << 1u) & 2u), f32(vi & 2u));
    return vec4<f32>(uv * 2.0 - 1.0, 0.5, 1.0);
}
