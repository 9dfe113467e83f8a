// Flattening on the GPU (section 4.1): the precomputed sparse operator of
// format/src/flatten_op.rs applied to the hierarchical coefficients `i`, one invocation per
// flat point, each row summed in its stored order.

struct Params {
    // x: number of points; y: invocations per row of the dispatch grid.
    counts: vec4<u32>,
};

@group(0) @binding(0) var<storage, read> offsets: array<u32>;
@group(0) @binding(1) var<storage, read> slots: array<u32>;
@group(0) @binding(2) var<storage, read> values: array<f32>;
@group(0) @binding(3) var<storage, read> cols: array<u32>;
@group(0) @binding(4) var<storage, read> order: array<u32>;
@group(0) @binding(5) var<storage, read> hier: array<f32>;
@group(0) @binding(6) var<storage, read_write> flat: array<f32>;
@group(0) @binding(7) var<uniform> params: Params;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let pos = id.x + id.y * params.counts.y;
    if pos >= params.counts.x {
        return;
    }
    var acc: array<f32, 9>;
    for (var d = 0u; d < 9u; d++) {
        acc[d] = 0.0;
    }
    let end = offsets[pos + 1u];
    for (var e = offsets[pos]; e < end; e++) {
        let k = cols[slots[e]] * 9u;
        let v = values[e];
        for (var d = 0u; d < 9u; d++) {
            acc[d] += v * hier[k + d];
        }
    }
    let j = order[pos] * 9u;
    for (var d = 0u; d < 9u; d++) {
        flat[j + d] = acc[d];
    }
}
