// Lights and shadow-map visibility, shared by irradiance.wgsl and shade.wgsl (put between the
// prelude and the pass by runtime/src/contract.rs). GpuLight, the KIND_* constants, CUBE_LAYERS,
// range_window, spot_falloff and the shadow group (lights, shadow_mats, shadow_tex, shadow_sampler) come from
// the generated prelude and bindings.
//
// Shadow maps are reverse-Z (1 = at the light, 0 = far): a receiver is lit when its depth is
// >= the stored depth. Point lights own six layers (+X -X +Y -Y +Z -Z faces, 90°+ frusta);
// spot and directional lights one.

struct Incident {
    to_light: vec3f,
    distance: f32,
    irradiance: vec3f,
}

// Unoccluded light arriving at p (the same formula as prm::Light::incident).
fn incident(l: GpuLight, p: vec3f) -> Incident {
    if l.kind == KIND_DIRECTIONAL {
        return Incident(-l.direction, 3.4e38, l.intensity);
    }
    let d = l.position - p;
    let dist2 = dot(d, d);
    if !(dist2 > 0.0) {
        return Incident(vec3f(0.0, 0.0, 1.0), 0.0, vec3f(0.0));
    }
    let dist = sqrt(dist2);
    let to_light = d / dist;
    var scale = range_window(dist, l.range) / dist2;
    if l.kind == KIND_SPOT {
        scale *= spot_falloff(dot(l.direction, -to_light), l.cos_inner, l.cos_outer);
    }
    return Incident(to_light, dist, l.intensity * scale);
}

// Cube face of direction d from a point light: 0..5 = +X -X +Y -Y +Z -Z.
fn cube_face(d: vec3f) -> u32 {
    let a = abs(d);
    if a.x >= a.y && a.x >= a.z {
        return select(1u, 0u, d.x >= 0.0);
    }
    if a.y >= a.z {
        return select(3u, 2u, d.y >= 0.0);
    }
    return select(5u, 4u, d.z >= 0.0);
}

// The tile (x, y) of directional light l's n x n tiles (n^2 = l.layers) that a lookup at q
// reads: from where q falls in the first tile's map, whose tile-sized steps (the map less its
// SUN_TILE_MARGIN texels on each side) lead to the others (crate::lights::sun_tile).
fn sun_tile(l: GpuLight, q: vec3f) -> vec2u {
    let n = u32(round(sqrt(f32(l.layers))));
    let clip = shadow_mats[l.first_layer] * vec4f(q, 1.0);
    let uv = clip.xy * vec2f(0.5, -0.5) + vec2f(0.5);
    let size = f32(textureDimensions(shadow_tex).x);
    let t = floor((uv * size - SUN_TILE_MARGIN) / (size - 2.0 * SUN_TILE_MARGIN));
    return vec2u(clamp(t, vec2f(0.0), vec2f(f32(n - 1u))));
}

// The layer of directional light l's map that a lookup at q reads.
fn sun_layer(l: GpuLight, q: vec3f) -> u32 {
    if l.layers <= 1u {
        return l.first_layer;
    }
    let t = sun_tile(l, q);
    return l.first_layer + t.y * u32(round(sqrt(f32(l.layers)))) + t.x;
}

// Fraction of light l reaching the surface point p with unit normal n (toward the light side):
// normal-offset receiver (1.5 shadow texels along n; SUN_NORMAL_OFFSET for a directional
// light, whose map has no depth bias), 3x3 PCF of bilinear comparisons.
fn visibility(l: GpuLight, p: vec3f, n: vec3f, dist: f32) -> f32 {
    var texel_world = l.texel;
    var offset = SUN_NORMAL_OFFSET;
    if l.kind != KIND_DIRECTIONAL {
        texel_world = l.texel * dist;
        offset = 1.5;
    }
    let q = p + n * (offset * texel_world);
    var layer = l.first_layer;
    if l.kind == KIND_DIRECTIONAL {
        layer = sun_layer(l, q);
    } else if l.layers == CUBE_LAYERS {
        layer += cube_face(q - l.position);
    }
    let clip = shadow_mats[layer] * vec4f(q, 1.0);
    if clip.w <= 0.0 {
        return 1.0;
    }
    let ndc = clip.xyz / clip.w;
    let uv = ndc.xy * vec2f(0.5, -0.5) + vec2f(0.5);
    if any(uv < vec2f(0.0)) || any(uv > vec2f(1.0)) {
        // Outside the map: nothing was rendered there (beyond a spot's cone, or past the level).
        return 1.0;
    }
    let size = vec2f(textureDimensions(shadow_tex));
    var lit = 0.0;
    for (var j = -1; j <= 1; j++) {
        for (var i = -1; i <= 1; i++) {
            let o = vec2f(f32(i), f32(j)) / size;
            lit += textureSampleCompareLevel(shadow_tex, shadow_sampler, uv + o, i32(layer), ndc.z);
        }
    }
    return lit / 9.0;
}

// Direct irradiance at p (unit normal n) from every light, with shadow-map visibility (W/m²).
fn direct_irradiance(p: vec3f, n: vec3f, count: u32) -> vec3f {
    var sum = vec3f(0.0);
    for (var k = 0u; k < count; k++) {
        let l = lights[k];
        let inc = incident(l, p);
        let c = dot(n, inc.to_light);
        if c <= 0.0 || all(inc.irradiance == vec3f(0.0)) {
            continue;
        }
        sum += inc.irradiance * c * visibility(l, p, n, inc.distance);
    }
    return sum;
}

// Power (W) light l delivers to the front of triangle (p0, p1, p2), counter-clockwise seen from
// the front, without visibility: prm::Light::triangle_power, the same operations in the same
// order (a GPU twin test holds them together). I x solid angle (Van Oosterom and Strackee) for
// point and spot lights, E x projected area for directional ones.
fn triangle_power(l: GpuLight, p0: vec3f, p1: vec3f, p2: vec3f) -> vec3f {
    let twice_area = cross(p1 - p0, p2 - p0);
    if l.kind == KIND_DIRECTIONAL {
        return l.intensity * max(0.5 * dot(twice_area, -l.direction), 0.0);
    }
    let a = p0 - l.position;
    let b = p1 - l.position;
    let c = p2 - l.position;
    let triple = -dot(a, twice_area);
    if !(triple > 0.0) {
        return vec3f(0.0);
    }
    let la = length(a);
    let lb = length(b);
    let lc = length(c);
    let denominator = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la;
    var scale = 2.0 * atan2(triple, denominator);
    if l.kind == KIND_SPOT {
        let s = a / la + b / lb + c / lc;
        var mean = vec3f(0.0);
        if dot(s, s) > 0.0 {
            mean = normalize(s);
        }
        scale *= spot_falloff(dot(l.direction, mean), l.cos_inner, l.cos_outer);
    }
    scale *= range_window(length((a + b + c) / 3.0), l.range);
    return l.intensity * scale;
}
