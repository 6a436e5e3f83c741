// The near field's echo (runtime/src/near.rs, prm_runtime::cpu::echo_bounce): two bounces of
// the near field's own irradiance between the near points. echo_first_main, one invocation per
// point: echo_sum = sum over its links of factor x near_sum(source). echo_second_main:
// near_sum += echo_sum + sum over its links of factor x echo_sum(source); it reads only
// echo_sum, so writing its own near_sum races with nothing. factor = albedo(source) x the form
// factor to the source's texel square. Structs, bindings, WG_LINEAR: the generated prelude.

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
        sum += l.factor * near_sum[l.source].xyz;
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
