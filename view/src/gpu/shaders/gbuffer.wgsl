// The G-buffer pass: world position, shading normal and albedo per pixel.

struct Material {
    albedo: vec4<f32>,
};

@group(0) @binding(0) var<uniform> g: Globals;
@group(1) @binding(0) var<uniform> material: Material;
@group(1) @binding(1) var albedo_tex: texture_2d<f32>;
@group(1) @binding(2) var albedo_sampler: sampler;

struct VsIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) face_normal: vec3<f32>,
    @location(3) uv: vec2<f32>,
};

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) @interpolate(flat) face_normal: vec3<f32>,
    @location(3) uv: vec2<f32>,
};

@vertex
fn vs(v: VsIn) -> VsOut {
    var out: VsOut;
    out.clip = g.view_proj * vec4<f32>(v.position, 1.0);
    out.world = v.position;
    out.normal = v.normal;
    out.face_normal = v.face_normal;
    out.uv = v.uv;
    return out;
}

struct GOut {
    @location(0) position: vec4<f32>,
    @location(1) normal: vec4<f32>,
    @location(2) albedo: vec4<f32>,
};

@fragment
fn fs(v: VsOut) -> GOut {
    // The geometric normal faces the camera (as a ray hit's does); the shading normal is
    // turned to its side, or replaced by it where the mesh has none.
    var ng = normalize(v.face_normal);
    if dot(ng, g.cam_pos.xyz - v.world) < 0.0 {
        ng = -ng;
    }
    var ns = ng;
    let len = length(v.normal);
    if len > 1e-6 {
        ns = v.normal / len;
        if dot(ns, ng) < 0.0 {
            ns = -ns;
        }
    }
    let albedo = material.albedo.rgb * textureSample(albedo_tex, albedo_sampler, v.uv).rgb;
    var out: GOut;
    out.position = vec4<f32>(v.world, 1.0);
    out.normal = vec4<f32>(ns, 0.0);
    out.albedo = vec4<f32>(albedo, 1.0);
    return out;
}
