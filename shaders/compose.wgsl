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
// active_count[t]; compose_main (one invocation per atlas texel) sums only those, one 16-byte
// entry and one byte each, plus the near field's sum where the texel has one, then clamped at
// 0 (runtime/src/near.rs; the far field's light is in the same sums, runtime/src/far.rs).
// Texels with neither a stored tile nor a sum are written 0.
//
// A record whose data offset has DIPOLE_RECORD set is a dipole tile (prm::prm_file::Dipoles):
// one signed code (i8 / 127) per dipole_block x dipole_block block of the tile, dipole_side a
// row; its weight in `selected` is the cluster's moment along the axis (weights.wgsl).
//
// Bindings, ComposeParams, TileRecord, ActiveRecord, NO_SLOT and the workgroup sizes: the
// generated prelude (runtime/src/contract.rs, runtime/src/compose.rs).

@compute @workgroup_size(WG_LINEAR)
fn gather_main(@builtin(global_invocation_id) id: vec3u) {
    let t = id.x;
    if t >= params.tile_count {
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
    active_count[t] = n;
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
        let n = active_count[t];
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
