//! Polygon-light form factors against Monte Carlo integration over the polygon, and the
//! epsilon shift, point fallback and sphere light.

use glam::Vec3;
use prm_precompute::reference::form_factor::{epsilon_shift, point_to_polygon, PolygonLight, SphereLight};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Monte Carlo estimate (mean, standard error) of the form factor
/// `(1/pi) int_A max(cos_y, 0) |cos_x| / r^2 dA` by uniform area samples of a convex polygon.
fn mc_form_factor(p: Vec3, n: Vec3, poly: &[Vec3], samples: usize, rng: &mut Pcg64Mcg) -> (f64, f64) {
    let nx = (poly[1] - poly[0]).cross(poly[2] - poly[0]).normalize();
    let tris: Vec<(Vec3, Vec3, Vec3, f32)> = (1..poly.len() - 1)
        .map(|k| {
            (poly[0], poly[k], poly[k + 1], 0.5 * (poly[k] - poly[0]).cross(poly[k + 1] - poly[0]).length())
        })
        .collect();
    let area: f32 = tris.iter().map(|t| t.3).sum();
    let (mut s, mut s2) = (0.0f64, 0.0f64);
    for _ in 0..samples {
        let mut pick = rng.random::<f32>() * area;
        let mut tri = tris[tris.len() - 1];
        for t in &tris {
            if pick < t.3 {
                tri = *t;
                break;
            }
            pick -= t.3;
        }
        let (mut u, mut v) = (rng.random::<f32>(), rng.random::<f32>());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        let y = tri.0 + (tri.1 - tri.0) * u + (tri.2 - tri.0) * v;
        let d = y - p;
        let r2 = d.length_squared();
        let r = r2.sqrt();
        let cy = (n.dot(d) / r).max(0.0);
        let cx = (nx.dot(d) / r).abs();
        let f = (cy * cx / (std::f32::consts::PI * r2) * area) as f64;
        s += f;
        s2 += f * f;
    }
    let m = s / samples as f64;
    (m, ((s2 / samples as f64 - m * m).max(0.0) / samples as f64).sqrt())
}

fn square(c: Vec3, half: f32, nx: Vec3) -> Vec<Vec3> {
    let (t, b) = nx.any_orthonormal_pair();
    // Counter-clockwise seen from the front (along -nx).
    vec![c - t * half - b * half, c + t * half - b * half, c + t * half + b * half, c - t * half + b * half]
}

#[test]
fn analytic_matches_monte_carlo_in_random_configurations() {
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let mut checked = 0;
    for _ in 0..40 {
        let rand_unit = |rng: &mut Pcg64Mcg| {
            Vec3::new(rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5)
                .normalize()
        };
        let nx = rand_unit(&mut rng);
        let c = Vec3::new(rng.random(), rng.random(), rng.random()) * 2.0;
        // A convex pentagon-ish polygon: a regular polygon with jittered radius.
        let (t, b) = nx.any_orthonormal_pair();
        let k = rng.random_range(3..=8);
        let poly: Vec<Vec3> = (0..k)
            .map(|i| {
                let a = std::f32::consts::TAU * i as f32 / k as f32;
                c + (t * a.cos() + b * a.sin()) * 0.5
            })
            .collect();
        let p = c + nx * rng.random_range(0.05..1.5) + rand_unit(&mut rng) * rng.random_range(0.0..1.5);
        let n = rand_unit(&mut rng);
        let exact = point_to_polygon(p, n, &poly) as f64;
        let (mc, se) = mc_form_factor(p, n, &poly, 200_000, &mut rng);
        assert!((exact - mc).abs() <= 4.0 * se + 1e-5, "exact {exact} vs MC {mc} +- {se}");
        checked += (mc > 1e-3) as usize;
    }
    assert!(checked > 10, "most configurations should see the polygon");
}

#[test]
fn polygon_partly_below_the_receiver_plane_is_clipped() {
    let mut rng = Pcg64Mcg::seed_from_u64(4);
    // A floor receiver at the origin facing up; a vertical light (facing -x) straddling y = 0.
    let poly = square(Vec3::new(1.0, 0.1, 0.0), 0.5, -Vec3::X);
    let (p, n) = (Vec3::ZERO, Vec3::Y);
    let exact = point_to_polygon(p, n, &poly) as f64;
    let (mc, se) = mc_form_factor(p, n, &poly, 400_000, &mut rng);
    assert!(exact > 0.01 && (exact - mc).abs() <= 4.0 * se + 1e-5, "exact {exact} vs MC {mc} +- {se}");
    // Wholly below: nothing.
    assert_eq!(point_to_polygon(p, n, &square(Vec3::new(1.0, -0.6, 0.0), 0.5, -Vec3::X)), 0.0);
}

#[test]
fn nearly_grazing_receiver() {
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let poly = square(Vec3::new(0.0, 0.02, 2.0), 0.4, -Vec3::Z);
    let n = Vec3::new(0.0, 1.0, 0.0);
    let exact = point_to_polygon(Vec3::ZERO, n, &poly) as f64;
    let (mc, se) = mc_form_factor(Vec3::ZERO, n, &poly, 400_000, &mut rng);
    assert!((exact - mc).abs() <= 4.0 * se + 1e-6, "exact {exact} vs MC {mc} +- {se}");
}

#[test]
fn receiver_in_the_light_plane_gets_the_epsilon_shift() {
    // A floor light and a wall texel at its edge, in the floor's plane.
    let light = PolygonLight::new(square(Vec3::new(0.5, 0.0, 0.0), 0.5, Vec3::Y), Vec3::Y, Vec3::splat(2.0));
    let (p, n) = (Vec3::new(-0.001, 0.0, 0.0), Vec3::X);
    assert_eq!(point_to_polygon(p, n, &light.vertices), 0.0, "in the plane the polygon has no solid angle");
    let eps = 0.01;
    let shifted = epsilon_shift(p, n, light.centroid(), light.normal, eps);
    assert!((shifted - Vec3::new(-0.001, eps, 0.0)).length() < 1e-6, "moved up the wall to eps: {shifted}");
    let e = light.irradiance(p, n, eps);
    let want = light.power / light.area() * point_to_polygon(shifted, n, &light.vertices);
    assert!(e.x > 0.0 && (e - want).length() < 1e-6);
}

#[test]
fn tiny_distant_polygon_falls_back_to_a_point_light_consistently() {
    let poly = square(Vec3::new(0.0, 100.0, 0.0), 0.01, -Vec3::Y);
    let light = PolygonLight::new(poly.clone(), -Vec3::Y, Vec3::splat(5.0));
    let (p, n) = (Vec3::new(3.0, 0.0, 1.0), Vec3::Y);
    let d = light.centroid() - p;
    let dist = d.length();
    let point = 5.0 * (d.y / dist) * (d.y / dist) / (std::f32::consts::PI * dist * dist);
    let e = light.irradiance(p, n, 1e-3).x;
    assert!((e - point).abs() <= 1e-4 * point, "fallback {e} vs point light {point}");
    // Just above the threshold the contour formula is used and agrees to O((r/d)^2).
    let near =
        PolygonLight::new(square(Vec3::new(0.0, 5.0, 0.0), 0.01, -Vec3::Y), -Vec3::Y, Vec3::splat(5.0));
    let exact = near.irradiance(Vec3::ZERO, Vec3::Y, 1e-3).x;
    let point = 5.0 / (std::f32::consts::PI * 25.0);
    assert!((exact - point).abs() <= 1e-3 * point, "{exact} vs {point}");
}

#[test]
fn polygon_irradiance_is_power_over_area_times_form_factor() {
    // A large square light close above a receiver: E -> L pi = Phi / A as it fills the sky.
    let light =
        PolygonLight::new(square(Vec3::new(0.0, 0.01, 0.0), 50.0, -Vec3::Y), -Vec3::Y, Vec3::splat(1e4));
    let e = light.irradiance(Vec3::ZERO, Vec3::Y, 1e-4).x;
    let full = 1e4 / light.area();
    assert!((e - full).abs() <= 1e-3 * full, "{e} vs {full}");
    // Behind the light: nothing.
    assert_eq!(light.irradiance(Vec3::new(0.0, 1.0, 0.0), -Vec3::Y, 1e-4), Vec3::ZERO);
}

#[test]
fn sphere_light_is_bounded_and_inverse_square_far_away() {
    let s = SphereLight {
        centre: Vec3::new(0.0, 1.0, 0.0),
        radius: 0.2,
        normal: -Vec3::Y,
        power: Vec3::splat(3.0),
    };
    let at = |y: f32| s.irradiance(Vec3::new(0.0, 1.0 - y, 0.0), Vec3::Y).x;
    assert!(at(1e-6).is_finite() && at(1e-6) <= 3.0 / (std::f32::consts::PI * 0.04) + 1e-3);
    // Beyond its radius it is exactly a point light.
    let mid = at(0.5);
    assert!((mid - 3.0 / (std::f32::consts::PI * 0.25)).abs() < 1e-5);
    let far = at(100.0);
    let point = 3.0 / (std::f32::consts::PI * 100.0 * 100.0);
    assert!((far - point).abs() < 1e-5 * point + 1e-9);
}
