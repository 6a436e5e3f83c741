//! Sampling shared by the bakers (precompute, reference baker): seeded random streams, cosine
//! directions, the radical inverse.
//!
//! Every random decision draws from a stream seeded by (seed, purpose tag, index), so a result
//! does not depend on which thread computed what: the same seed gives the same bytes at any
//! thread count (STYLE.md 8). The ground-truth tracer keeps its own small copy of these on
//! purpose: the judge shares no sampling code with what it judges.

use glam::Vec3;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

/// A per-index random stream derived from a seed and a purpose tag. Tags in use: 1 entry
/// placement, 2 k-means seeding, 3 gather walks (per texel), 4 scatter walks (per entry),
/// 5 enclosure rays, 10 + l photons of light l, 20 plane fitting, 30 reference texels. Tags
/// 10 + 10 and 10 + 20 meet the plane-fitting and texel tags: a level's 11th and 21st lights
/// share streams with those (correlated, not wrong; changing it would change every bake).
pub fn stream(seed: u64, tag: u64, index: u64) -> Pcg64Mcg {
    let mix = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ tag.wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ index.wrapping_mul(0xD1B5_4A32_D192_ED03);
    Pcg64Mcg::seed_from_u64(mix ^ (mix >> 29))
}

/// A cosine-distributed unit direction around unit `n` from two uniforms in [0, 1): the
/// density is `cos / pi` per steradian.
pub fn cosine_direction(n: Vec3, u1: f32, u2: f32) -> Vec3 {
    let (t, b) = n.any_orthonormal_pair();
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u1).max(0.0).sqrt()).normalize()
}

/// Van der Corput radical inverse in base 2: the `i`-th point of a low-discrepancy sequence
/// in [0, 1).
pub fn radical_inverse(i: u32) -> f32 {
    (i.reverse_bits() as f64 / 4_294_967_296.0) as f32
}

/// Point `i` of an `n`-point Hammersley set shifted by `shift` modulo 1 (Cranley-Patterson
/// rotation): each point is uniform in [0, 1)² (unbiased), the set stratifies the square. The
/// first directions of the gather's walks and of the far field's energy rays.
pub fn shifted_hammersley(i: u32, n: u32, shift: (f32, f32)) -> (f32, f32) {
    (((i as f32 + 0.5) / n as f32 + shift.0).fract(), (radical_inverse(i) + shift.1).fract())
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
    use rand::Rng;

    #[test]
    fn radical_inverse_is_the_bit_reversed_fraction() {
        let want = [0.0, 0.5, 0.25, 0.75, 0.125, 0.625, 0.375, 0.875];
        for (i, w) in want.iter().enumerate() {
            assert_eq!(radical_inverse(i as u32), *w);
        }
    }

    #[test]
    fn cosine_directions_have_the_cosine_moments() {
        // E[cos] = 2/3 and E[cos²] = 1/2 under the cos/pi density; 64² stratified samples
        // give both to well under 1e-3 (the stratified error is O(1/n)).
        let n = Vec3::new(0.3, -0.5, 0.8).normalize();
        let k = 64;
        let (mut c1, mut c2) = (0.0f64, 0.0f64);
        for i in 0..k {
            for j in 0..k {
                let d = cosine_direction(n, (i as f32 + 0.5) / k as f32, (j as f32 + 0.5) / k as f32);
                assert!((d.length() - 1.0).abs() < 1e-5 && d.dot(n) >= 0.0);
                c1 += d.dot(n) as f64;
                c2 += (d.dot(n) as f64).powi(2);
            }
        }
        let m = (k * k) as f64;
        assert!((c1 / m - 2.0 / 3.0).abs() < 1e-3, "E[cos] = {}", c1 / m);
        assert!((c2 / m - 0.5).abs() < 1e-3, "E[cos²] = {}", c2 / m);
    }

    #[test]
    fn streams_differ_by_tag_and_index_and_repeat_by_seed() {
        use rand::Rng;
        let first = |s: u64, t: u64, i: u64| stream(s, t, i).random::<u64>();
        assert_eq!(first(7, 1, 3), first(7, 1, 3));
        assert_ne!(first(7, 1, 3), first(7, 2, 3));
        assert_ne!(first(7, 1, 3), first(7, 1, 4));
        assert_ne!(first(7, 1, 3), first(8, 1, 3));
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
        // a stratified 128 x 128 grid (the mapping's midpoints converge as 1/m: 1 % off at 32 x 32
        // on the widest triangles) of uniforms integrates a smooth lobe as the fine
        // quadrature does, and every direction lies inside the triangle.
        let mut rng = stream(7, 0, 0);
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
                    let (w, a) = spherical_triangle(corners[0], corners[1], corners[2], u1, u2).unwrap();
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
            assert!((got - want).abs() < 5e-3 * want, "case {case}: {got} against {want}");
        }
        assert!(spherical_triangle(Vec3::X, Vec3::X, Vec3::Y, 0.5, 0.5).is_none(), "a degenerate triangle");
    }
}
