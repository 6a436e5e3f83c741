// Shading (DESIGN.md §5 step 5, runtime/src/shade.rs): outgoing radiance of a diffuse surface,
// L = emission + albedo / pi x (E_direct + indirect_scale x E_indirect), into an HDR target.
// E_direct uses the same shadow maps as the entry irradiance (lights.wgsl); E_indirect is the
// composed lightmap (a layer per page) read with a manual bilinear filter (rgba32float is not filterable
// everywhere). Back faces of single-sided materials are black, as in the CPU render.
// ShadeParams and the bindings: the generated prelude (runtime/src/contract.rs, shade.rs).

struct VertexIn {
    @location(0) position: vec3f,
    @location(1) normal: vec3f,
    @location(2) uv1: vec2f,
    @location(3) albedo: vec3f,
    @location(4) emissive: vec3f,
    @location(5) double_sided: u32,
}

struct VertexOut {
    @builtin(position) clip: vec4f,
    @location(0) position: vec3f,
    @location(1) normal: vec3f,
    @location(2) uv1: vec2f,
    @location(3) albedo: vec3f,
    @location(4) emissive: vec3f,
    @location(5) @interpolate(flat) double_sided: u32,
}

@vertex
fn vs_main(v: VertexIn) -> VertexOut {
    return VertexOut(params.view_proj * vec4f(v.position, 1.0), v.position, v.normal, v.uv1, v.albedo, v.emissive, v.double_sided);
}

// The lightmap's pages are layers: a UV's v runs over all of them (prm::density::Atlas), and
// the lookup stays inside the page it falls in, as the CPU render's does.
fn lightmap_bilinear(uv: vec2f) -> vec3f {
    let size = vec2f(f32(params.atlas_width), f32(params.atlas_height));
    let rows = i32(params.atlas_height / params.pages);
    let page = clamp(i32(floor(uv.y * f32(params.pages))), 0, i32(params.pages) - 1);
    let x = uv * size - vec2f(0.5);
    let x0 = floor(x);
    let f = x - x0;
    let hi = vec2i(i32(params.atlas_width) - 1, rows - 1);
    let a = vec2i(x0) - vec2i(0, page * rows);
    let t00 = textureLoad(lightmap, clamp(a, vec2i(0), hi), page, 0).xyz;
    let t10 = textureLoad(lightmap, clamp(a + vec2i(1, 0), vec2i(0), hi), page, 0).xyz;
    let t01 = textureLoad(lightmap, clamp(a + vec2i(0, 1), vec2i(0), hi), page, 0).xyz;
    let t11 = textureLoad(lightmap, clamp(a + vec2i(1, 1), vec2i(0), hi), page, 0).xyz;
    return mix(mix(t00, t10, f.x), mix(t01, t11, f.x), f.y);
}

@fragment
fn fs_main(v: VertexOut, @builtin(front_facing) front: bool) -> @location(0) vec4f {
    var n = normalize(v.normal);
    if !front {
        if v.double_sided == 0u {
            return vec4f(0.0, 0.0, 0.0, 1.0);
        }
        n = -n;
    }
    var e = direct_irradiance(v.position, n, params.light_count);
    if params.indirect_scale != 0.0 {
        e += params.indirect_scale * lightmap_bilinear(v.uv1);
    }
    return vec4f(v.emissive + v.albedo / PI * e, 1.0);
}
