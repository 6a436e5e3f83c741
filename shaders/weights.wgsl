// Cluster weights and top-K selection (DESIGN.md §5 steps 2-3, runtime/src/weights.rs).
//
// weights_main: w_c = the power on cluster c's cells over their area, each entry's counted in
// each channel by its bounce gain times its albedo (energy[C + G + 6 k ..] for the member at
// indices[k]), less the near field's share, tinted by the member's albedo (energy[C + G + 6 k
// + 3 ..]: the links carry the first bounce) (prm_runtime::cpu::cluster_weights); score_c = luminance(w_c) x
// energy_c (lift.wgsl rescores lifted weights by |luminance|: they may be negative). select_main: cluster c is kept when score_c > 0 and fewer than top_k clusters beat
// it (higher score, or equal score and lower index: the CPU twin's order). selected[c] holds
// w_c for kept clusters and 0 otherwise. residual_main: group g's weight, selected[C + g], is
// sum over its left-out clusters of w_c x energy_c / energy_g (prm_runtime::cpu::
// residual_weights), 0 without residual. selected is all compose.wgsl reads.
//
// Bindings (their meaning: runtime/src/weights.rs), IndirectParams, luminance and WG_LINEAR:
// the generated prelude (runtime/src/contract.rs).

// A colour over its luminance (prm_runtime::cpu::tint_of): grey for black.
fn tint_of(colour: vec3f) -> vec3f {
    let l = luminance(colour);
    if l > 0.0 {
        return colour / l;
    }
    return vec3f(1.0);
}

@compute @workgroup_size(WG_LINEAR)
fn weights_main(@builtin(global_invocation_id) id: vec3u) {
    let c = id.x;
    if c >= params.cluster_count {
        return;
    }
    let r = ranges[c];
    var sum = vec3f(0.0);
    var near_sum = vec3f(0.0);
    var near_total = vec3f(0.0);
    var t_total = 0.0;
    var stay_sum = vec3f(0.0);
    var stay_t = vec3f(0.0);
    let stays = params.cluster_count + params.group_count;
    for (var k = r.x; k < r.x + r.y; k++) {
        let m = indices[k];
        let e = entry_irradiance[m.x].xyz;
        let near = bitcast<f32>(m.y);
        let t = bitcast<f32>(m.z);
        let at = stays + 6u * k;
        let s = vec3f(energy[at], energy[at + 1u], energy[at + 2u]);
        let tint = vec3f(energy[at + 3u], energy[at + 4u], energy[at + 5u]);
        sum += e;
        stay_sum += e * s;
        stay_t += t * s;
        near_sum += tint * (e * near);
        near_total += tint * (near * t);
        t_total += t;
    }
    var plain = vec3f(0.0);
    if t_total > 0.0 {
        plain = sum / t_total;
    }
    var w = select(plain, stay_sum / max(stay_t, vec3f(1.17549435e-38)), stay_t > vec3f(0.0));
    // The pane's energy in each channel: its luminance's, tinted by the cluster's albedo.
    let energy_c = energy[c] * tint_of(stay_t);
    if max(max(near_total.x, near_total.y), near_total.z) > 0.0 && energy[c] > 0.0 {
        // A channel the cluster reflects none of keeps its weight: its pane carries none.
        let balanced = max((w * energy_c - near_sum) / max(energy_c - near_total, 0.1 * energy_c), vec3f(0.0));
        w = select(w, balanced, energy_c > vec3f(0.0));
    }
    weights[c] = vec4f(w, 0.0);
    scores[c] = luminance(w) * energy[c];
}

@compute @workgroup_size(WG_LINEAR)
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

@compute @workgroup_size(WG_LINEAR)
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
            let c = indices[k].x;
            if all(selected[c].xyz == vec3f(0.0)) {
                sum += weights[c].xyz * energy[c];
            }
        }
        sum /= eg;
    }
    selected[params.cluster_count + g] = vec4f(sum, 0.0);
}
