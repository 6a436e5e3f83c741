// Near field (runtime/src/near.rs, prm_precompute::near). deviation_main, one invocation per
// entry: deviation = E_entry - w_cluster(entry) t_entry, t the cell's area over A/N
// (prm_runtime::cpu::NearTables). near_main, one per texel with links: near_sum = sum over its
// links of factor x deviation, factor = albedo x the cell's first bounce per unit weight (one
// read per link); a link of a hot cell whose light concentrate.wgsl wrote this update uses it
// in place of the entry's. deviation.w: luminance(E_entry), which far.wgsl's threshold reads;
// deviation[N + j]: E_entry, which far.wgsl's sources lit up close send whole, from where
// the cell's light lands (the entry pass's, after the records: crate::far::deviation_len).
// near_main also writes each point's expected light, sum over its links of factor x
// w_cluster(entry) t_entry, at near_sum[near_expected_at + k], where echo.wgsl reads it
// (prm_runtime::cpu::echo_input).
// Structs, bindings, WG_LINEAR, luminance: the generated prelude.

@compute @workgroup_size(WG_LINEAR)
fn deviation_main(@builtin(global_invocation_id) id: vec3u) {
    let j = id.x;
    if j >= params.entry_count {
        return;
    }
    let ec = entry_cluster[j];
    let fit = weights[ec.x].xyz;
    let e = entry_irradiance[j].xyz;
    deviation[j] = vec4f(e - fit * bitcast<f32>(ec.y), luminance(e));
    // For the far field (far.wgsl): E_j itself, and where the cell's light lands and which way
    // it leaves (after the sources' records, crate::far::deviation_len).
    deviation[params.entry_count + j] = vec4f(e, 0.0);
    deviation[2u * params.entry_count + 2u * FAR_SOURCES + j] = entry_irradiance[params.entry_count + j];
    deviation[3u * params.entry_count + 2u * FAR_SOURCES + j] = entry_irradiance[2u * params.entry_count + j];
}

@compute @workgroup_size(WG_LINEAR)
fn near_main(@builtin(global_invocation_id) id: vec3u) {
    let k = id.x;
    if k >= params.near_texel_count {
        return;
    }
    let t = near_texels[k];
    var sum = vec3f(0.0);
    var expected = vec3f(0.0);
    for (var i = t.first; i < t.first + t.count; i++) {
        let l = near_links[i];
        var d = deviation[l.entry].xyz;
        // w_c t_j = E_j - deviation_j, both of this buffer (one more read a link).
        expected += l.factor * (deviation[params.entry_count + l.entry].xyz - d);
        if params.any_hot != 0u {
            let own = link_light[i];
            if own.w == params.frame {
                // A hot cell: the link's own light in place of the entry's.
                d += bitcast<vec3f>(own.xyz) - entry_irradiance[l.entry].xyz;
            }
        }
        sum += l.factor * d;
    }
    near_sum[k] = vec4f(sum, 0.0);
    near_sum[params.near_expected_at + k] = vec4f(expected, 0.0);
}
