// The energy a hot entry's links deliver this update (prm_runtime::cpu::concentrate,
// LinkLight::energy): one invocation per entry; when its first link carries this update's
// number (concentrate.wgsl wrote it: the cell is hot), hot_energy = (sum over its links of
// link_weight x link light, the number); link_weight = luminance(albedo) x factor x the echo
// gain of the link's texel. The weight pass uses it for the
// entry's share of the near field's energy. Structs, constants, bindings: the generated prelude.

@compute @workgroup_size(WG_LINEAR)
fn link_energy_main(@builtin(global_invocation_id) id: vec3u) {
    let j = id.x;
    if j >= params.entry_count {
        return;
    }
    let h = hot_entries[j];
    if h.link_count == 0u || link_light[link_ids[h.first_link]].w != params.frame {
        return;
    }
    // Kept since its last run, when it was hot too (the same lights reach it, so it is hot for
    // the same reasons): its links hold the light they held, and the sum is what it was.
    if (u32(entry_irradiance[j].w) & ENTRY_UNCHANGED) != 0u && hot_energy[j].w != 0u {
        hot_energy[j].w = params.frame;
        return;
    }
    var sum = vec3f(0.0);
    for (var k = h.first_link; k < h.first_link + h.link_count; k++) {
        let i = link_ids[k];
        sum += link_weight[i] * bitcast<vec3f>(link_light[i].xyz);
    }
    hot_energy[j] = vec4u(bitcast<vec3u>(sum), params.frame);
}
