// Compose (DESIGN.md §5 step 4, runtime/src/compose.rs): the indirect lightmap is
// sum over selected clusters c of selected[c] x pane_c, read only from stored tiles.
//
// The stored tiles covering atlas tile t are records tile_range(t).x .. +tile_range(t).y
// (each names its pane). A record's texels are 8-bit intensity codes (four per u32, decoded by
// the prelude's intensity) at data_offset + slot, where slot is the texel's place among its
// atlas tile's stored texels (row-major), times the record's RGB scale.
//
// gather_main (one invocation per atlas tile) lists the stored tiles of selected panes in
// active_records[tile_range(t).x ..] (the places of its own records) as (weight x scale at the tile's four corners, data
// offset), their number in counts[t]; compose_main (one invocation per listed tile's texel) sums only
// those, one entry (its four corners blended at the texel, or the first alone when they are
// equal) and one byte each, plus the near field's sum where the texel has one, then clamped at
// 0 (runtime/src/near.rs; the far field's light is in the same sums, runtime/src/far.rs).
// Texels with neither a stored tile nor a sum are written 0.
//
// Only what may have changed since the last compose is worked again (runtime/src/tile_changes.rs
// marks it): select_main at the vertices beside a tile with CHANGED_WEIGHT, gather_main at the
// tiles with REGATHER, compose_main at the listed tiles; the rest keeps what it holds.
//
// Under a local budget (params.local_k > 0; runtime/src/cpu/budget.rs is the twin) selected
// holds every cluster's weight and no group's, and each pane's weight is chosen at the
// vertices of the atlas tile grid, then blended bilinearly over each tile from its four
// corners (no step where neighbouring tiles pick differently). select_main (one workgroup per
// vertex) takes the panes stored in the up-to-four tiles around the vertex, each pane's energy
// summed over them, and keeps the local_k clusters with the largest |luminance(weight)| x energy
// (ties to the lower pane; the local_k-th score found a byte at a time by histograms of the
// scores' bits, which order non-negative floats as their values); a group's weight there is the light of its
// clusters left out over its own energy. It writes
// each record's weight at that corner of its tile; gather_main lists the records weighed at
// any corner, and compose_main blends the four.
//
// Bindings, ComposeParams, TileRecord, ActiveRecord, NO_SLOT and the workgroup sizes: the
// generated prelude (runtime/src/contract.rs, runtime/src/compose.rs).

// counts holds, after the per-tile record counts gather_main writes, CORNER_WORDS words per
// record and corner of its tile ((0,0), (1,0), (0,1), (1,1)), for the vertex there: the state
// of the pane if the record stands for it there (TileRecord::owner; 1: not kept, 2: kept), and
// the bits of the pane's weight at the vertex (3 words). Other records read their pane's
// owner's words. From params.state_offset: each atlas tile's state, then the list of tiles to
// compose (runtime/src/tile_changes.rs).

// Atlas tile t's run of records (first, count): after the texel slots in `slots`.
fn tile_range(t: u32) -> vec2u {
    return slots[params.atlas_width * params.atlas_height + t];
}

// Code i (a byte) of the pane data, which lies in two buffers (runtime/src/compose.rs,
// split_words).
fn code_at(i: u32) -> u32 {
    let w = i / 4u;
    var word = 0u;
    if w < params.data_split {
        word = data[w];
    } else {
        word = data_hi[w - params.data_split];
    }
    return (word >> (8u * (i & 3u))) & 0xffu;
}

fn word_at(owner: u32) -> u32 {
    return params.tile_count + owner * CORNER_WORDS;
}

var<workgroup> wg_sum: atomic<u32>;
var<workgroup> wg_total: u32;
var<workgroup> wg_hist: array<atomic<u32>, 256>;
var<workgroup> wg_prefix: u32;
var<workgroup> wg_need: u32;
var<workgroup> wg_changed: u32;

// The tiles around vertex v, in the order (x-1, y-1), (x, y-1), (x-1, y), (x, y); off the grid
// an empty range. The vertex is corner 3 - slot of the tile in slot `slot`.
fn tile_around(v: u32, slot: u32) -> u32 {
    let vx = v % (params.tiles_x + 1u);
    let vy = v / (params.tiles_x + 1u);
    let tiles_y = params.tile_count / params.tiles_x;
    let x = vx + (slot & 1u);
    let y = vy + (slot >> 1u);
    if x == 0u || y == 0u || x > params.tiles_x || y > tiles_y {
        return NO_SLOT;
    }
    return (y - 1u) * params.tiles_x + x - 1u;
}

fn around(v: u32, slot: u32) -> vec2u {
    let t = tile_around(v, slot);
    if t == NO_SLOT {
        return vec2u(0u, 0u);
    }
    return tile_range(t);
}

// An atlas tile's state (runtime/src/tile_changes.rs): CHANGED_WEIGHT, CHANGED_SUM, REGATHER.
fn tile_state(t: u32) -> u32 {
    return counts[params.state_offset + t];
}

// The list of tiles to compose: its length, the dispatch's three words, then the tiles.
fn tile_list() -> u32 {
    return params.state_offset + params.tile_count;
}

// The record of `pane` in range r, or NO_SLOT (records are in pane order).
fn find(r: vec2u, pane: u32) -> u32 {
    var lo = r.x;
    var hi = r.x + r.y;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if records[mid].cluster < pane {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    if lo < r.x + r.y && records[lo].cluster == pane {
        return lo;
    }
    return NO_SLOT;
}

// The score at vertex v of record k in slot `slot`: |luminance(weight)| x the pane's energy
// around v for a cluster's record standing for its pane there, else 0. select_main keeps it in
// the record's own words for the corner (where the pane's weight goes afterwards).
fn vertex_score(k: u32, slot: u32) -> u32 {
    let corner = 3u - slot;
    let cluster = records[k].cluster;
    if records[k].owner[corner] != k * 4u + corner || cluster >= params.cluster_count {
        return 0u;
    }
    // Positive scores only (not -0 or NaN, whose bits would rank first), as the CPU's; a weight
    // the lift made negative ranks by its magnitude.
    let s = abs(luminance(selected[cluster].xyz)) * records[k].summed[corner];
    return select(0u, bitcast<u32>(s), s > 0.0);
}

fn score_at(k: u32, slot: u32) -> u32 {
    return counts[word_at(k * 4u + 3u - slot) + 1u];
}

// How many clusters around vertex v score at least `bits` (uniform over the workgroup).
fn count_at_least(v: u32, li: u32, bits: u32) -> u32 {
    if li == 0u {
        atomicStore(&wg_sum, 0u);
    }
    workgroupBarrier();
    var n = 0u;
    for (var slot = 0u; slot < 4u; slot++) {
        let r = around(v, slot);
        for (var k = r.x + li; k < r.x + r.y; k += WG_LINEAR) {
            n += select(0u, 1u, score_at(k, slot) >= bits);
        }
    }
    atomicAdd(&wg_sum, n);
    workgroupBarrier();
    if li == 0u {
        wg_total = atomicLoad(&wg_sum);
    }
    return workgroupUniformLoad(&wg_total);
}

// Whether the pane of record j (in slot s around the vertex) is kept there.
fn kept_at(j: u32, s: u32) -> bool {
    return counts[word_at(records[j].owner[3u - s])] == 2u;
}

@compute @workgroup_size(WG_LINEAR)
fn select_main(
    @builtin(workgroup_id) wid: vec3u,
    @builtin(num_workgroups) groups: vec3u,
    @builtin(local_invocation_index) li: u32,
) {
    let v = wid.y * groups.x + wid.x;
    let tiles_y = params.tile_count / params.tiles_x;
    if v >= (params.tiles_x + 1u) * (tiles_y + 1u) {
        return;
    }
    // The picks at v read only the records of the four tiles around it: when none is of a
    // changed pane, they are what the last compose found, and so are the words they fill.
    if li == 0u {
        var changed = 0u;
        for (var slot = 0u; slot < 4u; slot++) {
            let t = tile_around(v, slot);
            if t != NO_SLOT {
                changed |= tile_state(t) & CHANGED_WEIGHT;
            }
        }
        wg_changed = changed;
    }
    if workgroupUniformLoad(&wg_changed) == 0u {
        return;
    }
    for (var slot = 0u; slot < 4u; slot++) {
        let r = around(v, slot);
        for (var k = r.x + li; k < r.x + r.y; k += WG_LINEAR) {
            counts[word_at(k * 4u + 3u - slot) + 1u] = vertex_score(k, slot);
        }
    }
    storageBarrier();
    // kth: the local_k-th strongest score's bits (1, the least positive, when fewer are lit),
    // found a byte at a time from the top (the bits order non-negative floats as their values).
    var kth = 1u;
    if count_at_least(v, li, 1u) > params.local_k {
        // prefix: the bytes found so far, under mask.
        var prefix = 0u;
        var mask = 0u;
        var need = params.local_k;
        for (var round = 0u; round < 4u; round++) {
            let shift = 24u - 8u * round;
            for (var b = li; b < 256u; b += WG_LINEAR) {
                atomicStore(&wg_hist[b], 0u);
            }
            workgroupBarrier();
            for (var slot = 0u; slot < 4u; slot++) {
                let r = around(v, slot);
                for (var k = r.x + li; k < r.x + r.y; k += WG_LINEAR) {
                    let bits = score_at(k, slot);
                    if bits > 0u && (bits & mask) == prefix {
                        atomicAdd(&wg_hist[(bits >> shift) & 0xffu], 1u);
                    }
                }
            }
            workgroupBarrier();
            if li == 0u {
                // The byte whose bucket holds the need-th strongest of those left.
                var above = 0u;
                var digit = 0u;
                for (var b = 255i; b >= 0i; b--) {
                    let h = atomicLoad(&wg_hist[b]);
                    if above + h >= need {
                        digit = u32(b);
                        break;
                    }
                    above += h;
                }
                wg_prefix = prefix | (digit << shift);
                wg_need = need - above;
            }
            prefix = workgroupUniformLoad(&wg_prefix);
            need = workgroupUniformLoad(&wg_need);
            mask |= 0xffu << shift;
        }
        kth = prefix;
    }
    // Clusters tied at kth fill what those above it leave of the budget, lower panes first.
    let ties = params.local_k - min(count_at_least(v, li, kth + 1u), params.local_k);
    for (var slot = 0u; slot < 4u; slot++) {
        let r = around(v, slot);
        for (var k = r.x + li; k < r.x + r.y; k += WG_LINEAR) {
            let corner = 3u - slot;
            if records[k].owner[corner] != k * 4u + corner {
                continue;
            }
            let bits = score_at(k, slot);
            var keep = bits > kth;
            if bits == kth {
                var before = 0u;
                for (var s = 0u; s < 4u; s++) {
                    let q = around(v, s);
                    for (var j = q.x; j < q.x + q.y; j++) {
                        let lower = records[j].cluster < records[k].cluster;
                        before += select(0u, 1u, lower && score_at(j, s) == kth);
                    }
                }
                keep = before < ties;
            }
            counts[word_at(k * 4u + corner)] = select(1u, 2u, keep);
        }
    }
    storageBarrier();
    // Each pane's weight at the vertex, in the words of the record standing for it.
    for (var slot = 0u; slot < 4u; slot++) {
        let r = around(v, slot);
        for (var k = r.x + li; k < r.x + r.y; k += WG_LINEAR) {
            let corner = 3u - slot;
            let rec = records[k];
            if rec.owner[corner] != k * 4u + corner {
                continue;
            }
            var w = vec3f(0.0);
            if rec.cluster < params.cluster_count {
                w = select(vec3f(0.0), selected[rec.cluster].xyz, kept_at(k, slot));
            } else {
                // The light of the group's clusters left out, in the tiles around that store the
                // group's pane, over its energy there.
                let e = rec.summed[corner];
                if params.residual == 1u && e > 0.0 {
                    for (var s = slot; s < 4u; s++) {
                        let g = select(find(around(v, s), rec.cluster), k, s == slot);
                        if g == NO_SLOT {
                            continue;
                        }
                        for (var j = records[g].next; j != NO_SLOT; j = records[j].next) {
                            if !kept_at(j, s) {
                                w += selected[records[j].cluster].xyz * records[j].energy;
                            }
                        }
                    }
                    w /= e;
                }
            }
            let c = word_at(k * 4u + corner);
            counts[c + 1u] = bitcast<u32>(w.x);
            counts[c + 2u] = bitcast<u32>(w.y);
            counts[c + 3u] = bitcast<u32>(w.z);
        }
    }
}

fn corner_weight(k: u32, corner: u32) -> vec3f {
    let c = word_at(records[k].owner[corner]);
    return vec3f(bitcast<f32>(counts[c + 1u]), bitcast<f32>(counts[c + 2u]), bitcast<f32>(counts[c + 3u]));
}

fn gather_local(t: u32) {
    let r = tile_range(t);
    var n = 0u;
    for (var k = r.x; k < r.x + r.y; k++) {
        let s = records[k].scale;
        let w0 = corner_weight(k, 0u);
        let w1 = corner_weight(k, 1u);
        let w2 = corner_weight(k, 2u);
        let w3 = corner_weight(k, 3u);
        if any(w0 != vec3f(0.0)) || any(w1 != vec3f(0.0)) || any(w2 != vec3f(0.0)) || any(w3 != vec3f(0.0)) {
            let same = all(w0 == w1) && all(w0 == w2) && all(w0 == w3);
            let blend = select(1u, 0u, same);
            active_records[r.x + n] =
                ActiveRecord(w0 * s, records[k].data_offset, w1 * s, blend, w2 * s, 0u, w3 * s, 0u);
            n++;
        }
    }
    counts[t] = n;
}

@compute @workgroup_size(WG_LINEAR)
fn gather_main(@builtin(global_invocation_id) id: vec3u) {
    let t = id.x;
    if t >= params.tile_count || (tile_state(t) & REGATHER) == 0u {
        return;
    }
    if params.local_k > 0u {
        gather_local(t);
        return;
    }
    let r = tile_range(t);
    var n = 0u;
    for (var k = r.x; k < r.x + r.y; k++) {
        let w = selected[records[k].cluster].xyz;
        if any(w != vec3f(0.0)) {
            let ws = w * records[k].scale;
            active_records[r.x + n] = ActiveRecord(ws, records[k].data_offset, ws, 0u, ws, 0u, ws, 0u);
            n++;
        }
    }
    counts[t] = n;
}

// Dispatched over the listed tiles (runtime/src/tile_changes.rs): workgroup x is a block of
// WG_TILE x WG_TILE texels of the tile, y + 32768 z the tile's place in the list. A texel of a
// tile not listed keeps what the last compose wrote.
@compute @workgroup_size(WG_TILE, WG_TILE)
fn compose_main(@builtin(workgroup_id) wid: vec3u, @builtin(local_invocation_id) lid: vec3u) {
    let list = tile_list();
    let i = wid.y + wid.z * 32768u;
    if i >= counts[list] {
        return;
    }
    let t = counts[list + 4u + i];
    let blocks = (params.tile_size + WG_TILE - 1u) / WG_TILE;
    let inner = vec2u(wid.x % blocks, wid.x / blocks) * WG_TILE + lid.xy;
    let id = vec2u(t % params.tiles_x, t / params.tiles_x) * params.tile_size + inner;
    if inner.x >= params.tile_size || inner.y >= params.tile_size || id.x >= params.atlas_width
        || id.y >= params.atlas_height {
        return;
    }
    let texel = slots[id.y * params.atlas_width + id.x];
    let slot = texel.x;
    var sum = vec3f(0.0);
    if slot != NO_SLOT {
        let t = (id.y / params.tile_size) * params.tiles_x + id.x / params.tile_size;
        let n = counts[t];
        let base = tile_range(t).x;
        let ts = params.tile_size;
        // The texel's place in its tile, for the blend of each record's corner weights.
        let f = (vec2f(id.xy % vec2u(ts)) + 0.5) / f32(ts);
        for (var a = 0u; a < n; a++) {
            // Most records weigh the same at all four corners: read just the first.
            let data_offset = active_records[base + a].data_offset;
            var weighted_scale = active_records[base + a].c00;
            if active_records[base + a].blend != 0u {
                let rec = active_records[base + a];
                weighted_scale = mix(mix(rec.c00, rec.c10, f.x), mix(rec.c01, rec.c11, f.x), f.y);
            }
            sum += weighted_scale * intensity(code_at(data_offset + slot));
        }
    }
    if texel.y != NO_SLOT {
        sum += near_sum[texel.y].xyz;
    }
    // The near field is signed.
    sum = max(sum, vec3f(0.0));
    let rows = params.page_rows;
    textureStore(lightmap, vec2i(i32(id.x), i32(id.y % rows)), i32(id.y / rows), vec4f(sum, 1.0));
}
