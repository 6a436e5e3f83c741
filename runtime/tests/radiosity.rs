//! Hierarchical radiosity over precomputed visibility (paper 003 §4) on the bundled doorway
//! level: the hierarchy against brute force, and the indirect lightmap against the ground truth
//! with the door and block where the rig puts them.

use glam::Vec3;
use prm::visibility::{Poses, Visibility};
use prm::{Bvh, Scene, TexelSet};
use prm_precompute::ground_truth::{indirect_noise, GtParams, Tracer};
use prm_precompute::parallel::Control;
use prm_precompute::visibility::{build_visibility, moving_texel_set, VisibilityParams};
use prm_runtime::cpu::radiosity::{
    gather, indirect, posed_points, sender_direct, Frame, Hierarchy, RadiosityParams, RayVisibility,
    SenderLight,
};

fn root() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn setup() -> (Scene, TexelSet, Visibility, Hierarchy) {
    let scene = prm::load_scene(
        root().join("assets/doorway.glb"),
        &prm::LoadOptions { unwrap_resolution: Some(64), ..Default::default() },
    )
    .unwrap();
    let size = std::env::var("RAD_SIZE").ok().and_then(|v| v.parse().ok()).unwrap_or(64);
    let texels = moving_texel_set(&scene, size, size);
    let vis = build_visibility(&scene, &texels, &VisibilityParams::default(), Control::none()).unwrap();
    let h = Hierarchy::build(&scene, &texels);
    (scene, texels, vis, h)
}

/// The posed level's indirect irradiance at the posed texel points (128 paths) and its noise.
fn ground_truth(posed: &Scene, bvh: &Bvh, texels: &TexelSet, points: &[(Vec3, Vec3)]) -> (Vec<Vec3>, f64) {
    let mut moved = texels.texels.clone();
    for (m, &(p, n)) in moved.iter_mut().zip(points) {
        m.position = p;
        m.normal = n;
    }
    let gt = Tracer::new(posed, bvh, GtParams { spp: 128, ..GtParams::preview() })
        .texels(&moved, texels.width, Control::none())
        .unwrap();
    (gt.iter().map(|g| g.indirect).collect(), indirect_noise(&gt))
}

/// The doorway level with its rig, and a GPU radiosity pass over it.
struct Level {
    gpu: prm_runtime::Gpu,
    scene: Scene,
    texels: TexelSet,
    vis: Visibility,
    h: Hierarchy,
    rig: prm::rig::Rig,
    motion: prm::rig::Motion,
    pass: prm_runtime::radiosity::RadiosityPass,
}

fn gpu_level() -> Level {
    let gpu = prm_runtime::Gpu::new().expect("this GPU test needs a wgpu adapter");
    let (scene, texels, vis, h) = setup();
    let rig = prm::rig::Rig::load(&root().join("assets/doorway_rig.json"), &scene.lights).unwrap();
    let motion = rig.object_motion(std::path::Path::new("rig"), &scene).unwrap();
    let pass = prm_runtime::radiosity::RadiosityPass::new(&gpu.device, &scene, &texels, &h, &vis).unwrap();
    Level { gpu, scene, texels, vis, h, rig, motion, pass }
}

/// The walk visits every texel exactly once when nothing is refined away; every node's
/// sphere holds its leaves; with threshold 0 the gather equals the texel-by-texel sum.
#[test]
fn the_hierarchy_covers_every_texel_once_and_a_full_cut_is_brute_force() {
    let (scene, texels, vis, h) = setup();
    let mut seen = vec![0u32; texels.len()];
    let mut k = 0usize;
    while k < h.nodes.len() {
        let n = &h.nodes[k];
        for &t in &h.leaves[n.first as usize..n.end as usize] {
            let p = texels.texels[t as usize].position;
            assert!((p - n.centre).length() <= n.radius * 1.0001, "node {k} does not hold texel {t}");
        }
        if n.is_leaf() {
            seen[h.leaves[n.first as usize] as usize] += 1;
            k = n.skip as usize;
        } else {
            k += 1;
        }
    }
    assert!(seen.iter().all(|&c| c == 1), "a texel visited {:?} times", seen.iter().max());
    // threshold 0 refines to the leaves: the sum over every texel (brute force twin).
    let poses = Poses::at_rest(3);
    let points = posed_points(&scene, &texels, &poses);
    let frame = Frame { poses: &poses, points: &points };
    let b: Vec<Vec3> = (0..texels.len()).map(|t| Vec3::splat(((t * 7919) % 13) as f32 + 1.0)).collect();
    let (e, _) = gather(&h, &vis, &frame, &b, None, 0.0, false);
    let total: f32 = h.area.iter().sum();
    eprintln!("texel area {total:.2} m², surfaces {:.2} m²", scene.total_area());
    for r in (0..texels.len()).step_by(97) {
        let (x, nr) = points[r];
        let mut want = Vec3::ZERO;
        for s in 0..texels.len() {
            let (ps, ns) = points[s];
            let v = ps - x;
            let d2 = v.length_squared();
            let u = v / d2.sqrt();
            if s == r || u.dot(nr) <= 0.0 || -u.dot(ns) <= 0.0 {
                continue;
            }
            // Within 3 texel sizes a texel sends by the form factor of its shape.
            let g = if d2 < 9.0 * h.area[s] {
                if h.shapes[s].area <= 0.0 {
                    continue;
                }
                prm::form_factor::point_to_polygon(x, nr, h.shapes[s].vertices()) / h.shapes[s].area
            } else {
                u.dot(nr) * -u.dot(ns) / (std::f32::consts::PI * d2)
            };
            want += b[s] * h.area[s] * g * vis.between(&poses, r, x, s, ps);
        }
        assert!(
            (e[r] - want).abs().max_element() <= 1e-3 * want.max_element().max(1e-6),
            "texel {r}: {} vs {want}",
            e[r]
        );
    }
}

/// In the closed level (door shut) every watt a bounce sends lands somewhere: the transport
/// keeps the power it is given, up to the texel discretisation (brute force, threshold 0) and
/// the clusters' approximations (the default cut).
#[test]
fn a_bounce_keeps_the_power_it_is_given() {
    let (scene, texels, vis, h) = setup();
    let poses = Poses::at_rest(3);
    let points = posed_points(&scene, &texels, &poses);
    let frame = Frame { poses: &poses, points: &points };
    let bvh = Bvh::build(&scene);
    let direct: Vec<Vec3> =
        points.iter().map(|&(p, n)| prm::bvh::direct_irradiance(&bvh, &scene.lights, p, n)).collect();
    let b: Vec<Vec3> = direct.iter().zip(&h.albedo).map(|(e, a)| *e * *a).collect();
    let power =
        |e: &[Vec3]| -> f64 { e.iter().zip(&h.area).map(|(e, a)| (prm::luminance(*e) * a) as f64).sum() };
    let rays = RayVisibility { bvh: &bvh, points: &points };
    for (threshold, keep) in [(0.0, 0.99), (RadiosityParams::default().threshold, 0.975)] {
        let (e, _) = gather(&h, &rays, &frame, &b, None, threshold, false);
        let kept = power(&e) / power(&b);
        eprintln!("threshold {threshold}: a bounce keeps {:.2} % of its power", kept * 100.0);
        assert!((keep..=1.01).contains(&kept), "threshold {threshold}: {:.2} %", kept * 100.0);
    }
    let _ = vis;
}

/// Per frame of the doorway rig (door closed, half open, open; the block sliding), the
/// radiosity's indirect lightmap against the ground truth's (noise removed in quadrature).
/// Issue 15's target: 10 % on every frame. Measured at this 64² atlas (25 cm texels): 5.7, 4.5
/// and 5.7 % (bias -0.6 %); with ray-cast visibility 4.3, 2.7 and 3.1 %; the CSSM against ray
/// casting 4.1-5.3 % (bias -0.7 %). At 128² (the level's own, `RAD_SIZE=128 RAD_T0=1`) t = 0
/// gives 3.5 %. Without power conservation the cut and the point-sampled texels lose 1-2 % a
/// bounce, compounding (21-30 % before it and the texel shapes).
#[test]
fn radiosity_follows_the_moving_door_and_block() {
    let (scene, texels, vis, h) = setup();
    let rig = prm::rig::Rig::load(&root().join("assets/doorway_rig.json"), &scene.lights).unwrap();
    let motion = rig.object_motion(std::path::Path::new("rig"), &scene).unwrap();
    for (t, limit) in [(0.0, 0.10), (2.0, 0.10), (4.0, 0.10)] {
        if std::env::var("RAD_T0").is_ok() && t > 0.0 {
            break;
        }
        let poses = Poses::new(&motion.at_time(t));
        let lights = rig.at_time(t);
        // The posed level with the rig's lights at t (the ground truth lights it with its own).
        let mut posed = scene.moved(&motion.at_time(t));
        posed.lights = lights.clone();
        let bvh = Bvh::build(&posed);
        let points = posed_points(&scene, &texels, &poses);
        let frame = Frame { poses: &poses, points: &points };
        let direct = sender_direct(&scene, &texels, &h, &frame, &bvh, &lights);
        let params = RadiosityParams::default();
        let (truth, noise) = ground_truth(&posed, &bvh, &texels, &points);
        let (ind, stats) = indirect(&h, &vis, &frame, &direct, &params, &vis.escape);
        let rays = RayVisibility { bvh: &bvh, points: &points };
        let (ind_rays, _) = indirect(&h, &rays, &frame, &direct, &params, &vis.escape);
        let c = prm::metric::compare(&ind, &truth, None);
        let cr = prm::metric::compare(&ind_rays, &truth, None);
        let cv = prm::metric::compare(&ind, &ind_rays, None);
        eprintln!(
            "t = {t}: with ray-cast visibility {:.2} % (bias {:+.2} %); CSSM against ray-cast {:.2} % (bias {:+.2} %)",
            (cr.error * cr.error - noise * noise).max(0.0).sqrt() * 100.0,
            cr.bias * 100.0,
            cv.error * 100.0,
            cv.bias * 100.0
        );
        let err = (c.error * c.error - noise * noise).max(0.0).sqrt();
        eprintln!(
            "t = {t}: error {:.2} % (raw {:.2} %, ground-truth noise {:.2} %), bias {:+.2} %, {} transfers",
            err * 100.0,
            c.error * 100.0,
            noise * 100.0,
            c.bias * 100.0,
            stats.transfers
        );
        assert!(c.non_finite == 0 && c.negative == 0);
        assert!(err <= limit, "t = {t}: {:.1} %", err * 100.0);
    }
}

/// The GPU radiosity against its CPU twin on the doorway level, at rest and with the door half
/// open and the block moved (the same poses, direct light and parameters): the jittered final
/// pass, the CSSM and occluder-map queries and the tail included.
#[test]
fn gpu_radiosity_matches_the_cpu_twin() {
    let Level { gpu, scene, texels, vis, h, rig, motion, mut pass } = gpu_level();
    for t in [0.0, 2.0] {
        let poses = Poses::new(&motion.at_time(t));
        let posed = scene.moved(&motion.at_time(t));
        let bvh = Bvh::build(&posed);
        let points = posed_points(&scene, &texels, &poses);
        let lights = rig.at_time(t);
        let frame = Frame { poses: &poses, points: &points };
        let direct = sender_direct(&scene, &texels, &h, &frame, &bvh, &lights);
        let params = RadiosityParams::default();
        let (cpu, _) = indirect(&h, &vis, &frame, &direct, &params, &vis.escape);
        let gpu_out = pass.indirect(&gpu.device, &gpu.queue, &poses, &direct, &params).unwrap();
        let c = prm::metric::compare(&gpu_out, &cpu, None);
        eprintln!(
            "t = {t}: GPU against CPU {:.4} % (max {:.2e}), on {}",
            c.error * 100.0,
            c.max_abs,
            gpu.describe()
        );
        // The same walk, cut, representatives and queries: only float sums in another order
        // and f32 contour integrals (the CPU's are f64) differ. Measured 1e-6.
        assert!(c.non_finite == 0 && c.error < 1e-4, "t = {t}: {:.5} %", c.error * 100.0);
    }
}

/// What a texel sends with carries the power its shape receives, at any light height: a
/// lamp 2 cm, 10 cm and 1 m over room B's floor delivers the same power to the floor's texels
/// (the sum of sender direct light x shape area) as to its triangles (`Light::triangle_power`,
/// exact), on the CPU with rays and on the GPU with shadow maps. A texel's point, or a few
/// points over it, misses most of a hot spot 2 cm across.
#[test]
fn senders_carry_the_power_their_shapes_receive_at_any_light_height() {
    let Level { gpu, scene, texels, h, mut pass, .. } = gpu_level();
    let poses = Poses::at_rest(scene.movables.len() + 1);
    let points = posed_points(&scene, &texels, &poses);
    let frame = Frame { poses: &poses, points: &points };
    let bvh = Bvh::build(&scene);
    let floor_b = |t: usize| {
        let [a, b, c] = scene.corners(t);
        let n = (b - a).cross(c - a).normalize_or_zero();
        n.y > 0.99 && a.y.abs() < 1e-4 && (a + b + c).x / 3.0 > 0.1
    };
    let on_floor: Vec<usize> =
        (0..texels.len()).filter(|&k| floor_b(texels.texels[k].triangle as usize)).collect();
    assert!(on_floor.len() > 100, "{} texels on room B's floor", on_floor.len());
    for height in [0.02f32, 0.1, 1.0] {
        let lamp = prm::Light::point("lamp", Vec3::new(2.0, height, 0.1), Vec3::splat(10.0));
        let exact: f64 = (0..scene.triangles.len())
            .filter(|&t| floor_b(t))
            .map(|t| prm::luminance(lamp.triangle_power(&scene.corners(t))) as f64)
            .sum();
        let lights = [lamp];
        let cpu = sender_direct(&scene, &texels, &h, &frame, &bvh, &lights);
        pass.light_texels(&gpu.device, &gpu.queue, &scene, &poses, &lights, 1024).unwrap();
        let gpu_direct = pass.direct(&gpu.device, &gpu.queue).unwrap();
        let carried = |e: &[Vec3]| -> f64 {
            on_floor.iter().map(|&k| prm::luminance(e[k]) as f64 * h.shapes[k].area as f64).sum()
        };
        let (c, g) = (carried(&cpu.mean) / exact, carried(&gpu_direct.mean) / exact);
        eprintln!("lamp {height} m over the floor: senders carry {c:.4} (CPU), {g:.4} (GPU) of the power");
        assert!((c - 1.0).abs() < 0.01 && (g - 1.0).abs() < 0.01, "{height} m: {c:.4} / {g:.4}");
        // The parts divide the mean: area-weighted, they average to 1 on every lit texel,
        // and the GPU's (shadow maps) are the CPU's (rays) where no shadow falls.
        for &k in &on_floor {
            let v = h.shapes[k].vertices();
            let c0 = v.iter().sum::<Vec3>() / v.len() as f32;
            let area = |i: usize| 0.5 * (v[i] - c0).cross(v[(i + 1) % v.len()] - c0).length();
            for (what, light) in [("CPU", &cpu), ("GPU", &gpu_direct)] {
                let m: f32 =
                    (0..v.len()).map(|i| light.parts[k][i] * area(i)).sum::<f32>() / h.shapes[k].area;
                assert!((m - 1.0).abs() < 1e-3, "{height} m, texel {k} ({what}): parts average {m}");
            }
            for i in 0..v.len() {
                let (a, b) = (cpu.parts[k][i], gpu_direct.parts[k][i]);
                assert!(
                    (a - b).abs() <= 1e-3 * a.abs().max(1.0),
                    "{height} m, texel {k} part {i}: {a} / {b}"
                );
            }
        }
    }
}

/// The GPU's own direct light at the texels (shadow maps of the posed level,
/// `RadiosityPass::light_texels`) against the CPU twin's ray-traced one, and the radiosity lit
/// by it against the ground truth, with the door half open and the block moved: a frame that
/// never leaves the GPU is held to the same 10 % as the twin.
#[test]
fn shadow_mapped_texel_light_matches_rays_and_the_ground_truth() {
    let Level { gpu, scene, texels, vis, h, rig, motion, mut pass } = gpu_level();
    // Bad sizes and a level of another shape are refused by name.
    let poses = Poses::at_rest(scene.movables.len() + 1);
    let lights = rig.at_time(0.0);
    let err = pass.light_texels(&gpu.device, &gpu.queue, &scene, &poses, &lights, 4).unwrap_err();
    assert!(err.to_string().contains("shadow maps of 4 texels"), "{err}");
    let mut fewer = scene.clone();
    fewer.triangles.pop();
    let err = pass.light_texels(&gpu.device, &gpu.queue, &fewer, &poses, &lights, 256).unwrap_err();
    assert!(err.to_string().contains("triangles"), "{err}");
    let short = SenderLight::uniform(vec![Vec3::ONE; texels.len() - 1]);
    let err =
        pass.indirect(&gpu.device, &gpu.queue, &poses, &short, &RadiosityParams::default()).unwrap_err();
    assert!(err.to_string().contains("direct light for"), "{err}");
    for t in [0.0, 2.0, 4.0] {
        let moves = motion.at_time(t);
        let poses = Poses::new(&moves);
        let mut posed = scene.moved(&moves);
        let lights = rig.at_time(t);
        posed.lights = lights.clone();
        let bvh = Bvh::build(&posed);
        let points = posed_points(&scene, &texels, &poses);
        let frame = Frame { poses: &poses, points: &points };
        let rays = sender_direct(&scene, &texels, &h, &frame, &bvh, &lights);
        pass.light_texels(&gpu.device, &gpu.queue, &posed, &poses, &lights, 1024).unwrap();
        let mapped = pass.direct(&gpu.device, &gpu.queue).unwrap();
        let c = prm::metric::compare(&mapped.mean, &rays.mean, None);
        eprintln!(
            "t = {t}: shadow-mapped direct light against ray traced {:.2} % (bias {:+.2} %) on {}",
            c.error * 100.0,
            c.bias * 100.0,
            gpu.describe()
        );
        // They differ at shadow edges only (3x3 PCF and a normal offset against hard rays):
        // measured 0.4-0.8 %, bias under 0.1 %.
        assert!(c.non_finite == 0 && c.error < 0.03 && c.bias.abs() < 0.01, "t = {t}: {c:?}");
        let params = RadiosityParams::default();
        let lit = pass.indirect_lit(&gpu.device, &gpu.queue, &params).unwrap();
        let (twin, _) = indirect(&h, &vis, &frame, &rays, &params, &vis.escape);
        let ct = prm::metric::compare(&lit, &twin, None);
        eprintln!("t = {t}: its radiosity against the ray-lit twin's {:.2} %", ct.error * 100.0);
        assert!(ct.non_finite == 0 && ct.error < 0.01, "t = {t}: {:.2} %", ct.error * 100.0);
        if t == 2.0 {
            let (truth, noise) = ground_truth(&posed, &bvh, &texels, &points);
            let c = prm::metric::compare(&lit, &truth, None);
            let err = (c.error * c.error - noise * noise).max(0.0).sqrt();
            eprintln!("t = {t}: GPU-lit radiosity against the ground truth {:.2} %", err * 100.0);
            assert!(err <= 0.10, "t = {t}: {:.1} %", err * 100.0);
        }
    }
}
