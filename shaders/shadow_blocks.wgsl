// The shadow maps' block minima (runtime/src/shadow.rs): for each block of SHADOW_BLOCKS x
// SHADOW_BLOCKS per layer, the least depth stored in it, i.e. its farthest occluder (reverse-Z:
// 0 = far, and 0 where nothing was drawn). Texel x lies in block x * SHADOW_BLOCKS / size
// (integer division), so block b holds texels ceil(b size / SHADOW_BLOCKS) up to the next
// block's first. One invocation per block of each layer listed in block_layers (the layers
// drawn this update). Bindings: the generated prelude.

// The first texel of block b along a side of `size` texels.
fn block_start(b: u32, size: u32) -> u32 {
    return (b * size + SHADOW_BLOCKS - 1u) / SHADOW_BLOCKS;
}

@compute @workgroup_size(WG_LINEAR)
fn blocks_main(@builtin(global_invocation_id) id: vec3u) {
    if id.x >= SHADOW_BLOCKS * SHADOW_BLOCKS || id.y >= arrayLength(&block_layers) {
        return;
    }
    let layer = block_layers[id.y];
    let size = textureDimensions(shadow_depth).x;
    let bx = id.x % SHADOW_BLOCKS;
    let by = id.x / SHADOW_BLOCKS;
    var least = 1.0;
    for (var y = block_start(by, size); y < block_start(by + 1u, size); y++) {
        for (var x = block_start(bx, size); x < block_start(bx + 1u, size); x++) {
            least = min(least, textureLoad(shadow_depth, vec2u(x, y), layer, 0));
        }
    }
    textureStore(block_minima, vec2u(bx, by), layer, vec4f(least, 0.0, 0.0, 0.0));
}
