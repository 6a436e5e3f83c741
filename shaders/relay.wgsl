// The near field's own deviation for the far field (runtime/src/near.rs; twin:
// prm_runtime::cpu::near_deviation, whose doc says why). After the near links and their echo,
// before far.wgsl lists its sources. relay_main, one invocation per cluster: u_c = sum over its
// members with texels of t_j n_j / sum t_j, n_j the mean of the links' sum over the member's
// cell's texels (0 at a texel the far field alone lights), then deviation_j += t_j (n_j - u_c)
// for those members, so that far.wgsl sends it with the entry's own deviation. Bindings,
// IndirectParams and WG_LINEAR: the generated prelude.

fn linked(slot: u32) -> vec3f {
    if slot < params.near_texel_count {
        return near_sum[slot].xyz;
    }
    return vec3f(0.0);
}

// Member k's four words: its cell's run of slots (first, end) further on in the table, t_j,
// its entry.
fn member(k: u32) -> vec4u {
    return vec4u(relay_members[4u * k], relay_members[4u * k + 1u], relay_members[4u * k + 2u], relay_members[4u * k + 3u]);
}

// The links' mean over a member's cell.
fn cell_mean(m: vec4u) -> vec3f {
    var sum = vec3f(0.0);
    for (var i = m.x; i < m.y; i++) {
        sum += linked(relay_members[i]);
    }
    return sum / f32(m.y - m.x);
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
        let m = member(k);
        if m.y > m.x {
            let t = bitcast<f32>(m.z);
            sum += cell_mean(m) * t;
            t_sum += t;
        }
    }
    if t_sum <= 0.0 {
        return;
    }
    let u = sum / t_sum;
    for (var k = r.x; k < r.x + r.y; k++) {
        let m = member(k);
        if m.y > m.x {
            let d = deviation[m.w];
            deviation[m.w] = vec4f(d.xyz + (cell_mean(m) - u) * bitcast<f32>(m.z), d.w);
        }
    }
}
