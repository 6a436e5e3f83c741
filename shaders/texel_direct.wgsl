// Direct light at the radiosity's texels (runtime/src/radiosity.rs, `RadiosityPass::light_texels`;
// the CPU twin is prm_runtime::cpu::radiosity::sender_direct, ray traced): one invocation per
// texel, the mean direct irradiance over the texel's shape under its object's pose. Per light,
// the unshadowed part is exact: the power the light delivers to the shape (triangle_power,
// lights.wgsl, over a fan of its triangles) over its area, scaled by the shape's visible share
// from the shadow maps (the irradiance-weighted mean of the visibility at its centroid and the
// points halfway from it to each vertex). A texel without a shape: the irradiance at its
// point. Structs and bindings: the generated prelude.

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
    if len < 3u || !(t.shape_area > 0.0) {
        direct[k] = vec4f(direct_irradiance(posed(t, t.position), n, params.light_count), 0.0);
        return;
    }
    var v: array<vec3f, 7>;
    var c = vec3f(0.0);
    for (var i = 0u; i < len; i++) {
        v[i] = posed(t, shapes[8u * k + i].xyz);
        c += v[i];
    }
    c /= f32(len);
    var sum = vec3f(0.0);
    for (var li = 0u; li < params.light_count; li++) {
        let l = lights[li];
        var power = vec3f(0.0);
        for (var m = 1u; m + 1u < len; m++) {
            if dot(cross(v[m] - v[0], v[m + 1u] - v[0]), n) < 0.0 {
                power += triangle_power(l, v[0], v[m + 1u], v[m]);
            } else {
                power += triangle_power(l, v[0], v[m], v[m + 1u]);
            }
        }
        if all(power == vec3f(0.0)) {
            continue;
        }
        var seen = 0.0;
        var total = 0.0;
        for (var i = 0u; i <= len; i++) {
            var p = c;
            if i > 0u {
                p = mix(c, v[i - 1u], 0.5);
            }
            let inc = incident(l, p);
            let w = luminance(inc.irradiance) * dot(n, inc.to_light);
            if !(w > 0.0) {
                continue;
            }
            total += w;
            seen += w * visibility(l, p, n, inc.distance);
        }
        if total > 0.0 {
            sum += power / t.shape_area * (seen / total);
        }
    }
    direct[k] = vec4f(sum, 0.0);
}
