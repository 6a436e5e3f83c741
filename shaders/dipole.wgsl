// Dipole weights (prm_runtime::cpu::dipole_moments / dipole_offsets; prm::prm_file::Dipoles).
//
// moments_main, one invocation per cluster: m_k = sum over its members j of E_j coef_jk, the
// slope of the light's linear fit over the cluster along axis k, written to
// weights[C + 3 c + k] (weights.wgsl reads them for the energy balance and the selection).
// lin_main, one per entry: lin_j = sum_k m_k(c(j)) offset_jk, the fit's part of the entry's
// expected weight, written to `lin` (the near pass's deviation buffer: deviation_main in
// near.wgsl turns it into E_j - (w_c + lin_j) t_j, relay.wgsl adds to it). Structs, bindings, WG_LINEAR: the
// generated prelude.

@compute @workgroup_size(WG_LINEAR)
fn moments_main(@builtin(global_invocation_id) id: vec3u) {
    let c = id.x;
    if c >= params.cluster_count {
        return;
    }
    let r = ranges[c];
    var m0 = vec3f(0.0);
    var m1 = vec3f(0.0);
    var m2 = vec3f(0.0);
    for (var k = r.x; k < r.x + r.y; k++) {
        let d = dipole_members[k];
        let e = entry_irradiance[bitcast<u32>(d.w)].xyz;
        m0 += e * d.x;
        m1 += e * d.y;
        m2 += e * d.z;
    }
    let base = params.cluster_count + 3u * c;
    weights[base] = vec4f(m0, 0.0);
    weights[base + 1u] = vec4f(m1, 0.0);
    weights[base + 2u] = vec4f(m2, 0.0);
}

@compute @workgroup_size(WG_LINEAR)
fn lin_main(@builtin(global_invocation_id) id: vec3u) {
    let j = id.x;
    if j >= params.entry_count {
        return;
    }
    let d = entry_dipole[j];
    let base = params.cluster_count + 3u * bitcast<u32>(d.w);
    let l = weights[base].xyz * d.x + weights[base + 1u].xyz * d.y + weights[base + 2u].xyz * d.z;
    lin[j] = vec4f(l, 0.0);
}
