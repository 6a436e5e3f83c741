//! The pane filter (`prm::Smoothing`) against what it must be: weights summing to one, no light
//! carried between surfaces that only meet in the atlas or at a crease, linear, and the noise
//! reduction of its Gaussian (the analytic variance of a separable weighted mean).

use glam::{Vec2, Vec3};
use prm::{Scene, Smoothing, TexelSet};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

const SIDE: u32 = 32;
/// The charts' places in the atlas (`three_charts`; C, the wall, is 0).
const A: u32 = 1;
const B: u32 = 2;

/// Three charts side by side in a 96 x 32 atlas, each 32 x 32 texels:
/// - C: a 1 m wall at x = 1 facing -x (atlas columns 0-31), rising from A's edge: A's
///   neighbour in the world across a crease, and in the atlas;
/// - A: a 1 m floor at x, z in [0, 1] (columns 32-63);
/// - B: a 2 m floor as high, facing the same way, 5 m away (columns 64-95; texels twice A's
///   size): A's neighbour in the atlas only.
fn three_charts() -> Scene {
    let mut pos = Vec::new();
    let mut uv = Vec::new();
    let mut quad = |c: [Vec3; 4], u0: f32| {
        let corner_uv = [Vec2::new(0., 0.), Vec2::new(0., 1.), Vec2::new(1., 1.), Vec2::new(1., 0.)];
        for k in [0, 1, 2, 0, 2, 3] {
            pos.push(c[k]);
            uv.push(Vec2::new((u0 + corner_uv[k].x) / 3.0, corner_uv[k].y));
        }
    };
    let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    quad([v(1., 0., 0.), v(1., 0., 1.), v(1., 1., 1.), v(1., 1., 0.)], 0.0);
    quad([v(0., 0., 0.), v(0., 0., 1.), v(1., 0., 1.), v(1., 0., 0.)], 1.0);
    quad([v(5., 0., 0.), v(5., 0., 2.), v(7., 0., 2.), v(7., 0., 0.)], 2.0);
    let idx: Vec<u32> = (0..pos.len() as u32).collect();
    Scene::from_mesh(pos, uv, &idx)
}

/// The filter out to `radius` texels (a texel is 1/32 m).
fn setup(radius: u32) -> (TexelSet, Smoothing) {
    let scene = three_charts();
    let set = TexelSet::build(&scene, 3 * SIDE, SIDE);
    assert_eq!(set.len(), (3 * SIDE * SIDE) as usize, "every texel of the three charts is covered");
    let smoothing = set.smoothing(&scene, radius as f32 / SIDE as f32);
    (set, smoothing)
}

/// A full-atlas image with `f(chart, i, j)` at the covered texels (i, j within the chart).
fn image(set: &TexelSet, mut f: impl FnMut(u32, u32, u32) -> Vec3) -> Vec<Vec3> {
    let mut img = vec![Vec3::ZERO; (set.width * set.height) as usize];
    for t in &set.texels {
        img[(t.j * set.width + t.i) as usize] = f(t.i / SIDE, t.i % SIDE, t.j);
    }
    img
}

#[test]
fn weights_sum_to_one_and_no_light_crosses_charts_or_creases() {
    // 40 texels: a reach past the chart, held to prm::texels::MAX_RADIUS.
    for radius in [1, 3, 6, 40] {
        let (set, smoothing) = setup(radius);
        let mut ones = image(&set, |_, _, _| Vec3::ONE);
        smoothing.apply(&mut ones);
        let mut only_a = image(&set, |c, _, _| if c == A { Vec3::ONE } else { Vec3::ZERO });
        smoothing.apply(&mut only_a);
        for t in &set.texels {
            let k = (t.j * set.width + t.i) as usize;
            // f32 sums of up to 33 weights: 1e-5 is rounding.
            assert!(
                (ones[k] - Vec3::ONE).abs().max_element() < 1e-5,
                "radius {radius}: constant image moved at {t:?}"
            );
            let want = if t.i / SIDE == A { 1.0 } else { 0.0 };
            assert!(
                (only_a[k].x - want).abs() < 1e-5,
                "radius {radius}: texel ({}, {}) of chart {} reads {} (A's light leaked or was lost)",
                t.i,
                t.j,
                t.i / SIDE,
                only_a[k].x
            );
        }
    }
}

#[test]
fn smoothing_is_linear() {
    let (set, smoothing) = setup(3);
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let mut random = || image(&set, |_, _, _| Vec3::new(rng.random(), rng.random(), rng.random()));
    let (mut a, mut b) = (random(), random());
    let mut sum: Vec<Vec3> = a.iter().zip(&b).map(|(x, y)| *x + 2.0 * *y).collect();
    smoothing.apply(&mut a);
    smoothing.apply(&mut b);
    smoothing.apply(&mut sum);
    for k in 0..sum.len() {
        assert!((sum[k] - (a[k] + 2.0 * b[k])).abs().max_element() < 1e-5, "atlas texel {k}");
    }
}

/// Independent unit-variance noise on a floor comes out, away from the chart's edges, with the
/// variance of the separable weighted mean: `(sum of the 1D weights squared)^2`.
#[test]
fn noise_falls_as_the_gaussian_says() {
    let radius = 3u32;
    let (set, smoothing) = setup(radius);
    let sigma2 = (0.5 * radius as f32 + 0.5).powi(2);
    let g: Vec<f64> =
        (-(radius as i32)..=radius as i32).map(|s| (-(s * s) as f64 / (2.0 * sigma2 as f64)).exp()).collect();
    let total: f64 = g.iter().sum();
    let want = g.iter().map(|w| (w / total).powi(2)).sum::<f64>().powi(2);
    let mut rng = Pcg64Mcg::seed_from_u64(11);
    let interior =
        |i: u32, j: u32| (radius..SIDE - radius).contains(&i) && (radius..SIDE - radius).contains(&j);
    let (mut sum2, mut n) = (0.0f64, 0usize);
    for _ in 0..40 {
        // Uniform on [-sqrt 3, sqrt 3]: variance 1.
        let mut img = image(&set, |_, _, _| Vec3::splat((rng.random::<f32>() * 2.0 - 1.0) * 3f32.sqrt()));
        smoothing.apply(&mut img);
        for t in &set.texels {
            if t.i / SIDE == A && interior(t.i % SIDE, t.j) {
                sum2 += (img[(t.j * set.width + t.i) as usize].x as f64).powi(2);
                n += 1;
            }
        }
    }
    let got = sum2 / n as f64;
    // 40 images x 676 texels, correlated over ~3 texels each way: the estimate's own spread is
    // a few percent; 10 % tolerance.
    assert!((got / want - 1.0).abs() < 0.1, "variance {got} vs {want}");
}

/// The reach is in the world: on B, whose texels are twice as large, the same reach spans half
/// the texels (3 on A, 1.5 rounded to 2 on B).
#[test]
fn the_radius_in_texels_follows_the_texel_size() {
    let (set, smoothing) = setup(3);
    let centre = |chart: u32| {
        set.texels.iter().position(|t| t.i == chart * SIDE + SIDE / 2 && t.j == SIDE / 2).expect("covered")
    };
    for (chart, r) in [(A, 3), (B, 2)] {
        for pass in 0..2 {
            assert_eq!(smoothing.taps(pass, centre(chart)).len(), 2 * r + 1, "chart {chart}, pass {pass}");
        }
    }
}

/// A window of atlas rows, smoothed on its own (how the precompute encodes panes a
/// band at a time), gives exactly the whole atlas's values `row_reach` rows inside the window,
/// and at the atlas's edge: windows at the top, in the middle and at the bottom.
#[test]
fn a_window_of_rows_is_smoothed_as_the_whole_atlas() {
    let (set, smoothing) = setup(3);
    let reach = smoothing.row_reach();
    assert!((3..=4).contains(&reach), "the column pass reaches 3 rows: {reach}");
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let walked = image(&set, |_, _, _| Vec3::new(rng.random(), rng.random(), rng.random()));
    let mut whole = walked.clone();
    smoothing.apply(&mut whole);
    set.dilate(&mut whole);
    let w = set.width as usize;
    for window in [0..12u32, 6..20, 9..SIDE, 0..SIDE] {
        let rows = window.clone();
        let mut img = walked[rows.start as usize * w..rows.end as usize * w].to_vec();
        smoothing.apply_rows(&mut img, rows.clone(), SIDE);
        // Exact from reach + 1 rows inside a cut (the dilation's row), up to the atlas's edge.
        // (Every texel here is covered: the dilation's rows are checked by the precompute's
        // `same_bytes_at_any_band_height`.)
        let lo = if rows.start == 0 { 0 } else { rows.start + reach + 1 };
        let hi = if rows.end == SIDE { SIDE } else { rows.end - reach - 1 };
        set.dilate_rows(&mut img, rows.start, lo..hi);
        for j in lo..hi {
            for i in 0..w {
                let (a, b) = (img[(j - rows.start) as usize * w + i], whole[j as usize * w + i]);
                assert!(a == b, "window {window:?}, texel ({i}, {j}): {a} vs {b}");
            }
        }
        assert!(hi > lo, "window {window:?} has rows to check");
    }
}

/// A pane lit in two charts only, smoothed and dilated over the runs of columns it can reach (how the
/// precompute encodes a pane of a level of many rooms: `apply_rows_in`, `dilate_rows_in`),
/// equals the whole atlas's filter bit for bit, inside those columns and (zero) outside.
#[test]
fn columns_around_the_light_are_smoothed_as_the_whole_atlas() {
    for radius in [1, 3, 6] {
        let (set, smoothing) = setup(radius);
        let reach = smoothing.column_reach();
        assert!(reach >= radius && reach <= radius + 1, "radius {radius}: columns reached {reach}");
        let mut rng = Pcg64Mcg::seed_from_u64(radius as u64);
        // Light on chart A's columns 40..44 and chart B's 84..88 only: two runs of columns.
        let walked = image(&set, |c, i, _| {
            match (c == A && (8..12).contains(&i)) || (c == B && (20..24).contains(&i)) {
                true => Vec3::new(rng.random(), rng.random(), rng.random()),
                false => Vec3::ZERO,
            }
        });
        let mut whole = walked.clone();
        smoothing.apply(&mut whole);
        set.dilate(&mut whole);
        let around =
            |c: u32, lo: u32, hi: u32| (c * SIDE + lo).saturating_sub(reach + 1)..c * SIDE + hi + reach + 1;
        let runs = [around(A, 8, 12), around(B, 20, 24)];
        let mut img = walked.clone();
        smoothing.apply_rows_in(&mut img, 0..SIDE, SIDE, &runs);
        for r in &runs {
            set.dilate_rows_in(&mut img, 0, 0..SIDE, r.clone());
        }
        let w = set.width as usize;
        for j in 0..SIDE as usize {
            for i in 0..w {
                let (a, b) = (img[j * w + i], whole[j * w + i]);
                assert!(a == b, "radius {radius}, texel ({i}, {j}): {a} vs {b}");
            }
        }
        assert!(img.iter().filter(|v| **v != Vec3::ZERO).count() > 10 * SIDE as usize);
    }
}
