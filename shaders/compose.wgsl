// Compose (DESIGN.md §5 step 4, runtime/src/compose.rs): the indirect lightmap is
// sum over selected clusters c of selected[c] x pane_c, read only from stored tiles.
//
// The stored tiles covering atlas tile t are records tile_ranges[t].x .. +tile_ranges[t].y
// (each names its pane). A record's texels are 8-bit intensity codes (four per u32, decoded by
// the prelude's intensity) at data_offset + slot, where slot is the texel's place among its
// atlas tile's stored texels (row-major), times the record's RGB scale.
//
// gather_main (one invocation per atlas tile) lists the stored tiles of selected panes in
// active_records[t * active_stride ..] as (weight x scale, data offset), their number in
// counts[t]; compose_main (one invocation per atlas texel) sums only those, one 16-byte
// entry and one byte each, plus the near field's sum where the texel has one, then clamped at
// 0 (runtime/src/near.rs; the far field's light is in the same sums, runtime/src/far.rs).
// Texels with neither a stored tile nor a sum are written 0.
//
// Under a local budget (params.local_k > 0; runtime/src/cpu/budget.rs is the twin) selected
// holds every cluster's weight and no group's; select_main marks, per atlas tile,
// the local_k cluster records with the largest luminance(weight) x record energy (ties to the
// earlier record: records are in pane order), and gather_main lists those, each group record
// weighted by the light of its clusters' records left out there over its own energy, and the
// dipole records of the clusters it composes.
//
// A record whose data offset has DIPOLE_RECORD set is a dipole tile (prm::prm_file::Dipoles):
// one signed code (i8 / 127) per dipole_block x dipole_block block of the tile, dipole_side a
// row; its weight in `selected` is the cluster's moment along the axis (weights.wgsl).
//
// Bindings, ComposeParams, TileRecord, ActiveRecord, NO_SLOT and the workgroup sizes: the
// generated prelude (runtime/src/contract.rs, runtime/src/compose.rs).

// counts holds three arrays: per atlas tile the records gather_main listed, then (under a
// local budget) per record the bits of its score and whether its tile composes it.
fn score_at(k: u32) -> u32 {
    return params.tile_count + k;
}

fn chosen_at(k: u32) -> u32 {
    return params.tile_count + params.record_count + k;
}

// Under a local budget, select_main (one workgroup per atlas tile) writes each record's score,
// luminance(weight) x energy for a cluster's (0 for group and dipole records), and marks the
// local_k strongest: every record above the local_k-th strongest score, and the first of those
// equal to it (in record order) up to local_k. The local_k-th score is found by bisection over
// the scores' bits, which order non-negative floats as their values: 31 counts of the tile.
var<workgroup> wg_sum: atomic<u32>;
var<workgroup> wg_total: u32;

// How many of the records r.x .. r.x + r.y score at least `bits` (uniform over the workgroup).
fn count_at_least(r: vec2u, li: u32, bits: u32) -> u32 {
    if li == 0u {
        atomicStore(&wg_sum, 0u);
    }
    workgroupBarrier();
    var n = 0u;
    for (var k = r.x + li; k < r.x + r.y; k += WG_LINEAR) {
        n += select(0u, 1u, counts[score_at(k)] >= bits);
    }
    atomicAdd(&wg_sum, n);
    workgroupBarrier();
    if li == 0u {
        wg_total = atomicLoad(&wg_sum);
    }
    return workgroupUniformLoad(&wg_total);
}

@compute @workgroup_size(WG_LINEAR)
fn select_main(
    @builtin(workgroup_id) wid: vec3u,
    @builtin(num_workgroups) groups: vec3u,
    @builtin(local_invocation_index) li: u32,
) {
    let t = wid.y * groups.x + wid.x;
    if t >= params.tile_count {
        return;
    }
    let r = tile_ranges[t];
    for (var k = r.x + li; k < r.x + r.y; k += WG_LINEAR) {
        let rec = records[k];
        var s = 0.0;
        if rec.cluster < params.cluster_count {
            s = luminance(selected[rec.cluster].xyz) * rec.energy;
        }
        counts[score_at(k)] = bitcast<u32>(max(s, 0.0));
    }
    storageBarrier();
    // kth: the local_k-th strongest score's bits (1, the least positive, when fewer are lit).
    var kth = 1u;
    if count_at_least(r, li, 1u) > params.local_k {
        // count(>= lo) >= local_k > count(>= hi) throughout.
        var lo = 1u;
        var hi = 0x7f800001u;
        for (var i = 0u; i < 32u; i++) {
            if hi - lo <= 1u {
                break;
            }
            let mid = lo + (hi - lo) / 2u;
            if count_at_least(r, li, mid) >= params.local_k {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        kth = lo;
    }
    // Records tied at kth fill what those above it leave of the budget, in record order.
    let ties = params.local_k - min(count_at_least(r, li, kth + 1u), params.local_k);
    for (var k = r.x + li; k < r.x + r.y; k += WG_LINEAR) {
        let bits = counts[score_at(k)];
        var keep = bits > kth;
        if bits == kth {
            var before = 0u;
            for (var j = r.x; j < k; j++) {
                before += select(0u, 1u, counts[score_at(j)] == kth);
            }
            keep = before < ties;
        }
        counts[chosen_at(k)] = select(0u, 1u, keep);
    }
}

fn gather_local(t: u32) {
    let r = tile_ranges[t];
    let end = r.x + r.y;
    let groups_end = params.cluster_count + params.group_count;
    var n = 0u;
    for (var k = r.x; k < end; k++) {
        let rec = records[k];
        var w = vec3f(0.0);
        if rec.cluster < params.cluster_count {
            if counts[chosen_at(k)] == 1u {
                w = selected[rec.cluster].xyz;
            }
        } else if rec.cluster < groups_end {
            if params.residual == 1u && rec.energy > 0.0 {
                let g = rec.cluster - params.cluster_count;
                var left = vec3f(0.0);
                for (var j = r.x; j < end; j++) {
                    let q = records[j];
                    if q.group == g && counts[chosen_at(j)] == 0u {
                        left += selected[q.cluster].xyz * q.energy;
                    }
                }
                w = left / rec.energy;
            }
        } else {
            let c = (rec.cluster - groups_end) / 3u;
            for (var j = r.x; j < end; j++) {
                if records[j].cluster == c {
                    if counts[chosen_at(j)] == 1u {
                        w = selected[rec.cluster].xyz;
                    }
                    break;
                }
            }
        }
        if any(w != vec3f(0.0)) {
            active_records[t * params.active_stride + n] = ActiveRecord(w * rec.scale, rec.data_offset);
            n++;
        }
    }
    counts[t] = n;
}

@compute @workgroup_size(WG_LINEAR)
fn gather_main(@builtin(global_invocation_id) id: vec3u) {
    let t = id.x;
    if t >= params.tile_count {
        return;
    }
    if params.local_k > 0u {
        gather_local(t);
        return;
    }
    let r = tile_ranges[t];
    var n = 0u;
    for (var k = r.x; k < r.x + r.y; k++) {
        let w = selected[records[k].cluster].xyz;
        if any(w != vec3f(0.0)) {
            let rec = records[k];
            active_records[t * params.active_stride + n] = ActiveRecord(w * rec.scale, rec.data_offset);
            n++;
        }
    }
    counts[t] = n;
}

@compute @workgroup_size(WG_TILE, WG_TILE)
fn compose_main(@builtin(global_invocation_id) id: vec3u) {
    if id.x >= params.atlas_width || id.y >= params.atlas_height {
        return;
    }
    let texel = slots[id.y * params.atlas_width + id.x];
    let slot = texel.x;
    var sum = vec3f(0.0);
    if slot != NO_SLOT {
        let t = (id.y / params.tile_size) * params.tiles_x + id.x / params.tile_size;
        let n = counts[t];
        let base = t * params.active_stride;
        for (var a = 0u; a < n; a++) {
            let rec = active_records[base + a];
            if (rec.data_offset & DIPOLE_RECORD) != 0u {
                let ts = params.tile_size;
                let b = params.dipole_block;
                let q = ((id.y % ts) / b) * params.dipole_side + (id.x % ts) / b;
                let i = (rec.data_offset & ~DIPOLE_RECORD) + q;
                let code = (data[i / 4u] >> (8u * (i & 3u))) & 0xffu;
                let v = max(f32(bitcast<i32>(code << 24u) >> 24u), -127.0) / 127.0;
                sum += rec.weighted_scale * v;
            } else {
                let i = rec.data_offset + slot;
                let code = (data[i / 4u] >> (8u * (i & 3u))) & 0xffu;
                sum += rec.weighted_scale * intensity(code);
            }
        }
    }
    if texel.y != NO_SLOT {
        sum += near_sum[texel.y].xyz;
    }
    // The near field and the dipole panes are signed.
    sum = max(sum, vec3f(0.0));
    textureStore(lightmap, vec2i(id.xy), vec4f(sum, 1.0));
}
