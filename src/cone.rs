//! A spot light's power on a triangle: its falloff integrated over the triangle's solid angle;
//! and the spherical triangle's solid angle and even sampling ([`spherical_triangle`]), for
//! the near field's concentration.
//!
//! [`crate::Light::triangle_power`] gives a cell or texel triangle `I x` its solid angle, exact
//! at any distance. For a spot it took the falloff along the mean of the corner directions,
//! which holds while the falloff is smooth over the triangle. It is not near a surface: a spot
//! 3 cm above a floor, aimed at it with a 20° cone, lights a disk 2 cm across, and a cell
//! triangle half a metre long that holds that disk has its corners' mean direction well
//! outside the cone. The entry weights read no light at all from such a spot (its whole power
//! lost, 0.50 of it at 10 cm, and a smooth 40°-60° cone 1.25 of it at 3 cm and 0.01 at 1 cm).
//!
//! Here the falloff is integrated. With `s = w.d` (d the spot's axis) and `A(s)` the solid
//! angle of the part of the triangle within the cap `w.d >= s`, the falloff `f(s)` (0 below
//! the outer cone's cosine `co`, 1 above the inner's `ci`, `t²` between with `t = (s - co) /
//! (ci - co)`) integrates by parts to
//!
//! `int f dw = int_co^ci f'(s) A(s) ds = int_0^1 2t A(co + t (ci - co)) dt`,
//!
//! and a hard cone (`ci = co`) is `A(co)`. `A` is exact: the triangle is a fan of three
//! triangles from the cap's centre `d` to its edges (signed by their winding), and the part of
//! a fan triangle within the cap splits along its edge where the edge's great circle crosses the
//! cap's rim: where the edge is inside the cap, that piece is the spherical triangle from `d`
//! (Van Oosterom and Strackee), where it is outside, the cap's sector over the same azimuth,
//! `(1 - c) x` its angle. The `t` integral takes 8 Gauss-Legendre points over the part of
//! `[0, 1]` where `A` is neither the whole triangle nor nothing: a cap of cosine at least 0 is
//! convex on the sphere, so the triangle lies in it once its corners do, and it meets none
//! beyond the largest `w.d` over the triangle, 4 points where that part is at most half of
//! `[0, 1]`. A triangle across which a smooth falloff varies by under 6 % of its span keeps
//! the falloff along its corners' mean direction: the fan's pieces are as large as the cone,
//! and for a small, far triangle their sum loses its solid angle to f32 rounding.
//!
//! The GPU's twin is `cone_solid_angle` in `shaders/lights.wgsl`: the same operations in the
//! same order.

use glam::Vec3;

/// Gauss-Legendre nodes and weights on [0, 1], 4 points.
const GAUSS4: [(f32, f32); 4] = [
    (0.069_431_84, 0.173_927_42),
    (0.330_009_5, 0.326_072_58),
    (0.669_990_5, 0.326_072_58),
    (0.930_568_16, 0.173_927_42),
];

/// Gauss-Legendre nodes and weights on [0, 1], 8 points.
const GAUSS: [(f32, f32); 8] = [
    (0.019_855_072, 0.050_614_27),
    (0.101_666_76, 0.111_190_52),
    (0.237_233_79, 0.156_853_32),
    (0.408_282_68, 0.181_341_89),
    (0.591_717_3, 0.181_341_89),
    (0.762_766_2, 0.156_853_32),
    (0.898_333_24, 0.111_190_52),
    (0.980_144_9, 0.050_614_27),
];

/// The solid angle, weighted by the spot's falloff, of the spherical triangle with unit corner
/// directions `dirs` seen from the light (wound clockwise seen from the light, as a triangle
/// facing it with corners counter-clockwise from its front is). `whole` is its whole solid
/// angle (the caller's, exact for small far triangles), `axis` the spot's unit direction,
/// `cos_inner >= cos_outer >= 0` its cones' cosines.
pub fn spot_solid_angle(dirs: [Vec3; 3], whole: f32, axis: Vec3, cos_inner: f32, cos_outer: f32) -> f32 {
    let [a, b, c] = dirs;
    let lowest = axis.dot(a).min(axis.dot(b)).min(axis.dot(c));
    if lowest >= cos_inner {
        return whole;
    }
    // Beyond the outer cone by more than the triangle's angular radius about its corners' mean
    // direction (the cap of that radius holds the triangle): nothing, for a few products.
    let mean = (a + b + c).normalize_or_zero();
    let cos_radius = mean.dot(a).min(mean.dot(b)).min(mean.dot(c));
    let (sin_radius, sin_outer) =
        ((1.0 - cos_radius * cos_radius).max(0.0).sqrt(), (1.0 - cos_outer * cos_outer).max(0.0).sqrt());
    if cos_radius > 0.0 && axis.dot(mean) < cos_outer * cos_radius - sin_outer * sin_radius {
        return 0.0;
    }
    // The axis inside the triangle: its edges' great circles have it on their inner side.
    let holds = |d: Vec3| d.dot(a.cross(b)) < 0.0 && d.dot(b.cross(c)) < 0.0 && d.dot(c.cross(a)) < 0.0;
    let highest = if holds(axis) {
        1.0
    } else {
        arc_highest(axis, a, b).max(arc_highest(axis, b, c)).max(arc_highest(axis, c, a))
    };
    if highest < cos_outer {
        return 0.0;
    }
    // A triangle across which a smooth falloff varies by under 6 % of its span takes it along
    // its corners' mean direction: within (spread / span)² / 4 < 1e-3 of the mean there, and
    // the fan about the axis would lose a small, far triangle's solid angle to rounding (a 1
    // mm cell 2.4 m away: 1e-3 of it).
    let span = cos_inner - cos_outer;
    if span > 1e-6 && highest - lowest < 0.06 * span {
        return whole * crate::light::spot_falloff_cos(axis.dot(mean), cos_inner, cos_outer);
    }
    let behind = holds(-axis);
    let within = |cap: f32| in_cap(dirs, axis, cap, behind).clamp(0.0, whole);
    if span <= 1e-6 {
        return within(cos_outer);
    }
    let lo = ((lowest - cos_outer) / span).clamp(0.0, 1.0);
    let hi = ((highest - cos_outer) / span).clamp(lo, 1.0);
    let mut sum = whole * lo * lo;
    // Over half the falloff's span or less, 4 points (the fan's work halved).
    let rule: &[(f32, f32)] = if hi - lo > 0.5 { &GAUSS } else { &GAUSS4 };
    for &(x, w) in rule {
        let t = lo + (hi - lo) * x;
        sum += (hi - lo) * w * 2.0 * t * within(cos_outer + t * span);
    }
    sum
}

/// The largest `w.d` over the minor arc from unit `p` to unit `q`: at an end, or where the arc
/// passes nearest `d` (`d` less its part along the arc's pole, whose length that largest is).
fn arc_highest(d: Vec3, p: Vec3, q: Vec3) -> f32 {
    let m = p.cross(q);
    let mut best = d.dot(p).max(d.dot(q));
    let m2 = m.length_squared();
    if m2 > 0.0 {
        let x = d - m * (d.dot(m) / m2);
        if p.cross(x).dot(m) > 0.0 && x.cross(q).dot(m) > 0.0 {
            best = best.max(x.length());
        }
    }
    best
}

/// The solid angle of the triangle within the cap `w.d >= cap`, from the signed fan about `d`.
/// With `-d` inside the triangle (`behind`), the fan counts the triangle's part of the cap less
/// the whole cap.
fn in_cap(dirs: [Vec3; 3], d: Vec3, cap: f32, behind: bool) -> f32 {
    let [a, b, c] = dirs;
    // The corners wind clockwise seen from the light: each fan triangle's sign is negative.
    let fan = -(fan_in_cap(d, a, b, cap) + fan_in_cap(d, b, c, cap) + fan_in_cap(d, c, a, cap));
    if behind {
        fan + std::f32::consts::TAU * (1.0 - cap)
    } else {
        fan
    }
}

/// The signed solid angle of the part of the spherical triangle (d, p, q) within the cap
/// `w.d >= cap`: the edge from `p` to `q` cut where it crosses the cap's rim, each piece the
/// triangle from `d` (inside the cap) or the cap's sector (outside).
fn fan_in_cap(d: Vec3, p: Vec3, q: Vec3, cap: f32) -> f32 {
    let m = p.cross(q);
    let len = m.length();
    if !(len > 0.0) {
        return 0.0;
    }
    let pole = m / len;
    // The rim (w.d = cap) meets the edge's great circle (w.pole = 0) at cap d + y e + z (d x e),
    // e the unit part of the pole across d.
    let k = d.dot(pole);
    let across2 = 1.0 - k * k;
    let mut cuts = [Vec3::ZERO; 2];
    let mut n = 0;
    if across2 > 1e-12 {
        let across = across2.sqrt();
        let e = (pole - d * k) / across;
        let y = -cap * k / across;
        let z2 = 1.0 - cap * cap - y * y;
        if z2 > 0.0 {
            let z = z2.sqrt();
            let (base, side) = (d * cap + e * y, d.cross(e) * z);
            for x in [base + side, base - side] {
                if p.cross(x).dot(m) > 0.0 && x.cross(q).dot(m) > 0.0 {
                    cuts[n] = x;
                    n += 1;
                }
            }
        }
    }
    if n == 2 && p.dot(cuts[0]) < p.dot(cuts[1]) {
        cuts.swap(0, 1);
    }
    let mut sum = 0.0;
    let mut u = p;
    for v in cuts[..n].iter().copied().chain([q]) {
        sum += fan_piece(d, u, v, cap);
        u = v;
    }
    sum
}

/// One piece of a fan triangle between unit `u` and `v` on its edge, all of the piece's edge on
/// one side of the rim.
fn fan_piece(d: Vec3, u: Vec3, v: Vec3, cap: f32) -> f32 {
    let turn = d.dot(u.cross(v));
    let (du, dv) = (d.dot(u), d.dot(v));
    let mid = u + v;
    if d.dot(mid) >= cap * mid.length() {
        2.0 * turn.atan2(1.0 + du + dv + u.dot(v))
    } else {
        (1.0 - cap) * turn.atan2(u.dot(v) - du * dv)
    }
}

/// The solid angle (sr) of the spherical triangle with unit corners `a`, `b`, `c` (Van
/// Oosterom and Strackee: accurate for small triangles, where the angle sum is not).
pub fn solid_angle(a: Vec3, b: Vec3, c: Vec3) -> f32 {
    2.0 * a.dot(b.cross(c)).abs().atan2(1.0 + a.dot(b) + b.dot(c) + c.dot(a))
}

/// A direction uniform in solid angle over the spherical triangle with unit corners `a`, `b`,
/// `c`, from two uniforms in [0, 1), and the triangle's solid angle (sr); `None` for a
/// triangle too thin or too small to sample (under 1e-7 sr, or a corner angle that is not a
/// number). Arvo's mapping ("Stratified sampling of spherical triangles", SIGGRAPH 1995): the
/// first uniform picks the sub-triangle `(a, b, c')` holding that share of the area, the second
/// a point along the arc from `b` to `c'` evenly in the area it sweeps. A stratified grid of
/// uniforms stays stratified over the triangle. The near field's concentration
/// (`prm_runtime::cpu::concentrate`) places its points by it where a light is near a cell.
pub fn spherical_triangle(a: Vec3, b: Vec3, c: Vec3, u1: f32, u2: f32) -> Option<(Vec3, f32)> {
    let area = solid_angle(a, b, c);
    if !(area > 1e-7) {
        return None;
    }
    let tangent = |from: Vec3, to: Vec3| (to - from * from.dot(to)).try_normalize();
    let (ab, ac) = (tangent(a, b)?, tangent(a, c)?);
    let alpha = ab.dot(ac).clamp(-1.0, 1.0).acos();
    let (sin_alpha, cos_alpha) = alpha.sin_cos();
    let (s, t) = (u1 * area - alpha).sin_cos();
    let u = t - cos_alpha;
    let v = s + sin_alpha * a.dot(b);
    let q = ((v * t - u * s) * cos_alpha - v) / ((v * s + u * t) * sin_alpha);
    if !q.is_finite() {
        return None;
    }
    let q = q.clamp(-1.0, 1.0);
    let c2 = a * q + ac * (1.0 - q * q).max(0.0).sqrt();
    let z = 1.0 - u2 * (1.0 - c2.dot(b));
    let dir = match tangent(b, c2) {
        Some(bc) => b * z + bc * (1.0 - z * z).max(0.0).sqrt(),
        None => b,
    };
    dir.try_normalize().map(|d| (d, area))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn falloff(s: f32, ci: f32, co: f32) -> f32 {
        crate::light::spot_falloff_cos(s, ci, co)
    }

    /// The falloff-weighted solid angle by quadrature: the flat triangle split in four at its
    /// edges' midpoints, 6 levels everywhere and down to 12 where the falloff at the corners
    /// differs by more than 0.01, each piece its exact solid angle (f64) times the falloff
    /// along its centroid.
    fn reference(tri: [Vec3; 3], axis: Vec3, ci: f32, co: f32) -> f64 {
        fn go(t: [glam::DVec3; 3], axis: glam::DVec3, ci: f32, co: f32, depth: u32) -> f64 {
            let f = |p: glam::DVec3| falloff(p.normalize().dot(axis) as f32, ci, co) as f64;
            let spread = {
                let v = t.map(f);
                v[0].max(v[1]).max(v[2]) - v[0].min(v[1]).min(v[2])
            };
            if depth >= 12 || (depth >= 6 && spread <= 0.01) {
                let d = t.map(|p| p.normalize());
                let omega = 2.0
                    * d[0]
                        .dot(d[1].cross(d[2]))
                        .abs()
                        .atan2(1.0 + d[0].dot(d[1]) + d[1].dot(d[2]) + d[2].dot(d[0]));
                return omega * f((t[0] + t[1] + t[2]) / 3.0);
            }
            let m = [(t[0] + t[1]) / 2.0, (t[1] + t[2]) / 2.0, (t[2] + t[0]) / 2.0];
            [[t[0], m[0], m[2]], [m[0], t[1], m[1]], [m[2], m[1], t[2]], [m[0], m[1], m[2]]]
                .into_iter()
                .map(|s| go(s, axis, ci, co, depth + 1))
                .sum()
        }
        go(tri.map(|p| p.as_dvec3()), axis.as_dvec3(), ci, co, 0)
    }

    /// A point uniform in the cube [-1, 1]³.
    fn in_cube(rng: &mut rand_pcg::Pcg64) -> Vec3 {
        Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0))
    }

    /// A triangle wound clockwise seen from the origin (the light).
    fn seen_clockwise(t: [Vec3; 3]) -> [Vec3; 3] {
        if t[0].dot((t[1] - t[0]).cross(t[2] - t[0])) > 0.0 {
            [t[0], t[2], t[1]]
        } else {
            t
        }
    }

    /// Random triangles and cones, hard and smooth, against a fine quadrature: hard cones
    /// within 1e-4 of the triangle's whole solid angle (measured: 6e-5 at worst), smooth ones
    /// within 3e-3 (1.7e-3: the 8 Gauss points across the kinks of `A`, where the rim passes a
    /// corner; 16 points gave 9e-5 for twice the work); and cell-sized triangles across the
    /// falloff's band within 3e-3 (2.6e-3 with 4 points where they may be taken, 1.4e-3 with 8).
    #[test]
    fn spot_solid_angle_matches_sampling() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let mut worst = 0.0f64;
        for case in 0..200 {
            let centre = in_cube(&mut rng);
            let size = rng.random_range(0.05f32..1.5);
            let tri = seen_clockwise(std::array::from_fn(|_| centre + in_cube(&mut rng) * size));
            let axis = in_cube(&mut rng).normalize();
            let outer = rng.random_range(0.1f32..std::f32::consts::FRAC_PI_2);
            let inner = if case % 3 == 0 { outer } else { rng.random_range(0.0..outer) };
            let (ci, co) = (inner.cos(), outer.cos());
            let dirs = tri.map(|p| p.normalize());
            let whole = solid_angle(dirs[0], dirs[1], dirs[2]);
            if !(whole > 1e-3) {
                continue;
            }
            let got = spot_solid_angle(dirs, whole, axis, ci, co) as f64;
            let want = reference(tri, axis, ci, co);
            let err = (got - want).abs() / whole as f64;
            worst = worst.max(err);
            let tolerance = if case % 3 == 0 { 1e-4 } else { 3e-3 };
            assert!(
                err < tolerance,
                "case {case}: {got} vs {want} of {whole} (inner {inner}, outer {outer})"
            );
        }
        println!("worst {worst:.2e} of the whole");
        // Cell-sized triangles across the falloff's band, where fewer points are taken.
        let mut worst = 0.0f64;
        for case in 0..200 {
            let axis = Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), 1.0).normalize();
            let outer = rng.random_range(0.2f32..1.4);
            let inner = rng.random_range(0.5 * outer..outer);
            let (ci, co) = (inner.cos(), outer.cos());
            // A direction inside the band, and a triangle about it 1-5 m away, 5-50 cm across.
            let off = 0.5 * (inner + outer);
            let side = axis.any_orthonormal_vector();
            let dir = (axis * off.cos() + side * off.sin()).normalize();
            let centre = dir * rng.random_range(1.0f32..5.0);
            let size = rng.random_range(0.05f32..0.5);
            let tri = seen_clockwise(std::array::from_fn(|_| centre + in_cube(&mut rng) * size));
            // Not a sliver: f32 rounding in the fan's pieces, as long as the triangle, is
            // measured against its area (a 5 cm sliver 5 m away of 1e-6 sr: 4e-3 of it).
            let longest = (0..3).map(|k| (tri[k] - tri[(k + 1) % 3]).length_squared()).fold(0.0f32, f32::max);
            let fat = 2.0 * (tri[1] - tri[0]).cross(tri[2] - tri[0]).length() / longest;
            let dirs = tri.map(|p| p.normalize());
            let whole = solid_angle(dirs[0], dirs[1], dirs[2]);
            if !(whole > 1e-6 && fat > 0.3) {
                continue;
            }
            let got = spot_solid_angle(dirs, whole, axis, ci, co) as f64;
            let want = reference(tri, axis, ci, co);
            let err = (got - want).abs() / whole as f64;
            worst = worst.max(err);
            assert!(err < 3e-3, "band case {case}: {got} vs {want} of {whole}");
        }
        println!("worst {worst:.2e} of the whole across the band");
    }
    /// A triangle's solid angle and the integral of a smooth function over it by a fine
    /// quadrature of the planar triangle (`dw = cos / r² dA`), for the sampler's tests.
    fn brute_force(p: [Vec3; 3], f: impl Fn(Vec3) -> f32) -> (f64, f64) {
        let n = (p[1] - p[0]).cross(p[2] - p[0]);
        let (area2, normal) = (n.length(), n.normalize());
        let m = 400;
        let (mut omega, mut sum) = (0.0f64, 0.0f64);
        for i in 0..m {
            for j in 0..m - i {
                for (fa, fb) in [
                    (i as f32 + 1.0 / 3.0, j as f32 + 1.0 / 3.0),
                    (i as f32 + 2.0 / 3.0, j as f32 + 2.0 / 3.0),
                ] {
                    if fa + fb > m as f32 {
                        continue;
                    }
                    let y = p[0] + (p[1] - p[0]) * (fa / m as f32) + (p[2] - p[0]) * (fb / m as f32);
                    let r2 = y.length_squared();
                    let dw = (normal.dot(y).abs() / (r2 * r2.sqrt())) as f64
                        * (0.5 * area2 / (m * m) as f32) as f64;
                    omega += dw;
                    sum += dw * f(y.normalize()) as f64;
                }
            }
        }
        (omega, sum)
    }

    #[test]
    fn spherical_triangle_samples_are_uniform_in_solid_angle() {
        // Triangles seen from the origin, from a wide one just above it to a small far one;
        // a stratified 128 x 128 grid of uniforms integrates a smooth lobe as the fine
        // quadrature does, within 1 % (the mapping's midpoints converge as 1/m: 0.6 % at worst
        // here, on the widest triangles; 1 % at 32 x 32), and every direction lies inside the
        // triangle.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(7);
        let d = Vec3::new(0.3, 0.8, -0.5).normalize();
        let f = |w: Vec3| (1.0 + w.dot(d)).powi(3);
        for case in 0..40 {
            let s = if case < 10 { 0.05 } else { 1.0 + 4.0 * rng.random::<f32>() };
            let centre =
                Vec3::new(rng.random::<f32>() - 0.5, -0.2 - rng.random::<f32>(), rng.random::<f32>() - 0.5);
            let p: [Vec3; 3] = std::array::from_fn(|_| {
                centre * s + Vec3::new(rng.random::<f32>() - 0.5, 0.0, rng.random::<f32>() - 0.5) * (0.4 + s)
            });
            let (omega, want) = brute_force(p, f);
            let corners = p.map(|q| q.normalize());
            let m = 128;
            let mut got = 0.0f64;
            let mut area = 0.0f32;
            for i in 0..m {
                for j in 0..m {
                    let (u1, u2) = ((i as f32 + 0.5) / m as f32, (j as f32 + 0.5) / m as f32);
                    let Some((w, a)) = spherical_triangle(corners[0], corners[1], corners[2], u1, u2) else {
                        panic!("case {case}: no direction for ({u1}, {u2})");
                    };
                    area = a;
                    got += f(w) as f64;
                    // Inside: on the triangle's side of each edge's great circle.
                    for k in 0..3 {
                        let (e0, e1, opp) = (corners[k], corners[(k + 1) % 3], corners[(k + 2) % 3]);
                        let side = e0.cross(e1);
                        assert!(
                            side.dot(w) * side.dot(opp) >= -1e-4,
                            "case {case}: a direction outside the triangle"
                        );
                    }
                }
            }
            let got = got * area as f64 / (m * m) as f64;
            assert!(
                (area as f64 - omega).abs() < 2e-3 * omega,
                "case {case}: solid angle {area} against {omega}"
            );
            assert!((got - want).abs() < 1e-2 * want, "case {case}: {got} against {want}");
        }
        assert!(spherical_triangle(Vec3::X, Vec3::X, Vec3::Y, 0.5, 0.5).is_none(), "a degenerate triangle");
    }
}
