// Flattening on the GPU (section 4.1): the precomputed sparse operator of
// the relighting crate's flatten_op applied to the hierarchical coefficients `i`, one invocation per
// flat point, each row summed in its stored order. An entry packs the block-local column (low
// 16 bits) and the value as a fraction of `counts.w` (high 16 bits). The same shader runs the
// sharpening steps after it (`mode.x` = 1): the operator is then the flat basis' smoothing `W`,
// `hier` holds the flat coefficients `c_k` of the step before, `original` those of the first
// pass, `c_0`, and the output is `c_{k+1} = c_k + w_k (c_0 - W c_k)`, `w_k` the step's
// relaxation weight (`mode.y`, a float's bits).

struct Params {
    // x: number of points; y: invocations per row of the dispatch grid; z: rows per block;
    // w: the values' fixed-point scale.
    counts: vec4<u32>,
    // x: 0 writes the row's sum; 1 writes the point's own input plus the relaxation weight
    // times its original value minus the row's sum. y: the relaxation weight's bits.
    mode: vec4<u32>,
};

@group(0) @binding(0) var<storage, read> offsets: array<u32>;
@group(0) @binding(1) var<storage, read> entries: array<u32>;
@group(0) @binding(2) var<storage, read> block_offsets: array<u32>;
@group(0) @binding(3) var<storage, read> cols: array<u32>;
@group(0) @binding(4) var<storage, read> order: array<u32>;
@group(0) @binding(5) var<storage, read> hier: array<f32>;
@group(0) @binding(6) var<storage, read_write> flat: array<f32>;
@group(0) @binding(7) var<uniform> params: Params;
@group(0) @binding(8) var<storage, read> original: array<f32>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let pos = id.x + id.y * params.counts.y;
    if pos >= params.counts.x {
        return;
    }
    let base = block_offsets[pos / params.counts.z];
    let scale = 1.0 / f32(params.counts.w);
    var acc: array<f32, 9>;
    for (var d = 0u; d < 9u; d++) {
        acc[d] = 0.0;
    }
    let end = offsets[pos + 1u];
    for (var e = offsets[pos]; e < end; e++) {
        let packed = entries[e];
        let k = cols[base + (packed & 0xffffu)] * 9u;
        let v = f32(packed >> 16u) * scale;
        for (var d = 0u; d < 9u; d++) {
            acc[d] += v * hier[k + d];
        }
    }
    let j = order[pos] * 9u;
    if params.mode.x == 1u {
        let w = bitcast<f32>(params.mode.y);
        for (var d = 0u; d < 9u; d++) {
            flat[j + d] = hier[j + d] + w * (original[j + d] - acc[d]);
        }
    } else {
        for (var d = 0u; d < 9u; d++) {
            flat[j + d] = acc[d];
        }
    }
}
