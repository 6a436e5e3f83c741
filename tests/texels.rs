//! The texel set against a brute-force twin: exact coverage for slivers and tiny triangles,
//! sample points on their triangles, unit normals, a dilation ring that bilinear lookups never
//! read past, and the same set at any thread count.

use glam::{DVec2, Vec2, Vec3};
use prm::{Scene, TexelSet};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Area of the part of triangle `t` (texel units) inside the unit square at (x0, y0), by
/// Sutherland-Hodgman clipping: a different algorithm from the separating-axis test.
fn clipped_area(t: &[DVec2; 3], x0: f64, y0: f64) -> f64 {
    let mut poly: Vec<DVec2> = t.to_vec();
    let planes: [(DVec2, f64); 4] =
        [(DVec2::X, x0), (-DVec2::X, -(x0 + 1.0)), (DVec2::Y, y0), (-DVec2::Y, -(y0 + 1.0))];
    for (n, d) in planes {
        let mut out = Vec::new();
        for k in 0..poly.len() {
            let (a, b) = (poly[k], poly[(k + 1) % poly.len()]);
            let (da, db) = (a.dot(n) - d, b.dot(n) - d);
            if da >= 0.0 {
                out.push(a);
            }
            if (da >= 0.0) != (db >= 0.0) {
                out.push(a + (b - a) * (da / (da - db)));
            }
        }
        poly = out;
        if poly.len() < 3 {
            return 0.0;
        }
    }
    let mut area = 0.0;
    for k in 0..poly.len() {
        area += poly[k].perp_dot(poly[(k + 1) % poly.len()]);
    }
    0.5 * area.abs()
}

/// Distance from `p` to triangle (a, b, c) in 3D, by sampling-free projection and clamping.
fn point_triangle_distance(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> f32 {
    let n = (b - a).cross(c - a).normalize();
    let q = p - n * (p - a).dot(n);
    let inside = [(a, b), (b, c), (c, a)].iter().all(|&(u, v)| (v - u).cross(q - u).dot(n) >= 0.0);
    if inside {
        return (p - q).length();
    }
    [(a, b), (b, c), (c, a)]
        .iter()
        .map(|&(u, v)| {
            let e = v - u;
            let s = ((p - u).dot(e) / e.length_squared()).clamp(0.0, 1.0);
            (p - (u + e * s)).length()
        })
        .fold(f32::INFINITY, f32::min)
}

/// Slivers, tiny triangles, grid-aligned edges and ordinary triangles scattered over a 64^2
/// atlas (UVs) and a sloped surface (positions).
fn sliver_scene(seed: u64) -> Scene {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let (mut pos, mut uv, mut idx) = (Vec::new(), Vec::new(), Vec::new());
    let mut add = |a: Vec2, b: Vec2, c: Vec2| {
        // Keep the winding counter-clockwise in UV so the 3D normal points +z-ish.
        let (b, c) = if (b - a).perp_dot(c - a) < 0.0 { (c, b) } else { (b, c) };
        for p in [a, b, c] {
            uv.push(p);
            pos.push(Vec3::new(p.x * 3.0, p.y * 2.0, 0.3 * p.x + 0.1 * p.y));
        }
        let k = idx.len() as u32;
        idx.extend_from_slice(&[k, k + 1, k + 2]);
    };
    let w = 64.0f32;
    for _ in 0..300 {
        // Needle: long and under a hundredth of a texel wide.
        let a = Vec2::new(rng.random(), rng.random());
        let dir = Vec2::from_angle(rng.random::<f32>() * std::f32::consts::TAU);
        let len = rng.random_range(2.0..10.0) / w;
        let width = rng.random_range(1e-4..1e-2) / w;
        add(a, a + dir * len, a + dir * len * 0.5 + dir.perp() * width);
    }
    for _ in 0..300 {
        // Tiny: well inside one texel or straddling a corner.
        let a = Vec2::new(rng.random(), rng.random());
        let s = rng.random_range(1e-3..0.3) / w;
        add(a, a + Vec2::new(s, 0.0), a + Vec2::new(0.0, s));
    }
    for _ in 0..100 {
        // Edges exactly on texel lines: touching a texel is not covering it.
        let i = rng.random_range(1..60) as f32;
        let j = rng.random_range(1..60) as f32;
        add(Vec2::new(i, j) / w, Vec2::new(i + 2.0, j) / w, Vec2::new(i, j + rng.random_range(0.3..2.0)) / w);
    }
    for _ in 0..50 {
        let a = Vec2::new(rng.random(), rng.random()) * 0.9;
        add(
            a,
            a + Vec2::new(rng.random(), rng.random()) * 0.1,
            a + Vec2::new(rng.random(), rng.random()) * 0.1,
        );
    }
    Scene::from_mesh(pos, uv, &idx)
}

#[test]
fn coverage_equals_brute_force_for_slivers_and_tiny_triangles() {
    let scene = sliver_scene(1);
    let (w, h) = (64u32, 64u32);
    let set = TexelSet::build(&scene, w, h);
    let size = DVec2::new(w as f64, h as f64);
    let mut brute = vec![0.0f64; (w * h) as usize];
    for t in 0..scene.triangles.len() {
        let uv = scene.uv1_corners(t).map(|v| v.as_dvec2() * size);
        for j in 0..h {
            for i in 0..w {
                let a = clipped_area(&uv, i as f64, j as f64);
                let k = (j * w + i) as usize;
                brute[k] = brute[k].max(a);
            }
        }
    }
    // Clipping and separating axes differ by round-off only for overlaps thinner than 1e-7
    // texel, whose clipped area is below 1e-9 texel^2: that band is the only one not compared.
    let (mut compared, mut ambiguous) = (0, 0);
    for (k, &area) in brute.iter().enumerate() {
        let covered = set.index[k] != TexelSet::EMPTY;
        if area > 1e-9 {
            assert!(covered, "texel {k} overlapped by area {area} is missing");
            compared += 1;
        } else if area == 0.0 {
            assert!(!covered, "texel {k} is covered but no triangle overlaps it");
            compared += 1;
        } else {
            ambiguous += 1;
        }
    }
    assert!(set.len() > 500, "the fixture covers a fair number of texels ({})", set.len());
    assert!(ambiguous * 1000 <= compared, "too many round-off cases: {ambiguous}");
    // Slivers that cover no texel centre are the point of the exercise: count some.
    let centre_missed = set
        .texels
        .iter()
        .filter(|t| {
            let c = DVec2::new(t.i as f64 + 0.5, t.j as f64 + 0.5);
            let uv = scene.uv1_corners(t.triangle as usize).map(|v| v.as_dvec2() * size);
            let b = prm::texels::closest_barycentrics(c, &uv);
            b.iter().any(|&x| x <= 0.0)
        })
        .count();
    assert!(
        centre_missed > 100,
        "fixture should exercise texels whose centre no triangle covers ({centre_missed})"
    );
}

#[test]
fn sample_points_lie_on_their_triangles_with_unit_normals() {
    let scene = sliver_scene(2);
    let set = TexelSet::build(&scene, 64, 64);
    let diag = scene.diagonal();
    for t in &set.texels {
        let [a, b, c] = scene.corners(t.triangle as usize);
        let d = point_triangle_distance(t.position, a, b, c);
        assert!(d <= 1e-5 * diag, "texel ({}, {}) is {d} off its triangle", t.i, t.j);
        assert!((t.normal.length() - 1.0).abs() < 1e-5);
        assert!(t.bary.min_element() >= 0.0 && (t.bary.element_sum() - 1.0).abs() < 1e-5);
        assert!(t.normal.dot(scene.face_normal(t.triangle as usize)) > 0.9999);
    }
}

#[test]
fn bilinear_lookups_on_the_surface_never_read_an_empty_texel() {
    let scene = sliver_scene(3);
    let (w, h) = (64u32, 64u32);
    let set = TexelSet::build(&scene, w, h);
    let mut filled = set.mask();
    for d in &set.dilation {
        assert!(!filled[d.target as usize]);
        filled[d.target as usize] = true;
    }
    let mut rng = Pcg64Mcg::seed_from_u64(9);
    for _ in 0..200_000 {
        let t = rng.random_range(0..scene.triangles.len());
        let (mut r1, mut r2) = (rng.random::<f32>(), rng.random::<f32>());
        if r1 + r2 > 1.0 {
            (r1, r2) = (1.0 - r1, 1.0 - r2);
        }
        let [a, b, c] = scene.uv1_corners(t);
        let p = a + (b - a) * r1 + (c - a) * r2;
        if !(0.0..=1.0).contains(&p.x) || !(0.0..=1.0).contains(&p.y) {
            continue; // outside the atlas: such UVs are reported and get no texels
        }
        let (x, y) = (p.x * w as f32 - 0.5, p.y * h as f32 - 0.5);
        for (di, dj) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let i = (x.floor() as i64 + di).clamp(0, w as i64 - 1);
            let j = (y.floor() as i64 + dj).clamp(0, h as i64 - 1);
            assert!(filled[(j * w as i64 + i) as usize], "bilinear tap ({i}, {j}) is empty");
        }
    }
    // Dilated values are means of covered neighbours.
    let values: Vec<Vec3> = set.texels.iter().map(|t| t.position).collect();
    let img = set.to_image(&values, Vec3::splat(-1.0));
    for d in &set.dilation {
        let want =
            d.sources[..d.count as usize].iter().map(|&s| img[s as usize]).fold(Vec3::ZERO, |a, b| a + b)
                / d.count as f32;
        assert!((img[d.target as usize] - want).length() < 1e-5);
    }
}

#[test]
fn texel_set_is_the_same_at_any_thread_count() {
    let scene = sliver_scene(4);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| TexelSet::build(&scene, 64, 64));
    let two = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap()
        .install(|| TexelSet::build(&scene, 64, 64));
    assert_eq!(one.texels, two.texels);
    assert_eq!(one.dilation, two.dilation);
}

/// A 1 m floor (its own UVs over the whole 16² atlas: texel (i, j) is x, z in [i, i+1] / 16,
/// [j, j+1] / 16) with a closed box of side 0.3 m standing on it over x, z in [0.3, 0.6]. The
/// box has zero UV area, so it owns no texels.
fn floor_with_box() -> Scene {
    let mut pos = Vec::new();
    let mut uv = Vec::new();
    let mut quad = |c: [Vec3; 4], floor: bool| {
        for k in [0, 1, 2, 0, 2, 3] {
            pos.push(c[k]);
            uv.push(if floor { Vec2::new(c[k].x, c[k].z) } else { Vec2::ZERO });
        }
    };
    let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    quad([v(0., 0., 0.), v(0., 0., 1.), v(1., 0., 1.), v(1., 0., 0.)], true);
    let (a, b, h) = (0.3, 0.6, 0.3);
    quad([v(a, h, a), v(a, h, b), v(b, h, b), v(b, h, a)], false); // top, up
    quad([v(b, 0., a), v(b, h, a), v(b, h, b), v(b, 0., b)], false); // +x
    quad([v(a, 0., b), v(a, h, b), v(a, h, a), v(a, 0., a)], false); // -x
    quad([v(b, 0., b), v(b, h, b), v(a, h, b), v(a, 0., b)], false); // +z
    quad([v(a, 0., a), v(a, h, a), v(b, h, a), v(b, 0., a)], false); // -z
    let idx: Vec<u32> = (0..pos.len() as u32).collect();
    Scene::from_mesh(pos, uv, &idx)
}

#[test]
fn buried_points_move_to_the_visible_part_and_buried_texels_are_dropped() {
    let scene = floor_with_box();
    let bvh = prm::Bvh::build(&scene);
    let plain = TexelSet::build(&scene, 16, 16);
    assert_eq!(plain.len(), 256);
    let set = TexelSet::build_visible(&scene, &bvh, 16, 16);
    // Texel columns (and rows) 5..=8 lie wholly under the box (x in [0.3125, 0.5625] within
    // [0.3, 0.6]); column 9 ([0.5625, 0.625]) has its centre under it and a visible strip
    // beyond x = 0.6; column 4's centre (0.28) is already outside.
    let under = |i: u32| (5..=8).contains(&i);
    let edge = |i: u32| (5..=9).contains(&i);
    assert_eq!(set.buried.dropped, 16, "the 4 x 4 texels wholly under the box");
    assert_eq!(set.buried.moved, 9, "column 9 and row 9 next to the box, their corner included");
    assert_eq!(set.len(), 256 - 16);
    for t in &set.texels {
        assert!(!(under(t.i) && under(t.j)), "texel ({}, {}) is wholly under the box", t.i, t.j);
        assert!(
            !prm::texels::is_buried(&scene, &bvh, t.position, t.normal),
            "texel ({}, {}) buried",
            t.i,
            t.j
        );
        let p = t.position;
        let in_square = |x: f32, i: u32| x >= i as f32 / 16.0 - 1e-6 && x <= (i + 1) as f32 / 16.0 + 1e-6;
        assert!(in_square(p.x, t.i) && in_square(p.z, t.j), "texel ({}, {}) left its square: {p}", t.i, t.j);
        if edge(t.i) && edge(t.j) {
            assert!(p.x > 0.6 || p.z > 0.6, "texel ({}, {}) point {p} is under the box", t.i, t.j);
        } else {
            let centre = Vec3::new((t.i as f32 + 0.5) / 16.0, 0.0, (t.j as f32 + 0.5) / 16.0);
            // 1e-3: a centre on the floor's diagonal is pulled 0.01 texel off it (`EDGE_PULL`).
            assert!(p.distance(centre) < 1e-3, "texel ({}, {}) moved though its centre is visible", t.i, t.j);
        }
    }
    // The dropped texels next to visible ones are filled from them, like the gutter.
    let targets: Vec<u32> = set.dilation.iter().map(|d| d.target).collect();
    for (i, j) in [(5, 5), (8, 8), (5, 8), (8, 5)] {
        assert!(targets.contains(&(j * 16 + i)), "corner texel ({i}, {j}) under the box is not dilated");
    }
    // Without the box nothing moves.
    let mut bare = floor_with_box();
    bare.triangles.truncate(2);
    let bare_set = TexelSet::build_visible(&bare, &prm::Bvh::build(&bare), 16, 16);
    assert_eq!((bare_set.buried.moved, bare_set.buried.dropped, bare_set.len()), (0, 0, 256));
}

/// The world area each covered texel stands for: on the sliver fixture every triangle's area
/// inside the atlas lands in the texels it covers (slivers and tiny triangles included); a sloped square
/// mapped onto 4 x 4 texels by two triangles gives each texel a sixteenth of it, the ones its
/// diagonal crosses from both triangles, and a square mapped half a texel off the grid gives
/// its edge texels half and its corners a quarter.
#[test]
fn covered_areas_hold_each_triangle_s_area_where_it_lies() {
    let scene = sliver_scene(1);
    let set = TexelSet::build(&scene, 64, 64);
    let areas = set.covered_areas(&scene);
    assert_eq!(areas.len(), set.len());
    let got: f64 = areas.iter().map(|&a| a as f64).sum();
    // Each triangle's share inside the atlas (some needles run off its edge).
    let want: f64 = (0..scene.triangles.len())
        .map(|t| {
            let uv = scene.uv1_corners(t).map(|v| v.as_dvec2());
            let whole = 0.5 * (uv[1] - uv[0]).perp_dot(uv[2] - uv[0]).abs();
            scene.area(t) as f64 * clipped_area(&uv, 0.0, 0.0) / whole
        })
        .sum();
    assert!((got - want).abs() <= 1e-5 * want, "covered {got}, triangles {want}");
    assert!(areas.iter().all(|&a| a >= 0.0));

    // A square 2 m x 1.5 m, tilted (world area 2 x 1.5 x sqrt(1 + 0.5^2)), on texels
    // [4, 8) x [4, 8) of a 16^2 atlas, then shifted half a texel.
    for shift in [0.0f32, 0.5] {
        let (lo, hi) = ((4.0 + shift) / 16.0, (8.0 + shift) / 16.0);
        let uv = vec![Vec2::new(lo, lo), Vec2::new(hi, lo), Vec2::new(hi, hi), Vec2::new(lo, hi)];
        let pos = uv
            .iter()
            .map(|p| {
                let (x, y) = ((p.x - lo) / (hi - lo) * 2.0, (p.y - lo) / (hi - lo) * 1.5);
                Vec3::new(x, y, 0.5 * y)
            })
            .collect();
        let square = Scene::from_mesh(pos, uv, &[0, 1, 2, 0, 2, 3]);
        let set = TexelSet::build(&square, 16, 16);
        let areas = set.covered_areas(&square);
        let texel = 2.0 * 1.5 * 1.25f32.sqrt() / 16.0;
        for (t, &a) in set.texels.iter().zip(&areas) {
            let share = |k: u32| {
                if shift == 0.0 {
                    1.0
                } else if k == 4 || k == 8 {
                    0.5
                } else {
                    1.0
                }
            };
            let want = texel * share(t.i) * share(t.j);
            assert!(
                (a - want).abs() <= 1e-5,
                "shift {shift}: texel ({}, {}) holds {a}, want {want}",
                t.i,
                t.j
            );
        }
        assert_eq!(set.len(), if shift == 0.0 { 16 } else { 25 });
    }
}

/// The visible part of each texel: the floor under the 0.3 m box is 0.09 of its 1 m^2; the
/// visible areas add up to the rest within the 4 x 4 grid's step (a texel on the box's edge
/// keeps its visible share to an eighth of a texel: 28 such texels, 0.014), and texels a
/// texel or more from the box keep their whole area.
#[test]
fn visible_areas_leave_out_the_floor_under_a_box() {
    let scene = floor_with_box();
    let bvh = prm::Bvh::build(&scene);
    let set = TexelSet::build_visible(&scene, &bvh, 16, 16);
    // The 16 texels wholly under it are no texels of the set.
    let covered: f32 = set.covered_areas(&scene).iter().sum();
    assert!((covered - 240.0 / 256.0).abs() <= 1e-5, "covered {covered}");
    let areas = set.visible_areas(&scene, &bvh);
    let visible: f32 = areas.iter().sum();
    assert!((visible - 0.91).abs() <= 0.014, "visible {visible}, want 0.91");
    for (t, &a) in set.texels.iter().zip(&areas) {
        if !(3..=10).contains(&t.i) || !(3..=10).contains(&t.j) {
            assert!((a - 1.0 / 256.0).abs() <= 1e-7, "texel ({}, {}) far from the box holds {a}", t.i, t.j);
        }
    }
    // The texel whose centre lies under the box's corner: 0.36 of its square is under it.
    let k = set.index[9 * 16 + 9] as usize;
    assert!((areas[k] * 256.0 - 0.64).abs() <= 0.125, "corner texel holds {}", areas[k] * 256.0);
}
