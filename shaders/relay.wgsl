// The near field's own deviation for the far field (runtime/src/near.rs; twin:
// prm_runtime::cpu::near_deviation, whose doc says why). After the near links and their echo,
// before far.wgsl lists its sources. relay_main, one invocation per cluster: u_c = sum over its
// members with a slot of t_j n_j / sum t_j, n_j the links' sum at the member's texel (0 for a
// texel the far field alone lights), then deviation_j += t_j (n_j - u_c) for those members, so
// that far.wgsl sends it with the entry's own deviation. Bindings, IndirectParams, NO_SLOT and
// WG_LINEAR: the generated prelude.

fn linked(slot: u32) -> vec3f {
    if slot < params.near_texel_count {
        return near_sum[slot].xyz;
    }
    return vec3f(0.0);
}

@compute @workgroup_size(WG_LINEAR)
fn relay_main(@builtin(global_invocation_id) id: vec3u) {
    let c = id.x;
    if c >= params.cluster_count {
        return;
    }
    let r = relay_ranges[c];
    var sum = vec3f(0.0);
    var t_sum = 0.0;
    for (var k = r.x; k < r.x + r.y; k++) {
        let m = relay_members[k];
        if m.x != NO_SLOT {
            let t = bitcast<f32>(m.y);
            sum += linked(m.x) * t;
            t_sum += t;
        }
    }
    if t_sum <= 0.0 {
        return;
    }
    let u = sum / t_sum;
    for (var k = r.x; k < r.x + r.y; k++) {
        let m = relay_members[k];
        if m.x != NO_SLOT {
            let d = deviation[m.z];
            deviation[m.z] = vec4f(d.xyz + (linked(m.x) - u) * bitcast<f32>(m.y), d.w);
        }
    }
}
