// Depth-only pass rendering the level into one shadow-map layer (runtime/src/shadow.rs).
// The draw's instance index is the layer, which picks its view-projection matrix; the output
// depth is reverse-Z (1 at the light). Bindings: the generated prelude (runtime/src/shadow.rs).

@vertex
fn vs_main(@location(0) position: vec3f, @builtin(instance_index) layer: u32) -> @builtin(position) vec4f {
    return layer_mats[layer] * vec4f(position, 1.0);
}
