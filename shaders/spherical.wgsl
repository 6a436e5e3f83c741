// Sampling a spherical triangle (prm::cone), shared by irradiance.wgsl (where a light lands on
// a cell triangle) and concentrate.wgsl (the footprint's points). Put between the prelude and
// the pass by runtime/src/contract.rs.

// prm::cone::solid_angle.
fn solid_angle(a: vec3f, b: vec3f, c: vec3f) -> f32 {
    return 2.0 * atan2(abs(dot(a, cross(b, c))), 1.0 + dot(a, b) + dot(b, c) + dot(c, a));
}

// The unit part of `to` across `origin` (0 where there is none).
fn across(origin: vec3f, to: vec3f) -> vec3f {
    let v = to - origin * dot(origin, to);
    let len = length(v);
    return select(vec3f(0.0), v / len, len > 0.0);
}

// prm::cone::spherical_triangle: xyz a direction uniform in solid angle over the spherical
// triangle (a, b, c) from (u1, u2), w its solid angle; w = 0 where it cannot be sampled.
fn spherical_triangle(a: vec3f, b: vec3f, c: vec3f, u1: f32, u2: f32) -> vec4f {
    let area = solid_angle(a, b, c);
    let ab = across(a, b);
    let ac = across(a, c);
    if !(area > 1e-7) || all(ab == vec3f(0.0)) || all(ac == vec3f(0.0)) {
        return vec4f(0.0);
    }
    let alpha = acos(clamp(dot(ab, ac), -1.0, 1.0));
    let sin_alpha = sin(alpha);
    let cos_alpha = cos(alpha);
    let s = sin(u1 * area - alpha);
    let t = cos(u1 * area - alpha);
    let u = t - cos_alpha;
    let v = s + sin_alpha * dot(a, b);
    var q = ((v * t - u * s) * cos_alpha - v) / ((v * s + u * t) * sin_alpha);
    // Not finite: the triangle is too thin to sample.
    if !(abs(q) < 3.4e38) {
        return vec4f(0.0);
    }
    q = clamp(q, -1.0, 1.0);
    let c2 = a * q + ac * sqrt(max(1.0 - q * q, 0.0));
    let z = 1.0 - u2 * (1.0 - dot(c2, b));
    let bc = across(b, c2);
    var dir = b;
    if any(bc != vec3f(0.0)) {
        dir = b * z + bc * sqrt(max(1.0 - z * z, 0.0));
    }
    let len = length(dir);
    if !(len > 0.0) {
        return vec4f(0.0);
    }
    return vec4f(dir / len, area);
}
