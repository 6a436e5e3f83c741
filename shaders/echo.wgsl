// The near field's echo (runtime/src/near.rs, prm_runtime::cpu::echo_bounce): two bounces of
// the near field's own irradiance between the near points. echo_cells_main, one invocation per
// entry: over the points of its cell (echo_cells[j] = first, end of its texels' points, end of
// its crease points in echo_cell_points), the mean of their expected light (near.wgsl's, at
// near_sum[near_expected_at + x]), which it then takes from each of them; echo_runs[x].z is the
// point's cell (NO_CELL: none). echo_first_main, one invocation per point: echo_sum = sum over
// its links of factor x (near_sum(source) + that difference, where the source has a cell):
// what the walks took at the source was its cell's mean (prm_runtime::cpu::echo_input). echo_second_main:
// near_sum += echo_sum + sum over its links of factor x echo_sum(source); it reads only
// echo_sum, so writing its own near_sum races with nothing. factor = albedo(source) x the form
// factor to the source's texel square. Structs, bindings, WG_LINEAR: the generated prelude.

@compute @workgroup_size(WG_LINEAR)
fn echo_cells_main(@builtin(global_invocation_id) id: vec3u) {
    let j = id.x;
    if j >= arrayLength(&echo_cells) {
        return;
    }
    let cell = echo_cells[j];
    if cell.y == cell.x {
        return;
    }
    let at = params.near_expected_at;
    var mean = vec3f(0.0);
    for (var i = cell.x; i < cell.y; i++) {
        mean += near_sum[at + echo_cell_points[i]].xyz;
    }
    mean /= f32(cell.y - cell.x);
    for (var i = cell.x; i < cell.z; i++) {
        let x = at + echo_cell_points[i];
        near_sum[x] = vec4f(near_sum[x].xyz - mean, 0.0);
    }
}

@compute @workgroup_size(WG_LINEAR)
fn echo_first_main(@builtin(global_invocation_id) id: vec3u) {
    let y = id.x;
    if y >= params.near_texel_count {
        return;
    }
    let run = echo_runs[y];
    var sum = vec3f(0.0);
    for (var i = run.x; i < run.x + run.y; i++) {
        let l = echo_links[i];
        var d = near_sum[l.source].xyz;
        if echo_runs[l.source].z != NO_CELL {
            d += near_sum[params.near_expected_at + l.source].xyz;
        }
        sum += l.factor * d;
    }
    echo_sum[y] = vec4f(sum, 0.0);
}

@compute @workgroup_size(WG_LINEAR)
fn echo_second_main(@builtin(global_invocation_id) id: vec3u) {
    let y = id.x;
    if y >= params.near_texel_count {
        return;
    }
    let run = echo_runs[y];
    var sum = echo_sum[y].xyz;
    for (var i = run.x; i < run.x + run.y; i++) {
        let l = echo_links[i];
        sum += l.factor * echo_sum[l.source].xyz;
    }
    near_sum[y] = vec4f(near_sum[y].xyz + sum, 0.0);
}
