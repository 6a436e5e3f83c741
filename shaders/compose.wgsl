// Compose (DESIGN.md §5 step 4, runtime/src/compose.rs): the indirect lightmap is
// sum over selected clusters c of selected[c] x pane_c, read only from stored tiles.
//
// The stored tiles covering atlas tile t are records tile_ranges[t].x .. +tile_ranges[t].y
// (record_clusters holds their clusters densely). A record's texels are f16 intensities (two
// per u32) at data_offset + slot, where slot is the texel's place among its atlas tile's stored
// texels (row-major), times the record's RGB scale.
//
// gather_main (one invocation per atlas tile) lists the stored tiles of selected panes in
// active_records[t * active_stride ..] as (weight x scale, data offset), their number in
// active_count[t]; compose_main (one invocation per atlas texel) sums only those, one 16-byte
// entry and one half float each. Texels outside the stored mask are written 0.

struct Params {
    atlas_width: u32,
    atlas_height: u32,
    tile_size: u32,
    tiles_x: u32,
    tile_count: u32,
    // Most records covering one atlas tile.
    active_stride: u32,
    _pad0: u32,
    _pad1: u32,
}

struct TileRecord {
    scale: vec3f,
    cluster: u32,
    data_offset: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

struct ActiveRecord {
    // The pane's weight times the tile's colour scale.
    weighted_scale: vec3f,
    data_offset: u32,
}

const NO_SLOT: u32 = 0xffffffffu;

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> selected: array<vec4f>;
@group(0) @binding(2) var<storage, read> tile_ranges: array<vec2u>;
@group(0) @binding(3) var<storage, read> records: array<TileRecord>;
@group(0) @binding(4) var<storage, read> slots: array<u32>;
@group(0) @binding(5) var<storage, read> data: array<u32>;
@group(0) @binding(6) var lightmap: texture_storage_2d<rgba32float, write>;
@group(0) @binding(7) var<storage, read> record_clusters: array<u32>;
@group(0) @binding(8) var<storage, read_write> active_records: array<ActiveRecord>;
@group(0) @binding(9) var<storage, read_write> active_count: array<u32>;

@compute @workgroup_size(64)
fn gather_main(@builtin(global_invocation_id) id: vec3u) {
    let t = id.x;
    if t >= params.tile_count {
        return;
    }
    let r = tile_ranges[t];
    var n = 0u;
    for (var k = r.x; k < r.x + r.y; k++) {
        let w = selected[record_clusters[k]].xyz;
        if any(w != vec3f(0.0)) {
            let rec = records[k];
            active_records[t * params.active_stride + n] = ActiveRecord(w * rec.scale, rec.data_offset);
            n++;
        }
    }
    active_count[t] = n;
}

@compute @workgroup_size(8, 8)
fn compose_main(@builtin(global_invocation_id) id: vec3u) {
    if id.x >= params.atlas_width || id.y >= params.atlas_height {
        return;
    }
    let slot = slots[id.y * params.atlas_width + id.x];
    var sum = vec3f(0.0);
    if slot != NO_SLOT {
        let t = (id.y / params.tile_size) * params.tiles_x + id.x / params.tile_size;
        let n = active_count[t];
        let base = t * params.active_stride;
        for (var a = 0u; a < n; a++) {
            let rec = active_records[base + a];
            let i = rec.data_offset + slot;
            let pair = unpack2x16float(data[i / 2u]);
            sum += rec.weighted_scale * select(pair.x, pair.y, (i & 1u) == 1u);
        }
    }
    textureStore(lightmap, vec2i(id.xy), vec4f(sum, 1.0));
}
