//! BVH queries against the brute-force twin, and the offset scheme at 1e-3, 1 and 1e4 scale.

use glam::{Vec2, Vec3};
use prm::{Bvh, Scene, TexelSet};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

const SCALES: [f32; 3] = [1e-3, 1.0, 1e4];

/// A scene of the triangles `pos` lists corner by corner (no lightmap UVs).
fn unindexed(pos: Vec<Vec3>) -> Scene {
    let idx: Vec<u32> = (0..pos.len() as u32).collect();
    let uv = vec![Vec2::ZERO; pos.len()];
    Scene::from_mesh(pos, uv, &idx)
}

fn random_soup(scale: f32, seed: u64) -> Scene {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut pos = Vec::new();
    for _ in 0..1500 {
        let c = Vec3::new(rng.random(), rng.random(), rng.random()) * 10.0;
        for _ in 0..3 {
            pos.push((c + Vec3::new(rng.random(), rng.random(), rng.random()) - 0.5) * scale);
        }
    }
    unindexed(pos)
}

#[test]
fn closest_hits_equal_brute_force_at_three_scales() {
    const RAYS: usize = 4000;
    for (k, &s) in SCALES.iter().enumerate() {
        let scene = random_soup(s, k as u64);
        let bvh = Bvh::build(&scene);
        let mut rng = Pcg64Mcg::seed_from_u64(100 + k as u64);
        let (mut hits, mut misses, mut ties) = (0, 0, 0);
        for _ in 0..RAYS {
            let o = Vec3::new(rng.random(), rng.random(), rng.random()) * 12.0 * s - s;
            let d =
                Vec3::new(rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5)
                    .normalize();
            let tmax = if rng.random::<f32>() < 0.3 { 2.0 * s } else { f32::INFINITY };
            let fast = bvh.closest_hit(o, d, tmax);
            let slow = bvh.closest_hit_brute_force(o, d, tmax);
            match (fast, slow) {
                (None, None) => misses += 1,
                (Some(f), Some(b)) if f.triangle == b.triangle => {
                    // Same triangle, same ray, same intersection routine: bit-identical t, u, v.
                    assert_eq!(f, b, "scale {s}: the same triangle gave another hit");
                    hits += 1;
                }
                (Some(f), Some(b)) => {
                    // Another triangle only in a genuine tie: the same distance, and both hit
                    // points (each from its own triangle's corners and barycentrics) on the ray
                    // there. 1e-5 of the scene scale: the soup's coordinates are about 10 s, so
                    // interpolation round-off is ~1e-6 s; a wrong triangle is off by ~s.
                    assert_eq!(f.t, b.t, "scale {s}: BVH {f:?} vs brute force {b:?}");
                    let on_ray = o + d * f.t;
                    for h in [f, b] {
                        let p = scene.point(h.triangle as usize, h.bary());
                        assert!(
                            (p - on_ray).length() <= 1e-5 * s,
                            "scale {s}: tie {f:?} / {b:?}: triangle {} is hit at {p}, not at {on_ray}",
                            h.triangle
                        );
                    }
                    ties += 1;
                    hits += 1;
                }
                _ => panic!("scale {s}: BVH {fast:?} vs brute force {slow:?}"),
            }
            assert_eq!(bvh.occluded(o, d, tmax), slow.is_some(), "scale {s}: occlusion disagrees");
        }
        // Both outcomes are common, so neither the hit nor the miss path is checked only
        // vacuously; ties between independent random triangles (shared points have measure
        // zero) must stay rare, or "tie" is excusing a wrong answer.
        assert!(hits >= RAYS / 8 && misses >= RAYS / 8, "scale {s}: {hits} hits and {misses} misses");
        assert!(ties * 1000 <= RAYS, "scale {s}: {ties} ties in {RAYS} rays");
    }
}

/// A closed box room (faces inward) of side `s`, with a dividing wall at x = 0 (two faces).
fn box_room(s: f32, offset: Vec3) -> Scene {
    let mut pos = Vec::new();
    let mut quad = |a: Vec3, b: Vec3, c: Vec3, d: Vec3| {
        for p in [a, b, c, a, c, d] {
            pos.push(p * s + offset);
        }
    };
    let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    quad(v(0., 0., 0.), v(0., 0., 1.), v(1., 0., 1.), v(1., 0., 0.)); // floor, up
    quad(v(0., 1., 0.), v(1., 1., 0.), v(1., 1., 1.), v(0., 1., 1.)); // ceiling, down
    quad(v(0., 0., 0.), v(1., 0., 0.), v(1., 1., 0.), v(0., 1., 0.)); // z = 0, +z
    quad(v(1., 0., 1.), v(0., 0., 1.), v(0., 1., 1.), v(1., 1., 1.)); // z = 1, -z
    quad(v(0., 0., 1.), v(0., 0., 0.), v(0., 1., 0.), v(0., 1., 1.)); // x = 0, +x
    quad(v(1., 0., 0.), v(1., 0., 1.), v(1., 1., 1.), v(1., 1., 0.)); // x = 1, -x
    let n = pos.len();
    // UVs: six charts on a 3 x 2 grid, each quad's corners mapped to its cell (with margin).
    let corners = [
        Vec2::new(0.0, 0.0),
        Vec2::new(0.0, 1.0),
        Vec2::new(1.0, 1.0),
        Vec2::new(0.0, 0.0),
        Vec2::new(1.0, 1.0),
        Vec2::new(1.0, 0.0),
    ];
    let uv = (0..n)
        .map(|k| {
            let (face, corner) = (k / 6, k % 6);
            let cell = Vec2::new((face % 3) as f32, (face / 3) as f32);
            (cell + Vec2::splat(0.05) + corners[corner] * 0.9) / Vec2::new(3.0, 2.0)
        })
        .collect();
    let idx: Vec<u32> = (0..n as u32).collect();
    Scene::from_mesh(pos, uv, &idx)
}

#[test]
fn rays_leaving_texels_never_hit_their_own_surface_or_leak_at_any_scale() {
    for &s in &SCALES {
        for offset in [Vec3::ZERO, Vec3::splat(3.0 * s)] {
            let scene = box_room(s, offset);
            let bvh = Bvh::build(&scene);
            let set = TexelSet::build(&scene, 96, 64);
            let mut rng = Pcg64Mcg::seed_from_u64(5);
            for t in &set.texels {
                for _ in 0..8 {
                    let (u1, u2) = (rng.random::<f32>(), rng.random::<f32>());
                    let (a, b) = t.normal.any_orthonormal_pair();
                    let r = u1.sqrt();
                    let phi = std::f32::consts::TAU * u2;
                    let d =
                        (a * r * phi.cos() + b * r * phi.sin() + t.normal * (1.0 - u1).sqrt()).normalize();
                    let hit = bvh.trace_from_surface(t.position, t.normal, d);
                    let hit = hit.unwrap_or_else(|| {
                        panic!("scale {s}: a ray leaked out of the closed box from texel ({}, {})", t.i, t.j)
                    });
                    let n_hit = scene.face_normal(hit.triangle as usize);
                    assert!(
                        n_hit.dot(t.normal) < 0.999,
                        "scale {s}: self-intersection at texel ({}, {}), t = {}",
                        t.i,
                        t.j,
                        hit.t
                    );
                    assert!(n_hit.dot(d) < 0.0, "scale {s}: hit a back face (leak through a seam)");
                }
            }
        }
    }
}

#[test]
fn visibility_between_points_and_through_a_wall() {
    for &s in &SCALES {
        let scene = box_room(s, Vec3::splat(-0.5 * s));
        let bvh = Bvh::build(&scene);
        let floor = Vec3::new(0.2, -0.5, 0.3) * s;
        let ceiling = Vec3::new(-0.1, 0.5, -0.2) * s;
        assert!(bvh.visible(floor, Vec3::Y, ceiling, -Vec3::Y), "scale {s}: floor sees ceiling");
        assert!(
            bvh.visible_point(floor, Vec3::Y, Vec3::new(0.0, 0.4, 0.0) * s),
            "scale {s}: floor sees a light"
        );
        // A light outside the box is hidden by the ceiling.
        assert!(
            !bvh.visible_point(floor, Vec3::Y, Vec3::new(0.0, 2.0, 0.0) * s),
            "scale {s}: the ceiling blocks"
        );
        // Two points on the same floor plane see each other (grazing, no self-occlusion).
        let other = Vec3::new(-0.3, -0.5, -0.4) * s;
        assert!(bvh.visible(floor, Vec3::Y, other, Vec3::Y), "scale {s}: grazing visibility on one plane");
        // A light 1e-4 units (relative) above the floor still lights the floor beneath it.
        assert!(bvh.visible_point(
            floor + Vec3::new(0.01, 0.0, 0.0) * s,
            Vec3::Y,
            floor + Vec3::new(0.0, 1e-3, 0.0) * s
        ));
    }
}

#[test]
fn axis_aligned_rays_with_negative_zero_components_hit() {
    // obvhs picks the traversal octant from d < 0 but the inverse direction from the sign bit;
    // -(0, -1, 0) = (-0, 1, -0) used to miss everything.
    let pos = vec![Vec3::new(-1.0, 1.0, -1.0), Vec3::new(1.0, 1.0, -1.0), Vec3::new(0.0, 1.0, 1.0)];
    let scene = Scene::from_mesh(pos, vec![Vec2::ZERO; 3], &[0, 1, 2]);
    let bvh = Bvh::build(&scene);
    let n = Vec3::new(0.0, -1.0, 0.0);
    for dir in [-n, Vec3::new(-0.0, 1.0, 0.0), Vec3::new(0.0, 1.0, -0.0)] {
        let hit = bvh.closest_hit(Vec3::ZERO, dir, f32::INFINITY);
        assert!(hit.is_some_and(|h| (h.t - 1.0).abs() < 1e-6), "direction {dir:?} missed");
    }
}

/// `Scene::distance_to_triangle` and `nearest_surface_distance` against hand-worked answers: a
/// right triangle in y = 0, points above its inside, beyond an edge and beyond a corner.
#[test]
fn distance_to_a_triangle_is_to_its_plane_edge_or_corner() {
    let pos = vec![Vec3::ZERO, Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 0.0, 0.0)];
    let scene = Scene::from_mesh(pos, vec![Vec2::ZERO; 3], &[0, 1, 2]);
    let cases = [
        (Vec3::new(0.2, 0.5, 0.2), 0.5),           // above the inside: the plane
        (Vec3::new(0.2, -0.3, 0.2), 0.3),          // below it
        (Vec3::new(0.5, 0.0, -0.4), 0.4),          // beyond the edge z = 0
        (Vec3::new(1.0, 0.0, 1.0), 0.5f32.sqrt()), // beyond the hypotenuse
        (Vec3::new(-0.3, 0.4, -0.0), 0.5),         // beyond the corner at 0
        (Vec3::new(2.0, 0.0, 0.0), 1.0),           // beyond the corner at x = 1
    ];
    for (p, want) in cases {
        let got = scene.distance_to_triangle(0, p);
        assert!((got - want).abs() < 1e-6, "{p}: {got} vs {want}");
        assert_eq!(scene.nearest_surface_distance(p), got);
    }
}

#[test]
fn visibility_over_a_partition_of_the_triangles_is_the_product_of_its_parts() {
    // The incremental baker traces only the moved triangles to tell which shadow rays an edit
    // changed; that is exact only if a segment is visible in the level iff it is in each part.
    for (k, &s) in SCALES.iter().enumerate() {
        let scene = random_soup(s, 20 + k as u64);
        let diagonal = scene.diagonal();
        let whole = Bvh::build_with_extent(&scene, diagonal);
        let part: Vec<u32> = (0..scene.triangles.len() as u32).filter(|t| t % 7 == 3).collect();
        let rest: Vec<u32> = (0..scene.triangles.len() as u32).filter(|t| t % 7 != 3).collect();
        let (a, b) = (Bvh::build_subset(&scene, &part, diagonal), Bvh::build_subset(&scene, &rest, diagonal));
        assert_eq!(a.len() + b.len(), whole.len());
        let mut rng = Pcg64Mcg::seed_from_u64(300 + k as u64);
        let (mut blocked_by_part, mut clear) = (0, 0);
        for _ in 0..4000 {
            let p = Vec3::new(rng.random(), rng.random(), rng.random()) * 12.0 * s - s;
            let q = Vec3::new(rng.random(), rng.random(), rng.random()) * 12.0 * s - s;
            let (n, nq) = ((q - p).normalize(), (p - q).normalize());
            let (va, vb) = (a.visible(p, n, q, nq), b.visible(p, n, q, nq));
            assert_eq!(whole.visible(p, n, q, nq), va && vb, "scale {s}: {p} -> {q}");
            blocked_by_part += (!va && vb) as u32;
            clear += (va && vb) as u32;
        }
        // Both cases occur, so the product is not checked only where it is trivially false.
        assert!(blocked_by_part >= 20 && clear >= 200, "scale {s}: {blocked_by_part} / {clear}");
    }
}

/// `rooms` closed box rooms of side `side` in a row, 1/3 of a side apart, each with a hollow
/// closed pillar (faces outward) and 200 random triangles inside, scaled by `s`.
fn rooms_in_a_row(rooms: usize, s: f32, seed: u64) -> Scene {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut pos = Vec::new();
    let side = 3.0;
    for r in 0..rooms {
        let o = Vec3::new(r as f32 * side * 4.0 / 3.0, 0.0, 0.0);
        // The room's faces (inward) and the pillar's (outward: the same quads wound back).
        for (lo, size, outward) in [(o, side, false), (o + Vec3::new(2.0, 0.0, 2.0), 0.5, true)] {
            let room = box_room(size, lo);
            for t in 0..room.triangles.len() {
                let [a, b, c] = room.corners(t);
                pos.extend(if outward { [a, c, b] } else { [a, b, c] });
            }
        }
        for _ in 0..200 {
            let c = o + Vec3::new(0.3, 0.3, 0.3) + Vec3::new(rng.random(), rng.random(), rng.random()) * 1.5;
            for _ in 0..3 {
                pos.push(c + (Vec3::new(rng.random(), rng.random(), rng.random()) - 0.5) * 0.6);
            }
        }
    }
    let pos: Vec<Vec3> = pos.into_iter().map(|p| p * s).collect();
    unindexed(pos)
}

#[test]
fn rooms_own_trees_give_the_closest_hits_and_occlusion_of_the_whole_level() {
    const RAYS: usize = 6000;
    for (k, &s) in SCALES.iter().enumerate() {
        let scene = rooms_in_a_row(4, s, k as u64);
        let bvh = Bvh::build(&scene);
        bvh.localise(&scene, &prm::rooms::Rooms::of_scene(&scene));
        // The four rooms, each its own, and not the pillars' hollows (their rays leave them at
        // once) nor the outside (it holds every triangle); a pocket the clutter closes off in
        // a room's corner may have one too.
        let regions = bvh.local_regions();
        assert!((4..=6).contains(&regions), "scale {s}: {regions} room trees");
        let centres: Vec<Option<usize>> =
            (0..4).map(|r| bvh.region_at(Vec3::new(r as f32 * 4.0 + 1.5, 1.5, 1.5) * s)).collect();
        let distinct: std::collections::BTreeSet<_> = centres.iter().flatten().collect();
        assert_eq!(distinct.len(), 4, "scale {s}: the rooms' middles try {centres:?}");
        let mut rng = Pcg64Mcg::seed_from_u64(200 + k as u64);
        let (mut regional, mut hits, mut ties) = (0, 0, 0);
        for i in 0..RAYS {
            // Origins in a room (most), or anywhere about the level; a third of the rays short.
            let room = rng.random_range(0..4) as f32 * 4.0;
            let o = if i % 4 == 0 {
                Vec3::new(
                    rng.random::<f32>() * 16.0 - 0.5,
                    rng.random::<f32>() * 4.0 - 0.5,
                    rng.random::<f32>() * 4.0 - 0.5,
                )
            } else {
                Vec3::new(
                    room + 0.05 + rng.random::<f32>() * 2.9,
                    0.05 + rng.random::<f32>() * 2.9,
                    0.05 + rng.random::<f32>() * 2.9,
                )
            } * s;
            let d =
                Vec3::new(rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5)
                    .normalize();
            let tmax = if rng.random::<f32>() < 0.3 { rng.random::<f32>() * 6.0 * s } else { f32::INFINITY };
            regional += bvh.region_at(o).is_some() as usize;
            let (fast, slow) = (bvh.closest_hit(o, d, tmax), bvh.closest_hit_brute_force(o, d, tmax));
            match (fast, slow) {
                (None, None) => {}
                (Some(f), Some(b)) if f.triangle == b.triangle => {
                    assert_eq!(f, b, "scale {s}: the same triangle gave another hit");
                    hits += 1;
                }
                (Some(f), Some(b)) => {
                    // A tie within round-off (two triangles crossing where the ray meets them:
                    // obvhs's traversal may find either when their distances are an ulp or
                    // two apart), both points on the ray there.
                    assert!(
                        (f.t - b.t).abs() <= 1e-6 * b.t,
                        "scale {s}: room trees {f:?} vs brute force {b:?}"
                    );
                    let on_ray = o + d * b.t;
                    for h in [f, b] {
                        let p = scene.point(h.triangle as usize, h.bary());
                        assert!((p - on_ray).length() <= 1e-5 * s, "scale {s}: {h:?} is not on the ray");
                    }
                    ties += 1;
                    hits += 1;
                }
                _ => panic!("scale {s}: room trees {fast:?} vs brute force {slow:?} from {o} along {d}"),
            }
            assert_eq!(bvh.occluded(o, d, tmax), slow.is_some(), "scale {s}: occlusion disagrees from {o}");
        }
        // Most rays start in a room's box and take its tree; some start outside every room.
        assert!((RAYS / 2..RAYS).contains(&regional), "scale {s}: {regional} of {RAYS} rays in rooms");
        assert!(hits >= RAYS / 2, "scale {s}: {hits} hits");
        assert!(ties * 1000 <= RAYS, "scale {s}: {ties} ties");
    }
}

#[test]
fn a_level_of_one_room_gets_no_room_trees() {
    let scene = rooms_in_a_row(1, 1.0, 9);
    let bvh = Bvh::build(&scene);
    bvh.localise(&scene, &prm::rooms::Rooms::of_scene(&scene));
    assert_eq!(bvh.local_regions(), 0);
    assert_eq!(bvh.region_at(Vec3::splat(1.0)), None);
}
