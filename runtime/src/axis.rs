//! Where a ray along a spot's axis first meets the level: the far field's eye of a narrow spot
//! (`crate::cpu::sight_eye`), one ray a spot each time its light changes. The runtime carries
//! no BVH (a game's build has neither obvhs nor rayon: `.ci/run` checks), so the level's
//! triangles are binned once into a uniform grid over its box, and a ray walks the grid's cells
//! in order (Amanatides and Woo's traversal), testing the triangles of each, until a hit lies
//! before the cell's far side. The CPU twin casts the same ray through its BVH; both test
//! triangles exactly, and agree to float precision (tested).

use glam::Vec3;
use prm::Scene;

/// Cells along the grid's longest side at most, and about one cell a triangle overall.
const MAX_SIDE: usize = 64;

/// The level's triangles in a uniform grid, for [`AxisCaster::first_hit`].
#[derive(Clone, Debug, Default)]
pub struct AxisCaster {
    lo: Vec3,
    /// A cell's side (0: no triangles).
    side: f32,
    dims: [usize; 3],
    /// Per cell, where its triangles start in `ids` (one more entry than cells).
    start: Vec<u32>,
    ids: Vec<u32>,
    tris: Vec<[Vec3; 3]>,
}

impl AxisCaster {
    /// The grid over `scene`'s triangles (those with a non-finite corner left out).
    pub fn new(scene: &Scene) -> AxisCaster {
        let tris: Vec<[Vec3; 3]> = (0..scene.triangles.len())
            .map(|t| scene.corners(t))
            .filter(|c| c.iter().all(|p| p.is_finite()))
            .collect();
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for c in &tris {
            for p in c {
                lo = lo.min(*p);
                hi = hi.max(*p);
            }
        }
        if tris.is_empty() {
            return AxisCaster::default();
        }
        let extent = (hi - lo).max(Vec3::splat(1e-6));
        let per_side = (tris.len() as f32).cbrt().ceil().clamp(1.0, MAX_SIDE as f32);
        let side = extent.max_element() / per_side;
        let dims = [0, 1, 2].map(|a| ((extent[a] / side).ceil() as usize).clamp(1, MAX_SIDE));
        let cell_of = |p: Vec3| {
            let q = ((p - lo) / side).floor();
            [0, 1, 2].map(|a| (q[a].max(0.0) as usize).min(dims[a] - 1))
        };
        let index = |c: [usize; 3]| (c[2] * dims[1] + c[1]) * dims[0] + c[0];
        // Each triangle in every cell its box overlaps: counted, then placed.
        let mut count = vec![0u32; dims[0] * dims[1] * dims[2] + 1];
        let boxes: Vec<([usize; 3], [usize; 3])> = tris
            .iter()
            .map(|c| (cell_of(c[0].min(c[1]).min(c[2])), cell_of(c[0].max(c[1]).max(c[2]))))
            .collect();
        let each = |(a, b): ([usize; 3], [usize; 3]), f: &mut dyn FnMut(usize)| {
            for z in a[2]..=b[2] {
                for y in a[1]..=b[1] {
                    for x in a[0]..=b[0] {
                        f(index([x, y, z]));
                    }
                }
            }
        };
        for &b in &boxes {
            each(b, &mut |k| count[k + 1] += 1);
        }
        for k in 1..count.len() {
            count[k] += count[k - 1];
        }
        let mut ids = vec![0u32; count[count.len() - 1] as usize];
        let mut next = count.clone();
        for (t, &b) in boxes.iter().enumerate() {
            each(b, &mut |k| {
                ids[next[k] as usize] = t as u32;
                next[k] += 1;
            });
        }
        AxisCaster { lo, side, dims, start: count, ids, tris }
    }

    /// The distance along unit `dir` from `origin` to the first triangle it meets, within
    /// `(0, tmax)`; None for none (or a ray that is not finite).
    pub fn first_hit(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<f32> {
        if self.side <= 0.0 || !origin.is_finite() || !dir.is_finite() || !(tmax > 0.0) {
            return None;
        }
        // Where the ray is inside the grid's box.
        let hi =
            self.lo + Vec3::new(self.dims[0] as f32, self.dims[1] as f32, self.dims[2] as f32) * self.side;
        let inv = dir.recip();
        let (t0, t1) = ((self.lo - origin) * inv, (hi - origin) * inv);
        let enter = t0.min(t1).max_element().max(0.0);
        let leave = t0.max(t1).min_element().min(tmax);
        if !(enter <= leave) {
            return None;
        }
        let p = origin + dir * enter;
        let mut cell = [0usize; 3];
        let (mut step, mut next, mut delta) = ([0isize; 3], [f32::INFINITY; 3], [f32::INFINITY; 3]);
        for a in 0..3 {
            let q = ((p[a] - self.lo[a]) / self.side).floor();
            cell[a] = (q.max(0.0) as usize).min(self.dims[a] - 1);
            if dir[a] > 0.0 {
                step[a] = 1;
                next[a] = (self.lo[a] + (cell[a] + 1) as f32 * self.side - origin[a]) * inv[a];
                delta[a] = self.side * inv[a];
            } else if dir[a] < 0.0 {
                step[a] = -1;
                next[a] = (self.lo[a] + cell[a] as f32 * self.side - origin[a]) * inv[a];
                delta[a] = -self.side * inv[a];
            }
        }
        // Not the box's exit: a level's outer walls lie on its faces, and a hit there may read
        // a hair past it.
        let mut best = tmax;
        let mut found = false;
        loop {
            let k = (cell[2] * self.dims[1] + cell[1]) * self.dims[0] + cell[0];
            for &t in &self.ids[self.start[k] as usize..self.start[k + 1] as usize] {
                if let Some(d) = ray_triangle(origin, dir, &self.tris[t as usize]) {
                    if d > 0.0 && d < best {
                        (best, found) = (d, true);
                    }
                }
            }
            // The next cell along the ray, unless the best hit lies before it.
            let a = if next[0] <= next[1] && next[0] <= next[2] {
                0
            } else if next[1] <= next[2] {
                1
            } else {
                2
            };
            if next[a] >= best {
                break;
            }
            let c = cell[a] as isize + step[a];
            if c < 0 || c >= self.dims[a] as isize {
                break;
            }
            cell[a] = c as usize;
            next[a] += delta[a];
        }
        found.then_some(best)
    }
}

/// Möller and Trumbore's ray-triangle test, both sides: the distance along unit `dir`. The
/// BVH's (`prm::bvh`, behind its `bvh` feature) is the same test on obvhs's SIMD types in the
/// precompute's hottest loop; sharing one would either pull obvhs into the runtime or move
/// that loop off its types (and its `.prm` bytes with the rounding).
fn ray_triangle(origin: Vec3, dir: Vec3, tri: &[Vec3; 3]) -> Option<f32> {
    let (e1, e2) = (tri[1] - tri[0], tri[2] - tri[0]);
    let p = dir.cross(e2);
    let det = e1.dot(p);
    if det.abs() < f32::MIN_POSITIVE {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - tri[0];
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = dir.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    Some(e2.dot(q) * inv)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Against every triangle tried in turn, on random rays from inside and outside a box of
    /// random triangles: the same first hit (to 1e-5 of the distance) or none.
    #[test]
    fn the_grid_finds_the_first_hit_every_triangle_tried_in_turn_finds() {
        let mut rng = rand_pcg::Pcg32::seed_from_u64(7);
        let mut r = |s: f32| Vec3::new(rng.random::<f32>(), rng.random::<f32>(), rng.random::<f32>()) * s;
        let mut positions = Vec::new();
        for _ in 0..300 {
            let c = r(10.0) - Vec3::new(2.0, 0.0, 3.0);
            positions.extend([c, c + r(1.5) - Vec3::splat(0.75), c + r(1.5) - Vec3::splat(0.75)]);
        }
        let indices: Vec<u32> = (0..positions.len() as u32).collect();
        let scene = Scene::from_mesh(positions.clone(), vec![glam::Vec2::ZERO; positions.len()], &indices);
        let caster = AxisCaster::new(&scene);
        let tris: Vec<[Vec3; 3]> = (0..scene.triangles.len()).map(|t| scene.corners(t)).collect();
        let (mut hits, mut misses) = (0, 0);
        for k in 0..2000 {
            let origin = r(16.0) - Vec3::new(5.0, 3.0, 6.0);
            // Half the rays aimed into the triangles' box, half anywhere.
            let dir = if k % 2 == 0 {
                (r(10.0) - Vec3::new(2.0, 0.0, 3.0) - origin).normalize_or_zero()
            } else {
                (r(2.0) - Vec3::ONE).normalize_or_zero()
            };
            if dir == Vec3::ZERO {
                continue;
            }
            let tmax = if k % 3 == 0 { 4.0 } else { f32::INFINITY };
            let brute = tris
                .iter()
                .filter_map(|t| ray_triangle(origin, dir, t))
                .filter(|&d| d > 0.0 && d < tmax)
                .min_by(f32::total_cmp);
            let got = caster.first_hit(origin, dir, tmax);
            match (brute, got) {
                (Some(a), Some(b)) => {
                    hits += 1;
                    assert!((a - b).abs() <= 1e-5 * a.max(1.0), "ray {k}: {b} against {a}");
                }
                (None, None) => misses += 1,
                _ => panic!("ray {k} from {origin} along {dir}: {got:?} against {brute:?}"),
            }
        }
        assert!(hits > 200 && misses > 200, "{hits} hits, {misses} misses: the rays test too little");
        assert_eq!(AxisCaster::new(&Scene::default()).first_hit(Vec3::ZERO, Vec3::X, 1.0), None);
        assert_eq!(caster.first_hit(Vec3::NAN, Vec3::X, 1.0), None);
    }

    /// The chamber: rays from points in the room, and the flashlight rig's eight aims, meet
    /// the level where the CPU twin's BVH says (to 1e-4 of the distance), so the GPU runtime
    /// and the twin place a spot's eye alike.
    #[test]
    fn the_grid_and_the_twins_bvh_find_the_same_first_hit_in_the_chamber() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let scene = match prm::gltf_load::load_scene(root.join("assets/chamber.glb"), &Default::default()) {
            Ok(s) => s,
            Err(e) => panic!("the bundled chamber: {e}"),
        };
        let (caster, bvh) = (AxisCaster::new(&scene), prm::Bvh::build(&scene));
        let mut rng = rand_pcg::Pcg32::seed_from_u64(3);
        let mut rays: Vec<(Vec3, Vec3)> = (0..3000)
            .map(|_| {
                let o = Vec3::new(
                    rng.random_range(-5.5..5.5),
                    rng.random_range(0.1..6.5),
                    rng.random_range(-9.5..9.5),
                );
                let d = Vec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                );
                (o, d.normalize_or_zero())
            })
            .filter(|(_, d)| *d != Vec3::ZERO)
            .collect();
        for (p, d) in [
            ((0.0, 1.6, 0.0), (-1.0, -0.1, 0.0)),
            ((-5.0, 1.6, -3.0), (-1.0, -0.2, 0.0)),
            ((0.0, 1.6, -6.0), (0.0, -0.62, -0.78)),
            ((-4.5, 1.6, -8.0), (-1.5, -1.0, -2.0)),
            ((0.5, 1.6, -3.0), (2.5, -0.1, -1.0)),
            ((0.0, 1.6, -6.0), (0.0, 1.0, 0.0)),
            ((2.0, 1.2, -2.0), (0.3, -1.0, 0.0)),
            ((-5.5, 1.6, 0.0), (0.0, -0.1, 1.0)),
        ] {
            rays.push((Vec3::from(p), Vec3::from(d).normalize()));
        }
        let mut agree = 0;
        for (k, &(o, d)) in rays.iter().enumerate() {
            let (grid, tree) =
                (caster.first_hit(o, d, f32::INFINITY), bvh.closest_hit(o, d, f32::INFINITY).map(|h| h.t));
            match (grid, tree) {
                (Some(a), Some(b)) => {
                    assert!((a - b).abs() <= 1e-4 * b.max(1.0), "ray {k} from {o} along {d}: {a} against {b}")
                }
                (None, None) => {}
                _ => panic!("ray {k} from {o} along {d}: {grid:?} against {tree:?}"),
            }
            agree += 1;
        }
        assert!(agree > 2900);
    }
}
