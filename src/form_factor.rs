//! Lambert's contour integral: the form factor from a differential receiver to a polygon,
//! `F = 1/(2 pi) sum_i gamma_i n . Gamma_i / |Gamma_i|`, `Gamma_i = V_i x V_{i+1}` for the
//! vectors V_i from the receiver to the vertices and gamma_i the angle between them. The
//! formula needs the whole polygon above the receiver's plane, so it is clipped first.
//!
//! Polygon area lights ([`crate::light::Aperture::Polygon`]) and the bakers' virtual polygon
//! lights use it. The sum is taken in f32, four edges at a time, where that is accurate (the
//! receiver within 64 edge lengths of the polygon, off its edges), else in f64.

use glam::{Vec3, Vec4};

/// The form factor from a differential receiver (p, n) to the polygon `poly`, whose vertices lie
/// in a plane and are wound counter-clockwise seen from its emitting front. Parts of the polygon
/// below the receiver's plane are clipped away. In [0, 1].
pub fn point_to_polygon(p: Vec3, n: Vec3, poly: &[Vec3]) -> f32 {
    // Most receivers see the whole polygon above their plane: then the clip would give it back
    // as it is, and it is used without the copy.
    let seen = Seen::of(poly, p, n);
    let clipped;
    let (clipped, seen) = if seen.wholly_above() {
        (poly, seen)
    } else {
        clipped = clip_above_plane(poly, p, n);
        (&clipped[..], Seen::of(&clipped, p, n))
    };
    if clipped.len() < 3 {
        return 0.0;
    }
    let fast = match clipped.len() <= 8 && seen.well_conditioned() {
        true => contour_f32x4(p, n, clipped),
        false => None,
    };
    let sum = fast.map_or_else(|| contour_f64(p, n, clipped), f64::from);
    (sum.abs() / (2.0 * std::f64::consts::PI)).min(1.0) as f32
}

/// The largest ratio of the receiver's distance to a polygon's edge length for which
/// [`contour_f32x4`] is used. Its relative error grows as distance / size (the edge terms,
/// of order size / distance, cancel to order (size / distance)²). Within it, the f32 sum is
/// within 1.1e-4 of the f64 one, relative to the larger of the sum and a thousandth of the
/// edge terms' order, 2 pi size / distance (a receiver's cosine can cancel the sum itself to
/// nothing; tested).
const F32_MAX_RATIO: f32 = 64.0;

/// A polygon as a receiver sees it, in one pass over its corners: the squared distance to the
/// furthest, the squared length of the longest edge, and the lowest height above the receiver's
/// plane.
struct Seen {
    far2: f32,
    edge2: f32,
    low: f32,
}

impl Seen {
    fn of(poly: &[Vec3], p: Vec3, n: Vec3) -> Seen {
        let mut s = Seen { far2: 0.0, edge2: 0.0, low: f32::INFINITY };
        let mut w = poly.last().copied().unwrap_or(p);
        for v in poly {
            // Edges from the last corner round: the same set.
            let d = *v - p;
            s.far2 = s.far2.max(d.length_squared());
            s.edge2 = s.edge2.max((*v - w).length_squared());
            w = *v;
            s.low = s.low.min(d.dot(n));
        }
        s
    }

    /// Whether [`clip_above_plane`] would keep every corner and add none: each above its
    /// tolerance, `CLIP_REL sqrt(far2)`, compared squared, with a margin over the rounding of
    /// either form (so that a corner this takes as above, the clip does too).
    fn wholly_above(&self) -> bool {
        self.low > 0.0 && self.low * self.low > (CLIP_REL * CLIP_REL * 1.0001) * self.far2
    }

    /// Whether every corner lies within [`F32_MAX_RATIO`] of the longest edge from the receiver.
    fn well_conditioned(&self) -> bool {
        self.far2 <= F32_MAX_RATIO * F32_MAX_RATIO * self.edge2
    }
}

/// The contour sum `sum_i gamma_i n . Gamma_i / |Gamma_i|` in f64, for any polygon.
fn contour_f64(p: Vec3, n: Vec3, poly: &[Vec3]) -> f64 {
    let mut sum = 0.0f64;
    let n = n.as_dvec3();
    for k in 0..poly.len() {
        let a = (poly[k] - p).as_dvec3();
        let b = (poly[(k + 1) % poly.len()] - p).as_dvec3();
        let g = a.cross(b);
        let gl = g.length();
        if gl <= 0.0 {
            continue;
        }
        sum += gl.atan2(a.dot(b)) * n.dot(g / gl);
    }
    sum
}

/// The contour sum in f32, four edges at a time (a polygon of at most 8 corners; the bakers'
/// virtual lights have at most 8). A bake evaluates it for every texel and virtual light, and
/// the f64 sum with libm's `atan2` was a fifth of the incremental baker's time.
///
/// `Gamma_i` is taken as `V_i x (V_{i+1} - V_i)`: the same vector, but its rounding is relative
/// to the edge, not to the distance. The angle is [`atan2_f32x4`]'s.
///
/// `None` where f32 is not enough: a receiver within 1e-2 of an edge's length from the edge
/// itself (an angle near pi), where `Gamma_i`'s direction rests on the last digits.
fn contour_f32x4(p: Vec3, n: Vec3, poly: &[Vec3]) -> Option<f32> {
    let m = poly.len();
    // The corners from the receiver, and the edges, coordinate by coordinate; lanes past the
    // last edge are zero.
    let mut a = [[0.0f32; 8]; 3];
    let mut e = [[0.0f32; 8]; 3];
    for k in 0..m {
        let (v, w) = (poly[k] - p, poly[(k + 1) % m] - p);
        for c in 0..3 {
            a[c][k] = v[c];
            e[c][k] = w[c] - v[c];
        }
    }
    let at = |x: &[f32; 8], first: usize| Vec4::from_slice(&x[first..first + 4]);
    let mut sum = Vec4::ZERO;
    for first in (0..m).step_by(4) {
        let (ax, ay, az) = (at(&a[0], first), at(&a[1], first), at(&a[2], first));
        let (ex, ey, ez) = (at(&e[0], first), at(&e[1], first), at(&e[2], first));
        let (gx, gy, gz) = (ay * ez - az * ey, az * ex - ax * ez, ax * ey - ay * ex);
        let gl = (gx * gx + gy * gy + gz * gz).sqrt();
        // V_{i+1} = V_i + e_i.
        let (bx, by, bz) = (ax + ex, ay + ey, az + ez);
        let dot = ax * bx + ay * by + az * bz;
        let (a2, b2) = (ax * ax + ay * ay + az * az, bx * bx + by * by + bz * bz);
        if (dot.cmplt(Vec4::ZERO) & (gl * gl).cmplt(a2 * b2 * 1e-4)).any() {
            return None;
        }
        let term = atan2_f32x4(gl, dot) * (gx * n.x + gy * n.y + gz * n.z) / gl;
        // Padding lanes and degenerate edges (gl = 0) give 0/0: they add nothing.
        sum += Vec4::select(gl.cmpgt(Vec4::ZERO), term, Vec4::ZERO);
    }
    Some(sum.element_sum())
}

/// `atan2(y, x)` lane by lane for `y >= 0` (an angle in [0, pi]), within 3e-7 of libm's
/// relative to the angle (tested). The ratio of the smaller to the larger argument is brought
/// into [0, tan(pi/8)] by `atan(t) = pi/4 + atan((t - 1)/(t + 1))`; there `atan(u) = u P(u²)`,
/// P of degree 4 fitted to atan on Chebyshev nodes (relative error 1.8e-8 in exact arithmetic).
fn atan2_f32x4(y: Vec4, x: Vec4) -> Vec4 {
    use std::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI};
    const TAN_PI_8: f32 = 0.414_213_57;
    const P: [f32; 5] = [0.999_999_98, -0.333_327_97, 0.199_744_05, -0.138_514_78, 0.079_849_63];
    let ax = x.abs();
    let swap = y.cmpgt(ax);
    let (lo, hi) = (Vec4::select(swap, ax, y), Vec4::select(swap, y, ax));
    // (t - 1)/(t + 1) with t = lo/hi is (lo - hi)/(lo + hi): one division either way.
    let big = lo.cmpgt(hi * TAN_PI_8);
    let u = Vec4::select(big, lo - hi, lo) / Vec4::select(big, lo + hi, hi);
    let s = u * u;
    let poly = P.iter().rev().fold(Vec4::ZERO, |acc, c| acc * s + Vec4::splat(*c));
    let a = Vec4::select(big, Vec4::splat(FRAC_PI_4), Vec4::ZERO) + u * poly;
    let a = Vec4::select(swap, Vec4::splat(FRAC_PI_2) - a, a);
    Vec4::select(x.cmplt(Vec4::ZERO), Vec4::splat(PI) - a, a)
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
/// on or below it, relative to the polygon's furthest corner from the receiver.
const CLIP_REL: f32 = 1e-5;

/// [`CLIP_REL`] of the distance from `p` to the furthest corner of `poly`.
fn clip_tolerance(poly: &[Vec3], p: Vec3) -> f32 {
    let scale = poly.iter().map(|v| (*v - p).length()).fold(0.0f32, f32::max);
    CLIP_REL * scale
}

/// The point of triangle `t` nearest to `p` (Ericson, *Real-Time Collision Detection*, 5.1.5:
/// the Voronoi region of a corner, an edge or the face).
pub fn closest_point(t: &[Vec3; 3], p: Vec3) -> Vec3 {
    let (a, b, c) = (t[0], t[1], t[2]);
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = va + vb + vc;
    if !(denom > 0.0) {
        return (a + b + c) / 3.0;
    }
    a + ab * (vb / denom) + ac * (vc / denom)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn the_lane_angle_agrees_with_libm_over_every_octant() {
        let mut worst = 0.0f64;
        for k in 0..=100_000 {
            let theta = std::f64::consts::PI * k as f64 / 100_000.0;
            for r in [1e-20f64, 1.0, 3.7, 1e20] {
                let (y, x) = ((r * theta.sin()).abs() as f32, (r * theta.cos()) as f32);
                let ours = atan2_f32x4(Vec4::splat(y), Vec4::splat(x)).x as f64;
                let libm = (y as f64).atan2(x as f64);
                worst = worst.max(if libm == 0.0 { ours.abs() } else { (ours - libm).abs() / libm });
            }
        }
        assert!(worst < 3e-7, "relative error {worst:e}");
    }

    /// A random convex polygon of `m` corners in a plane: a regular polygon of radius `size`,
    /// its corners jittered along the circle, around `centre` facing `normal`.
    fn polygon(rng: &mut impl Rng, m: usize, centre: Vec3, normal: Vec3, size: f32) -> Vec<Vec3> {
        let (t, b) = normal.any_orthonormal_pair();
        (0..m)
            .map(|k| {
                let phi = std::f32::consts::TAU * (k as f32 + 0.4 * rng.random::<f32>()) / m as f32;
                centre + size * (phi.cos() * t + phi.sin() * b)
            })
            .collect()
    }

    #[test]
    fn the_f32_contour_sum_agrees_with_the_f64_one_wherever_it_is_used() {
        // Receivers at 1e-3 to 100 sizes from polygons of 3 to 8 corners at any orientation,
        // including grazing ones and polygons the receiver's plane cuts (clipped first).
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(7);
        let (mut used, mut worst) = (0, 0.0f64);
        for _ in 0..200_000 {
            let m = rng.random_range(3..=8);
            let size = 10f32.powf(rng.random_range(-2.0..2.0));
            let unit = |rng: &mut rand_pcg::Pcg64Mcg| {
                Vec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
                .normalize_or(Vec3::Z)
            };
            let dist = size * 10f32.powf(rng.random_range(-3.0..2.0));
            let p = Vec3::new(3.0, -2.0, 1.0) * rng.random_range(0.0..10.0f32);
            let centre = p + unit(&mut rng) * dist;
            let (normal, n) = (unit(&mut rng), unit(&mut rng));
            let poly = polygon(&mut rng, m, centre, normal, size);
            let clipped = clip_above_plane(&poly, p, n);
            if clipped.len() < 3 || clipped.len() > 8 || !Seen::of(&clipped, p, n).well_conditioned() {
                continue;
            }
            used += 1;
            let Some(fast) = contour_f32x4(p, n, &clipped) else { continue };
            let (fast, exact) = (fast as f64, contour_f64(p, n, &clipped));
            // Relative to the largest term's size (the receiver's cosine may cancel the sum
            // itself to nothing).
            let scale = exact.abs().max(1e-3 * 2.0 * std::f64::consts::PI * (size / dist.max(size)) as f64);
            worst = worst.max((fast - exact).abs() / scale);
        }
        assert!(used > 100_000, "only {used} cases took the f32 sum");
        assert!(worst < 2e-4, "relative error {worst:e}");
    }

    #[test]
    fn a_polygon_taken_as_wholly_above_is_one_the_clip_keeps_as_it_is() {
        // Corners at heights around the clip's tolerance, so that both answers occur.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(11);
        let (mut above, mut below) = (0, 0);
        for _ in 0..100_000 {
            let p = Vec3::new(rng.random_range(-9.0..9.0), rng.random_range(-9.0..9.0), 0.0);
            let n = Vec3::Z;
            let far = rng.random_range(0.1..10.0f32);
            let poly: Vec<Vec3> = (0..rng.random_range(3..=6))
                .map(|k| {
                    let h = CLIP_REL * far * rng.random_range(0.5..1.5);
                    let phi = k as f32;
                    p + Vec3::new(far * phi.cos(), far * phi.sin(), h)
                })
                .collect();
            if Seen::of(&poly, p, n).wholly_above() {
                above += 1;
                assert_eq!(clip_above_plane(&poly, p, n), poly);
            } else {
                below += 1;
            }
        }
        assert!(above > 1000 && below > 1000, "{above} above, {below} not");
    }
}
