// The resolve pass: divides the splatted sums (Shepard normalisation of the flat basis; the
// splat pass has dotted the vector irradiance with the normal), clamps at 0, multiplies by
// albedo / pi, adds the shadow-mapped direct light. Outputs linear radiance: direct,
// indirect and final.

@group(0) @binding(0) var<uniform> g: Globals;
@group(0) @binding(1) var gbuf_position: texture_2d<f32>;
@group(0) @binding(2) var gbuf_normal: texture_2d<f32>;
@group(0) @binding(3) var gbuf_albedo: texture_2d<f32>;
@group(0) @binding(4) var sums: texture_2d<f32>;
@group(0) @binding(5) var shadow_map: texture_depth_2d_array;
@group(0) @binding(6) var shadow_sampler: sampler_comparison;

@vertex
fn vs(@builtin(vertex_index) vi: u32) -> @builtin(position) vec4<f32> {
    return fullscreen_clip(vi);
}

fn shadow_face(d: vec3<f32>) -> i32 {
    if g.light_params.z < 1.5 {
        return 0;
    }
    let a = abs(d);
    if a.x >= a.y && a.x >= a.z {
        return select(1, 0, d.x >= 0.0);
    }
    if a.y >= a.z {
        return select(3, 2, d.y >= 0.0);
    }
    return select(5, 4, d.z >= 0.0);
}

// Fraction of a 3x3 percentage-closer filter that sees the light.
fn visibility(x: vec3<f32>, n: vec3<f32>) -> f32 {
    if g.light_params.z < 0.5 {
        return 1.0;
    }
    let dist = length(x - g.light_pos.xyz);
    // Offsets of a few texels at this distance: along the normal against acne, and in depth.
    let texel = dist * g.light_params.y;
    let xo = x + n * (1.5 * texel);
    let d = xo - g.light_pos.xyz;
    let face = shadow_face(d);
    let clip = g.face_vp[face] * vec4<f32>(xo, 1.0);
    if clip.w <= 0.0 {
        return 1.0;
    }
    let uv = clip.xy / clip.w * vec2<f32>(0.5, -0.5) + vec2<f32>(0.5, 0.5);
    let depth = (length(d) - 1.5 * texel) / g.light_intensity.w;
    let step = 1.0 / g.light_params.w;
    var lit = 0.0;
    for (var i = -1; i <= 1; i++) {
        for (var k = -1; k <= 1; k++) {
            let o = vec2<f32>(f32(i), f32(k)) * step;
            lit += textureSampleCompareLevel(shadow_map, shadow_sampler, uv + o, face, depth);
        }
    }
    return lit / 9.0;
}

struct Out {
    @location(0) direct: vec4<f32>,
    @location(1) indirect: vec4<f32>,
    @location(2) final_: vec4<f32>,
};

@fragment
fn fs(@builtin(position) frag: vec4<f32>) -> Out {
    let px = vec2<i32>(frag.xy);
    let x = textureLoad(gbuf_position, px, 0);
    var out: Out;
    if x.w == 0.0 {
        out.direct = vec4<f32>(0.0);
        out.indirect = vec4<f32>(0.0);
        out.final_ = vec4<f32>(0.0);
        return out;
    }
    let n = textureLoad(gbuf_normal, px, 0).xyz;
    let albedo = textureLoad(gbuf_albedo, px, 0).rgb;
    let s = textureLoad(sums, px, 0);
    var e_ind = vec3<f32>(0.0);
    if s.w > MIN_WEIGHT_SUM {
        e_ind = max(s.xyz / s.w, vec3<f32>(0.0));
    }
    let e_dir = light_irradiance(g, x.xyz, n) * visibility(x.xyz, n);
    let k = albedo / PI;
    out.direct = vec4<f32>(k * e_dir, 1.0);
    out.indirect = vec4<f32>(k * e_ind, 1.0);
    out.final_ = vec4<f32>(k * (e_dir + e_ind), 1.0);
    return out;
}
