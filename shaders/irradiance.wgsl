// Entry irradiance (DESIGN.md §4-5, runtime/src/irradiance.rs): one invocation per entry
// point, E_j = (sum over its cell's triangles and the lights of the power the light delivers
// to the triangle, shadow-mapped at the triangle's centroid) / the entry's area. Each cell
// triangle also keeps the visible share of the power on it (luminance-weighted over the lights;
// 1 where none arrives) for the near field's concentration (concentrate.wgsl). Structs,
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
        let twice_area = cross(t.b - t.a, t.c - t.a);
        let len = length(twice_area);
        var share = 1.0;
        if len > 0.0 {
            let n = twice_area / len;
            let centroid = (t.a + t.b + t.c) / 3.0;
            var total = 0.0;
            var seen = 0.0;
            for (var i = 0u; i < params.light_count; i++) {
                let l = lights[i];
                let p = triangle_power(l, t.a, t.b, t.c);
                if all(p == vec3f(0.0)) {
                    continue;
                }
                let v = visibility(l, centroid, n, distance(l.position, centroid));
                power += p * v;
                total += luminance(p);
                seen += luminance(p) * v;
            }
            if total > 0.0 {
                share = seen / total;
            }
        }
        cells[k].visibility = share;
    }
    entry_irradiance[j] = vec4f(power * e.inv_area, 0.0);
}
