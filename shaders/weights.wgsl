// Cluster weights and top-K selection (DESIGN.md §5 steps 2-3, runtime/src/weights.rs).
//
// weights_main: w_c = mean irradiance of cluster c's members; score_c = luminance(w_c) x
// energy_c. select_main: cluster c is kept when score_c > 0 and fewer than top_k clusters beat
// it (higher score, or equal score and lower index: the CPU twin's order). selected[c] holds
// w_c for kept clusters and 0 otherwise, which is all compose.wgsl reads.

struct Params {
    entry_count: u32,
    light_count: u32,
    cluster_count: u32,
    top_k: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> entry_irradiance: array<vec4f>;
// Per cluster: (first member, member count) into `members`.
@group(0) @binding(2) var<storage, read> member_ranges: array<vec2u>;
@group(0) @binding(3) var<storage, read> members: array<u32>;
@group(0) @binding(4) var<storage, read> energy: array<f32>;
@group(0) @binding(5) var<storage, read_write> weights: array<vec4f>;
@group(0) @binding(6) var<storage, read_write> scores: array<f32>;
@group(0) @binding(7) var<storage, read_write> selected: array<vec4f>;

fn luminance(c: vec3f) -> f32 {
    return dot(c, vec3f(0.2126, 0.7152, 0.0722));
}

@compute @workgroup_size(64)
fn weights_main(@builtin(global_invocation_id) id: vec3u) {
    let c = id.x;
    if c >= params.cluster_count {
        return;
    }
    let r = member_ranges[c];
    var sum = vec3f(0.0);
    for (var k = r.x; k < r.x + r.y; k++) {
        sum += entry_irradiance[members[k]].xyz;
    }
    let w = sum / f32(max(r.y, 1u));
    weights[c] = vec4f(w, 0.0);
    scores[c] = luminance(w) * energy[c];
}

@compute @workgroup_size(64)
fn select_main(@builtin(global_invocation_id) id: vec3u) {
    let c = id.x;
    if c >= params.cluster_count {
        return;
    }
    let s = scores[c];
    var rank = 0u;
    for (var d = 0u; d < params.cluster_count && rank < params.top_k; d++) {
        let t = scores[d];
        if t > s || (t == s && d < c) {
            rank++;
        }
    }
    let keep = s > 0.0 && rank < params.top_k;
    selected[c] = select(vec4f(0.0), weights[c], keep);
}
