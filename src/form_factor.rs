//! Lambert's contour integral: the form factor from a differential receiver to a polygon,
//! `F = 1/(2 pi) sum_i gamma_i n . Gamma_i / |Gamma_i|`, `Gamma_i = V_i x V_{i+1}` for the
//! vectors V_i from the receiver to the vertices and gamma_i the angle between them. The
//! formula needs the whole polygon above the receiver's plane, so it is clipped first.
//!
//! Polygon area lights ([`crate::light::Aperture::Polygon`]) and the reference baker's virtual
//! polygon lights both use it.

use glam::Vec3;

/// The form factor from a differential receiver (p, n) to the polygon `poly`, whose vertices lie
/// in a plane and are wound counter-clockwise seen from its emitting front. Parts of the polygon
/// below the receiver's plane are clipped away. In [0, 1].
pub fn point_to_polygon(p: Vec3, n: Vec3, poly: &[Vec3]) -> f32 {
    // Most receivers see the whole polygon above their plane: then the clip would give it back
    // as it is, and it is used without the copy.
    let clipped;
    let clipped = if wholly_above(poly, p, n) {
        poly
    } else {
        clipped = clip_above_plane(poly, p, n);
        &clipped[..]
    };
    if clipped.len() < 3 {
        return 0.0;
    }
    let mut sum = 0.0f64;
    for k in 0..clipped.len() {
        let a = (clipped[k] - p).as_dvec3();
        let b = (clipped[(k + 1) % clipped.len()] - p).as_dvec3();
        let g = a.cross(b);
        let gl = g.length();
        if gl <= 0.0 {
            continue;
        }
        let angle = g.length().atan2(a.dot(b));
        sum += angle * n.as_dvec3().dot(g / gl);
    }
    (sum.abs() / (2.0 * std::f64::consts::PI)).min(1.0) as f32
}

/// The part of polygon `poly` on the positive side of the plane through `p` with normal `n`
/// (Sutherland-Hodgman against one plane).
///
/// Heights within 1e-5 of the polygon's size are taken as zero: a light lying in the receiver's
/// own plane would otherwise leave a round-off sliver whose contour integral is anything
/// between 0 and 1, and light its own surface.
pub fn clip_above_plane(poly: &[Vec3], p: Vec3, n: Vec3) -> Vec<Vec3> {
    let tol = clip_tolerance(poly, p);
    let mut out = Vec::with_capacity(poly.len() + 1);
    for k in 0..poly.len() {
        let (a, b) = (poly[k], poly[(k + 1) % poly.len()]);
        let (da, db) = ((a - p).dot(n) - tol, (b - p).dot(n) - tol);
        if da > 0.0 {
            out.push(a);
        }
        if (da > 0.0) != (db > 0.0) && da != db {
            out.push(a + (b - a) * (da / (da - db)));
        }
    }
    out
}

/// The height above the receiver's plane under which [`clip_above_plane`] takes a corner as
/// on or below it: 1e-5 of the polygon's furthest corner from `p`.
fn clip_tolerance(poly: &[Vec3], p: Vec3) -> f32 {
    let scale = poly.iter().map(|v| (*v - p).length()).fold(0.0f32, f32::max);
    1e-5 * scale
}

/// Whether [`clip_above_plane`] keeps every corner of `poly` and adds none (all above its
/// tolerance): it would return the polygon as it is.
fn wholly_above(poly: &[Vec3], p: Vec3, n: Vec3) -> bool {
    let tol = clip_tolerance(poly, p);
    poly.iter().all(|v| (*v - p).dot(n) - tol > 0.0)
}
