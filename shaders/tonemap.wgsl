// Tone mapping of the HDR frame for display (runtime/src/tonemap.rs): exposure x radiance,
// Reinhard, then sRGB encoding unless the target format encodes itself. One full-screen
// triangle; the frame is read with textureLoad (rgba32float is not filterable everywhere).
// TonemapParams and the bindings: the generated prelude (runtime/src/contract.rs, tonemap.rs).

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> @builtin(position) vec4f {
    let uv = vec2f(f32((i << 1u) & 2u), f32(i & 2u));
    return vec4f(uv * 2.0 - 1.0, 0.0, 1.0);
}

fn srgb(c: f32) -> f32 {
    if c <= 0.0031308 {
        return 12.92 * c;
    }
    return 1.055 * pow(c, 1.0 / 2.4) - 0.055;
}

@fragment
fn fs_main(@builtin(position) pos: vec4f) -> @location(0) vec4f {
    let size = vec2i(textureDimensions(frame));
    let p = clamp(vec2i(pos.xy), vec2i(0), size - vec2i(1));
    let hdr = max(textureLoad(frame, p, 0).rgb * params.exposure, vec3f(0.0));
    var c = hdr / (vec3f(1.0) + hdr);
    if params.encode == 1u {
        c = vec3f(srgb(c.r), srgb(c.g), srgb(c.b));
    }
    return vec4f(c, 1.0);
}
