// The bounce light at the sender points, the first half of the fine bounces' emission
// `P-dagger (n . R i)`: the indirect vector irradiance `i` reconstructed at each sender point
// over every level (Eq. 6: its precomputed basis values), along the point's normal, RGB. The
// pull-push passes then project it onto the sender levels.

struct Params {
    // x: sender points; z: invocations per row of the dispatch grid.
    counts: vec4<u32>,
};

@group(0) @binding(0) var<storage, read> normals: array<f32>;
@group(0) @binding(1) var<storage, read> offsets: array<u32>;
@group(0) @binding(2) var<storage, read> columns: array<u32>;
@group(0) @binding(3) var<storage, read> weights: array<f32>;
@group(0) @binding(4) var<storage, read> i: array<f32>;
@group(0) @binding(5) var<storage, read_write> out: array<f32>;
@group(0) @binding(6) var<uniform> params: Params;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let s = id.x + id.y * params.counts.z;
    if s >= params.counts.x {
        return;
    }
    var acc: array<f32, 9>;
    for (var d = 0u; d < 9u; d++) {
        acc[d] = 0.0;
    }
    for (var e = offsets[s]; e < offsets[s + 1u]; e++) {
        let k = columns[e] * 9u;
        let w = weights[e];
        for (var d = 0u; d < 9u; d++) {
            acc[d] += w * i[k + d];
        }
    }
    let n = vec3<f32>(normals[s * 3u], normals[s * 3u + 1u], normals[s * 3u + 2u]);
    for (var c = 0u; c < 3u; c++) {
        out[s * 3u + c] = dot(n, vec3<f32>(acc[3u * c], acc[3u * c + 1u], acc[3u * c + 2u]));
    }
}
