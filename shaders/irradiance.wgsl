// Entry irradiance (DESIGN.md §4-5, runtime/src/irradiance.rs): one invocation per entry
// point, E_j = (sum over its cell's triangles and the lights of the power the light delivers
// to the triangle times its visible share) / the entry's area. The share (prm::cell_light says
// why and how; the CPU twin runs the same steps with rays): each light's shadow maps at four
// probe points of the triangle (the fine points at its corners and its centroid); where they
// agree, what they say; where they differ, the irradiance-weighted mean over the
// CELL_FINE_SUB² fine points, and per fine point a bit says whether it receives at least half
// the light that reaches it unshadowed; where those bits differ the triangle is mixed (a
// shadow edge crosses it) and keeps them (fine_lo: points 0-31; fine_hi: points 32-35, and
// CELL_MIXED), else they are 0. Each cell triangle also keeps
// its visible share (luminance-weighted over the lights that reach it; 1 where none does), its
// unshadowed level (its power over that share and its area) and those lights' bits (reach_lo,
// reach_hi). The near field's concentration
// (concentrate.wgsl) reads them, and the w of E_j: flags, ENTRY_EDGE where one of the cell's
// triangles is mixed, ENTRY_UNCHANGED where the entry kept last update's light. After the N
// entries' irradiance, where each cell's light lands (landing()), for the far field. A light that
// changed since the last update, hidden from the whole cell then and now, cannot change it:
// such an entry is not run again (entry_hidden keeps the lights hidden at its last run). Structs, constants and bindings: the generated prelude (runtime/src/contract.rs,
// runtime/src/irradiance.rs); the power: lights.wgsl; spherical_triangle: spherical.wgsl.

// Fine point (fa, fb) of a triangle, in units of a sub-triangle's side.
fn fine_point(a: vec3f, e1: vec3f, e2: vec3f, fa: f32, fb: f32) -> vec3f {
    let s = f32(CELL_FINE_SUB);
    return a + e1 * (fa / s) + e2 * (fb / s);
}

// prm::cell_light::landing: where light l's power on triangle (a, b, c) of unit normal n lands,
// the irradiance-weighted mean point; a point or spot light nearer than LANDING_REACH longest
// edges: the mean of where LANDING_SIDE² stratified directions even in solid angle over the
// triangle meet its plane, each weighted by the light's intensity that way; else the centroid.
fn landing(l: GpuLight, a: vec3f, b: vec3f, c: vec3f, n: vec3f) -> vec3f {
    let centroid = (a + b + c) / 3.0;
    let longest = max(max(length(b - a), length(c - b)), length(a - c));
    let height = dot(n, l.position - a);
    if l.kind == KIND_DIRECTIONAL || !(height > 0.0) || distance(l.position, centroid) >= LANDING_REACH * longest {
        return centroid;
    }
    let ca = normalize(a - l.position);
    let cb = normalize(b - l.position);
    let cc = normalize(c - l.position);
    var sum = vec3f(0.0);
    var weight = 0.0;
    let side = f32(LANDING_SIDE);
    for (var i = 0u; i < LANDING_SIDE; i++) {
        for (var j = 0u; j < LANDING_SIDE; j++) {
            let s = spherical_triangle(ca, cb, cc, (f32(i) + 0.5) / side, (f32(j) + 0.5) / side);
            let down = -dot(n, s.xyz);
            if !(s.w > 0.0) || !(down > 1e-6) {
                continue;
            }
            let y = l.position + s.xyz * (height / down);
            let to = y - l.position;
            let w = luminance(incident(l, y).irradiance) * dot(to, to);
            if w > 0.0 && w < 3.4e38 {
                sum += y * w;
                weight += w;
            }
        }
    }
    if weight > 0.0 {
        return sum / weight;
    }
    return centroid;
}

// The light's unshadowed irradiance (luminance) at a point of normal n (prm::Light::irradiance).
fn point_light(l: GpuLight, y: vec3f, n: vec3f) -> f32 {
    let inc = incident(l, y);
    return luminance(inc.irradiance) * max(dot(n, inc.to_light), 0.0);
}

// Light l's visibility at point y of the triangle (a, a + e1, a + e2) of unit normal n for the
// entry pass: lights.wgsl's visibility, and where y lies within FOOTPRINT_TEXELS shadow texels
// of an edge, the least of that and the visibility at y pulled towards the centroid until it is
// that far from every edge (to the centroid on a triangle too small for that). Near its edge a
// receiver's lookup reads what the map holds beyond it: past a wall's top edge, under a ceiling
// that shades it from a low sun, nothing, and the band under the ceiling read "lit" (a room lit
// through a window: with the slope bias the sun's map had then, the entries took 1.9 % more
// power than the rays give, the lightmap 12-21 % more than the twin's). The least keeps a
// shadow, never adds light.
fn entry_visibility(l: GpuLight, y: vec3f, a: vec3f, e1: vec3f, e2: vec3f, n: vec3f) -> f32 {
    let here = visibility(l, y, n, distance(l.position, y));
    if here == 0.0 {
        return here;
    }
    var texel_world = l.texel;
    if l.kind != KIND_DIRECTIONAL {
        texel_world = l.texel * distance(l.position, y);
    }
    let margin = FOOTPRINT_TEXELS * texel_world;
    let twice = cross(e1, e2);
    let len2 = dot(twice, twice);
    let d = y - a;
    let u = dot(cross(d, e2), twice) / len2;
    let v = dot(cross(e1, d), twice) / len2;
    let lambda = vec3f(1.0 - u - v, u, v);
    // Each vertex's height over the edge opposite it.
    let height = sqrt(len2) / vec3f(length(e2 - e1), length(e2), length(e1));
    let least = min(margin / height, vec3f(1.0 / 3.0));
    var s = 1.0;
    for (var i = 0u; i < 3u; i++) {
        if lambda[i] < least[i] {
            s = min(s, (1.0 / 3.0 - least[i]) / (1.0 / 3.0 - lambda[i]));
        }
    }
    if s >= 1.0 {
        return here;
    }
    let centroid = a + (e1 + e2) / 3.0;
    let q = centroid + (y - centroid) * s;
    return min(here, visibility(l, q, n, distance(l.position, q)));
}

// The probes' verdict for one light: their mean where all lie on one side of one half, or -1
// where they differ (prm::cell_light::triangle_light).
fn probes(l: GpuLight, a: vec3f, e1: vec3f, e2: vec3f, n: vec3f) -> f32 {
    let s = f32(CELL_FINE_SUB);
    let third = 1.0 / 3.0;
    let p0 = fine_point(a, e1, e2, third, third);
    let p1 = fine_point(a, e1, e2, s - 2.0 * third, third);
    let p2 = fine_point(a, e1, e2, third, s - 2.0 * third);
    let p3 = a + (e1 + e2) / 3.0;
    let v0 = entry_visibility(l, p0, a, e1, e2, n);
    let v1 = entry_visibility(l, p1, a, e1, e2, n);
    let v2 = entry_visibility(l, p2, a, e1, e2, n);
    let v3 = entry_visibility(l, p3, a, e1, e2, n);
    let side = v0 >= 0.5;
    if (v1 >= 0.5) == side && (v2 >= 0.5) == side && (v3 >= 0.5) == side {
        return 0.25 * (v0 + v1 + v2 + v3);
    }
    return -1.0;
}

// Whether the cube of half-side `reach` around c is hidden in shadow layer `layer`: every
// corner in front of the layer's camera, and the largest depth any point of the cube has
// (reverse-Z depth falls with the distance along the layer's axis, so it is largest at the
// corner nearest the light; an orthographic depth is linear, largest at a corner too) below the
// farthest occluder of every block its lookups could read,
// 2 texels around the corners' rectangle. On a cube face (`on_cube`) a lookup comes only from
// a point inside the face's pyramid, which projects inside its map: the rectangle is clamped
// to the map, and a cube wholly off it has no lookup there. A spot or directional light's map
// must hold it all (off the map a lookup reads lit).
fn hidden_in_layer(layer: u32, c: vec3f, reach: f32, on_cube: bool) -> bool {
    let m = shadow_mats[layer];
    var lo = vec2f(3.0e38);
    var hi = vec2f(-3.0e38);
    var depth = 0.0;
    for (var k = 0u; k < 8u; k++) {
        let s = vec3f(f32(k & 1u), f32((k >> 1u) & 1u), f32((k >> 2u) & 1u)) * 2.0 - 1.0;
        let clip = m * vec4f(c + reach * s, 1.0);
        if !(clip.w > 0.0) {
            return false;
        }
        let ndc = clip.xyz / clip.w;
        let uv = ndc.xy * vec2f(0.5, -0.5) + vec2f(0.5);
        lo = min(lo, uv);
        hi = max(hi, uv);
        depth = max(depth, ndc.z);
    }
    if on_cube {
        if any(hi < vec2f(0.0)) || any(lo > vec2f(1.0)) {
            return true;
        }
        lo = max(lo, vec2f(0.0));
        hi = min(hi, vec2f(1.0));
    } else if any(lo < vec2f(0.0)) || any(hi > vec2f(1.0)) {
        return false;
    }
    let size = textureDimensions(shadow_tex).x;
    let last = i32(size) - 1;
    let t_lo = clamp(vec2i(floor(lo * f32(size) - 2.0)), vec2i(0), vec2i(last));
    let t_hi = clamp(vec2i(floor(hi * f32(size) + 2.0)), vec2i(0), vec2i(last));
    let b_lo = vec2u(t_lo) * SHADOW_BLOCKS / size;
    let b_hi = vec2u(t_hi) * SHADOW_BLOCKS / size;
    let span = b_hi - b_lo + vec2u(1u);
    if span.x * span.y > 64u {
        return false;
    }
    var farthest = 1.0;
    for (var by = b_lo.y; by <= b_hi.y; by++) {
        for (var bx = b_lo.x; bx <= b_hi.x; bx++) {
            farthest = min(farthest, textureLoad(shadow_blocks, vec2u(bx, by), layer, 0).x);
        }
    }
    // A margin for the rounding of the probes' own depths.
    return depth * (1.0 + 1e-4) + 1e-7 < farthest;
}

// Whether light l's shadow maps hide the whole sphere (c, r) (an entry's cell, its corners
// inside): every comparison a probe of any point within it could make (normal offset and 3x3
// PCF of bilinear taps, lights.wgsl) finds an occluder nearer the light, so each probe reads 0.
// Checked on the cube of side 2 x reach around it (the sphere grown by the largest normal
// offset), in every layer one of its points could look up: a spot light's one map, or each
// face of a point light's cube whose pyramid the cube may meet (a cube across two faces is
// hidden when it is in both), or each tile of a directional light's orthographic map that a
// point of the cube may pick (hidden in all; at most 2 x 2), whose normal offset is
// SUN_NORMAL_OFFSET texels of a fixed world size.
fn hidden(l: GpuLight, c: vec3f, r: f32) -> bool {
    if params.cull_hidden == 0u {
        return false;
    }
    if l.kind == KIND_DIRECTIONAL {
        let reach = (r + SUN_NORMAL_OFFSET * l.texel) * 1.001 + 1e-6 * (length(c) + r);
        // Every tile a point of the cube may pick: those its corners pick, and between.
        var t_lo = sun_tile(l, c - vec3f(reach));
        var t_hi = t_lo;
        for (var k = 1u; k < 8u; k++) {
            let s = vec3f(f32(k & 1u), f32((k >> 1u) & 1u), f32((k >> 2u) & 1u)) * 2.0 - 1.0;
            let t = sun_tile(l, c + reach * s);
            t_lo = min(t_lo, t);
            t_hi = max(t_hi, t);
        }
        if any(t_hi - t_lo > vec2u(1u)) {
            return false;
        }
        let n = u32(round(sqrt(f32(l.layers))));
        for (var ty = t_lo.y; ty <= t_hi.y; ty++) {
            for (var tx = t_lo.x; tx <= t_hi.x; tx++) {
                if !hidden_in_layer(l.first_layer + ty * n + tx, c, reach, false) {
                    return false;
                }
            }
        }
        return true;
    }
    let d = c - l.position;
    let dist = length(d);
    let reach = (r + 1.5 * l.texel * (dist + r)) * 1.001 + 1e-6 * dist;
    if l.layers != CUBE_LAYERS {
        return hidden_in_layer(l.first_layer, c, reach, false);
    }
    // The least |coordinate| over the cube, per axis.
    let least = max(abs(d) - vec3f(reach), vec3f(0.0));
    for (var face = 0u; face < 6u; face++) {
        let axis = face / 2u;
        // The cube's farthest reach along the face's axis; a point in its pyramid lies at
        // least as far along it as across both other axes.
        let along = select(d[axis], -d[axis], (face & 1u) == 1u) + reach;
        let across = max(least[(axis + 1u) % 3u], least[(axis + 2u) % 3u]);
        if along * (1.0 + 1e-4) + 1e-6 * dist < across {
            continue;
        }
        if !hidden_in_layer(l.first_layer + face, c, reach, true) {
            return false;
        }
    }
    return true;
}

@compute @workgroup_size(WG_LINEAR)
fn entry_main(@builtin(global_invocation_id) id: vec3u) {
    let j = id.x;
    if j >= params.entry_count {
        return;
    }
    let e = entries[j];
    var power = vec3f(0.0);
    // Where the light lands on the cell (prm_runtime::cpu::LinkLight::landing): each light's
    // landing on each triangle weighted by the luminance of the power it brings there.
    var landed = vec3f(0.0);
    var landed_weight = 0.0;
    // Which way it leaves (prm_runtime::cpu::LinkLight::landing_normal): the triangles' unit
    // normals, each weighted by the luminance of the power it takes (the sum of the landings'
    // weights on it).
    var leaving = vec3f(0.0);
    var any_mixed = false;
    // Bit i: light i hidden from the whole cell.
    var hid = vec2u(0u);
    var hid_count = 0u;
    if e.cell_count > 0u {
        // Unchanged: every light that changed since the last update is hidden from the whole
        // cell now and was at the last update that ran this entry (the others cast the same
        // shadow maps as then), so its triangles' light and its irradiance are what they were;
        // the concentration keeps its links' light (w + 2).
        if params.keep_unchanged != 0u {
            let changed = vec2u(params.changed_lo, params.changed_hi);
            let before = entry_hidden[j];
            var same = true;
            for (var i = 0u; i < params.light_count && same; i++) {
                let w = i / 32u;
                let bit = 1u << (i % 32u);
                if (changed[w] & bit) != 0u {
                    same = (before[w] & bit) != 0u && hidden(lights[i], e.bound_centre, e.bound_radius);
                }
            }
            if same {
                atomicAdd(&entry_stats[1], 1u);
                let old = entry_irradiance[j];
                entry_irradiance[j] = vec4f(old.xyz, f32(u32(old.w) | ENTRY_UNCHANGED));
                return;
            }
        }
        for (var i = 0u; i < params.light_count; i++) {
            if hidden(lights[i], e.bound_centre, e.bound_radius) {
                hid[i / 32u] |= 1u << (i % 32u);
                hid_count++;
            }
        }
    }
    entry_hidden[j] = hid;
    if hid_count > 0u {
        atomicAdd(&entry_stats[0], hid_count);
    }
    for (var k = e.first_cell; k < e.first_cell + e.cell_count; k++) {
        let t = cells[k];
        let e1 = t.b - t.a;
        let e2 = t.c - t.a;
        let twice_area = cross(e1, e2);
        let len = length(twice_area);
        var share = 1.0;
        var tri_power = vec3f(0.0);
        var fine_lo = 0u;
        var fine_hi = 0u;
        var reach = vec2u(0u);
        if len > 0.0 {
            let n = twice_area / len;
            var total = 0.0;
            var seen = 0.0;
            var mixed = false;
            // Per light, the probes' verdict (-1: they differ; -2: the light does not reach the
            // triangle: no unshadowed power, or no probe sees it), kept for the fine points. The
            // lights whose probes agree are summed here; the others wait for the fine points.
            var verdict: array<f32, MAX_LIGHTS>;
            for (var i = 0u; i < params.light_count; i++) {
                verdict[i] = -2.0;
                // Hidden from the whole cell: every probe would read 0.
                if ((hid[i / 32u] >> (i % 32u)) & 1u) != 0u {
                    continue;
                }
                let l = lights[i];
                let p = triangle_power(l, t.a, t.b, t.c);
                if all(p == vec3f(0.0)) {
                    continue;
                }
                let v = probes(l, t.a, e1, e2, n);
                if v == 0.0 {
                    continue;
                }
                verdict[i] = v;
                reach[i / 32u] |= 1u << (i % 32u);
                if v < 0.0 {
                    mixed = true;
                    continue;
                }
                tri_power += p * v;
                total += luminance(p);
                seen += luminance(p) * v;
                let w = luminance(p * v);
                if w > 0.0 {
                    landed += landing(l, t.a, t.b, t.c, n) * w;
                    landed_weight += w;
                }
            }
            if mixed {
                // Per fine point, every light's unshadowed light and what arrives.
                var all_at: array<f32, CELL_FINE_POINTS>;
                var lit_at: array<f32, CELL_FINE_POINTS>;
                for (var i = 0u; i < params.light_count; i++) {
                    let l = lights[i];
                    let uniform = verdict[i];
                    if uniform == -2.0 {
                        continue;
                    }
                    var e_sum = 0.0;
                    var ev_sum = 0.0;
                    var v_sum = 0.0;
                    var q = 0u;
                    for (var a = 0u; a < CELL_FINE_SUB; a++) {
                        for (var b = 0u; b < CELL_FINE_SUB - a; b++) {
                            for (var up = 0u; up < 2u; up++) {
                                if up == 1u && a + b + 1u == CELL_FINE_SUB {
                                    continue;
                                }
                                let off = select(1.0 / 3.0, 2.0 / 3.0, up == 1u);
                                let y = fine_point(t.a, e1, e2, f32(a) + off, f32(b) + off);
                                let ey = point_light(l, y, n);
                                var v = uniform;
                                if uniform < 0.0 {
                                    v = entry_visibility(l, y, t.a, e1, e2, n);
                                }
                                all_at[q] += ey;
                                lit_at[q] += ey * v;
                                e_sum += ey;
                                ev_sum += ey * v;
                                v_sum += v;
                                q++;
                            }
                        }
                    }
                    if uniform < 0.0 {
                        let p = triangle_power(l, t.a, t.b, t.c);
                        var v = v_sum / f32(CELL_FINE_POINTS);
                        if e_sum > 0.0 {
                            v = ev_sum / e_sum;
                        }
                        tri_power += p * v;
                        total += luminance(p);
                        seen += luminance(p) * v;
                        let w = luminance(p * v);
                        if w > 0.0 {
                            landed += landing(l, t.a, t.b, t.c, n) * w;
                            landed_weight += w;
                        }
                    }
                }
                var bits = vec2u(0u);
                for (var q = 0u; q < CELL_FINE_POINTS; q++) {
                    if lit_at[q] >= 0.5 * all_at[q] {
                        bits[q / 32u] |= 1u << (q % 32u);
                    }
                }
                // A shadow edge is where the bits differ; all alike, the triangle takes its
                // share everywhere (prm::cell_light::triangle_light).
                let all_set = vec2u(~0u, (1u << (CELL_FINE_POINTS - 32u)) - 1u);
                if any(bits != vec2u(0u)) && any(bits != all_set) {
                    fine_lo = bits.x;
                    fine_hi = bits.y | CELL_MIXED;
                    any_mixed = true;
                }
            }
            if total > 0.0 {
                share = seen / total;
            }
        }
        power += tri_power;
        if len > 0.0 {
            leaving += (twice_area / len) * luminance(tri_power);
        }
        // The unshadowed level the concentration spreads by the visibility where no light is
        // near (prm_runtime::cpu::concentrate::unshadowed_level).
        var level = vec3f(0.0);
        if len > 0.0 && share > 0.0 {
            level = tri_power / (share * 0.5 * len);
        }
        cells[k].visibility = share;
        cells[k].level = level;
        cells[k].fine_lo = fine_lo;
        cells[k].fine_hi = fine_hi;
        cells[k].reach_lo = reach.x;
        cells[k].reach_hi = reach.y;
    }
    // w: ENTRY_EDGE where a shadow edge crosses the cell (a mixed triangle), for the
    // concentration.
    entry_irradiance[j] = vec4f(power * e.inv_area, f32(select(0u, ENTRY_EDGE, any_mixed)));
    // After the entries: where the light lands, w 1 (0: none arrives; the far field then takes
    // the cell's centroid).
    // Then which way it leaves, w 1 (0: none arrives; the far field then takes the entry's
    // normal).
    var at = vec4f(0.0);
    var toward = vec4f(0.0);
    if landed_weight > 0.0 {
        at = vec4f(landed / landed_weight, 1.0);
        if length(leaving) > 0.0 {
            toward = vec4f(normalize(leaving), 1.0);
        }
    }
    entry_irradiance[params.entry_count + j] = at;
    entry_irradiance[2u * params.entry_count + j] = toward;
}
