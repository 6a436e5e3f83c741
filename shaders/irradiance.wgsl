// Entry irradiance (DESIGN.md §4-5, runtime/src/irradiance.rs): one invocation per entry
// point, E_j = (sum over its cell's triangles and the lights of the power the light delivers
// to the triangle, shadow-mapped at the triangle's centroid) / the entry's area. Structs,
// constants and bindings: the generated prelude (runtime/src/contract.rs,
// runtime/src/irradiance.rs); the power: lights.wgsl.

@compute @workgroup_size(WG_LINEAR)
fn entry_main(@builtin(global_invocation_id) id: vec3u) {
    let j = id.x;
    if j >= params.entry_count {
        return;
    }
    let e = entries[j];
    var power = vec3f(0.0);
    for (var k = e.first_cell; k < e.first_cell + e.cell_count; k++) {
        let t = cells[k];
        power += lit_triangle_power(t.a, t.b, t.c, params.light_count);
    }
    entry_irradiance[j] = vec4f(power * e.inv_area, 0.0);
}
