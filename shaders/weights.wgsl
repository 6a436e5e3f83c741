// Cluster weights and top-K selection (DESIGN.md §5 steps 2-3, runtime/src/weights.rs).
//
// weights_main: w_c = mean irradiance of cluster c's members; score_c = luminance(w_c) x
// energy_c. select_main: cluster c is kept when score_c > 0 and fewer than top_k clusters beat
// it (higher score, or equal score and lower index: the CPU twin's order). selected[c] holds
// w_c for kept clusters and 0 otherwise. residual_main: group g's weight, selected[C + g], is
// sum over its left-out clusters of w_c x energy_c / energy_g (prm::prm_file::Prm::
// residual_weights), 0 without residual. selected is all compose.wgsl reads.

struct Params {
    entry_count: u32,
    light_count: u32,
    cluster_count: u32,
    top_k: u32,
    group_count: u32,
    // 1: groups stand in for the clusters left out.
    residual: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> entry_irradiance: array<vec4f>;
// Per cluster c: (first member, member count) into `indices` at ranges[c]; per group g:
// (first child cluster, child count) into `indices` at ranges[C + g].
@group(0) @binding(2) var<storage, read> ranges: array<vec2u>;
@group(0) @binding(3) var<storage, read> indices: array<u32>;
// Pane energy: C clusters, then G groups.
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
    let r = ranges[c];
    var sum = vec3f(0.0);
    for (var k = r.x; k < r.x + r.y; k++) {
        sum += entry_irradiance[indices[k]].xyz;
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

@compute @workgroup_size(64)
fn residual_main(@builtin(global_invocation_id) id: vec3u) {
    let g = id.x;
    if g >= params.group_count {
        return;
    }
    var sum = vec3f(0.0);
    let r = ranges[params.cluster_count + g];
    let eg = energy[params.cluster_count + g];
    if params.residual == 1u && eg > 0.0 {
        for (var k = r.x; k < r.x + r.y; k++) {
            let c = indices[k];
            if all(selected[c].xyz == vec3f(0.0)) {
                sum += weights[c].xyz * energy[c];
            }
        }
        sum /= eg;
    }
    selected[params.cluster_count + g] = vec4f(sum, 0.0);
}
