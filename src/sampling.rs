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

#[cfg(test)]
mod tests {
    use super::*;

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
}
