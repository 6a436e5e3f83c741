// How a texel sees a hot cell (prm_runtime::cpu::concentrate says why and what; the CPU twin
// computes the same). concentrate_main, one invocation per texel with near-field links: for
// each link whose entry's cell is hot (a point or spot light closer to its centroid than
// HOT_REACH x its size), link_light = (E_j kappa, this update's number), kappa = per channel,
// (form-factor-kernel-weighted mean of the unshadowed irradiance over the centroids of SUB²
// sub-triangles of each cell triangle, each times its triangle's visibility) / (their area
// mean); SUB = CONCENTRATION_SUB within NEAR_SIZES cell sizes of the centroid, else
// CONCENTRATION_SUB_FAR. Links of cells that are not hot are not written: their number stays old. (u32
// words: the number kept as bits of a float could be a denormal, which a GPU may flush.)
// Structs, constants, bindings: the generated prelude; the lights: lights.wgsl.

fn is_hot(h: GpuHotEntry) -> bool {
    for (var i = 0u; i < params.light_count; i++) {
        let l = lights[i];
        if l.kind != KIND_DIRECTIONAL && distance(l.position, h.centroid) < HOT_REACH * h.size {
            return true;
        }
    }
    return false;
}

// Per channel: the seen mean over the plain mean, 1 where either is undefined.
fn ratio(seen: f32, plain: f32, weight: f32, area: f32) -> f32 {
    if plain > 0.0 {
        return (seen / weight) / (plain / area);
    }
    return 1.0;
}

fn kappa(x: vec3f, nx: vec3f, h: GpuHotEntry) -> vec3f {
    var seen = vec3f(0.0);
    var weight = 0.0;
    var plain = vec3f(0.0);
    var area_sum = 0.0;
    let sub = select(CONCENTRATION_SUB_FAR, CONCENTRATION_SUB, distance(x, h.centroid) < NEAR_SIZES * h.size);
    let s = f32(sub);
    for (var k = h.first_cell; k < h.first_cell + h.cell_count; k++) {
        let t = cells[k];
        let e1 = t.b - t.a;
        let e2 = t.c - t.a;
        let c = cross(e1, e2);
        let len = length(c);
        if !(len > 0.0) {
            continue;
        }
        let n = c / len;
        let area = 0.5 * len / (s * s);
        for (var a = 0u; a < sub; a++) {
            for (var b = 0u; b < sub - a; b++) {
                for (var up = 0u; up < 2u; up++) {
                    let off = select(1.0 / 3.0, 2.0 / 3.0, up == 1u);
                    let fa = f32(a) + off;
                    let fb = f32(b) + off;
                    if fa + fb > s {
                        continue;
                    }
                    let y = t.a + e1 * (fa / s) + e2 * (fb / s);
                    var e = vec3f(0.0);
                    for (var i = 0u; i < params.light_count; i++) {
                        let inc = incident(lights[i], y);
                        e += inc.irradiance * max(dot(n, inc.to_light), 0.0);
                    }
                    e *= t.visibility * area;
                    plain += e;
                    area_sum += area;
                    let d = y - x;
                    let r2 = dot(d, d);
                    let g = max(dot(nx, d), 0.0) * max(-dot(n, d), 0.0) / max(r2 * r2, 1e-30);
                    seen += e * g;
                    weight += g * area;
                }
            }
        }
    }
    if !(weight > 0.0 && area_sum > 0.0) {
        return vec3f(1.0);
    }
    return vec3f(
        ratio(seen.x, plain.x, weight, area_sum),
        ratio(seen.y, plain.y, weight, area_sum),
        ratio(seen.z, plain.z, weight, area_sum),
    );
}

@compute @workgroup_size(WG_LINEAR)
fn concentrate_main(@builtin(global_invocation_id) id: vec3u) {
    let k = id.x;
    if k >= params.near_texel_count {
        return;
    }
    let t = near_texels[k];
    for (var i = t.first; i < t.first + t.count; i++) {
        let j = near_links[i].entry;
        let h = hot_entries[j];
        if !is_hot(h) {
            continue;
        }
        let e = entry_irradiance[j].xyz * kappa(t.position, t.normal, h);
        link_light[i] = vec4u(bitcast<vec3u>(e), params.frame);
    }
}
