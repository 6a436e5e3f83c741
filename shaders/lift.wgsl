// The near field's later bounces (runtime/src/lift.rs; twin: prm_runtime::cpu::lift_weights).
// After the near pass (near links, echo, far field into near_sum) and before the selection:
// lift_main, one invocation per cluster: u_c = sum over its members with texels of t_j n_j /
// sum t_j, n_j the mean of near_sum over the member's cell's texels, into lifted[c].
// With params.lift_power (a map with its far texels' areas), lift_main also writes per cluster
// what its cells send over every bounce, sum E_j (A/N) g_j rho_j, into lifted[C + R + 2c], and
// the near field's power over its cells' texels (area x near_sum) into lifted[C + R + 2c + 1].
// lambda_main, one workgroup per room: per channel K = sum_c w_c energy_c and L = sum_c u_c
// energy_c over the room's clusters; lambda = L / K, or with params.lift_power (energy_c then the
// pane's power P_c) (K + L - D) / K with D = the room's sent less its near power, held within
// [POWER_KEPT_LO K, POWER_KEPT_HI K]; 0 where K is 0; into lifted[C + room].
// apply_main, one per cluster: w_c = w_c (1 - lambda of its room) + u_c, signed (the twin's doc
// says why), and its score |luminance(w_c)| x energy_c.w.
// lift_tables (runtime/src/lift.rs, lift_tables): per cluster its energy (vec4 as f32 bits),
// then the rooms' words (R, each cluster's room (C), where each room's clusters start in the
// list (R + 1), the list (C, ascending within a room; prm_runtime::cpu::rooms)), then per entry
// (A/N) g rho (vec4), then per word of lift_members the area of its slot's texel.
// Bindings, IndirectParams, NO_SLOT, luminance and WG_LINEAR: the generated prelude.

fn table_vec4(at: u32) -> vec4f {
    return bitcast<vec4f>(vec4u(lift_tables[at], lift_tables[at + 1u], lift_tables[at + 2u], lift_tables[at + 3u]));
}

fn energy_of(c: u32) -> vec4f {
    return table_vec4(4u * c);
}

fn room_word(i: u32) -> u32 {
    return lift_tables[4u * params.cluster_count + i];
}

// Where the entries' (A/N) g rho start: past the energies and the rooms' 2 + 2C + R words.
fn reflect_start() -> u32 {
    return 4u * params.cluster_count + 2u + 2u * params.cluster_count + room_word(0u);
}

fn reflect_of(j: u32) -> vec3f {
    return table_vec4(reflect_start() + 4u * j).xyz;
}

fn area_at(i: u32) -> f32 {
    return bitcast<f32>(lift_tables[reflect_start() + 4u * params.entry_count + i]);
}

@compute @workgroup_size(WG_LINEAR)
fn lift_main(@builtin(global_invocation_id) id: vec3u) {
    let c = id.x;
    if c >= params.cluster_count {
        return;
    }
    let r = ranges[c];
    var sum = vec3f(0.0);
    var t_sum = 0.0;
    var sent = vec3f(0.0);
    var field = vec3f(0.0);
    for (var k = r.x; k < r.x + r.y; k++) {
        let m = vec4u(lift_members[4u * k], lift_members[4u * k + 1u], lift_members[4u * k + 2u],
            lift_members[4u * k + 3u]);
        if params.lift_power == 1u {
            sent += entry_irradiance[m.w].xyz * reflect_of(m.w);
        }
        if m.y > m.x {
            var cell = vec3f(0.0);
            for (var i = m.x; i < m.y; i++) {
                let slot = lift_members[i];
                if slot != NO_SLOT {
                    cell += near_sum[slot].xyz;
                    if params.lift_power == 1u {
                        field += area_at(i) * near_sum[slot].xyz;
                    }
                }
            }
            let t = bitcast<f32>(m.z);
            sum += cell / f32(m.y - m.x) * t;
            t_sum += t;
        }
    }
    var u = vec3f(0.0);
    if t_sum > 0.0 {
        u = sum / t_sum;
    }
    lifted[c] = vec4f(u, 0.0);
    if params.lift_power == 1u {
        let at = params.cluster_count + room_word(0u) + 2u * c;
        lifted[at] = vec4f(sent, 0.0);
        lifted[at + 1u] = vec4f(field, 0.0);
    }
}

var<workgroup> part_lifted: array<vec3f, WG_LINEAR>;
var<workgroup> part_kept: array<vec3f, WG_LINEAR>;
var<workgroup> part_power: array<vec3f, WG_LINEAR>;

fn room_of(c: u32) -> u32 {
    return room_word(1u + c);
}

// In rows of at most 32768 workgroups; those past the rooms sum nothing and write nothing.
@compute @workgroup_size(WG_LINEAR)
fn lambda_main(
    @builtin(workgroup_id) wid: vec3u,
    @builtin(num_workgroups) groups: vec3u,
    @builtin(local_invocation_index) lid: u32,
) {
    let room = wid.x + wid.y * groups.x;
    let room_count = room_word(0u);
    let starts = 1u + params.cluster_count;
    let list = starts + room_count + 1u;
    var first = 0u;
    var end = 0u;
    if room < room_count {
        first = room_word(starts + room);
        end = room_word(starts + room + 1u);
    }
    var l = vec3f(0.0);
    var k = vec3f(0.0);
    var d = vec3f(0.0);
    let sums = params.cluster_count + room_count;
    for (var i = first + lid; i < end; i += WG_LINEAR) {
        let c = room_word(list + i);
        l += lifted[c].xyz * energy_of(c).xyz;
        k += weights[c].xyz * energy_of(c).xyz;
        if params.lift_power == 1u {
            d += lifted[sums + 2u * c].xyz - lifted[sums + 2u * c + 1u].xyz;
        }
    }
    part_lifted[lid] = l;
    part_kept[lid] = k;
    part_power[lid] = d;
    workgroupBarrier();
    for (var stride = WG_LINEAR / 2u; stride > 0u; stride /= 2u) {
        if lid < stride {
            part_lifted[lid] += part_lifted[lid + stride];
            part_kept[lid] += part_kept[lid + stride];
            part_power[lid] += part_power[lid + stride];
        }
        workgroupBarrier();
    }
    if lid == 0u && room < room_count {
        let kept = part_kept[0];
        var ratio = part_lifted[0] / max(kept, vec3f(1e-30));
        if params.lift_power == 1u {
            let want = min(max(part_power[0], POWER_KEPT_LO * kept), POWER_KEPT_HI * kept);
            ratio = (kept + part_lifted[0] - want) / max(kept, vec3f(1e-30));
        }
        lifted[params.cluster_count + room] = vec4f(select(vec3f(0.0), ratio, kept > vec3f(0.0)), 0.0);
    }
}

@compute @workgroup_size(WG_LINEAR)
fn apply_main(@builtin(global_invocation_id) id: vec3u) {
    let c = id.x;
    if c >= params.cluster_count {
        return;
    }
    let lambda = lifted[params.cluster_count + room_of(c)].xyz;
    let w = weights[c].xyz * (vec3f(1.0) - lambda) + lifted[c].xyz;
    weights[c] = vec4f(w, 0.0);
    scores[c] = abs(luminance(w)) * energy_of(c).w;
}
