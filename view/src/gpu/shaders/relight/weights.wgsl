// The sender weights of one product of `S` (sections 3.1-3.3): per stored sender slot, its
// scale times the light it emits, RGB, twice: for the rows of the level-0 receivers (first
// three floats) and for the finer rows (last three). Mode 0: both `e`; mode 1 (the lagged fine
// bounces): `e` and `e + y`; mode 2 (the fine bounces' own product): `y` for the finer rows.

struct Params {
    // x: sender slots; y: mode; z: invocations per row of the dispatch grid.
    counts: vec4<u32>,
};

@group(0) @binding(0) var<storage, read> sender_ids: array<u32>;
@group(0) @binding(1) var<storage, read> scales: array<f32>;
@group(0) @binding(2) var<storage, read> e: array<f32>;
@group(0) @binding(3) var<storage, read> y: array<f32>;
@group(0) @binding(4) var<storage, read_write> w: array<f32>;
@group(0) @binding(5) var<uniform> params: Params;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let s = id.x + id.y * params.counts.z;
    if s >= params.counts.x {
        return;
    }
    let j = sender_ids[s] * 3u;
    let ev = vec3<f32>(e[j], e[j + 1u], e[j + 2u]);
    let yv = vec3<f32>(y[j], y[j + 1u], y[j + 2u]);
    var first = ev;
    var rest = ev;
    if params.counts.y == 1u {
        rest = ev + yv;
    } else if params.counts.y == 2u {
        first = vec3<f32>(0.0);
        rest = yv;
    }
    first *= scales[s];
    rest *= scales[s];
    let o = s * 6u;
    w[o] = first.x;
    w[o + 1u] = first.y;
    w[o + 2u] = first.z;
    w[o + 3u] = rest.x;
    w[o + 4u] = rest.y;
    w[o + 5u] = rest.z;
}
