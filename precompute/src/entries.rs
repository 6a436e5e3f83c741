//! Entry points (DESIGN.md §4, paper 004 §2.1): N points on the surfaces, sampled by area.
//!
//! Entry j takes the stratum `u in [j, j+1) / N` of the cumulative surface area, so every
//! triangle gets entries in proportion to its area (to within one). Inside a triangle the point
//! is `(s, r)` warped onto the triangle, where `s` is u's position inside the triangle's stratum
//! range and `r` a golden-ratio sequence: large triangles get an evenly spread lattice, not
//! clumps. Each entry stands for area A/N. Streams are seeded per entry: the same seed gives the
//! same entries at any thread count.

use glam::Vec3;
use prm::prm_file::Entry;
use prm::sampling::{cosine_direction, stream};
use prm::Scene;
use rand::Rng;

/// Sample `n` entry points by area.
pub fn sample_entries(scene: &Scene, n: usize, seed: u64) -> Vec<Entry> {
    // Areas to 16 mantissa bits (1.5e-5, rounded): moving an object rounds its corners where
    // they now are and moves its triangles' areas in their last bits. At full precision that
    // would shift every later triangle's stratum, so every entry of the level would move by an
    // ulp, and with them near links and far shares everywhere: `prm precompute --update`
    // (`crate::update`) could then reuse nothing. Rounded, the strata of unchanged triangles
    // stay exactly where they were (unless a moved triangle's area crosses a rounding step).
    let areas: Vec<f64> =
        (0..scene.triangles.len()).map(|t| crate::update::round16(scene.area(t)) as f64).collect();
    let total: f64 = areas.iter().sum();
    if n == 0 || !(total > 0.0) {
        return Vec::new();
    }
    let mut cdf = Vec::with_capacity(areas.len() + 1);
    cdf.push(0.0);
    for a in &areas {
        cdf.push(cdf.last().copied().unwrap_or(0.0) + a / total);
    }
    let golden = 0.618_033_988_749_894_9_f64;
    (0..n)
        .map(|j| {
            let mut rng = stream(seed, 1, j as u64);
            let u = ((j as f64 + rng.random::<f64>()) / n as f64).min(1.0 - 1e-12);
            let t = cdf.partition_point(|&c| c <= u).saturating_sub(1).min(areas.len() - 1);
            let span = (cdf[t + 1] - cdf[t]).max(1e-300);
            let s = ((u - cdf[t]) / span).clamp(0.0, 1.0);
            let r = (j as f64 * golden + rng.random::<f64>() * 0.25).fract();
            let sq = s.sqrt();
            let bary = Vec3::new((1.0 - sq) as f32, (r * sq) as f32, ((1.0 - r) * sq) as f32);
            Entry {
                position: scene.point(t, bary),
                normal: scene.face_normal(t),
                albedo: scene.albedo(t, bary),
                area: (total / n as f64) as f32,
                triangle: t as u32,
            }
        })
        .collect()
}

/// Rays an entry sends to decide whether it is enclosed.
const ENCLOSURE_RAYS: u32 = 16;

/// True when the point is inside a solid: at least 3/4 of `ENCLOSURE_RAYS` cosine rays from it
/// hit the back of a one-sided surface (floor under a plinth, a wall behind a dais). Such
/// entries never receive light, and counted in a cluster's mean they would dim it.
pub fn is_enclosed(scene: &Scene, bvh: &prm::Bvh, e: &Entry, seed: u64, index: u64) -> bool {
    let mut rng = stream(seed, 5, index);
    let mut inside = 0;
    for k in 0..ENCLOSURE_RAYS {
        let u1 = (k as f32 + rng.random::<f32>()) / ENCLOSURE_RAYS as f32;
        let d = cosine_direction(e.normal, u1, rng.random());
        if let Some(h) = bvh.trace_from_surface(e.position, e.normal, d) {
            let t = h.triangle as usize;
            if scene.facing_normal(t, d).is_none() {
                inside += 1;
            }
        }
    }
    inside * 4 >= ENCLOSURE_RAYS * 3
}

/// Points tried when moving an enclosed entry.
const RELOCATION_TRIES: u64 = 8;

/// An enclosed entry moved to a point of its own triangle outside the solid, if one of
/// eight uniform points is (a plinth top whose entry fell under the pillar
/// standing on it keeps its share of entries on the part that is lit); `None` if none is.
pub fn relocate(scene: &Scene, bvh: &prm::Bvh, e: &Entry, seed: u64, index: u64) -> Option<Entry> {
    let mut rng = stream(seed, 6, index);
    let t = e.triangle as usize;
    (0..RELOCATION_TRIES).find_map(|k| {
        let (s, r) = (rng.random::<f32>().sqrt(), rng.random::<f32>());
        let bary = Vec3::new(1.0 - s, r * s, (1.0 - r) * s);
        let moved = Entry { position: scene.point(t, bary), albedo: scene.albedo(t, bary), ..*e };
        (!is_enclosed(scene, bvh, &moved, seed, index + (k + 1) * (1 << 40))).then_some(moved)
    })
}
