// Direct light at the radiosity's texels (runtime/src/radiosity.rs, `RadiosityPass::light_texels`;
// the CPU twin is prm_runtime::cpu::radiosity::sender_direct, ray traced): one invocation per
// texel, the mean of the shadow-mapped direct irradiance (lights.wgsl) over the texel's shape
// (its centroid and the points halfway from it to each vertex) under its object's pose; a
// texel without a shape, at its point. Structs and bindings: the generated prelude.

fn posed(t: RadTexel, p: vec3f) -> vec3f {
    return (objects[t.object].to_world * vec4f(p, 1.0)).xyz;
}

@compute @workgroup_size(WG_LINEAR)
fn texel_direct_main(@builtin(global_invocation_id) id: vec3u) {
    let k = id.x;
    if k >= params.texels {
        return;
    }
    let t = texels[k];
    let n = normalize((objects[t.object].to_world * vec4f(t.normal, 0.0)).xyz);
    let len = u32(shapes[8u * k + 7u].x);
    if len < 3u {
        direct[k] = vec4f(direct_irradiance(posed(t, t.position), n, params.light_count), 0.0);
        return;
    }
    var c = vec3f(0.0);
    for (var i = 0u; i < len; i++) {
        c += posed(t, shapes[8u * k + i].xyz);
    }
    c /= f32(len);
    var sum = direct_irradiance(c, n, params.light_count);
    for (var i = 0u; i < len; i++) {
        sum += direct_irradiance(mix(c, posed(t, shapes[8u * k + i].xyz), 0.5), n, params.light_count);
    }
    direct[k] = vec4f(sum / f32(len + 1u), 0.0);
}
