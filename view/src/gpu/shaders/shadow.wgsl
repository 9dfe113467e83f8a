// Shadow maps: one face per pass, storing the distance to the light divided by the far
// distance (linear, so precision does not depend on the near plane).

struct Face {
    view_proj: mat4x4<f32>,
    // xyz: light position; w: far distance.
    light: vec4<f32>,
};

@group(0) @binding(0) var<uniform> face: Face;

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
};

@vertex
fn vs(@location(0) position: vec3<f32>) -> VsOut {
    var out: VsOut;
    out.clip = face.view_proj * vec4<f32>(position, 1.0);
    out.world = position;
    return out;
}

@fragment
fn fs(v: VsOut) -> @builtin(frag_depth) f32 {
    return clamp(length(v.world - face.light.xyz) / face.light.w, 0.0, 1.0);
}
