// The atlas tiles whose light may have changed since the last compose (runtime/src/tile_changes.rs
// says why and what it keeps): only they are composed again.
//
// tiles_main, one invocation per atlas tile: CHANGED_WEIGHT in the tile's state when the weights
// in `selected` of its records' panes moved from those it was last gathered with
// (last_records): with no tolerance when a bit differs; with params.tolerance, when the light
// they move, sum over its records of luminance(|w - last|) x the pane's energy there, is more
// than that share of the light they gave, sum of luminance(|last|) x energy. The
// tile's mean light per texel goes after the list, for sums_main.
// sums_main, one invocation per near-field sum: CHANGED_SUM in its tile's state when the sum
// moved from what it was when it last counted as changed (by more than params.tolerance of its
// tile's mean light plus its own magnitude), keeping the new sum when it did.
// list_main, one invocation per atlas tile: REGATHER when a tile of the 3 x 3 around it has
// CHANGED_WEIGHT (a local budget's picks at the tile's four corners read the tiles around each),
// and then its records' weights kept in last_records (under a local budget only when it has
// CHANGED_WEIGHT itself); listed for the compose when so or when it has CHANGED_SUM itself.
// args_main, one invocation: the compose's indirect dispatch over the list.
//
// Under params.recompose_all every tile counts as changed. ComposeParams, the bindings, the
// state bits and TileRecord: the generated prelude.

// Whether a channel of v moved from `last` by more than `share` of `scale` (a NaN, every time);
// with no tolerance, whether the bits differ (-0 and +0, and two denormals a GPU may flush, are
// changes then).
fn moved_by(v: vec3f, last: vec3f, scale: vec3f) -> bool {
    if params.tolerance == 0.0 {
        return any(bitcast<vec3u>(v) != bitcast<vec3u>(last));
    }
    return any(!(abs(v - last) <= params.tolerance * scale));
}

fn state_at(t: u32) -> u32 {
    return params.state_offset + t;
}

// The list: its length, the dispatch's three words, then the tiles.
fn list_at() -> u32 {
    return params.state_offset + params.tile_count;
}

// Per tile, its mean light per texel (f32 bits), after the list.
fn light_at(t: u32) -> u32 {
    return params.state_offset + 2u * params.tile_count + 4u + t;
}

@compute @workgroup_size(WG_LINEAR)
fn tiles_main(@builtin(global_invocation_id) id: vec3u) {
    let t = id.x;
    if t == 0u {
        atomicStore(&state[list_at()], 0u);
    }
    if t >= params.tile_count {
        return;
    }
    var s = 0u;
    let r = slots[params.atlas_width * params.atlas_height + t];
    var moved = 0.0;
    var light = 0.0;
    var record_moved = false;
    for (var k = r.x; k < r.x + r.y; k++) {
        let w = selected[records[k].cluster].xyz;
        let last = last_records[k].xyz;
        let e = records[k].energy;
        if params.tolerance == 0.0 || e <= 0.0 {
            if moved_by(w, last, max(abs(w), abs(last))) {
                record_moved = true;
            }
        } else {
            moved += luminance(abs(w - last)) * e;
            light += luminance(abs(last)) * e;
        }
    }
    if params.recompose_all != 0u || record_moved || !(moved <= params.tolerance * light) {
        s = CHANGED_WEIGHT;
    }
    if params.recompose_all != 0u {
        s |= CHANGED_SUM;
    }
    atomicStore(&state[state_at(t)], s);
    atomicStore(&state[light_at(t)], bitcast<u32>(light / f32(params.tile_size * params.tile_size)));
}

@compute @workgroup_size(WG_LINEAR)
fn sums_main(@builtin(global_invocation_id) id: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let s = id.x + id.y * groups.x * WG_LINEAR;
    if s >= params.sum_count {
        return;
    }
    let v = near_sum[s].xyz;
    let last = last_sum[s].xyz;
    let tile_light = bitcast<f32>(atomicLoad(&state[light_at(sum_tiles[s])]));
    if params.recompose_all != 0u || moved_by(v, last, vec3f(tile_light) + max(abs(v), abs(last))) {
        atomicOr(&state[state_at(sum_tiles[s])], CHANGED_SUM);
        last_sum[s] = vec4f(v, 0.0);
    }
}

@compute @workgroup_size(WG_LINEAR)
fn list_main(@builtin(global_invocation_id) id: vec3u) {
    let t = id.x;
    if t >= params.tile_count {
        return;
    }
    let tiles_y = params.tile_count / params.tiles_x;
    let x = t % params.tiles_x;
    let y = t / params.tiles_x;
    var weights = false;
    for (var dy = 0u; dy < 3u; dy++) {
        for (var dx = 0u; dx < 3u; dx++) {
            let u = x + dx;
            let v = y + dy;
            if u >= 1u && v >= 1u && u <= params.tiles_x && v <= tiles_y {
                let n = atomicLoad(&state[state_at((v - 1u) * params.tiles_x + u - 1u)]);
                weights = weights || (n & CHANGED_WEIGHT) != 0u;
            }
        }
    }
    let sums = (atomicLoad(&state[state_at(t)]) & CHANGED_SUM) != 0u;
    let own = (atomicLoad(&state[state_at(t)]) & CHANGED_WEIGHT) != 0u;
    if weights {
        atomicOr(&state[state_at(t)], REGATHER);
    }
    // The weights the gather reads now, kept: under a global budget those in `selected`; under
    // a local one the words picked at the tile's four corners, which are picked again only
    // beside a tile with CHANGED_WEIGHT, so all four only when the tile has it itself (a tile
    // regathered for a neighbour keeps its older weights, and the words at its other corners
    // are within the tolerance of those).
    if (weights && params.local_k == 0u) || own {
        let r = slots[params.atlas_width * params.atlas_height + t];
        for (var k = r.x; k < r.x + r.y; k++) {
            last_records[k] = selected[records[k].cluster];
        }
    }
    if weights || sums {
        let at = atomicAdd(&state[list_at()], 1u);
        atomicStore(&state[list_at() + 4u + at], t);
    }
}

@compute @workgroup_size(1)
fn args_main() {
    let n = atomicLoad(&state[list_at()]);
    let blocks = (params.tile_size + WG_TILE - 1u) / WG_TILE;
    // A workgroup per block of WG_TILE x WG_TILE texels of a listed tile: x the block, y and z
    // the tile's place in the list, in rows of at most 32768 (the limit is 65535).
    atomicStore(&state[list_at() + 1u], blocks * blocks);
    atomicStore(&state[list_at() + 2u], min(n, 32768u));
    atomicStore(&state[list_at() + 3u], (n + 32767u) / 32768u);
}
