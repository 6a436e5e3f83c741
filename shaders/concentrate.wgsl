// How a texel sees a hot cell (prm_runtime::cpu::concentrate says why and what; the CPU twin
// computes the same). concentrate_main, one workgroup per work item (up to WG_LINEAR links of
// one entry): for each near-field link whose entry's cell is hot (a point or spot light that
// reaches it closer to its centroid than HOT_REACH x its size, or a mixed triangle in it: a shadow edge across
// it, irradiance.wgsl), link_light = (E_j kappa, this update's number; kappa 1 for a texel
// beyond NEAR_SIZES of a cell hot only by a shadow edge), kappa = per channel,
// (form-factor-kernel-weighted mean of the unshadowed irradiance over the centroids of SUB²
// sub-triangles of each cell triangle, each times its visibility: on a mixed triangle its fine
// point's bit, else the triangle's visible share) / (their area mean), the unshadowed
// irradiance on a cell no light is near being each triangle's level (irradiance.wgsl);
// SUB = CONCENTRATION_SUB on a mixed triangle and within NEAR_SIZES cell sizes of the centroid
// of a cell a light is near, else CONCENTRATION_SUB_FAR. Links of cells that are not hot are
// not written: their number stays old. (u32 words: the number kept as bits of a float could be
// a denormal, which a GPU may flush.)
// Structs, constants, bindings: the generated prelude; the lights: lights.wgsl.

// A point or spot light that reaches the cell (a reach bit of one of its triangles; a light
// past the 64th has none and is taken as reaching) closer to its centroid than HOT_REACH x
// its size.
fn near_light(h: GpuHotEntry) -> bool {
    var reach = vec2u(0u);
    for (var k = h.first_cell; k < h.first_cell + h.cell_count; k++) {
        reach |= vec2u(cells[k].reach_lo, cells[k].reach_hi);
    }
    for (var i = 0u; i < params.light_count; i++) {
        let l = lights[i];
        let reaches = i >= 64u || ((reach[i / 32u] >> (i % 32u)) & 1u) != 0u;
        if reaches && l.kind != KIND_DIRECTIONAL && distance(l.position, h.centroid) < HOT_REACH * h.size {
            return true;
        }
    }
    return false;
}

// A fine point's visibility bit (irradiance.wgsl).
fn fine_bit(t: GpuCellTriangle, q: u32) -> f32 {
    if q < 32u {
        return f32((t.fine_lo >> q) & 1u);
    }
    return f32((t.fine_hi >> (q - 32u)) & 1u);
}

// Per channel: the seen mean over the plain mean, 1 where either is undefined.
fn ratio(seen: f32, plain: f32, weight: f32, area: f32) -> f32 {
    if plain > 0.0 {
        return (seen / weight) / (plain / area);
    }
    return 1.0;
}

// lit_near: near_light(h).
fn kappa(x: vec3f, nx: vec3f, h: GpuHotEntry, lit_near: bool) -> vec3f {
    var seen = vec3f(0.0);
    var weight = 0.0;
    var plain = vec3f(0.0);
    var area_sum = 0.0;
    // Every triangle fine near a cell a light is near; near one hot only by a shadow edge, its
    // mixed triangles (prm_runtime::cpu::concentrate::concentration).
    let near = lit_near && distance(x, h.centroid) < NEAR_SIZES * h.size;
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
        let mixed = (t.fine_hi & CELL_MIXED) != 0u;
        let sub = select(CONCENTRATION_SUB_FAR, CONCENTRATION_SUB, near || mixed);
        let s = f32(sub);
        let area = 0.5 * len / (s * s);
        var q = 0u;
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
                    // Lights farther than HOT_REACH cell sizes: the triangle's unshadowed
                    // level (irradiance.wgsl) stands for them.
                    var e = t.level;
                    if lit_near {
                        e = vec3f(0.0);
                        for (var i = 0u; i < params.light_count; i++) {
                            // Only the lights that reach the triangle (irradiance.wgsl).
                            let bits = select(t.reach_lo, t.reach_hi, i >= 32u);
                            if ((bits >> (i % 32u)) & 1u) == 0u {
                                continue;
                            }
                            let inc = incident(lights[i], y);
                            e += inc.irradiance * max(dot(n, inc.to_light), 0.0);
                        }
                    }
                    var v = t.visibility;
                    if mixed {
                        v = fine_bit(t, q);
                    }
                    q++;
                    e *= v * area;
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

// The texel of link i: the last whose links start at or before it (links are stored texel by
// texel).
fn texel_of(i: u32) -> u32 {
    var lo = 0u;
    var hi = params.near_texel_count - 1u;
    while lo < hi {
        let mid = (lo + hi + 1u) / 2u;
        if near_texels[mid].first <= i {
            lo = mid;
        } else {
            hi = mid - 1u;
        }
    }
    return lo;
}

// The links of this work item that take kappa: (link, texel).
var<workgroup> seen_links: array<vec2u, WG_LINEAR>;
var<workgroup> seen_count: atomic<u32>;

// The work items of the hot cells, in link_ids after the links (at params.link_count: their
// count, the concentration's dispatch in three words, then per item the entry and the first
// of its links within the entry's run, at most WG_LINEAR links an item), listed anew each
// update in any order: one invocation per entry with links. So the concentration's
// workgroups are those of hot cells, not one for every WG_LINEAR links of the level.
@compute @workgroup_size(WG_LINEAR)
fn hot_items_main(@builtin(global_invocation_id) id: vec3u) {
    let j = id.x;
    if j >= params.entry_count || params.near_texel_count == 0u {
        return;
    }
    let h = hot_entries[j];
    if h.link_count == 0u {
        return;
    }
    // w: the entry pass's flags (irradiance.wgsl).
    let flags = u32(entry_irradiance[j].w);
    if (flags & ENTRY_EDGE) == 0u && !near_light(h) {
        return;
    }
    if (flags & ENTRY_UNCHANGED) != 0u {
        // Hot now and at its last run, with the same light: each link's light is what it was,
        // made this update's here, with no work items (a workgroup for every WG_LINEAR links
        // of every kept hot cell of the level was most of the pass on the 16 chambers).
        for (var k = 0u; k < h.link_count; k++) {
            link_light[atomicLoad(&link_ids[h.first_link + k])].w = params.frame;
        }
        return;
    }
    let n = (h.link_count + WG_LINEAR - 1u) / WG_LINEAR;
    let list = params.link_count;
    let at = atomicAdd(&link_ids[list], n);
    for (var k = 0u; k < n; k++) {
        atomicStore(&link_ids[list + 4u + 2u * (at + k)], j);
        atomicStore(&link_ids[list + 5u + 2u * (at + k)], k * WG_LINEAR);
    }
}

// The concentration's dispatch for the items listed: rows of at most 32768 workgroups (the
// limit is 65535), none when no cell is hot.
@compute @workgroup_size(1)
fn hot_args_main() {
    let list = params.link_count;
    let n = atomicLoad(&link_ids[list]);
    atomicStore(&link_ids[list + 1u], min(n, 32768u));
    atomicStore(&link_ids[list + 2u], (n + 32767u) / 32768u);
    atomicStore(&link_ids[list + 3u], 1u);
}

// One workgroup per work item of a hot cell (hot_items_main), in rows of at most 32768
// workgroups: a hot cell's links that take kappa are gathered first so that the group's
// invocations compute one each side by side (they cost alike: one cell). Per link (the old
// way) most invocations of a group found cold cells and waited on the one that found a hot
// cell.
@compute @workgroup_size(WG_LINEAR)
fn concentrate_main(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wg: vec3u,
    @builtin(num_workgroups) groups: vec3u,
) {
    let item = wg.x + wg.y * groups.x;
    let list = params.link_count;
    if item >= atomicLoad(&link_ids[list]) {
        return;
    }
    let j = atomicLoad(&link_ids[list + 4u + 2u * item]);
    let first = atomicLoad(&link_ids[list + 5u + 2u * item]);
    let h = hot_entries[j];
    let lit_near = near_light(h);
    // Entries kept since their last run are not listed (hot_items_main).
    let e = entry_irradiance[j];
    if lid == 0u {
        atomicStore(&seen_count, 0u);
    }
    workgroupBarrier();
    let k = first + lid;
    if k < h.link_count {
        let i = atomicLoad(&link_ids[h.first_link + k]);
        let t = texel_of(i);
        // A cell hot only by a shadow edge: a texel beyond NEAR_SIZES sees it under a kernel
        // that varies little, so at its mean (kappa 1).
        if lit_near || distance(near_texels[t].position, h.centroid) < NEAR_SIZES * h.size {
            seen_links[atomicAdd(&seen_count, 1u)] = vec2u(i, t);
        } else {
            link_light[i] = vec4u(bitcast<vec3u>(e.xyz), params.frame);
        }
    }
    workgroupBarrier();
    let n = atomicLoad(&seen_count);
    if lid < n {
        let p = seen_links[lid];
        let t = near_texels[p.y];
        let light = e.xyz * kappa(t.position, t.normal, h, lit_near);
        link_light[p.x] = vec4u(bitcast<vec3u>(light), params.frame);
    }
}
