// The pull of the pull-push projection (section 2.1) for one level's parents: each parent with
// children gets their weighted average, RGB. Levels are dispatched from the second finest up,
// so a parent reads its children's pulled values.

struct Params {
    // x: first pulled parent of the level; y: parents in the level; z: invocations per row of
    // the dispatch grid.
    counts: vec4<u32>,
};

@group(0) @binding(0) var<storage, read> parents: array<u32>;
@group(0) @binding(1) var<storage, read> offsets: array<u32>;
@group(0) @binding(2) var<storage, read> den: array<f32>;
@group(0) @binding(3) var<storage, read> children: array<u32>;
@group(0) @binding(4) var<storage, read> weights: array<f32>;
@group(0) @binding(5) var<storage, read_write> values: array<f32>;
@group(0) @binding(6) var<uniform> params: Params;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let k = id.x + id.y * params.counts.z;
    if k >= params.counts.y {
        return;
    }
    let p = params.counts.x + k;
    var num = vec3<f32>(0.0);
    for (var e = offsets[p]; e < offsets[p + 1u]; e++) {
        let c = children[e] * 3u;
        num += weights[e] * vec3<f32>(values[c], values[c + 1u], values[c + 2u]);
    }
    let i = parents[p] * 3u;
    let v = num / den[p];
    values[i] = v.x;
    values[i + 1u] = v.y;
    values[i + 2u] = v.z;
}
