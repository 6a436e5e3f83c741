//! The reference baker end to end: energy accounting, direct light, agreement with the ground
//! truth on a small closed scene, determinism.

mod common;

use common::{quads, unit_box_faces, v};
use glam::Vec3;
use prm::{Bvh, Light, LightKind, Scene, TexelSet};
use prm_precompute::ground_truth::{GtParams, Tracer};
use prm_precompute::reference::bake::{evaluate, virtual_lights, BakeParams};

fn point_light(at: Vec3, i: f32) -> Light {
    Light::point("p", at, Vec3::splat(i))
}

/// A closed unit box, faces inward, with a point light inside.
fn lit_box(albedo: f32) -> Scene {
    let mut s = quads(&unit_box_faces(), albedo);
    s.lights.push(point_light(v(0.3, 0.7, 0.4), 2.0));
    s
}

#[test]
fn energy_is_accounted_for_exactly() {
    // Closed: every photon lands; first-hit flux equals the emitted flux.
    let scene = lit_box(0.6);
    let bvh = Bvh::build(&scene);
    let p = BakeParams { photons: 5000, bounces: 4, ..Default::default() };
    let vl = virtual_lights(&scene, &bvh, &scene.lights, &p);
    let b = &vl.budgets[0];
    assert!(
        (b.emitted.x - 4.0 * std::f32::consts::PI * 2.0).abs() < 1e-3 * b.emitted.x,
        "point light emits 4 pi I"
    );
    assert_eq!(b.escaped, Vec3::ZERO);
    assert!(
        ((vl.light_power - vl.vpl_power).abs().max_element()) <= 1e-4 * vl.vpl_power.max_element(),
        "virtual-light power {} vs VPL power {}",
        vl.light_power,
        vl.vpl_power
    );
    // Each bounce re-emits a = 0.6 of what arrived: total VPL power = emitted (a + a^2 + a^3 + a^4).
    let a = 0.6f32;
    let want = b.emitted.x * (a + a * a + a * a * a + a * a * a * a);
    assert!((vl.vpl_power.x - want).abs() <= 1e-3 * want, "VPL power {} vs {want}", vl.vpl_power.x);
    assert!((b.beyond_last_bounce.x - b.emitted.x * a.powi(4)).abs() <= 1e-3 * b.emitted.x);

    // Open (a floor alone): first-hit flux + escaped = emitted.
    let mut floor = quads(&[[v(-1., 0., -1.), v(-1., 0., 1.), v(1., 0., 1.), v(1., 0., -1.)]], 0.5);
    floor.lights.push(point_light(v(0.0, 0.5, 0.0), 1.0));
    let bvh = Bvh::build(&floor);
    let (vpls, budgets) =
        prm_precompute::reference::vpl::trace_photons(&floor, &bvh, &floor.lights, 20_000, 1, 0);
    let incident = vpls.iter().fold(Vec3::ZERO, |s, v| s + v.incident);
    let b = &budgets[0];
    assert!(
        (incident + b.escaped + b.absorbed_by_backs - b.emitted).abs().max_element()
            <= 1e-3 * b.emitted.max_element()
    );
    // The floor subtends a known share of the sphere: 2 x 2 square at height 0.5.
    let share = incident.x / b.emitted.x;
    let exact = {
        // Solid angle of a 2a x 2b rectangle seen from distance d over its centre: 4 asin(ab / sqrt((a²+d²)(b²+d²))).
        let (a, d) = (1.0f32, 0.5f32);
        4.0 * (a * a / ((a * a + d * d) * (a * a + d * d)).sqrt()).asin() / (4.0 * std::f32::consts::PI)
    };
    assert!((share - exact).abs() < 0.01, "floor catches {share}, solid angle says {exact}");

    // A directional light straight down delivers E x area to the floor; a spot light only what
    // its cone (uniform inside, hard edge) covers: all of it when the cone fits on the floor.
    let mut sun = floor.clone();
    sun.lights = vec![Light {
        name: "sun".into(),
        kind: LightKind::Directional,
        position: Vec3::ZERO,
        direction: -Vec3::Y,
        intensity: Vec3::splat(2.0),
        range: None,
        aperture: Default::default(),
        profile: None,
    }];
    let (vpls, _) = prm_precompute::reference::vpl::trace_photons(&sun, &bvh, &sun.lights, 20_000, 1, 0);
    let got = vpls.iter().fold(0.0, |s, v| s + v.incident.x);
    assert!((got - 2.0 * 4.0).abs() < 0.03 * 8.0, "sun on a 2 x 2 floor: {got} W, want 8");
    let mut spot = floor.clone();
    spot.lights = vec![Light {
        name: "spot".into(),
        kind: LightKind::Spot { inner: 0.5, outer: 0.5 },
        position: v(0.0, 0.5, 0.0),
        direction: -Vec3::Y,
        intensity: Vec3::splat(3.0),
        range: None,
        aperture: Default::default(),
        profile: None,
    }];
    let (vpls, budgets) =
        prm_precompute::reference::vpl::trace_photons(&spot, &bvh, &spot.lights, 20_000, 1, 0);
    let got = vpls.iter().fold(0.0, |s, v| s + v.incident.x);
    let cone = 3.0 * std::f32::consts::TAU * (1.0 - 0.5f32.cos());
    assert!(
        (budgets[0].emitted.x - cone).abs() < 1e-3 * cone && (got - cone).abs() < 1e-3 * cone,
        "spot emits I x cone solid angle: {got} vs {cone}"
    );
}

#[test]
fn direct_light_over_a_plane_is_inverse_square() {
    let mut floor = quads(&[[v(-1., 0., -1.), v(-1., 0., 1.), v(1., 0., 1.), v(1., 0., -1.)]], 0.5);
    let at = v(0.2, 0.8, -0.1);
    floor.lights.push(point_light(at, 3.0));
    let bvh = Bvh::build(&floor);
    let set = TexelSet::build(&floor, 24, 24);
    let p = BakeParams {
        photons: 2000,
        bounces: 1,
        atlas: prm::density::Atlas::single(24),
        ..Default::default()
    };
    let vl = virtual_lights(&floor, &bvh, &floor.lights, &p);
    let baked =
        evaluate(&floor, &bvh, &set, &floor.lights, &vl, &p, prm_precompute::parallel::Control::none())
            .unwrap();
    for (t, d) in set.texels.iter().zip(&baked.direct) {
        let r = at - t.position;
        let want = 3.0 * (r.y / r.length()) / r.length_squared();
        assert!((d.x - want).abs() <= 1e-4 * want, "{} vs {want}", d.x);
    }
    // A lone plane cannot light itself.
    assert!(baked.indirect.iter().all(|i| *i == Vec3::ZERO));
}

#[test]
fn agrees_with_the_ground_truth_in_a_lit_box_and_is_deterministic() {
    let scene = lit_box(0.5);
    let bvh = Bvh::build(&scene);
    // At 16^2 the half-texel epsilon shift is 3 % of the box and biases corners (-4 %
    // measured); 32^2 is fine enough.
    let set = TexelSet::build(&scene, 32, 32);
    let p = BakeParams {
        photons: 20_000,
        atlas: prm::density::Atlas::single(32),
        visibility_samples: 4,
        ..Default::default()
    };
    let run = |threads| {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
            let vl = virtual_lights(&scene, &bvh, &scene.lights, &p);
            evaluate(&scene, &bvh, &set, &scene.lights, &vl, &p, prm_precompute::parallel::Control::none())
                .unwrap()
                .indirect
        })
    };
    let ours = run(2);
    assert_eq!(ours, run(1), "same result at 1 and 2 threads");
    let tracer = Tracer::new(&scene, &bvh, GtParams { spp: 512, ..Default::default() });
    let gt = tracer.texels(&set.texels, 32, prm_precompute::parallel::Control::none()).unwrap();
    let gt_ind: Vec<Vec3> = gt.iter().map(|g| g.indirect).collect();
    let c = prm::metric::compare(&ours, &gt_ind, None);
    let noise = (gt.iter().map(|g| g.indirect_stderr.x.powi(2) as f64).sum::<f64>()
        / gt.iter().map(|g| g.indirect.x.powi(2) as f64).sum::<f64>())
    .sqrt();
    // The reference is held to 3 % on the bundled scenes (note); on this small box with the
    // ground truth's own noise added, 6 % and a bias under 2 %.
    assert!(c.error <= 0.06 + noise, "error {} (gt noise {noise})", c.error);
    assert!(c.bias.abs() <= 0.02, "bias {}", c.bias);
}
