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
    return pcf(layer, q);
}

// The same in light l's cube, drawn at `eye` (crate::lights::layers: a point light's or a wide
// spot's at the light, or the one a spot that lights a cell up close owns after its frustum,
// at its eye: prm_runtime::cpu::sight_eye), which sees every way: how a far texel sees the
// spot of light the light makes (far.wgsl); `dist` is from the eye.
fn cube_visibility(l: GpuLight, eye: vec3f, p: vec3f, n: vec3f, dist: f32) -> f32 {
    // A cube face's texel per unit distance (crate::lights::frusta).
    let size = f32(textureDimensions(shadow_tex).x);
    let texel = 2.0 * (1.0 + CUBE_PAD_TEXELS / size) / size;
    let q = p + n * (1.5 * texel * dist);
    return pcf(l.first_layer + l.layers - CUBE_LAYERS + cube_face(q - eye), q);
}

// The share of the 3x3 PCF of bilinear comparisons around the point q in shadow layer `layer`
// that is lit.
fn pcf(layer: u32, q: vec3f) -> f32 {
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
// point lights, the spot's falloff integrated over it for spots (spot_solid_angle), a range's
// window at the centroids of up to 16² pieces (window_pieces); E x projected area for
// directional ones.
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
    // The window along the triangle: split it where the window falls across it. One call of
    // light_solid_angle for every case (small code: lavapipe's compiler copies every call);
    // unsplit, the piece is the triangle itself, as prm::Light::triangle_power has it.
    var pieces = 1u;
    if l.range > 0.0 {
        pieces = max(window_pieces(a, b, c, l.range), 1u);
    }
    let n = f32(pieces);
    let e1 = (b - a) / n;
    let e2 = (c - a) / n;
    var scale = 0.0;
    for (var i = 0u; i < pieces; i++) {
        for (var j = 0u; j < pieces - i; j++) {
            let last = i + j + 1u == pieces;
            for (var down = 0u; down < 2u; down++) {
                if down == 1u && last {
                    break;
                }
                var p = a;
                var q = b;
                var r = c;
                var t = triple;
                if pieces > 1u {
                    p = a + e1 * f32(i) + e2 * f32(j);
                    q = a + e1 * f32(i + 1u) + e2 * f32(j);
                    r = a + e1 * f32(i) + e2 * f32(j + 1u);
                    if down == 1u {
                        p = a + e1 * f32(i + 1u) + e2 * f32(j);
                        q = a + e1 * f32(i + 1u) + e2 * f32(j + 1u);
                        r = a + e1 * f32(i) + e2 * f32(j + 1u);
                    }
                    t = -dot(p, cross(q - p, r - p));
                }
                if t > 0.0 {
                    var w = 1.0;
                    if l.range > 0.0 {
                        w = range_window(length((p + q + r) / 3.0), l.range);
                    }
                    scale += light_solid_angle(l, p, q, r, t) * w;
                }
            }
        }
    }
    return l.intensity * scale;
}

// prm::Light::cone_solid_angle: the solid angle of the triangle (corners relative to the
// light, facing it: triple > 0), a spot's falloff integrated over it.
fn light_solid_angle(l: GpuLight, a: vec3f, b: vec3f, c: vec3f, triple: f32) -> f32 {
    let la = length(a);
    let lb = length(b);
    let lc = length(c);
    let denominator = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la;
    let whole = 2.0 * atan2(triple, denominator);
    if l.kind == KIND_SPOT {
        return spot_solid_angle(a / la, b / lb, c / lc, whole, l.direction, l.cos_inner, l.cos_outer);
    }
    return whole;
}

// prm::light::window_pieces: pieces a side so the range window is taken at each piece's
// centroid (16 x its fall across the triangle, 1 to 16; 0 beyond the range).
fn window_pieces(a: vec3f, b: vec3f, c: vec3f, range: f32) -> u32 {
    let centroid = (a + b + c) / 3.0;
    let radius = max(max(length(a - centroid), length(b - centroid)), length(c - centroid));
    let far = max(max(length(a), length(b)), length(c));
    let near = max(length(centroid) - radius, 0.0);
    if near >= range {
        return 0u;
    }
    let fall = range_window(near, range) - range_window(far, range);
    return clamp(u32(ceil(16.0 * fall)), 1u, 16u);
}

// prm::cone: a spot's falloff integrated over a spherical triangle (unit corners a, b, c wound
// clockwise seen from the light, whole its solid angle), the same operations in the same order.
const CONE_GAUSS_X = array<f32, 12>(0.019855072, 0.10166676, 0.23723379, 0.40828268,
    0.5917173, 0.7627662, 0.89833324, 0.9801449,
    0.06943184, 0.3300095, 0.6699905, 0.93056816);
const CONE_GAUSS_W = array<f32, 12>(0.05061427, 0.11119052, 0.15685332, 0.18134189,
    0.18134189, 0.15685332, 0.11119052, 0.05061427,
    0.17392742, 0.32607258, 0.32607258, 0.17392742);

fn spot_solid_angle(a: vec3f, b: vec3f, c: vec3f, whole: f32, axis: vec3f, ci: f32, co: f32) -> f32 {
    let lowest = min(min(dot(axis, a), dot(axis, b)), dot(axis, c));
    if lowest >= ci {
        return whole;
    }
    let s = a + b + c;
    var mean = vec3f(0.0);
    if dot(s, s) > 0.0 {
        mean = normalize(s);
    }
    let cos_radius = min(min(dot(mean, a), dot(mean, b)), dot(mean, c));
    let sin_radius = sqrt(max(1.0 - cos_radius * cos_radius, 0.0));
    let sin_outer = sqrt(max(1.0 - co * co, 0.0));
    if cos_radius > 0.0 && dot(axis, mean) < co * cos_radius - sin_outer * sin_radius {
        return 0.0;
    }
    var highest = 1.0;
    if !cone_holds(axis, a, b, c) {
        highest = max(max(cone_arc_highest(axis, a, b), cone_arc_highest(axis, b, c)), cone_arc_highest(axis, c, a));
    }
    if highest < co {
        return 0.0;
    }
    let span = ci - co;
    if span > 1e-6 && highest - lowest < 0.06 * span {
        return whole * spot_falloff(dot(axis, mean), ci, co);
    }
    let behind = cone_holds(-axis, a, b, c);
    if span <= 1e-6 {
        return clamp(cone_in_cap(a, b, c, axis, co, behind), 0.0, whole);
    }
    let lo = clamp((lowest - co) / span, 0.0, 1.0);
    let hi = clamp((highest - co) / span, lo, 1.0);
    var sum = whole * lo * lo;
    // Over half the falloff's span or less, 4 points (the 8-point rule's nodes, then the 4's).
    var first = 8u;
    var end = 12u;
    if hi - lo > 0.5 {
        first = 0u;
        end = 8u;
    }
    for (var i = first; i < end; i++) {
        let t = lo + (hi - lo) * CONE_GAUSS_X[i];
        let within = clamp(cone_in_cap(a, b, c, axis, co + t * span, behind), 0.0, whole);
        sum += (hi - lo) * CONE_GAUSS_W[i] * 2.0 * t * within;
    }
    return sum;
}

fn cone_holds(d: vec3f, a: vec3f, b: vec3f, c: vec3f) -> bool {
    return dot(d, cross(a, b)) < 0.0 && dot(d, cross(b, c)) < 0.0 && dot(d, cross(c, a)) < 0.0;
}

fn cone_arc_highest(d: vec3f, p: vec3f, q: vec3f) -> f32 {
    let m = cross(p, q);
    var best = max(dot(d, p), dot(d, q));
    let m2 = dot(m, m);
    if m2 > 0.0 {
        let x = d - m * (dot(d, m) / m2);
        if dot(cross(p, x), m) > 0.0 && dot(cross(x, q), m) > 0.0 {
            best = max(best, length(x));
        }
    }
    return best;
}

fn cone_in_cap(a: vec3f, b: vec3f, c: vec3f, d: vec3f, cap: f32, behind: bool) -> f32 {
    // The three fans in one loop body (small code: lavapipe's compiler copies every call).
    let corners = array<vec3f, 4>(a, b, c, a);
    var sum = 0.0;
    for (var e = 0u; e < 3u; e++) {
        sum += cone_fan(d, corners[e], corners[e + 1u], cap);
    }
    let fan = -sum;
    if behind {
        return fan + 2.0 * PI * (1.0 - cap);
    }
    return fan;
}

fn cone_fan(d: vec3f, p: vec3f, q: vec3f, cap: f32) -> f32 {
    let m = cross(p, q);
    let len = length(m);
    if !(len > 0.0) {
        return 0.0;
    }
    let pole = m / len;
    let k = dot(d, pole);
    let across2 = 1.0 - k * k;
    var cuts = array<vec3f, 2>(vec3f(0.0), vec3f(0.0));
    var n = 0u;
    if across2 > 1e-12 {
        let across = sqrt(across2);
        let e = (pole - d * k) / across;
        let y = -cap * k / across;
        let z2 = 1.0 - cap * cap - y * y;
        if z2 > 0.0 {
            let z = sqrt(z2);
            let base = d * cap + e * y;
            let side = cross(d, e) * z;
            for (var s = 0u; s < 2u; s++) {
                var x = base + side;
                if s == 1u {
                    x = base - side;
                }
                if dot(cross(p, x), m) > 0.0 && dot(cross(x, q), m) > 0.0 {
                    cuts[n] = x;
                    n += 1u;
                }
            }
        }
    }
    if n == 2u && dot(p, cuts[0]) < dot(p, cuts[1]) {
        let first = cuts[1];
        cuts[1] = cuts[0];
        cuts[0] = first;
    }
    var sum = 0.0;
    var u = p;
    for (var i = 0u; i <= n; i++) {
        var v = q;
        if i < n {
            v = cuts[i];
        }
        sum += cone_piece(d, u, v, cap);
        u = v;
    }
    return sum;
}

fn cone_piece(d: vec3f, u: vec3f, v: vec3f, cap: f32) -> f32 {
    let turn = dot(d, cross(u, v));
    let du = dot(d, u);
    let dv = dot(d, v);
    let mid = u + v;
    if dot(d, mid) >= cap * length(mid) {
        return 2.0 * atan2(turn, 1.0 + du + dv + dot(u, v));
    }
    return (1.0 - cap) * atan2(turn, dot(u, v) - du * dv);
}
