// Near field (runtime/src/near.rs, prm_precompute::near): for each texel with links,
// near_sum = sum over its links of factor x (E_entry - w_cluster(entry) t_entry), t the cell's
// area over its cluster's mean (prm_runtime::cpu::NearTables), factor = albedo x the
// cell's first bounce per unit weight. Structs, bindings, WG_LINEAR: the generated prelude.

@compute @workgroup_size(WG_LINEAR)
fn near_main(@builtin(global_invocation_id) id: vec3u) {
    let k = id.x;
    if k >= params.near_texel_count {
        return;
    }
    let t = near_texels[k];
    var sum = vec3f(0.0);
    for (var i = t.first; i < t.first + t.count; i++) {
        let l = near_links[i];
        let ec = entry_cluster[l.entry];
        let deviation = entry_irradiance[l.entry].xyz - weights[ec.x].xyz * bitcast<f32>(ec.y);
        sum += l.factor * deviation;
    }
    near_sum[k] = vec4f(sum, 0.0);
}
