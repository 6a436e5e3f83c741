//! The ground-truth tracer against analytic answers: inverse-square direct light, the furnace,
//! and the form factor of a square emitter.

use std::sync::atomic::AtomicBool;

mod common;

use glam::Vec3;
use prm::{Bvh, Light, LightKind, Material, Scene, TexelSet};
use prm_precompute::ground_truth::{GtParams, Irradiance, Tracer};

fn floor_quad(half: f32) -> [Vec3; 4] {
    [
        Vec3::new(-half, 0.0, -half),
        Vec3::new(-half, 0.0, half),
        Vec3::new(half, 0.0, half),
        Vec3::new(half, 0.0, -half),
    ]
}

#[test]
fn point_light_over_a_plane_is_inverse_square_times_cosine() {
    let mut scene = common::quads(&[floor_quad(2.0)], 0.5);
    let light_pos = Vec3::new(0.3, 1.5, -0.2);
    let intensity = Vec3::new(10.0, 5.0, 2.5);
    scene.lights.push(Light {
        name: "p".into(),
        kind: LightKind::Point,
        position: light_pos,
        direction: -Vec3::Y,
        intensity,
        range: None,
        aperture: Default::default(),
        profile: None,
    });
    let bvh = Bvh::build(&scene);
    let tracer = Tracer::new(&scene, &bvh, GtParams { spp: 8, ..Default::default() });
    let set = TexelSet::build(&scene, 32, 32);
    let out = tracer.texels(&set.texels, 32, prm_precompute::parallel::Control::none()).unwrap();
    for (t, r) in set.texels.iter().zip(&out) {
        let d = light_pos - t.position;
        let want = intensity * (d.y / d.length()) / d.length_squared();
        // Next-event estimation of a point light has no noise: only float round-off remains.
        assert!(
            (r.direct - want).abs().max_element() <= 1e-4 * want.max_element(),
            "texel ({}, {}): {} vs {}",
            t.i,
            t.j,
            r.direct,
            want
        );
        assert_eq!(r.direct_stderr, Vec3::ZERO);
        // Nothing for the light to bounce off.
        assert_eq!(r.indirect, Vec3::ZERO, "texel {:?} at {} n {}", (t.i, t.j), t.position, t.normal);
    }
}

/// A closed unit box facing inward, every wall emitting `le` with albedo `a`.
fn furnace(a: f32, le: f32) -> Scene {
    let mut s = common::quads(&common::unit_box_faces(), 0.5);
    s.materials[0] = Material { albedo: Vec3::splat(a), emissive: Vec3::splat(le), ..Default::default() };
    s
}

#[test]
fn furnace_indirect_is_a_over_one_minus_a_times_direct() {
    for a in [0.5f32, 0.9] {
        let le = 2.0;
        let scene = furnace(a, le);
        let bvh = Bvh::build(&scene);
        let tracer = Tracer::new(&scene, &bvh, GtParams { spp: 2000, ..Default::default() });
        let set = TexelSet::build(&scene, 32, 32);
        let picks: Vec<_> = set.texels.iter().step_by(37).copied().collect();
        let out = tracer.texels(&picks, 32, prm_precompute::parallel::Control::none()).unwrap();
        let direct = std::f32::consts::PI * le;
        let want = a / (1.0 - a) * direct;
        let n = out.len() as f32;
        let mean = out.iter().map(|r| r.indirect.x).sum::<f32>() / n;
        let se = (out.iter().map(|r| r.indirect_stderr.x.powi(2)).sum::<f32>()).sqrt() / n;
        for r in &out {
            // Every direction sees an emitting wall: the direct estimate has no variance.
            assert!((r.direct.x - direct).abs() < 1e-4 * direct);
        }
        assert!(
            (mean - want).abs() <= 3.0 * se,
            "albedo {a}: indirect {mean} vs {want} (3 sigma = {})",
            3.0 * se
        );
        assert!(se < 0.02 * want, "albedo {a}: the test needs a tight estimate (se {se})");
        assert_eq!(tracer.stats.truncated.load(std::sync::atomic::Ordering::Relaxed), 0);
    }
}

/// Integral of cos over the solid angle of polygon `poly` seen from `p` with normal `n`
/// (Lambert's contour formula).
fn polygon_cosine_integral(p: Vec3, n: Vec3, poly: &[Vec3]) -> f32 {
    let mut sum = 0.0;
    for k in 0..poly.len() {
        let (a, b) = ((poly[k] - p).normalize(), (poly[(k + 1) % poly.len()] - p).normalize());
        let c = a.cross(b);
        sum += a.dot(b).clamp(-1.0, 1.0).acos() * n.dot(c.normalize());
    }
    0.5 * sum.abs()
}

/// The floor under a square emitter, albedo 0 everywhere. With nothing to bounce off and no
/// punctual light, one direct sample (`ground_truth` module doc) is `pi Le` when its cosine
/// direction hits the emitter's front and 0 otherwise: a Bernoulli variable with
/// p = F = (1/pi) integral of cos over the emitter's solid angle. So the mean estimates
/// `Le x integral`, and its standard error must be `pi Le sqrt(p (1 - p) / N)`.
#[test]
fn square_emitter_irradiance_matches_the_form_factor() {
    let h = 0.7;
    // Emitter faces down (-y), 0.8 x 0.8, offset from the receiver's centre.
    let em =
        [Vec3::new(-0.2, h, -0.3), Vec3::new(0.6, h, -0.3), Vec3::new(0.6, h, 0.5), Vec3::new(-0.2, h, 0.5)];
    let mut scene = common::quads(&[floor_quad(1.0), em], 0.5);
    scene.materials[0].albedo = Vec3::ZERO;
    scene.materials.push(Material {
        albedo: Vec3::ZERO,
        emissive: Vec3::new(3.0, 2.0, 1.0),
        ..Default::default()
    });
    for t in scene.triangles.iter_mut().skip(2) {
        t.material = 1;
    }
    assert!(scene.face_normal(2).y < 0.0);
    let bvh = Bvh::build(&scene);
    let spp = 4000u32;
    let tracer = Tracer::new(&scene, &bvh, GtParams { spp, ..Default::default() });
    let set = TexelSet::build(&scene, 64, 64);
    let floor: Vec<_> = set.texels.iter().filter(|t| t.triangle < 2).copied().collect();
    let out = tracer.texels(&floor, 64, prm_precompute::parallel::Control::none()).unwrap();
    let m = floor.len();
    // The calibration figures below need many texels; the floor's chart is ~13 x 13 texels.
    assert!(m >= 100, "only {m} floor texels");
    let n = spp as f64;
    let sample = (3.0f32 * std::f32::consts::PI) as f64; // one hit's value, pi Le (red)
    let (mut z2_sum, mut bias_sum, mut var_sum) = (0.0f64, 0.0f64, 0.0f64);
    for (t, r) in floor.iter().zip(&out) {
        assert_eq!(t.normal, Vec3::Y);
        let want = 3.0 * polygon_cosine_integral(t.position, Vec3::Y, &em) as f64;
        let p = want / sample;
        assert!((0.01..0.99).contains(&p), "texel ({}, {}): form factor {p}", t.i, t.j);
        let (est, se) = (r.direct.x as f64, r.direct_stderr.x as f64);
        // Bernoulli: the mean is a whole number of hits over N (f32 round-off of a mean of at
        // most 4000 equal values: ~1e-4 of one hit).
        let k = est * n / sample;
        assert!((k - k.round()).abs() < 1e-2, "texel ({}, {}): {k} hits is not a count", t.i, t.j);
        // The stated error is the sample standard error of those hits (Welford in f64, stored
        // as f32: 1e-5 relative)...
        let ph = k.round() / n;
        let se_sample = sample * (ph * (1.0 - ph) / (n - 1.0)).sqrt();
        assert!(
            (se - se_sample).abs() <= 1e-5 * se_sample,
            "texel ({}, {}): se {se} vs {se_sample}",
            t.i,
            t.j
        );
        // ...and it estimates the analytic Bernoulli error. sqrt(p^(1 - p^)) moves with p^ by
        // |1 - 2p| / (2 sqrt(N p (1 - p))) relative per standard deviation of p^; allow 5 of
        // them (over ~200 texels, 4 would trip by chance about once in 100 seeds).
        let se_true = sample * (p * (1.0 - p) / n).sqrt();
        let spread = (1.0 - 2.0 * p).abs() / (2.0 * (n * p * (1.0 - p)).sqrt());
        assert!(
            (se / se_true - 1.0).abs() <= 5.0 * spread + 1e-3,
            "texel ({}, {}): stated se {se} vs analytic {se_true} (p = {p})",
            t.i,
            t.j
        );
        let z = (est - want) / se;
        // Per texel, 4.5 standard errors: P(|z| > 4.5) = 7e-6, so ~200 texels stay clear by
        // chance; N p >= 40 everywhere, so z is close to normal.
        assert!(z.abs() <= 4.5, "texel ({}, {}): {est} vs {want} ({z} se)", t.i, t.j);
        assert!((r.direct.y / r.direct.x - 2.0 / 3.0).abs() < 1e-5);
        z2_sum += z * z;
        bias_sum += est - want;
        var_sum += se * se;
    }
    // Calibration: mean z^2 is 1 when the stated errors are right; over M independent texels it
    // has standard deviation sqrt(2 / M) (normal z). 4 of those: errors stated 1.5x too large
    // or too small (mean z^2 0.44 or 2.25) fail at M = 196.
    let mean_z2 = z2_sum / m as f64;
    let band = 4.0 * (2.0 / m as f64).sqrt();
    assert!((mean_z2 - 1.0).abs() <= band, "mean z^2 {mean_z2} over {m} texels (band 1 +- {band})");
    // Pooled bias: the summed error over the summed variance, within 4 sigma. A 2 % bias in
    // the estimator is ~5 sigma here (3 % gave 8.6).
    let pooled = bias_sum / var_sum.sqrt();
    assert!(pooled.abs() <= 4.0, "pooled bias {pooled} sigma over {m} texels");
}

#[test]
fn ground_truth_is_the_same_at_any_thread_count() {
    let scene = furnace(0.7, 1.0);
    let bvh = Bvh::build(&scene);
    let tracer = Tracer::new(&scene, &bvh, GtParams { spp: 16, ..Default::default() });
    let set = TexelSet::build(&scene, 16, 16);
    let run =
        |n| {
            rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap().install(|| {
                tracer.texels(&set.texels, 16, prm_precompute::parallel::Control::none()).unwrap()
            })
        };
    assert_eq!(run(1), run(2));
}

#[test]
fn a_cancelled_run_returns_no_result() {
    let scene = furnace(0.5, 1.0);
    let bvh = Bvh::build(&scene);
    let tracer = Tracer::new(&scene, &bvh, GtParams::default());
    let set = TexelSet::build(&scene, 16, 16);
    assert!(tracer
        .texels(
            &set.texels,
            16,
            prm_precompute::parallel::Control { progress: &|_| {}, cancel: &AtomicBool::new(true) }
        )
        .is_err());
}

/// A lamp low over the floor of a closed box (albedo 0.5) makes a hot spot that gathering
/// paths find only by chance. At 12 cm the plain gathering estimator still converges (16384
/// samples): the light-path estimator at 512 samples must agree with it within their stated
/// errors, texel by texel and pooled. At 2 cm gathering's own error estimate is no longer
/// trustworthy (its rare hits are a heavy tail): there two independent light-path runs must
/// agree within their stated errors (so those errors are honest), and at equal samples be at
/// least 3x less noisy than gathering claims to be. Point and spot lights (the spot's cone
/// draws its own directions).
#[test]
fn light_paths_agree_with_gathering_and_cut_the_noise_near_a_lamp() {
    let spot = |y| Light {
        kind: LightKind::Spot { inner: 0.3, outer: 0.6 },
        direction: Vec3::new(0.3, -1.0, 0.1).normalize(),
        ..Light::point("spot", Vec3::new(0.6, y, 0.4), Vec3::splat(1.0))
    };
    let point = |y| Light::point("lamp", Vec3::new(0.4, y, 0.55), Vec3::splat(1.0));
    for lamp in [point(0.12), spot(0.12), point(0.02), spot(0.02)] {
        let near = lamp.position.y < 0.05;
        let mut scene = common::quads(&common::unit_box_faces(), 0.5);
        scene.lights.push(lamp.clone());
        // Wall and ceiling texels (the floor's own first bounce from the lamp is zero).
        let walls = WallTexels::of(scene);
        let run = |spp, light_paths, seed| walls.run(spp, light_paths, seed);
        let mis = run(512, true, 3);
        let other = if near { run(512, true, 4) } else { run(16384, false, 3) };
        let what = format!("{} at {} m", lamp.name, lamp.position.y);
        assert_agree_within_their_errors(&mis, &other, &what);
        if near {
            let (noise_mis, noise_gather) = (
                prm_precompute::ground_truth::indirect_noise(&mis),
                prm_precompute::ground_truth::indirect_noise(&run(512, false, 3)),
            );
            assert!(
                noise_mis * 3.0 < noise_gather,
                "{what}: noise {noise_mis} vs gathering's {noise_gather}"
            );
        }
    }
}

/// Every other texel facing sideways or down (walls and ceiling) of a 32² map of `scene`,
/// traced by the ground truth.
struct WallTexels {
    scene: Scene,
    bvh: Bvh,
    picks: Vec<prm::Texel>,
}

impl WallTexels {
    fn of(scene: Scene) -> WallTexels {
        let bvh = Bvh::build(&scene);
        let set = TexelSet::build(&scene, 32, 32);
        let picks = set.texels.iter().filter(|t| t.normal.y < 0.5).step_by(2).copied().collect();
        WallTexels { scene, bvh, picks }
    }

    fn run(&self, spp: u32, light_paths: bool, seed: u64) -> Vec<Irradiance> {
        let tracer =
            Tracer::new(&self.scene, &self.bvh, GtParams { spp, light_paths, seed, ..Default::default() });
        tracer.texels(&self.picks, 32, prm_precompute::parallel::Control::none()).unwrap()
    }
}

/// Two independent ground truths of the same texels (at least 100) agree within their stated
/// errors: every texel within 5 sigma of the other, the mean z² within 4 of its spread
/// (sqrt(2/m) about 1, which honest errors give), and the pooled difference within 4 sigma.
fn assert_agree_within_their_errors(a: &[Irradiance], b: &[Irradiance], what: &str) {
    let (mut z2, mut bias, mut var) = (0.0f64, 0.0f64, 0.0f64);
    for (k, (x, y)) in a.iter().zip(b).enumerate() {
        let (yx, yy) = (prm::luminance(x.indirect) as f64, prm::luminance(y.indirect) as f64);
        let se2 = (prm::luminance(x.indirect_stderr) as f64).powi(2)
            + (prm::luminance(y.indirect_stderr) as f64).powi(2);
        let z = (yx - yy) / se2.sqrt();
        assert!(z.abs() <= 5.0, "{what}: texel {k}: {yx} vs {yy} ({z} sigma)");
        z2 += z * z;
        bias += yx - yy;
        var += se2;
    }
    let m = a.len() as f64;
    assert!(m >= 100.0 && b.len() == a.len(), "{what}: {m} texels against {}", b.len());
    let mean_z2 = z2 / m;
    assert!((mean_z2 - 1.0).abs() <= 4.0 * (2.0 / m).sqrt(), "{what}: mean z^2 {mean_z2}");
    assert!((bias / var.sqrt()).abs() <= 4.0, "{what}: pooled bias {} sigma", bias / var.sqrt());
}

/// A sun through a small skylight lights a patch of floor that gathering finds by chance
/// (the low sun through the sunroom's window left 41 % noise at 128 samples). Light paths
/// started over the skylight ([`Tracer`]'s sun plane) must agree with gathering at many more
/// samples within their combined stated errors, texel by texel and pooled, and at equal
/// samples be at least 2x less noisy. The box's ceiling is one-sided, so the sun's rays that
/// miss the opening end on its back.
#[test]
fn a_suns_light_paths_agree_with_gathering_and_cut_the_noise_through_a_skylight() {
    use common::v;
    let (a, b) = (0.4, 0.65);
    let mut faces: Vec<[Vec3; 4]> =
        common::unit_box_faces().into_iter().filter(|f| f.iter().any(|p| p.y < 1.0)).collect();
    // The ceiling (facing down) around a square opening a..b in x and z.
    let ceiling =
        |x0: f32, x1: f32, z0: f32, z1: f32| [v(x0, 1., z0), v(x1, 1., z0), v(x1, 1., z1), v(x0, 1., z1)];
    faces.extend([
        ceiling(0., 1., 0., a),
        ceiling(0., 1., b, 1.),
        ceiling(0., a, a, b),
        ceiling(b, 1., a, b),
    ]);
    let mut scene = common::quads(&faces, 0.5);
    let sun = Light {
        kind: LightKind::Directional,
        direction: Vec3::new(0.25, -1.0, 0.15).normalize(),
        ..Light::point("sun", Vec3::ZERO, Vec3::splat(3.0))
    };
    scene.lights.push(sun);
    // Wall and ceiling texels, lit only by the floor's patch and what it lights.
    let walls = WallTexels::of(scene);
    let run = |spp, light_paths, seed| walls.run(spp, light_paths, seed);
    let paths = run(256, true, 3);
    let gathered = run(8192, false, 4);
    assert_agree_within_their_errors(&paths, &gathered, "a sun through a skylight");
    let (noise_paths, noise_gathered) = (
        prm_precompute::ground_truth::indirect_noise(&paths),
        prm_precompute::ground_truth::indirect_noise(&run(256, false, 3)),
    );
    assert!(noise_paths * 2.0 < noise_gathered, "noise {noise_paths} vs gathering's {noise_gathered}");
}
