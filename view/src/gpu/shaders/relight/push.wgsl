// The push of the pull-push projection (Eq. 7) for one level's points: each point's value less
// its reconstruction from the coarser levels, whose values are already coefficients (levels
// are dispatched from level 1 down to the finest). A row is (point, first segment, end), one
// segment per supported coarser level with its `1 / weight sum`.

struct Params {
    // x: first row of the level; y: rows in the level; z: invocations per row of the grid.
    counts: vec4<u32>,
};

@group(0) @binding(0) var<storage, read> rows: array<u32>;
@group(0) @binding(1) var<storage, read> seg_offsets: array<u32>;
@group(0) @binding(2) var<storage, read> seg_inv: array<f32>;
@group(0) @binding(3) var<storage, read> ids: array<u32>;
@group(0) @binding(4) var<storage, read> weights: array<f32>;
@group(0) @binding(5) var<storage, read_write> values: array<f32>;
@group(0) @binding(6) var<uniform> params: Params;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let k = id.x + id.y * params.counts.z;
    if k >= params.counts.y {
        return;
    }
    let r = (params.counts.x + k) * 3u;
    let j = rows[r] * 3u;
    var approx = vec3<f32>(0.0);
    for (var s = rows[r + 1u]; s < rows[r + 2u]; s++) {
        var acc = vec3<f32>(0.0);
        for (var e = seg_offsets[s]; e < seg_offsets[s + 1u]; e++) {
            let c = ids[e] * 3u;
            acc += weights[e] * vec3<f32>(values[c], values[c + 1u], values[c + 2u]);
        }
        approx += acc * seg_inv[s];
    }
    values[j] -= approx.x;
    values[j + 1u] -= approx.y;
    values[j + 2u] -= approx.z;
}
