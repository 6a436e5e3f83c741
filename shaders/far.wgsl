// Far field (runtime/src/far.rs; prm_precompute::far; twin: prm_runtime::cpu::far_sources and
// far_field). sources_main, one workgroup: phi_j = flux_j x deviation_j per entry, the sum of
// the light the surfaces reflect onto the level (luminance(flux_j) x deviation_j.w x stay_j,
// deviation_j.w the near pass's luminance(E_j)), the count over the stable threshold, the
// threshold (far_threshold; past the cap, by bisection), and the entries over it, ascending: their
// entries in source_sees' index (source_entry; their number at FAR_SOURCES), their records in
// deviation (record: phi, then the whole flux flux_j E_j with the slot of the sighted light
// that lights the cell up close, lit_by, or APART where its light lands apart, or NO_LIGHT).
// sees_main, one invocation per (source, block of 32 entries): which entries of the block see
// the source, a word of source_sees (row s of blocks() words: bit r of word a, entry 32 a + r
// sees source s; prm::prm_file::Far::sees), so that far_main reads one bit per neighbour.
// far_main, one invocation per far texel: sum over the sources of
// phi share V cos_x cos_j / (pi r² max(r², size²)), r to the cell's centroid, added to the
// texel's near_sum slot (written when the slot is past the near field's own texels), and for a
// source lit up close, its whole flux times (what the texel sees of that light from its eye, its cube of
// shadow maps, looked up once a texel, from where it lands, less V from the centroid), and for
// one whose light lands apart (tag APART) the same with V for the sight; its workgroup first
// lists the sources any of its texels' neighbours sees, or that are lit up close
// (group_words), and the sum runs over those, in the same order.
// Structs, bindings, WG_LINEAR, WG_FAR_SOURCES, FAR_SOURCES, FAR_SOURCE_SCALE, HOT_REACH,
// NO_LIGHT, CLOSE_SIGHTS, CONE_REACH, luminance, far_share: the generated prelude; cube_visibility:
// lights.wgsl.
//
// deviation: [0, N) the near pass's deviations, [N, 2N) the entries' irradiance E_j (rgb),
// then two vec4f a source (record). source_sees: FAR_SOURCES rows of blocks() words, then the
// sources' entries (index_base), their number, the number of those lit up close and theirs.

var<workgroup> reflected: array<f32, WG_FAR_SOURCES>;
var<workgroup> scan: array<u32, WG_FAR_SOURCES>;
var<workgroup> listed: u32;

fn flux_of(j: u32) -> vec3f {
    return far_entries[j].flux * deviation[j].xyz;
}

// Where source s's two vec4f lie in deviation: (phi, 0), (whole flux, bits of lit_by).
fn record(s: u32) -> u32 {
    return 2u * params.entry_count + 2u * s;
}

// Where the sources' entries start in source_sees (after the rows of bits).
fn index_base() -> u32 {
    return FAR_SOURCES * blocks();
}

// Where entry j's cell's light lands (the entry pass's, copied by the near pass after the
// records: crate::far::deviation_len), its centroid where none arrives.
fn landed_at(j: u32, centroid: vec3f) -> vec3f {
    let at = deviation[2u * params.entry_count + 2u * FAR_SOURCES + j];
    if at.w > 0.0 {
        return at.xyz;
    }
    return centroid;
}

// Which way entry j's cell's light leaves (after where it lands: crate::far::deviation_len),
// the entry's normal where none arrives.
fn leaving(j: u32, normal: vec3f) -> vec3f {
    let toward = deviation[3u * params.entry_count + 2u * FAR_SOURCES + j];
    if toward.w > 0.0 {
        return toward.xyz;
    }
    return normal;
}

// prm_runtime::cpu::lands_apart: entry j's cell's light lands more than LANDING_APART sizes
// from its centroid, or leaves turned from its normal past LANDING_TURN.
fn lands_apart(j: u32) -> bool {
    let e = far_entries[j];
    return distance(landed_at(j, e.centroid), e.centroid) > LANDING_APART * e.size
        || dot(leaving(j, e.normal), e.normal) < LANDING_TURN;
}

fn source_entry(s: u32) -> u32 {
    return source_sees[index_base() + s];
}

fn source_count() -> u32 {
    return source_sees[index_base() + FAR_SOURCES];
}

// Whether light k is one whose spots the far field sees (params.sighted_*: the first
// CLOSE_SIGHTS that light a cell up close, prm_runtime::cpu::sighted; each has a cube).
fn sighted(k: u32) -> bool {
    var bits = params.sighted_lo;
    if k >= 32u {
        bits = params.sighted_hi;
    }
    return k < 64u && ((bits >> (k % 32u)) & 1u) != 0u;
}

// prm_runtime::cpu::sight_share: how much a far texel takes a source lit up close as it sees
// the light's eye, the rest by the vote, for an eye `height` off the cell's plane.
fn sight_share(height: f32, size: f32) -> f32 {
    return min(max(HOT_REACH - height / size, 0.0), 1.0);
}

// Whether spot l's outer cone holds the point q.
fn in_cone(l: GpuLight, q: vec3f) -> bool {
    let d = q - l.position;
    var to = vec3f(0.0);
    if length(d) > 0.0 {
        to = d / length(d);
    }
    return dot(l.direction, to) > l.cos_outer;
}

// prm_runtime::cpu::LightSight::lit_by: of the sighted lights, the one whose eye is nearest
// within HOT_REACH sizes of entry j's cell centroid, in front of it and (a spot) whose cone
// reaches it; its rank among the sighted lights (the slot far_main looks it up in, and
// params.sight_eyes holds its eye in), or NO_LIGHT.
fn lit_by(j: u32) -> u32 {
    let e = far_entries[j];
    var best = NO_LIGHT;
    var best_d = HOT_REACH * e.size;
    var rank = 0u;
    for (var k = 0u; k < params.light_count && rank < CLOSE_SIGHTS; k++) {
        if !sighted(k) {
            continue;
        }
        let l = lights[k];
        // From the light's eye (prm_runtime::cpu::sight_eye; its cube is there).
        let eye = params.sight_eyes[rank].xyz;
        let d = distance(eye, e.centroid);
        var reaches = d < best_d && dot(e.normal, eye - e.centroid) > 0.0;
        if reaches && l.kind == KIND_SPOT {
            // The outer cone reaches CONE_REACH sizes of the centroid (prm_runtime::cpu::up_close).
            let r = e.size * CONE_REACH;
            let c = e.centroid;
            let toward = dot(l.direction, e.normal);
            var u = l.direction - e.normal * toward;
            var on_axis = false;
            if toward < 0.0 {
                let hit = l.position + l.direction * (dot(c - l.position, e.normal) / toward);
                u = hit - c;
                on_axis = length(u) <= r;
            }
            if length(u) > 1e-6 {
                u = u / length(u);
            } else {
                u = vec3f(0.0);
            }
            let v = cross(e.normal, u);
            reaches = on_axis || in_cone(l, c) || in_cone(l, c + u * r) || in_cone(l, c + v * r)
                || in_cone(l, c - v * r);
        }
        if reaches {
            best = rank;
            best_d = d;
        }
        rank++;
    }
    return best;
}

// How many entries' deviation fluxes exceed t in luminance, the same in every invocation of
// sources_main's workgroup (summed in scan, which is free again on return).
fn count_over(lid: u32, t: f32) -> u32 {
    var c = 0u;
    for (var j = lid; j < params.entry_count; j += WG_FAR_SOURCES) {
        c += u32(luminance(abs(flux_of(j))) > t);
    }
    scan[lid] = c;
    workgroupBarrier();
    for (var stride = WG_FAR_SOURCES / 2u; stride > 0u; stride /= 2u) {
        if lid < stride {
            scan[lid] += scan[lid + stride];
        }
        workgroupBarrier();
    }
    let count = workgroupUniformLoad(&scan[0]);
    workgroupBarrier();
    return count;
}

@compute @workgroup_size(WG_FAR_SOURCES)
fn sources_main(@builtin(local_invocation_index) lid: u32) {
    let n = params.entry_count;
    var r = 0.0;
    for (var j = lid; j < n; j += WG_FAR_SOURCES) {
        r += luminance(far_entries[j].flux) * deviation[j].w * far_entries[j].stay;
    }
    reflected[lid] = r;
    if lid == 0u {
        listed = 0u;
    }
    workgroupBarrier();
    for (var stride = WG_FAR_SOURCES / 2u; stride > 0u; stride /= 2u) {
        if lid < stride {
            reflected[lid] += reflected[lid + stride];
        }
        workgroupBarrier();
    }
    // prm_runtime::cpu::far_threshold: the stable threshold unless too many are over it.
    let stable = reflected[0] / FAR_SOURCE_SCALE;
    var threshold = stable;
    if count_over(lid, stable) > FAR_SOURCES {
        // The (FAR_SOURCES + 1)-th largest magnitude, the least value no more than
        // FAR_SOURCES exceed, so the cap is filled: bisection over the bits of non-negative
        // f32s, which order as their values do (31 halvings of the range reach it).
        var lo = bitcast<u32>(stable);
        var hi = 0x7f800000u;
        for (var step = 0u; step < 32u; step++) {
            let mid = lo + (hi - lo) / 2u;
            let count = count_over(lid, bitcast<f32>(mid));
            if hi - lo > 1u {
                if count <= FAR_SOURCES {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
        }
        threshold = bitcast<f32>(hi);
    }
    workgroupBarrier();
    for (var start = 0u; start < n; start += WG_FAR_SOURCES) {
        let j = start + lid;
        var keep = 0u;
        var phi = vec3f(0.0);
        if j < n {
            phi = flux_of(j);
            keep = u32(luminance(abs(phi)) > threshold);
        }
        scan[lid] = keep;
        workgroupBarrier();
        // Inclusive prefix sum (Hillis-Steele).
        for (var off = 1u; off < WG_FAR_SOURCES; off *= 2u) {
            var v = scan[lid];
            if lid >= off {
                v += scan[lid - off];
            }
            workgroupBarrier();
            scan[lid] = v;
            workgroupBarrier();
        }
        let at = listed + scan[lid] - keep;
        if keep == 1u && at < FAR_SOURCES {
            source_sees[index_base() + at] = j;
            deviation[record(at)] = vec4f(phi, 0.0);
            let whole = far_entries[j].flux * deviation[params.entry_count + j].xyz;
            var tag = lit_by(j);
            if tag == NO_LIGHT && lands_apart(j) {
                tag = APART;
            }
            deviation[record(at) + 1u] = vec4f(whole, bitcast<f32>(tag));
        }
        workgroupBarrier();
        if lid == 0u {
            listed += scan[WG_FAR_SOURCES - 1u];
        }
        workgroupBarrier();
    }
    // The records above were written by the whole workgroup.
    storageBarrier();
    if lid == 0u {
        let sources = min(listed, FAR_SOURCES);
        source_sees[index_base() + FAR_SOURCES] = sources;
        // The sources lit up close or landing apart, for far_main's second sum (few; in order).
        var lits = 0u;
        for (var s = 0u; s < sources; s++) {
            if lit(s) != NO_LIGHT {
                source_sees[index_base() + FAR_SOURCES + 2u + lits] = s;
                lits++;
            }
        }
        source_sees[index_base() + FAR_SOURCES + 1u] = lits;
    }
}

// far_visible holds prm::prm_file::Far's blocks of 32 entries: B + 1 offsets (each block's first
// pair, then the pair count P), P other blocks (ascending within a block), then 32 words per
// pair (bit c of word r: entry 32 a + r sees entry 32 b + c).
fn blocks() -> u32 {
    return (params.entry_count + 31u) / 32u;
}

// One invocation per (source, block), in rows of at most 32768 workgroups: FAR_SOURCES rows of
// blocks() words, those past the sources listed left alone (far_main never reads them).
@compute @workgroup_size(WG_LINEAR)
fn sees_main(@builtin(global_invocation_id) id: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let i = id.x + id.y * groups.x * WG_LINEAR;
    let b = blocks();
    let s = i / b;
    if s >= source_count() {
        return;
    }
    let a = i % b;
    let j = source_entry(s);
    let other = j / 32u;
    // The pair (a, other) in block a's run of pairs, whose other blocks ascend.
    let end = far_visible[a + 1u];
    var lo = far_visible[a];
    var hi = end;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if far_visible[b + 1u + mid] < other {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    var word = 0u;
    if lo < end && far_visible[b + 1u + lo] == other {
        let pairs = far_visible[b];
        for (var r = 0u; r < 32u; r++) {
            word |= ((far_visible[b + 1u + pairs + lo * 32u + r] >> (j % 32u)) & 1u) << r;
        }
    }
    // An entry sees itself.
    if other == a {
        word |= 1u << (j % 32u);
    }
    source_sees[i] = word;
}

var<workgroup> wg_count: u32;
var<workgroup> wg_flags: array<u32, WG_LINEAR>;
var<workgroup> wg_list: array<u32, WG_LINEAR>;
var<workgroup> wg_listed: u32;

// Where far_visible's per-workgroup table (runtime/src/far.rs group_words) starts: after the
// blocks' offsets, the pair count, the pairs' other blocks and their 32 words each.
fn group_table() -> u32 {
    let b = blocks();
    return b + 1u + 33u * far_visible[b];
}

// The slot of the sighted light that lights source s's cell up close (NO_LIGHT for none).
fn lit(s: u32) -> u32 {
    return bitcast<u32>(deviation[record(s) + 1u].w);
}

// The sources lit up close, listed by sources_main after the sources' entries: their number,
// then theirs, ascending.
fn lit_count() -> u32 {
    return source_sees[index_base() + FAR_SOURCES + 1u];
}

fn lit_source(i: u32) -> u32 {
    return source_sees[index_base() + FAR_SOURCES + 2u + i];
}

// Texel t's vote for source s (entry e): its neighbours' pair bits, over those that face the
// source (prm::prm_file::far_vote), as far_main's sum takes it.
fn texel_vote(t: GpuFarTexel, s: u32, e: FarEntry) -> f32 {
    let b = blocks();
    var seen = 0.0;
    var total = 0.0;
    var every = 0.0;
    for (var q = 0u; q < 4u; q++) {
        let m = t.entries[q];
        let vote = t.weights[q] * f32((source_sees[s * b + m / 32u] >> (m % 32u)) & 1u);
        every += vote;
        let n = far_entries[m];
        if dot(n.normal, e.centroid - n.centroid) > 0.0 {
            seen += vote;
            total += t.weights[q];
        }
    }
    if total > 0.0 {
        return seen / total;
    }
    return every;
}

// Whether any neighbour of the workgroup's texels sees source s (group_words).
fn group_sees(s: u32, group: u32) -> bool {
    let table = group_table();
    let groups = (params.far_texel_count + WG_LINEAR - 1u) / WG_LINEAR;
    let pairs = table + groups + 1u;
    let b = blocks();
    for (var p = far_visible[table + group]; p < far_visible[table + group + 1u]; p++) {
        if (source_sees[s * b + far_visible[pairs + 2u * p]] & far_visible[pairs + 2u * p + 1u]) != 0u {
            return true;
        }
    }
    return false;
}

@compute @workgroup_size(WG_LINEAR)
fn far_main(
    @builtin(global_invocation_id) id: vec3u,
    @builtin(workgroup_id) wid: vec3u,
    @builtin(local_invocation_index) lid: u32,
) {
    let k = id.x;
    let live = k < params.far_texel_count;
    let t = far_texels[min(k, params.far_texel_count - 1u)];
    if lid == 0u {
        wg_count = source_count();
    }
    let count = workgroupUniformLoad(&wg_count);
    // The neighbours' cells, for which of them face a source (their bits say nothing of one
    // their own surface hides: prm_runtime::cpu's far-field vote).
    var at: array<vec3f, 4>;
    var facing: array<vec3f, 4>;
    let b = blocks();
    for (var q = 0u; q < 4u; q++) {
        let m = far_entries[t.entries[q]];
        at[q] = m.centroid;
        facing[q] = m.normal;
    }
    var sum = vec3f(0.0);
    for (var start = 0u; start < count; start += WG_LINEAR) {
        // The workgroup lists, in order, the sources of this run that some neighbour of its
        // texels sees (a prefix sum over the run), and each texel sums over those alone.
        let s0 = start + lid;
        let seen0 = u32(s0 < count && group_sees(s0, wid.x));
        wg_flags[lid] = seen0;
        workgroupBarrier();
        for (var off = 1u; off < WG_LINEAR; off *= 2u) {
            var v = wg_flags[lid];
            if lid >= off {
                v += wg_flags[lid - off];
            }
            workgroupBarrier();
            wg_flags[lid] = v;
            workgroupBarrier();
        }
        if seen0 == 1u {
            wg_list[wg_flags[lid] - 1u] = s0;
        }
        if lid == WG_LINEAR - 1u {
            wg_listed = wg_flags[lid];
        }
        let n = workgroupUniformLoad(&wg_listed);
        for (var i = 0u; i < n && live; i++) {
            let s = wg_list[i];
            // The neighbours' votes first: a source none of them sees sends nothing, and is
            // passed over before its entry is read.
            var votes: array<f32, 4>;
            var every = 0.0;
            for (var q = 0u; q < 4u; q++) {
                let m = t.entries[q];
                votes[q] = t.weights[q] * f32((source_sees[s * b + m / 32u] >> (m % 32u)) & 1u);
                every += votes[q];
            }
            if every == 0.0 {
                continue;
            }
            let j = source_entry(s);
            let e = far_entries[j];
            let d = e.centroid - t.position;
            let cx = dot(t.normal, d);
            let cy = -dot(e.normal, d);
            if cx <= 0.0 || cy <= 0.0 {
                continue;
            }
            let share = far_share(distance(e.centroid, t.position), params.far_reach, e.size);
            if share <= 0.0 {
                continue;
            }
            let r2 = dot(d, d);
            var seen = 0.0;
            var total = 0.0;
            for (var q = 0u; q < 4u; q++) {
                if dot(facing[q], e.centroid - at[q]) > 0.0 {
                    seen += votes[q];
                    total += t.weights[q];
                }
            }
            var v = every;
            if total > 0.0 {
                v = seen / total;
            }
            sum += deviation[record(s)].xyz * (share * v * cx * cy / (PI * r2 * max(r2, e.size * e.size)));
        }
        workgroupBarrier();
    }
    // The sources lit up close or landing apart, in a second sum: their whole flux from where
    // it lands on the cell, the way it leaves, times what the texel sees of the light that
    // lights it up close (its cube of shadow maps, looked up once a texel) or (apart) the vote;
    // less their whole flux times the vote from the centroid (prm_runtime::cpu::far_field).
    // Inside the sum above the lookups doubled the pass on lavapipe, and even a branch there
    // that never ran slowed it by a tenth.
    let lits = lit_count();
    if lits > 0u && live {
        var sights = vec4f(0.0);
        var sighted_at = array<vec3f, CLOSE_SIGHTS>();
        var slot = 0u;
        for (var k = 0u; k < params.light_count && slot < CLOSE_SIGHTS; k++) {
            if sighted(k) {
                let eye = params.sight_eyes[slot].xyz;
                let seen = cube_visibility(lights[k], eye, t.position, t.normal, distance(eye, t.position));
                sights += seen * vec4f(vec4u(slot) == vec4u(0u, 1u, 2u, 3u));
                sighted_at[slot] = eye;
                slot++;
            }
        }
        for (var i = 0u; i < lits; i++) {
            let s = lit_source(i);
            let j = source_entry(s);
            let e = far_entries[j];
            let share = far_share(distance(e.centroid, t.position), params.far_reach, e.size);
            if share <= 0.0 {
                continue;
            }
            let size2 = e.size * e.size;
            let whole = deviation[record(s) + 1u];
            let tag = bitcast<u32>(whole.w);
            let v = texel_vote(t, s, e);
            var seen = v;
            if tag < CLOSE_SIGHTS {
                // The sight fades into the vote as the light stands 1 to HOT_REACH sizes off
                // the cell's plane (sight_share).
                let w = sight_share(dot(e.normal, sighted_at[tag] - e.centroid), e.size);
                seen = mix(v, dot(sights, vec4f(vec4u(tag) == vec4u(0u, 1u, 2u, 3u))), w);
            }
            let d = e.centroid - t.position;
            let cx = dot(t.normal, d);
            let cy = -dot(e.normal, d);
            if cx > 0.0 && cy > 0.0 {
                let r2 = dot(d, d);
                sum -= whole.xyz * (v * share * cx * cy / (PI * r2 * max(r2, size2)));
            }
            let dl = landed_at(j, e.centroid) - t.position;
            let lx = dot(t.normal, dl);
            let ly = -dot(leaving(j, e.normal), dl);
            if lx > 0.0 && ly > 0.0 {
                let l2 = dot(dl, dl);
                sum += whole.xyz * (seen * share * lx * ly / (PI * l2 * max(l2, size2)));
            }
        }
    }
    if !live {
        return;
    }
    if t.slot < params.near_texel_count {
        near_sum[t.slot] += vec4f(sum, 0.0);
    } else {
        near_sum[t.slot] = vec4f(sum, 0.0);
    }
}
