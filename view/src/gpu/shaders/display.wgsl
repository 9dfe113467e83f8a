// The display pass: one of the linear buffers (or a debug view), Reinhard 2002 global tone
// mapping, sRGB encoding when the target is not an sRGB format.

struct Display {
    // x: mode (0 final, 1 direct, 2 indirect, 3 level used, 4 points); y: key / log-average;
    // z: white luminance (scaled); w: 1 to encode sRGB in the shader.
    params: vec4<f32>,
    // x: number of levels.
    extra: vec4<f32>,
};

@group(0) @binding(0) var<uniform> d: Display;
@group(0) @binding(1) var direct_tex: texture_2d<f32>;
@group(0) @binding(2) var indirect_tex: texture_2d<f32>;
@group(0) @binding(3) var final_tex: texture_2d<f32>;
@group(0) @binding(4) var sums: texture_2d<f32>;
@group(0) @binding(5) var level_sum: texture_2d<f32>;

@vertex
fn vs(@builtin(vertex_index) vi: u32) -> @builtin(position) vec4<f32> {
    return fullscreen_clip(vi);
}

fn srgb(v: vec3<f32>) -> vec3<f32> {
    let lo = 12.92 * v;
    let hi = 1.055 * pow(max(v, vec3<f32>(0.0)), vec3<f32>(1.0 / 2.4)) - 0.055;
    return select(hi, lo, v <= vec3<f32>(0.0031308));
}

fn heat(t: f32) -> vec3<f32> {
    let s = clamp(t, 0.0, 1.0);
    return clamp(vec3<f32>(1.5 - abs(4.0 * s - 3.0), 1.5 - abs(4.0 * s - 2.0), 1.5 - abs(4.0 * s - 1.0)), vec3<f32>(0.0), vec3<f32>(1.0));
}

@fragment
fn fs(@builtin(position) frag: vec4<f32>) -> @location(0) vec4<f32> {
    let px = vec2<i32>(frag.xy);
    let mode = i32(d.params.x + 0.5);
    var c: vec3<f32>;
    if mode == 3 {
        let w = textureLoad(sums, px, 0).w;
        if w > MIN_WEIGHT_SUM {
            c = heat(textureLoad(level_sum, px, 0).x / w / max(d.extra.x - 1.0, 1.0));
        } else {
            c = vec3<f32>(0.0);
        }
    } else {
        if mode == 1 {
            c = textureLoad(direct_tex, px, 0).rgb;
        } else if mode == 2 {
            c = textureLoad(indirect_tex, px, 0).rgb;
        } else {
            c = textureLoad(final_tex, px, 0).rgb;
        }
        // Reinhard et al. 2002, Eq. 4, on luminance.
        let l = dot(c, vec3<f32>(0.2126, 0.7152, 0.0722));
        if l > 0.0 {
            let lm = d.params.y * l;
            let lw = max(d.params.z, 1e-30);
            let ld = lm * (1.0 + lm / (lw * lw)) / (1.0 + lm);
            c = clamp(c * (ld / l), vec3<f32>(0.0), vec3<f32>(1.0));
        } else {
            c = vec3<f32>(0.0);
        }
    }
    if d.params.w > 0.5 {
        c = srgb(c);
    }
    return vec4<f32>(c, 1.0);
}
