// Direct light at the radiosity's texels (runtime/src/radiosity.rs, `RadiosityPass::light_texels`;
// the CPU twin is prm_runtime::cpu::radiosity::sender_direct, ray traced): one invocation per
// texel, under its object's pose. Per light, the power it delivers to each part of the texel's
// shape (the triangles from its centroid to each edge; triangle_power, lights.wgsl) is exact,
// scaled by the shape's visible share from the shadow maps (the irradiance-weighted mean of the
// visibility at its centroid and the points halfway from it to each vertex). Written: the mean
// irradiance over the shape (`direct`) and each part's over it, in luminance (the w of the
// shape's vertex i, `shapes`: SenderLight::parts). A texel without a shape: the irradiance at
// its point. Structs and bindings: the generated prelude.

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
    // Power on each part (W).
    var power: array<vec3f, 7>;
    for (var li = 0u; li < params.light_count; li++) {
        let l = lights[li];
        var each: array<vec3f, 7>;
        var any_power = false;
        for (var i = 0u; i < len; i++) {
            let a = v[i];
            let b = v[(i + 1u) % len];
            // Counter-clockwise seen from the front, as triangle_power wants.
            if dot(cross(a - c, b - c), n) < 0.0 {
                each[i] = triangle_power(l, c, b, a);
            } else {
                each[i] = triangle_power(l, c, a, b);
            }
            any_power = any_power || any(each[i] != vec3f(0.0));
        }
        if !any_power {
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
            for (var i = 0u; i < len; i++) {
                power[i] += each[i] * (seen / total);
            }
        }
    }
    var sum = vec3f(0.0);
    for (var i = 0u; i < len; i++) {
        sum += power[i];
    }
    let mean = sum / t.shape_area;
    direct[k] = vec4f(mean, 0.0);
    let m = luminance(mean);
    for (var i = 0u; i < len; i++) {
        let area = 0.5 * length(cross(v[i] - c, v[(i + 1u) % len] - c));
        var ratio = 1.0;
        if m > 0.0 && area > 0.0 {
            ratio = luminance(power[i] / area) / m;
        }
        shapes[8u * k + i].w = ratio;
    }
}
