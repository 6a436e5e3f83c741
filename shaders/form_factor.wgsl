// The form factor from a point to a convex polygon (prm::form_factor::point_to_polygon), for
// the passes that need it (runtime/src/contract.rs, Library::FormFactor).

// Form factor from the point p (unit normal n) to the convex polygon v[0..count] (count <= 8),
// the part of it on p's side of p's plane: the polygon is clipped to that side first, with a
// tolerance of 1e-5 of its farthest vertex's distance.
fn polygon_form_factor(p: vec3f, n: vec3f, v: array<vec3f, 8>, count: u32) -> f32 {
    var scale = 0.0;
    for (var i = 0u; i < count; i++) {
        scale = max(scale, length(v[i] - p));
    }
    let tol = 1e-5 * scale;
    var c: array<vec3f, 9>;
    var m = 0u;
    for (var i = 0u; i < count; i++) {
        let a = v[i];
        let b = v[(i + 1u) % count];
        let da = dot(a - p, n) - tol;
        let db = dot(b - p, n) - tol;
        if da > 0.0 {
            c[m] = a;
            m++;
        }
        if (da > 0.0) != (db > 0.0) && da != db {
            c[m] = a + (b - a) * (da / (da - db));
            m++;
        }
    }
    if m < 3u {
        return 0.0;
    }
    var sum = 0.0;
    for (var i = 0u; i < m; i++) {
        let a = c[i] - p;
        let b = c[(i + 1u) % m] - p;
        let g = cross(a, b);
        let gl = length(g);
        if gl <= 0.0 {
            continue;
        }
        sum += atan2(gl, dot(a, b)) * dot(n, g / gl);
    }
    return min(abs(sum) / (2.0 * PI), 1.0);
}

// The same for the triangle (a, b, c).
fn triangle_form_factor(p: vec3f, n: vec3f, a: vec3f, b: vec3f, c: vec3f) -> f32 {
    var v: array<vec3f, 8>;
    v[0] = a;
    v[1] = b;
    v[2] = c;
    return polygon_form_factor(p, n, v, 3u);
}
