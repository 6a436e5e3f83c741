// Entry irradiance (DESIGN.md §5 step 2, runtime/src/irradiance.rs): one invocation per entry
// point, E_j = sum over lights of I(w) V cos / r² with shadow-mapped V (lights.wgsl).
// Entries with a zero normal (none in a valid .prm) get zero. Structs, constants and bindings:
// the generated prelude (runtime/src/contract.rs, runtime/src/irradiance.rs).

@compute @workgroup_size(WG_LINEAR)
fn entry_main(@builtin(global_invocation_id) id: vec3u) {
    let j = id.x;
    if j >= params.entry_count {
        return;
    }
    let e = entries[j];
    entry_irradiance[j] = vec4f(direct_irradiance(e.position, e.normal, params.light_count), 0.0);
}
