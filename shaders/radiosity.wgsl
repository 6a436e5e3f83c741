// Hierarchical radiosity over precomputed visibility (paper 003 §4), on the GPU. The twin of
// prm_runtime::cpu::radiosity (read its module doc): the same hierarchy walk, oracle, transfers,
// representative texels, jitter hash and visibility queries, one invocation per node or texel.
//
// `values` holds three sections of `params.texels` each: the exitance this pass gathers from,
// what it gathered, and the running total. `flux` holds three sections of `params.nodes`: two
// halves of node fluxes (xyz: exitance x area; w: its luminance less the escaping share, the
// power conservation's "sent"), `params.flux_half` the one `flux_main` writes and `gather_main`
// reads, the tail comparing the two halves' roots; and the nodes' gathered power (x, "got").

const BIG: f32 = 3.0e38;

fn rad_point(t: RadTexel) -> vec3f {
    return (objects[t.object].to_world * vec4f(t.position, 1.0)).xyz;
}

fn rad_normal(t: RadTexel) -> vec3f {
    return normalize((objects[t.object].to_world * vec4f(t.normal, 0.0)).xyz);
}

// --- cube maps (prm::visibility::cube) ---

fn cube_axes(f: u32) -> array<vec3f, 3> {
    let a = f / 2u;
    let s = select(-1.0, 1.0, f % 2u == 0u);
    var main = vec3f(0.0);
    main[a] = s;
    if a == 0u {
        return array<vec3f, 3>(main, vec3f(0.0, 1.0, 0.0), vec3f(0.0, 0.0, 1.0));
    }
    if a == 1u {
        return array<vec3f, 3>(main, vec3f(1.0, 0.0, 0.0), vec3f(0.0, 0.0, 1.0));
    }
    return array<vec3f, 3>(main, vec3f(1.0, 0.0, 0.0), vec3f(0.0, 1.0, 0.0));
}

fn pixel_direction(p: u32, res: u32) -> vec3f {
    let f = p / (res * res);
    let y = (p / res) % res;
    let x = p % res;
    let ax = cube_axes(f);
    let u = 2.0 * (f32(x) + 0.5) / f32(res) - 1.0;
    let v = 2.0 * (f32(y) + 0.5) / f32(res) - 1.0;
    return normalize(ax[0] + ax[1] * u + ax[2] * v);
}

// (face, x, y) of direction d; face < 0 for a zero direction.
fn cube_locate(d: vec3f, res: u32) -> vec3f {
    let a = abs(d);
    var axis = 2u;
    if a.x >= a.y && a.x >= a.z {
        axis = 0u;
    } else if a.y >= a.z {
        axis = 1u;
    }
    let major = a[axis];
    if !(major > 0.0) {
        return vec3f(-1.0, 0.0, 0.0);
    }
    let f = 2u * axis + select(0u, 1u, d[axis] < 0.0);
    let ax = cube_axes(f);
    let r = f32(res);
    let x = clamp((dot(d, ax[1]) / major + 1.0) * 0.5 * r, 0.0, r - 1e-3);
    let y = clamp((dot(d, ax[2]) / major + 1.0) * 0.5 * r, 0.0, r - 1e-3);
    return vec3f(f32(f), x, y);
}

fn pixel_of(d: vec3f, res: u32) -> u32 {
    let l = cube_locate(d, res);
    let f = u32(l.x);
    return f * res * res + min(u32(l.z), res - 1u) * res + min(u32(l.y), res - 1u);
}

// --- the CSSM (prm::visibility::cssm) ---

fn cssm_depth(o: RadObject, k: u32, p: u32) -> f32 {
    let a = vdata[o.offsets + p];
    let b = vdata[o.offsets + p + 1u];
    // A fixed trip count (32 halvings cover any u32 range): loops that end at different
    // iterations in neighbouring invocations miscompiled on Mesa 22's llvmpipe.
    var lo = a;
    var hi = b;
    for (var step = 0u; step < 32u; step++) {
        let mid = (lo + hi) / 2u;
        let go_right = lo < hi && vdata[o.starts + mid] <= k;
        let go_left = lo < hi && !go_right;
        lo = select(lo, mid + 1u, go_right);
        hi = select(hi, mid, go_left);
    }
    let i = max(lo, a + 1u) - 1u;
    let code = (vdata[o.depths + i / 2u] >> (16u * (i % 2u))) & 0xffffu;
    if code == CSSM_NOTHING {
        return BIG;
    }
    return f32(code) / f32(CSSM_NOTHING - 1u) * o.far;
}

fn cssm_visible(o: RadObject, k: u32, q: vec3f) -> f32 {
    let at = o.origins + 3u * k;
    let origin = vec3f(bitcast<f32>(vdata[at]), bitcast<f32>(vdata[at + 1u]), bitcast<f32>(vdata[at + 2u]));
    let d = q - origin;
    let dist = length(d);
    let l = cube_locate(d, o.res);
    if l.x < 0.0 {
        return 1.0;
    }
    let r = o.res;
    let f = u32(l.x);
    let fx = max(l.y - 0.5, 0.0);
    let fy = max(l.z - 0.5, 0.0);
    let x0 = min(u32(fx), r - 1u);
    let y0 = min(u32(fy), r - 1u);
    let x1 = min(x0 + 1u, r - 1u);
    let y1 = min(y0 + 1u, r - 1u);
    let tx = clamp(fx - f32(x0), 0.0, 1.0);
    let ty = clamp(fy - f32(y0), 0.0, 1.0);
    let base = f * r * r;
    let taps = array<vec3f, 4>(
        vec3f(f32(x0), f32(y0), (1.0 - tx) * (1.0 - ty)),
        vec3f(f32(x1), f32(y0), tx * (1.0 - ty)),
        vec3f(f32(x0), f32(y1), (1.0 - tx) * ty),
        vec3f(f32(x1), f32(y1), tx * ty),
    );
    let reach = dist - dist * CSSM_SLACK;
    var seen = 0.0;
    for (var i = 0u; i < 4u; i++) {
        let t = taps[i];
        if t.z > 0.0 && reach <= cssm_depth(o, k, base + u32(t.y) * r + u32(t.x)) {
            seen += t.z;
        }
    }
    return seen;
}

// --- occluder maps (prm::visibility::csm) ---

fn orthonormal_pair(n: vec3f) -> array<vec3f, 2> {
    let s = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    return array<vec3f, 2>(vec3f(1.0 + s * n.x * n.x * a, s * b, -s * n.x), vec3f(b, s + n.y * n.y * a, -n.y));
}

fn csm_entry_exit(o: RadObject, at: u32) -> vec2u {
    let word = (vdata[o.csm + at / 2u] >> (16u * (at % 2u))) & 0xffffu;
    return vec2u(word & 0xffu, word >> 8u);
}

fn csm_depth(o: RadObject, code: u32) -> f32 {
    return (f32(code) / f32(CSM_MISS - 1u) * 2.0 - 1.0) * o.csm_radius;
}

fn csm_coord(o: RadObject, t: f32) -> f32 {
    return clamp((t / o.csm_radius + 1.0) * 0.5 * f32(o.csm_res) - 0.5, 0.0, f32(o.csm_res) - 1.0);
}

fn csm_blocks(o: RadObject, a: vec3f, b: vec3f) -> f32 {
    let ab = b - a;
    let len = length(ab);
    if !(len > 0.0) {
        return 0.0;
    }
    let u = ab / len;
    let s = a + u * clamp(dot(o.csm_centre - a, u), 0.0, len);
    if dot(s - o.csm_centre, s - o.csm_centre) > o.csm_radius * o.csm_radius {
        return 0.0;
    }
    let k = pixel_of(u, o.csm_dirs);
    let d = pixel_direction(k, o.csm_dirs);
    let e = orthonormal_pair(d);
    let r = o.csm_res;
    let base = k * r * r;
    let ta = dot(a - o.csm_centre, d);
    let tb = dot(b - o.csm_centre, d);
    let lo = min(ta, tb);
    let hi = max(ta, tb);
    var p = s;
    if abs(tb - ta) > 1e-6 * len {
        for (var i = 0u; i < 2u; i++) {
            let rel = p - o.csm_centre;
            let x = u32(floor(csm_coord(o, dot(rel, e[0])) + 0.5));
            let y = u32(floor(csm_coord(o, dot(rel, e[1])) + 0.5));
            let ee = csm_entry_exit(o, base + y * r + x);
            if ee.x == CSM_MISS {
                break;
            }
            let mid = 0.5 * (csm_depth(o, ee.x) + csm_depth(o, ee.y));
            p = a + ab * clamp((mid - ta) / (tb - ta), 0.0, 1.0);
        }
    }
    let rel = p - o.csm_centre;
    let fx = csm_coord(o, dot(rel, e[0]));
    let fy = csm_coord(o, dot(rel, e[1]));
    let x0 = u32(fx);
    let y0 = u32(fy);
    let x1 = min(x0 + 1u, r - 1u);
    let y1 = min(y0 + 1u, r - 1u);
    let tx = fx - f32(x0);
    let ty = fy - f32(y0);
    let taps = array<vec3f, 4>(
        vec3f(f32(x0), f32(y0), (1.0 - tx) * (1.0 - ty)),
        vec3f(f32(x1), f32(y0), tx * (1.0 - ty)),
        vec3f(f32(x0), f32(y1), (1.0 - tx) * ty),
        vec3f(f32(x1), f32(y1), tx * ty),
    );
    var blocked = 0.0;
    for (var i = 0u; i < 4u; i++) {
        let t = taps[i];
        let ee = csm_entry_exit(o, base + u32(t.y) * r + u32(t.x));
        if t.z > 0.0 && ee.x != CSM_MISS && hi >= csm_depth(o, ee.x) && lo <= csm_depth(o, ee.y) {
            blocked += t.z;
        }
    }
    return blocked;
}

// prm::visibility::Visibility::between
fn between(r: RadTexel, pr: vec3f, s: RadTexel, ps: vec3f) -> f32 {
    let orr = objects[r.object];
    var v = cssm_visible(orr, r.seq, (orr.to_rest * vec4f(ps, 1.0)).xyz);
    let os = objects[s.object];
    if s.object == r.object {
        if v > CSSM_EDGE && v < 1.0 - CSSM_EDGE {
            v = 0.5 * (v + cssm_visible(os, s.seq, (os.to_rest * vec4f(pr, 1.0)).xyz));
        }
    } else if v > 0.0 {
        v *= cssm_visible(os, s.seq, (os.to_rest * vec4f(pr, 1.0)).xyz);
    }
    for (var o = 1u; o < params.objects; o++) {
        if v == 0.0 {
            break;
        }
        if o == r.object || o == s.object || objects[o].csm == NO_SLOT {
            continue;
        }
        let ob = objects[o];
        v *= 1.0 - csm_blocks(ob, (ob.to_rest * vec4f(pr, 1.0)).xyz, (ob.to_rest * vec4f(ps, 1.0)).xyz);
    }
    return v;
}

// --- Lambert's contour integral (form_factor.wgsl) ---

// Texel t's shape (crate::cpu::radiosity::Shape) posed by `w`: its vertices, count in [7].x.
fn shape_vertex(t: u32, i: u32, w: mat4x4f) -> vec3f {
    return (w * vec4f(shapes[8u * t + i].xyz, 1.0)).xyz;
}

// Texel t's shape posed by `w`, and its vertex count.
fn posed_shape(t: u32, w: mat4x4f) -> array<vec3f, 8> {
    var v: array<vec3f, 8>;
    let count = u32(shapes[8u * t + 7u].x);
    for (var i = 0u; i < count; i++) {
        v[i] = shape_vertex(t, i, w);
    }
    return v;
}

fn point_to_shape(p: vec3f, n: vec3f, t: u32, w: mat4x4f) -> f32 {
    return polygon_form_factor(p, n, posed_shape(t, w), u32(shapes[8u * t + 7u].x));
}

// The same, each part (centroid, vertex i, vertex i + 1) weighted by its share of the direct
// light (crate::cpu::radiosity::SenderLight::parts, the shape vertices' w).
fn point_to_parts(p: vec3f, n: vec3f, t: u32, w: mat4x4f) -> f32 {
    let count = u32(shapes[8u * t + 7u].x);
    let v = posed_shape(t, w);
    var c = vec3f(0.0);
    for (var i = 0u; i < count; i++) {
        c += v[i];
    }
    c /= f32(count);
    var sum = 0.0;
    for (var i = 0u; i < count; i++) {
        var tri: array<vec3f, 8>;
        tri[0] = c;
        tri[1] = v[i];
        tri[2] = v[(i + 1u) % count];
        sum += shapes[8u * t + i].w * polygon_form_factor(p, n, tri, 3u);
    }
    return sum;
}

// The jittered representatives' hash (crate::cpu::radiosity::hash).
fn hash(a: u32, b: u32) -> u32 {
    var h = (a * 0x9E3779B1u) ^ (b * 0x85EBCA77u);
    h ^= h >> 15u;
    h *= 0x2C1B3C6Du;
    h ^= h >> 12u;
    return h;
}

// --- passes ---

// Pull: each node's flux from its leaves' exitance x area.
@compute @workgroup_size(WG_LINEAR)
fn flux_main(@builtin(global_invocation_id) id: vec3u) {
    let k = id.x;
    if k >= params.nodes {
        return;
    }
    let n = nodes[k];
    var f = vec3f(0.0);
    var sent = 0.0;
    for (var i = n.first; i < n.end; i++) {
        let t = leaves[i];
        let p = values[t].xyz * texels[t].area;
        f += p;
        sent += luminance(p) * (1.0 - texels[t].escape);
    }
    flux[params.flux_half * params.nodes + k] = vec4f(f, sent);
}

// Each node's gathered power (luminance x area), for power conservation.
@compute @workgroup_size(WG_LINEAR)
fn got_main(@builtin(global_invocation_id) id: vec3u) {
    let k = id.x;
    if k >= params.nodes {
        return;
    }
    let n = nodes[k];
    var got = 0.0;
    for (var i = n.first; i < n.end; i++) {
        let t = leaves[i];
        got += luminance(values[params.texels + t].xyz) * texels[t].area;
    }
    flux[2u * params.nodes + k] = vec4f(got, 0.0, 0.0, 0.0);
}

fn root_power(half: u32) -> f32 {
    var sum = 0.0;
    for (var o = 0u; o < params.objects; o++) {
        if objects[o].root != NO_SLOT {
            sum += luminance(flux[half * params.nodes + objects[o].root].xyz);
        }
    }
    return sum;
}

// Refine-and-gather for one receiver texel (paper 003 Fig. 10).
@compute @workgroup_size(WG_LINEAR)
fn gather_main(@builtin(global_invocation_id) id: vec3u) {
    let r = id.x;
    if r >= params.texels {
        return;
    }
    let T = params.texels;
    let fb = params.flux_half * params.nodes;
    let mean = root_power(params.flux_half) / params.total_area;
    if !(mean > 0.0) {
        values[T + r] = vec4f(0.0);
        return;
    }
    let bound = params.threshold * mean * PI;
    let rt = texels[r];
    let x = rad_point(rt);
    let nr = rad_normal(rt);
    var e = vec3f(0.0);
    var k = 0u;
    while k < params.nodes {
        let n = nodes[k];
        let phi = flux[fb + k].xyz;
        if all(phi == vec3f(0.0)) {
            k = n.skip;
            continue;
        }
        let leaf_node = n.end - n.first == 1u;
        let c = (objects[n.object].to_world * vec4f(n.centre, 1.0)).xyz;
        let d = length(x - c);
        let refine = !leaf_node
            && (d < 2.0 * n.radius || luminance(phi) > bound * (d - n.radius) * (d - n.radius));
        if refine {
            k += 1u;
            continue;
        }
        let here = k;
        k = n.skip;
        var leaf = (n.first + n.end) / 2u;
        if leaf_node {
            leaf = n.first;
        } else if params.jitter != 0u {
            leaf = n.first + hash(r, here) % (n.end - n.first);
        }
        let s = leaves[leaf];
        if s == r {
            continue;
        }
        let st = texels[s];
        let ps = rad_point(st);
        let ns = rad_normal(st);
        var src = c;
        var m = (objects[n.object].to_world * vec4f(n.normal, 0.0)).xyz;
        if leaf_node {
            src = ps;
            m = ns;
        }
        let v = src - x;
        let d2 = dot(v, v);
        if !(d2 > 0.0) {
            continue;
        }
        let u = v / sqrt(d2);
        let cos_r = dot(u, nr);
        let cos_s = -dot(u, m);
        if cos_r <= 0.0 || cos_s <= 0.0 {
            continue;
        }
        var g = cos_r * cos_s / (PI * d2);
        if leaf_node && d2 < RADIOSITY_NEAR * RADIOSITY_NEAR * n.area {
            if st.shape_area <= 0.0 {
                continue;
            }
            var f = 0.0;
            if params.parts != 0u {
                f = point_to_parts(x, nr, s, objects[n.object].to_world);
            } else {
                f = point_to_shape(x, nr, s, objects[n.object].to_world);
            }
            if f <= 0.0 {
                continue;
            }
            g = f / st.shape_area;
        }
        e += phi * g * between(rt, x, st, ps);
    }
    values[T + r] = vec4f(e, 0.0);
}

// Before the first pass: the direct irradiance, put in the total's section (by a buffer copy),
// becomes the exitance the first pass gathers from (albedo x it); the other sections clear.
@compute @workgroup_size(WG_LINEAR)
fn seed_main(@builtin(global_invocation_id) id: vec3u) {
    let t = id.x;
    if t >= params.texels {
        return;
    }
    let T = params.texels;
    let e = values[2u * T + t];
    values[t] = vec4f(e.xyz * texels[t].albedo, 0.0);
    values[T + t] = vec4f(0.0);
    values[2u * T + t] = vec4f(0.0);
}

// Scale the gathered light to deliver what was sent (crate::cpu::radiosity::conserve_scale),
// total += it; the next pass gathers from albedo x it.
@compute @workgroup_size(WG_LINEAR)
fn next_main(@builtin(global_invocation_id) id: vec3u) {
    let t = id.x;
    if t >= params.texels {
        return;
    }
    var scale = 1.0;
    if params.conserve != 0u {
        var sent = 0.0;
        var got = 0.0;
        for (var o = 0u; o < params.objects; o++) {
            let root = objects[o].root;
            if root != NO_SLOT {
                sent += flux[params.flux_half * params.nodes + root].w;
                got += flux[2u * params.nodes + root].x;
            }
        }
        if got > 0.0 {
            scale = clamp(sent / got, 1.0, MAX_CONSERVE);
        }
    }
    let T = params.texels;
    let g = values[T + t] * scale;
    values[T + t] = g;
    values[2u * T + t] += g;
    values[t] = vec4f(g.xyz * texels[t].albedo, 0.0);
}

// The bounces not taken: the last pass's light x k / (1 - k), k the ratio of the last two
// passes' reflected power (flux_half: the newer half).
@compute @workgroup_size(WG_LINEAR)
fn tail_main(@builtin(global_invocation_id) id: vec3u) {
    let t = id.x;
    if t >= params.texels {
        return;
    }
    let newer = root_power(params.flux_half);
    let older = root_power(1u - params.flux_half);
    var k = 0.0;
    if older > 0.0 {
        k = clamp(newer / older, 0.0, 0.95);
    }
    let T = params.texels;
    values[2u * T + t] += values[T + t] * (k / (1.0 - k));
}
