// Entry irradiance (DESIGN.md §5 step 2, runtime/src/irradiance.rs): one invocation per entry
// point, E_j = sum over lights of I(w) V cos / r² with shadow-mapped V (lights.wgsl).
// Entries with a zero normal (none in a valid .prm) get zero.

struct Entry {
    position: vec3f,
    _pad0: u32,
    normal: vec3f,
    _pad1: u32,
}

struct Params {
    entry_count: u32,
    light_count: u32,
    cluster_count: u32,
    top_k: u32,
    group_count: u32,
    // 1: groups stand in for the clusters left out.
    residual: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<storage, read> lights: array<Light>;
@group(0) @binding(1) var<storage, read> shadow_mats: array<mat4x4f>;
@group(0) @binding(2) var shadow_tex: texture_depth_2d_array;
@group(0) @binding(3) var shadow_sampler: sampler_comparison;
@group(1) @binding(0) var<uniform> params: Params;
@group(1) @binding(1) var<storage, read> entries: array<Entry>;
@group(1) @binding(2) var<storage, read_write> entry_irradiance: array<vec4f>;

@compute @workgroup_size(64)
fn entry_main(@builtin(global_invocation_id) id: vec3u) {
    let j = id.x;
    if j >= params.entry_count {
        return;
    }
    let e = entries[j];
    entry_irradiance[j] = vec4f(direct_irradiance(e.position, e.normal, params.light_count), 0.0);
}
