// The near field's later bounces (runtime/src/lift.rs; twin: prm_runtime::cpu::lift_weights).
// After the near pass (near links, echo, far field into near_sum) and before the selection:
// lift_main, one invocation per cluster: u_c = sum over its members with texels of t_j n_j /
// sum t_j, n_j the mean of near_sum over the member's cell's texels, into lifted[c].
// lambda_main, one workgroup per room: per channel lambda = sum_c u_c energy_c / sum_c w_c
// energy_c over the room's clusters (energy_c in that channel: energy[c].xyz; 0 where the second
// sum is 0), into lifted[C + room]. apply_main, one per cluster: w_c = w_c (1 - lambda of its
// room) + u_c, signed (the twin's doc says why), and its score |luminance(w_c)| x energy[c].w.
// rooms holds R, then each cluster's room (C), then where each room's clusters start in the list
// (R + 1), then the list (C, ascending within a room; prm_runtime::cpu::rooms).
// Bindings, IndirectParams, NO_SLOT, luminance and WG_LINEAR: the generated prelude.

@compute @workgroup_size(WG_LINEAR)
fn lift_main(@builtin(global_invocation_id) id: vec3u) {
    let c = id.x;
    if c >= params.cluster_count {
        return;
    }
    let r = ranges[c];
    var sum = vec3f(0.0);
    var t_sum = 0.0;
    for (var k = r.x; k < r.x + r.y; k++) {
        let m = vec4u(lift_members[4u * k], lift_members[4u * k + 1u], lift_members[4u * k + 2u], 0u);
        if m.y > m.x {
            var cell = vec3f(0.0);
            for (var i = m.x; i < m.y; i++) {
                let slot = lift_members[i];
                if slot != NO_SLOT {
                    cell += near_sum[slot].xyz;
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
}

var<workgroup> part_lifted: array<vec3f, WG_LINEAR>;
var<workgroup> part_kept: array<vec3f, WG_LINEAR>;

fn room_of(c: u32) -> u32 {
    return rooms[1u + c];
}

// In rows of at most 32768 workgroups; those past the rooms sum nothing and write nothing.
@compute @workgroup_size(WG_LINEAR)
fn lambda_main(
    @builtin(workgroup_id) wid: vec3u,
    @builtin(num_workgroups) groups: vec3u,
    @builtin(local_invocation_index) lid: u32,
) {
    let room = wid.x + wid.y * groups.x;
    let room_count = rooms[0];
    let starts = 1u + params.cluster_count;
    let list = starts + room_count + 1u;
    var first = 0u;
    var end = 0u;
    if room < room_count {
        first = rooms[starts + room];
        end = rooms[starts + room + 1u];
    }
    var l = vec3f(0.0);
    var k = vec3f(0.0);
    for (var i = first + lid; i < end; i += WG_LINEAR) {
        let c = rooms[list + i];
        l += lifted[c].xyz * energy[c].xyz;
        k += weights[c].xyz * energy[c].xyz;
    }
    part_lifted[lid] = l;
    part_kept[lid] = k;
    workgroupBarrier();
    for (var stride = WG_LINEAR / 2u; stride > 0u; stride /= 2u) {
        if lid < stride {
            part_lifted[lid] += part_lifted[lid + stride];
            part_kept[lid] += part_kept[lid + stride];
        }
        workgroupBarrier();
    }
    if lid == 0u && room < room_count {
        let kept = part_kept[0];
        let ratio = part_lifted[0] / max(kept, vec3f(1e-30));
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
    scores[c] = abs(luminance(w)) * energy[c].w;
}
