//! The reference baker's geometry: hulls, simplification, growth and clipping of polygon
//! lights, and the kd-tree's gap split.

use glam::Vec2;
use prm_precompute::reference::kdtree::{cluster, gap_split};
use prm_precompute::reference::polygon::{
    area, contains, convex_hull, is_convex_ccw, light_polygon, simplify_outer,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

#[test]
fn light_polygons_are_convex_small_contain_their_vpls_and_stay_in_the_cell() {
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    for trial in 0..300 {
        let n = rng.random_range(1..200);
        let (lo, hi) = (Vec2::new(-1.0, -0.5), Vec2::new(2.0, 1.5));
        let centre = Vec2::new(rng.random_range(-0.5..1.5), rng.random_range(0.0..1.0));
        let spread = Vec2::new(rng.random_range(0.01..1.0), rng.random_range(0.0..1.0));
        let pts: Vec<Vec2> = (0..n)
            .map(|_| (centre + (Vec2::new(rng.random(), rng.random()) - 0.5) * spread).clamp(lo, hi))
            .collect();
        let hull = convex_hull(&pts);
        if hull.len() >= 3 {
            assert!(is_convex_ccw(&hull));
            let simple = simplify_outer(&hull, 8);
            assert!(
                simple.len() <= 8 && is_convex_ccw(&simple),
                "trial {trial}: simplified hull not convex or too big"
            );
            assert!(area(&simple) >= area(&hull) - 1e-6);
            for p in &pts {
                assert!(contains(&simple, *p, 1e-5), "trial {trial}: simplification lost a VPL");
            }
        }
        let poly = light_polygon(&pts, lo, hi);
        assert!(poly.len() >= 3 && poly.len() <= 12, "trial {trial}: {} vertices", poly.len());
        assert!(is_convex_ccw(&poly), "trial {trial}: light polygon not convex");
        for p in &pts {
            assert!(contains(&poly, *p, 1e-5), "trial {trial}: VPL {p} outside its light polygon");
        }
        for v in &poly {
            assert!(
                v.x >= lo.x - 1e-5 && v.x <= hi.x + 1e-5 && v.y >= lo.y - 1e-5 && v.y <= hi.y + 1e-5,
                "trial {trial}: vertex {v} leaves the cell"
            );
        }
    }
}

#[test]
fn gap_split_lands_in_the_gap_near_the_median() {
    // 40 points in [0, 1], a gap, 60 points in [1.5, 2.5]: the median is inside the second
    // group, but the gap is worth more.
    let mut xs: Vec<f32> = (0..40).map(|i| i as f32 / 40.0).collect();
    xs.extend((0..60).map(|i| 1.5 + i as f32 / 60.0));
    let j = gap_split(&xs);
    assert_eq!(j, 39, "split between {} and {}", xs[j], xs[j + 1]);
    // Without a gap the split stays near the median.
    let even: Vec<f32> = (0..100).map(|i| i as f32).collect();
    assert!((gap_split(&even) as i32 - 49).abs() <= 1);
    // A small gap near the end loses to the median region (its weight is small) ...
    let mut tail: Vec<f32> = (0..99).map(|i| i as f32 * 0.01).collect();
    tail.push(tail[98] + 0.05);
    assert!((gap_split(&tail) as i32 - 49).abs() <= 2, "{}", gap_split(&tail));
    // ... but a far outlier is split off: weight 0.17 x gap 49 beats every 0.01 gap.
    tail[99] = 50.0;
    assert_eq!(gap_split(&tail), 98);
    // The tree splits two separated blobs apart and leaves stay near the target size.
    let pts: Vec<[f32; 2]> = xs.iter().map(|&x| [x, 0.0]).collect();
    let leaves = cluster(&pts, 60, [0.0, -1.0], [3.0, 1.0]);
    assert_eq!(leaves.len(), 2);
    assert_eq!(leaves[0].members.len(), 40);
    assert!((leaves[0].hi[0] - 0.5 * (0.975 + 1.5)).abs() < 1e-5, "cut in the middle of the gap");
}
