// `i = S e` receiver-major (sections 3.1-3.3), one workgroup per row: the 64 invocations sum
// every 64th link of the row, then the partial sums are added in shared memory. A link is a
// sender slot and nine half floats (RGB-major: element d is multiplied by the slot's weight of
// channel d / 3), packed two to a word in five words (the tenth half is zero). The rows of the level-0 receivers
// (points below `m`) take the first three weights of a slot, the finer rows the last three.
// Mode 0 writes the row's sum, mode 1 adds it; rows `first..end` are computed, whose links are
// those of `slots` and `values` from link `base` on (the rows come in chunks that fit a buffer).

struct Params {
    // x: first row; y: end row; z: workgroups per row of the dispatch grid; w: `m`.
    counts: vec4<u32>,
    // x: 0 writes, 1 adds; y: the first link of this chunk's `slots` and `values`.
    mode: vec4<u32>,
};

@group(0) @binding(0) var<storage, read> receiver_ids: array<u32>;
@group(0) @binding(1) var<storage, read> offsets: array<u32>;
@group(0) @binding(2) var<storage, read> slots: array<u32>;
@group(0) @binding(3) var<storage, read> values: array<u32>;
@group(0) @binding(4) var<storage, read> w: array<f32>;
@group(0) @binding(5) var<storage, read_write> i: array<f32>;
@group(0) @binding(6) var<uniform> params: Params;

const LANES: u32 = 64u;
var<workgroup> partial: array<f32, 576>;

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let q = params.counts.x + wg.x + wg.y * params.counts.z;
    if q >= params.counts.y {
        return;
    }
    let r = receiver_ids[q];
    let wo = select(3u, 0u, r < params.counts.w);
    var acc: array<f32, 9>;
    for (var d = 0u; d < 9u; d++) {
        acc[d] = 0.0;
    }
    let base = params.mode.y;
    let end = offsets[q + 1u] - base;
    for (var k = offsets[q] - base + t; k < end; k += LANES) {
        let o = slots[k] * 6u + wo;
        let ws = vec3<f32>(w[o], w[o + 1u], w[o + 2u]);
        let h = k * 5u;
        let v01 = unpack2x16float(values[h]);
        let v23 = unpack2x16float(values[h + 1u]);
        let v45 = unpack2x16float(values[h + 2u]);
        let v67 = unpack2x16float(values[h + 3u]);
        let v8 = unpack2x16float(values[h + 4u]).x;
        acc[0] += v01.x * ws.x;
        acc[1] += v01.y * ws.x;
        acc[2] += v23.x * ws.x;
        acc[3] += v23.y * ws.y;
        acc[4] += v45.x * ws.y;
        acc[5] += v45.y * ws.y;
        acc[6] += v67.x * ws.z;
        acc[7] += v67.y * ws.z;
        acc[8] += v8 * ws.z;
    }
    for (var d = 0u; d < 9u; d++) {
        partial[t * 9u + d] = acc[d];
    }
    workgroupBarrier();
    for (var stride = LANES / 2u; stride > 0u; stride /= 2u) {
        if t < stride {
            for (var d = 0u; d < 9u; d++) {
                partial[t * 9u + d] += partial[(t + stride) * 9u + d];
            }
        }
        workgroupBarrier();
    }
    if t == 0u {
        let o = r * 9u;
        for (var d = 0u; d < 9u; d++) {
            if params.mode.x == 1u {
                i[o + d] += partial[d];
            } else {
                i[o + d] = partial[d];
            }
        }
    }
}
