// The atlas tiles whose light may have changed since the last compose (runtime/src/tile_changes.rs
// says why and what it keeps): only they are composed again.
//
// panes_main, one invocation per pane (clusters, groups, dipole axes): whether the pane's weight
// in `selected` moved from what it was when it last counted as changed (last_selected.xyz; by
// more than params.tolerance of its magnitude), marked in last_selected.w (1: changed), keeping
// the new weight when it did.
// tiles_main, one invocation per atlas tile: CHANGED_WEIGHT in the tile's state when one of its
// records is of a changed pane.
// sums_main, one invocation per near-field sum: CHANGED_SUM in its tile's state when the sum
// moved likewise, keeping the new sum when it did.
// list_main, one invocation per atlas tile: REGATHER when a tile of the 3 x 3 around it has
// CHANGED_WEIGHT (a local budget's picks at the tile's four corners read the tiles around each);
// listed for the compose when so or when it has CHANGED_SUM itself.
// args_main, one invocation: the compose's indirect dispatch over the list.
//
// Under params.recompose_all every pane and tile counts as changed. ComposeParams, the bindings,
// the state bits and TileRecord: the generated prelude.

// Whether a channel of v moved from `last` (what it was when it last counted as changed) by more
// than params.tolerance of its magnitude (a NaN, every time); with tolerance 0, whether the bits
// differ (-0 and +0, and two denormals a GPU may flush, are changes then).
fn moved(v: vec3f, last: vec3f) -> bool {
    if params.tolerance == 0.0 {
        return any(bitcast<vec3u>(v) != bitcast<vec3u>(last));
    }
    return any(!(abs(v - last) <= params.tolerance * max(abs(v), abs(last))));
}

fn state_at(t: u32) -> u32 {
    return params.state_offset + t;
}

// The list: its length, the dispatch's three words, then the tiles.
fn list_at() -> u32 {
    return params.state_offset + params.tile_count;
}

@compute @workgroup_size(WG_LINEAR)
fn panes_main(@builtin(global_invocation_id) id: vec3u) {
    let i = id.x;
    if i >= arrayLength(&selected) {
        return;
    }
    let w = selected[i].xyz;
    let changed = params.recompose_all != 0u || moved(w, last_selected[i].xyz);
    if changed {
        last_selected[i] = vec4f(w, 1.0);
    } else {
        last_selected[i].w = 0.0;
    }
    if i == 0u {
        atomicStore(&state[list_at()], 0u);
    }
}

@compute @workgroup_size(WG_LINEAR)
fn tiles_main(@builtin(global_invocation_id) id: vec3u) {
    let t = id.x;
    if t >= params.tile_count {
        return;
    }
    var s = 0u;
    if params.recompose_all != 0u {
        s = CHANGED_WEIGHT | CHANGED_SUM;
    } else {
        let r = slots[params.atlas_width * params.atlas_height + t];
        for (var k = r.x; k < r.x + r.y; k++) {
            if last_selected[records[k].cluster].w != 0.0 {
                s = CHANGED_WEIGHT;
                break;
            }
        }
    }
    atomicStore(&state[state_at(t)], s);
}

@compute @workgroup_size(WG_LINEAR)
fn sums_main(@builtin(global_invocation_id) id: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let s = id.x + id.y * groups.x * WG_LINEAR;
    if s >= params.sum_count {
        return;
    }
    let v = near_sum[s].xyz;
    if params.recompose_all != 0u || moved(v, last_sum[s].xyz) {
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
    if weights {
        atomicOr(&state[state_at(t)], REGATHER);
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
