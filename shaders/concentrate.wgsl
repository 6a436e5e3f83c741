// How a texel sees a hot cell (prm_runtime::cpu::concentrate says why and what; the CPU twin
// computes the same). concentrate_main, one workgroup per work item (up to WG_LINEAR links of
// one entry): for each near-field link whose entry's cell is hot (a point or spot light that
// reaches it closer to its centroid than HOT_REACH x its size, a spot's cone edge over it, or
// a mixed triangle in it: a shadow edge across it, irradiance.wgsl), link_light = (E_j kappa, this update's number; kappa 1 for a texel
// beyond NEAR_SIZES of a cell hot only by a shadow edge), kappa = per channel,
// (form-factor-kernel-weighted mean of the unshadowed irradiance over the centroids of SUB²
// sub-triangles of each cell triangle, each times its visibility: on a mixed triangle its fine
// point's bit, else the triangle's visible share) / (their area mean), the unshadowed
// irradiance on a cell no light is near being each triangle's level (irradiance.wgsl);
// SUB = CONCENTRATION_SUB on a mixed triangle and within NEAR_SIZES cell sizes of the centroid
// of a cell a light is near, else CONCENTRATION_SUB_FAR. A point or spot light near the cell
// takes footprint()'s points instead of the centroids alone, and the kernel's plain mean is
// then exact (triangle_form_factor). The kernel counts only the cell triangles the link's
// texel sees (its hidden bits, at the head of link_ids). Links of cells that are not hot are
// not written: their number stays old. (u32 words: the number kept as bits of a float could be
// a denormal, which a GPU may flush.)
// Structs, constants, bindings: the generated prelude; the lights: lights.wgsl;
// triangle_form_factor: form_factor.wgsl; solid_angle, spherical_triangle: spherical.wgsl.

// A point or spot light that reaches the cell (a reach bit of one of its triangles; a light
// past the 64th has none and is taken as reaching) and may light it unevenly (concentrates):
// x for any texel, y for a texel within BAND_SIZES of it.
fn near_light(h: GpuHotEntry) -> vec2<bool> {
    var reach = vec2u(0u);
    for (var k = h.first_cell; k < h.first_cell + h.cell_count; k++) {
        reach |= vec2u(cells[k].reach_lo, cells[k].reach_hi);
    }
    var out = vec2<bool>(false);
    for (var i = 0u; i < params.light_count; i++) {
        let reaches = i >= 64u || ((reach[i / 32u] >> (i % 32u)) & 1u) != 0u;
        if reaches {
            out = out | concentrates(lights[i], h);
            // x implies y (a band narrower than the radius is narrower than the diameter).
            if out.x {
                return out;
            }
        }
    }
    return out;
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
        return (max(seen, 0.0) / weight) / (plain / area);
    }
    return 1.0;
}

// Light i reaches triangle t (a light past the 64th has no bit: taken as reaching).
fn reaches(t: GpuCellTriangle, i: u32) -> bool {
    if i >= 64u {
        return true;
    }
    let bits = select(t.reach_lo, t.reach_hi, i >= 32u);
    return ((bits >> (i % 32u)) & 1u) != 0u;
}

// prm_runtime::cpu::concentrate::concentrates, x for any texel and y for a texel within
// BAND_SIZES of the cell: a point or spot light closer to the cell than HOT_REACH x its size,
// or a spot whose cone's edge band passes over the cell as the light sees it (a disk of radius
// the cell's size about its centroid) and is narrower than that radius (x), or than its
// diameter (y). Its light is uneven over the cell, and the footprint's points take it.
fn concentrates(l: GpuLight, h: GpuHotEntry) -> vec2<bool> {
    if l.kind == KIND_DIRECTIONAL {
        return vec2<bool>(false);
    }
    let d = distance(l.position, h.centroid);
    if d < HOT_REACH * h.size {
        return vec2<bool>(true);
    }
    if l.kind != KIND_SPOT {
        return vec2<bool>(false);
    }
    let spread = atan(h.size / d);
    let angle = acos(clamp(dot(l.direction, (h.centroid - l.position) / d), -1.0, 1.0));
    let band = acos(l.cos_outer) - acos(l.cos_inner);
    let over = angle - spread < acos(l.cos_outer) && angle + spread > acos(l.cos_inner);
    return vec2<bool>(over && spread > band, over && 2.0 * spread > band);
}

// The lights the footprint takes for a texel (close: within BAND_SIZES of the cell), as bits
// of the first 64 (taken() tests a later one itself): found once per texel, not at every point.
fn taken_bits(h: GpuHotEntry, close: bool) -> vec2u {
    var bits = vec2u(0u);
    for (var i = 0u; i < min(params.light_count, 64u); i++) {
        let c = concentrates(lights[i], h);
        if select(c.x, c.y, close) {
            bits[i / 32u] |= 1u << (i % 32u);
        }
    }
    return bits;
}

fn taken(bits: vec2u, i: u32, h: GpuHotEntry, close: bool) -> bool {
    if i >= 64u {
        let c = concentrates(lights[i], h);
        return select(c.x, c.y, close);
    }
    return ((bits[i / 32u] >> (i % 32u)) & 1u) != 0u;
}

// prm::cell_light::fine_index: the fine point whose sub-triangle holds y.
fn fine_index(t: GpuCellTriangle, y: vec3f) -> u32 {
    let e1 = t.b - t.a;
    let e2 = t.c - t.a;
    let d = y - t.a;
    let d00 = dot(e1, e1);
    let d01 = dot(e1, e2);
    let d11 = dot(e2, e2);
    let d20 = dot(d, e1);
    let d21 = dot(d, e2);
    let denom = d00 * d11 - d01 * d01;
    let s = f32(CELL_FINE_SUB);
    var fa = s / 3.0;
    var fb = s / 3.0;
    if denom > 0.0 {
        fa = (d11 * d20 - d01 * d21) / denom * s;
        fb = (d00 * d21 - d01 * d20) / denom * s;
    }
    fa = select(0.0, clamp(fa, 0.0, s), abs(fa) < 3.4e38);
    fb = select(0.0, clamp(fb, 0.0, s - fa), abs(fb) < 3.4e38);
    let a = min(u32(floor(fa)), CELL_FINE_SUB - 1u);
    let b = min(u32(floor(fb)), CELL_FINE_SUB - 1u - a);
    let down = a + b + 1u < CELL_FINE_SUB && (fa - f32(a)) + (fb - f32(b)) > 1.0;
    return a * (2u * CELL_FINE_SUB - a) + 2u * b + select(0u, 1u, down);
}

// prm_runtime::cpu::concentrate::closest_point: the point of triangle (a, b, c) nearest p.
fn closest_point(a: vec3f, b: vec3f, c: vec3f, p: vec3f) -> vec3f {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = va + vb + vc;
    if !(denom > 0.0) {
        return (a + b + c) / 3.0;
    }
    return a + ab * (vb / denom) + ac * (vc / denom);
}

struct Footprint {
    seen: vec3f,
    plain: vec3f,
}

// prm_runtime::cpu::concentrate::footprint: light l's (sum of E G dA, sum of E dA) over cell
// triangle t (unit normal n) for the texel at x (unit normal nx), from sub² area centroids
// and (sub / 2)² directions (rounded up) even in the triangle's solid angle from the light, combined by the
// balance heuristic, with the light at the triangle's point nearest x as a control within
// twice the triangle's size (kernel: the kernel's exact integral over t). One loop over both
// sets, the first sub² its centroids (sub_centroids' order), the rest the directions.
fn footprint(x: vec3f, nx: vec3f, t: GpuCellTriangle, n: vec3f, l: GpuLight, sub: u32, kernel: f32) -> Footprint {
    var out = Footprint(vec3f(0.0), vec3f(0.0));
    let height = dot(n, t.a - l.position);
    let ca = normalize(t.a - l.position);
    let cb = normalize(t.b - l.position);
    let cc = normalize(t.c - l.position);
    let omega = solid_angle(ca, cb, cc);
    if height >= 0.0 || !(omega > 0.0) {
        return out;
    }
    let mixed = (t.fine_hi & CELL_MIXED) != 0u;
    let m2 = f32(sub * sub);
    let e1 = t.b - t.a;
    let e2 = t.c - t.a;
    let cell_area = 0.5 * length(cross(e1, e2));
    let a_pt = cell_area / m2;
    let y0 = closest_point(t.a, t.b, t.c, x);
    var e0 = vec3f(0.0);
    if dot(y0 - x, y0 - x) < 4.0 * cell_area {
        let inc = incident(l, y0);
        var v0 = t.visibility;
        if mixed {
            v0 = fine_bit(t, fine_index(t, y0));
        }
        e0 = inc.irradiance * max(dot(n, inc.to_light), 0.0) * v0;
    }
    let s = f32(sub);
    // The light's points: half as many a side (prm_runtime::cpu::concentrate::light_side).
    let side = (sub + 1u) / 2u;
    let l2 = f32(side * side);
    for (var q = 0u; q < sub * sub + side * side; q++) {
        var y: vec3f;
        var k: u32;
        if q < sub * sub {
            // Centroid q: row a holds 2 (sub - a) - 1 of them, up and down by turns.
            var r = q;
            var a = 0u;
            while r >= 2u * (sub - a) - 1u {
                r -= 2u * (sub - a) - 1u;
                a++;
            }
            let off = select(1.0 / 3.0, 2.0 / 3.0, (r % 2u) == 1u);
            y = t.a + e1 * ((f32(a) + off) / s) + e2 * ((f32(r / 2u) + off) / s);
            k = select(fine_index(t, y), q, sub == CELL_FINE_SUB);
        } else {
            let p = q - sub * sub;
            let w = spherical_triangle(ca, cb, cc, (f32(p / side) + 0.5) / f32(side), (f32(p % side) + 0.5) / f32(side));
            let cos = -dot(n, w.xyz);
            if !(w.w > 0.0) || !(cos > 1e-6) {
                continue;
            }
            y = l.position + w.xyz * (-height / cos);
            k = fine_index(t, y);
        }
        let to = y - l.position;
        let dist2 = dot(to, to);
        let cos = -dot(n, to) / sqrt(dist2);
        var inv_patch = 0.0;
        if cos > 0.0 {
            inv_patch = cos * l2 / (dist2 * omega);
        }
        let wt = 1.0 / (1.0 / a_pt + inv_patch);
        let inc = incident(l, y);
        var v = t.visibility;
        if mixed {
            v = fine_bit(t, k);
        }
        let e = inc.irradiance * max(dot(n, inc.to_light), 0.0) * v;
        let d = y - x;
        let r2 = dot(d, d);
        let g = max(dot(nx, d), 0.0) * max(-dot(n, d), 0.0) / max(r2 * (r2 + wt / PI), 1e-30);
        out.seen += (e - e0) * (g * wt);
        out.plain += e * wt;
    }
    out.seen += e0 * kernel;
    return out;
}

// lit: near_light(h); link: the near-field link whose texel is at x (its hidden triangles).
fn kappa(x: vec3f, nx: vec3f, h: GpuHotEntry, lit: vec2<bool>, link: u32) -> vec3f {
    let close = distance(x, h.centroid) < BAND_SIZES * h.size;
    let lit_near = lit.x || (close && lit.y);
    var takes = vec2u(0u);
    if lit_near {
        takes = taken_bits(h, close);
    }
    var seen = vec3f(0.0);
    var weight = 0.0;
    var plain = vec3f(0.0);
    var area_sum = 0.0;
    var exact = 0.0;
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
        // A triangle the texel does not see adds its light to the plain mean only.
        let sees = select(0.0, 1.0, sees_triangle(link, k - h.first_cell));
        let mixed = (t.fine_hi & CELL_MIXED) != 0u;
        let sub = select(CONCENTRATION_SUB_FAR, CONCENTRATION_SUB, near || mixed);
        let s = f32(sub);
        let area = 0.5 * len / (s * s);
        // Near a light, the footprint takes the lights it samples and the kernel's mean is
        // exact: the centroids are needed only for the other lights that reach the triangle.
        var others = false;
        for (var i = 0u; lit_near && i < params.light_count; i++) {
            others = others || (reaches(t, i) && !taken(takes, i, h, close));
        }
        var rows = sub;
        if lit_near && !others {
            rows = 0u;
            area_sum += 0.5 * len;
        }
        var q = 0u;
        for (var a = 0u; a < rows; a++) {
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
                            // Only the lights that reach the triangle (irradiance.wgsl), and
                            // not those the footprint takes.
                            if !reaches(t, i) || taken(takes, i, h, close) {
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
                    let g = sees * max(dot(nx, d), 0.0) * max(-dot(n, d), 0.0) / max(r2 * r2, 1e-30);
                    seen += e * g;
                    weight += g * area;
                }
            }
        }
        if lit_near {
            // The kernel's integral over the part of the triangle facing x, exact (Lambert).
            var kernel = 0.0;
            if dot(n, x - t.a) > 0.0 {
                kernel = PI * triangle_form_factor(x, nx, t.a, t.b, t.c);
            }
            exact += kernel * sees;
            for (var i = 0u; i < params.light_count; i++) {
                if reaches(t, i) && taken(takes, i, h, close) {
                    let f = footprint(x, nx, t, n, lights[i], sub, kernel);
                    seen += f.seen * sees;
                    plain += f.plain;
                }
            }
        }
    }
    // Where a light is near, the kernel's mean is the exact one (the footprint's points crowd
    // where the light lands, which may be next to the texel).
    if lit_near {
        weight = exact;
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

// Where the hot cells' work list starts in link_ids: after each link's hidden triangles (two
// words) and the links by entry (prm_runtime::concentrate::work_list).
fn work_list() -> u32 {
    return 3u * params.link_count;
}

// Whether the texel of link i sees triangle q of its cell (prm::prm_file::sees_triangle).
fn sees_triangle(i: u32, q: u32) -> bool {
    if q >= 64u {
        return true;
    }
    let word = atomicLoad(&link_ids[2u * i + q / 32u]);
    return ((word >> (q % 32u)) & 1u) == 0u;
}

// The work items of the hot cells, in link_ids after the links (at work_list(): their
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
    if (flags & ENTRY_EDGE) == 0u && !near_light(h).y {
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
    let list = work_list();
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
    let list = work_list();
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
    let list = work_list();
    if item >= atomicLoad(&link_ids[list]) {
        return;
    }
    let j = atomicLoad(&link_ids[list + 4u + 2u * item]);
    let first = atomicLoad(&link_ids[list + 5u + 2u * item]);
    let h = hot_entries[j];
    let lit = near_light(h);
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
        // A cell hot only by a shadow edge, or by a spot's band for close texels alone: a
        // texel beyond NEAR_SIZES sees it under a kernel that varies little, so at its mean
        // (kappa 1).
        if lit.x || distance(near_texels[t].position, h.centroid) < NEAR_SIZES * h.size {
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
        let light = e.xyz * kappa(t.position, t.normal, h, lit, p.x);
        link_light[p.x] = vec4u(bitcast<vec3u>(light), params.frame);
    }
}
