//! Precomputed visibility (paper 003) against ray casting on the bundled doorway level, at rest
//! and with the door open and the block moved; bad visibility files.

use glam::Vec3;
use prm::visibility::{read_visibility, write_visibility, Poses, Visibility};
use prm::{Bvh, Scene, TexelSet};
use prm_precompute::parallel::Control;
use prm_precompute::visibility::{build_visibility, moving_texel_set, VisibilityParams};
use rand::{Rng, SeedableRng};

fn level() -> Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/doorway.glb");
    prm::load_scene(&path, &prm::LoadOptions { unwrap_resolution: Some(64), ..Default::default() }).unwrap()
}

/// Agreement of `vis` with ray casting through the posed level on random facing texel pairs
/// away from shadow edges, split by whether an end is on the static level; pairs with an end buried in the
/// posed level (under the block) are left out.
///
/// "Away from shadow edges": ray casting gives the same answer with either end moved by one
/// cube-map pixel's footprint at the pair's distance (2 / res radians) across the segment, in
/// four directions: visibility that changes within a pixel is an edge the map cannot resolve.
/// (`VIS_EDGE=tangent`: moved along its own surface instead; a move off the surface tends to
/// put the end behind a wall, which makes blocked pairs look stable.)
fn agreement(
    scene: &Scene,
    texels: &TexelSet,
    vis: &Visibility,
    poses: &Poses,
    res: u32,
) -> ((usize, usize), (usize, usize)) {
    let posed = scene.moved(&poses.to_world[1..]);
    let bvh = Bvh::build(&posed);
    let at = poses.texel_points(scene, &texels.texels);
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(7);
    let (mut with_static, mut movables_only) = ((0, 0), (0, 0));
    let mut tries = 0;
    while with_static.1 < 4000 && tries < 400_000 {
        tries += 1;
        let (r, s) = (rng.random_range(0..texels.len()), rng.random_range(0..texels.len()));
        let ((pr, nr), (ps, ns)) = (at[r], at[s]);
        let d = ps - pr;
        if r == s || d.dot(nr) <= 0.05 * d.length() || d.dot(ns) >= -0.05 * d.length() {
            continue;
        }
        if prm::texels::is_buried(&posed, &bvh, pr, nr) || prm::texels::is_buried(&posed, &bvh, ps, ns) {
            continue;
        }
        let truth = bvh.visible(pr, nr, ps, ns);
        let step = d.length() * 2.0 / res as f32;
        let stable = if std::env::var("VIS_EDGE").is_ok_and(|m| m == "tangent") {
            // Either end slid along its own surface (the edge of a shadow as it falls).
            let (ur, vr) = nr.any_orthonormal_pair();
            let (us, vs) = ns.any_orthonormal_pair();
            [ur, -ur, vr, -vr].iter().all(|&o| bvh.visible(pr + o * step, nr, ps, ns) == truth)
                && [us, -us, vs, -vs].iter().all(|&o| bvh.visible(pr, nr, ps + o * step, ns) == truth)
        } else {
            let (u, v) = (d / d.length()).any_orthonormal_pair();
            [u, -u, v, -v].iter().all(|&o| bvh.visible(pr + o * step, nr, ps, ns) == truth)
                && [u, -u, v, -v].iter().all(|&o| bvh.visible(pr, nr, ps + o * step, ns) == truth)
        };
        if !stable {
            continue;
        }
        let got = vis.between(poses, r, pr, s, ps) >= 0.5;
        let statics = scene.object(texels.texels[r].triangle as usize) == 0
            || scene.object(texels.texels[s].triangle as usize) == 0;
        if got != truth && std::env::var("VIS_DEBUG").is_ok() {
            let (or, os) = (
                scene.object(texels.texels[r].triangle as usize),
                scene.object(texels.texels[s].triangle as usize),
            );
            let (o, k) = vis.slots[r];
            let c = &vis.objects[o as usize].cssm;
            let dd = ps - c.origins[k as usize];
            for (p, w) in prm::visibility::cube::bilinear(dd, c.res).unwrap() {
                let dir = prm::visibility::cube::pixel_direction(p, c.res);
                let hit = bvh.closest_hit(c.origins[k as usize], dir, f32::INFINITY).map(|h| h.t);
                eprintln!(
                    "  tap {p} w {w:.2} stored {:.3} dist {:.3} centre hit {hit:?} dir {dir:.2}",
                    c.depth(k, p),
                    dd.length()
                );
            }
            eprintln!("truth {truth} got {:.2} objects {or}->{os} r {pr:.2} n {nr:.1} s {ps:.2} n {ns:.1} dist {:.2}", vis.between(poses, r, pr, s, ps), d.length());
        }
        let tally = if statics { &mut with_static } else { &mut movables_only };
        tally.0 += (got == truth) as usize;
        tally.1 += 1;
    }
    (with_static, movables_only)
}

#[test]
fn cssm_visibility_agrees_with_ray_casting_at_rest_and_moved() {
    let scene = level();
    assert_eq!(scene.movables.iter().map(|m| m.name.as_str()).collect::<Vec<_>>(), ["door", "block"]);
    let texels = moving_texel_set(&scene, 64, 64);
    let res =
        std::env::var("VIS_RES").ok().and_then(|r| r.parse().ok()).unwrap_or(VisibilityParams::default().res);
    let params = VisibilityParams { res, ..Default::default() };
    let vis = build_visibility(&scene, &texels, &params, Control::none()).unwrap();
    vis.check(texels.len()).unwrap();
    let rig = prm::rig::Rig::load(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/doorway_rig.json"),
        &scene.lights,
    )
    .unwrap();
    let motion = rig.object_motion(std::path::Path::new("rig"), &scene).unwrap();
    for t in [0.0, 1.5, 4.0] {
        let poses = Poses::new(&motion.at_time(t));
        let ((ok, n), (mok, mn)) = agreement(&scene, &texels, &vis, &poses, params.res);
        let rate = ok as f64 / n as f64;
        eprintln!("t = {t}: {ok} / {n} = {:.4} (pairs between movables: {mok} / {mn})", rate);
        // Issue 15's target: 99 %. Measured 99.4-99.7 % (res 16). With one end's map only for
        // pairs on one object, 98.1-98.8 %: the misses were its filtered lookups near 1/2, both
        // ways, which the other end's map mostly settles (`Visibility::between`).
        assert!(n >= 4000 && rate >= 0.99, "t = {t}: {ok} of {n} pairs agree");
    }
    eprintln!("visibility: {} bytes, {} uncompressed", vis.bytes(), vis.uncompressed_bytes());
}

/// Visibility made for a level whose movable flags changed since (same geometry, other
/// objects) is refused.
#[test]
fn visibility_of_another_arrangement_of_objects_is_refused() {
    let scene = level();
    let texels = moving_texel_set(&scene, 32, 32);
    let params = VisibilityParams { res: 4, occluder_dirs: 2, occluder_res: 4 };
    let vis = build_visibility(&scene, &texels, &params, Control::none()).unwrap();
    vis.check_objects(&scene, &texels.texels).unwrap();
    let mut fixed = scene.clone();
    fixed.movables.pop();
    for t in &mut fixed.triangles {
        if t.object == 2 {
            t.object = 0;
        }
    }
    let err = vis.check_objects(&fixed, &texels.texels).unwrap_err();
    assert!(err.contains("2 movable objects, the level has 1"), "{err}");
}

#[test]
fn bad_visibility_files_are_named_errors() {
    let scene = level();
    let texels = moving_texel_set(&scene, 64, 64);
    let params = VisibilityParams { res: 4, occluder_dirs: 2, occluder_res: 4 };
    let vis = build_visibility(&scene, &texels, &params, Control::none()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("doorway.vis");
    let fp = 42;
    write_visibility(&path, &vis, fp).unwrap();
    assert_eq!(read_visibility(&path, fp, texels.len()).unwrap(), vis);
    let err = |p: &std::path::Path, fp: u64, n: usize| read_visibility(p, fp, n).unwrap_err().to_string();
    assert!(err(&path, 43, texels.len()).contains("made for another level"));
    assert!(err(&path, fp, texels.len() + 1).contains("texel slots"));
    let bytes = std::fs::read(&path).unwrap();
    let bad = dir.path().join("bad.vis");
    let mut flipped = bytes.clone();
    flipped[bytes.len() / 2] ^= 1;
    std::fs::write(&bad, &flipped).unwrap();
    assert!(err(&bad, fp, texels.len()).contains("checksum"));
    std::fs::write(&bad, &bytes[..bytes.len() - 3]).unwrap();
    assert!(err(&bad, fp, texels.len()).contains("bad.vis"));
    std::fs::write(&bad, b"not a file").unwrap();
    assert!(err(&bad, fp, texels.len()).contains("no visibility header"));
    assert!(err(&dir.path().join("missing.vis"), fp, 1).contains("missing.vis"));
}

/// A movable's occluder maps block the segments that pass through it and no others (the door
/// at rest: a 4 cm slab across the doorway), against ray casting through the door alone.
#[test]
fn occluder_maps_block_segments_through_the_object() {
    let scene = level();
    let texels = moving_texel_set(&scene, 64, 64);
    let vis = build_visibility(&scene, &texels, &VisibilityParams::default(), Control::none()).unwrap();
    let door: Vec<u32> =
        (0..scene.triangles.len() as u32).filter(|&t| scene.object(t as usize) == 1).collect();
    let bvh = Bvh::build_subset(&scene, &door, scene.diagonal());
    let csm = vis.objects[1].occluder.as_ref().unwrap();
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
    let (mut agree, mut n) = (0, 0);
    while n < 2000 {
        let a =
            Vec3::new(rng.random_range(-3.9..-0.2), rng.random_range(0.1..2.9), rng.random_range(-1.9..1.9));
        let b =
            Vec3::new(rng.random_range(0.2..3.9), rng.random_range(0.1..2.9), rng.random_range(-1.9..1.9));
        let d = b - a;
        let truth = bvh.occluded(a, d.normalize(), d.length());
        // Away from the door's edges: the same answer with b moved 5 cm four ways.
        let (u, v) = d.normalize().any_orthonormal_pair();
        if [u, -u, v, -v]
            .iter()
            .any(|&o| bvh.occluded(a, (b + o * 0.05 - a).normalize(), (b + o * 0.05 - a).length()) != truth)
        {
            continue;
        }
        n += 1;
        let got = csm.blocks(a, b);
        if (got >= 0.5) != truth && std::env::var("VIS_DEBUG").is_ok() {
            eprintln!("csm: truth {truth} got {got:.2} a {a:.2} b {b:.2}");
        }
        agree += ((got >= 0.5) == truth) as usize;
    }
    eprintln!("door occluder maps: {agree} / {n}");
    assert!(agree as f64 >= 0.99 * n as f64, "{agree} of {n}");
}

/// Bad movables and object rigs are errors that name the node.
#[test]
fn bad_movables_and_object_rigs_name_the_node() {
    use prm::glb::{GlbMesh, GlbNode, GlbScene};
    let quad = GlbMesh {
        name: "quad".into(),
        positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 1.0], [0.0, 0.0, 1.0]],
        uv1: Some(vec![[0.1, 0.1], [0.9, 0.1], [0.9, 0.9], [0.1, 0.9]]),
        indices: Some(vec![0, 2, 1, 0, 3, 2]),
        ..Default::default()
    };
    let movable = Some(serde_json::json!({"prm": {"movable": true}}));
    let write = |scene: &GlbScene, dir: &std::path::Path| {
        let path = dir.join("level.glb");
        std::fs::write(&path, scene.to_glb()).unwrap();
        path
    };
    let dir = tempfile::tempdir().unwrap();
    // A movable without geometry.
    let mut s = GlbScene::default();
    s.add_mesh(quad.clone());
    s.add_node(GlbNode { name: "ghost".into(), extras: movable.clone(), ..Default::default() });
    let err = prm::load_scene(write(&s, dir.path()), &prm::LoadOptions::default()).unwrap_err().to_string();
    assert!(err.contains("movable node 'ghost'") && err.contains("no geometry"), "{err}");
    // prm.movable that is not a boolean.
    let mut s = GlbScene::default();
    let m = s.add_mesh(quad.clone());
    s.nodes[m].extras = Some(serde_json::json!({"prm": {"movable": "yes"}}));
    let err = prm::load_scene(write(&s, dir.path()), &prm::LoadOptions::default()).unwrap_err().to_string();
    assert!(err.contains("must be true or false"), "{err}");
    // A movable with a non-uniform scale, and a rig turning it; unknown and unmarked nodes.
    let mut s = GlbScene::default();
    s.add_mesh(quad.clone());
    let mut lid = quad.clone();
    lid.name = "lid".into();
    lid.uv1 = Some(vec![[0.1, 0.1], [0.4, 0.1], [0.4, 0.4], [0.1, 0.4]]);
    s.meshes[0].uv1 = Some(vec![[0.5, 0.5], [0.9, 0.5], [0.9, 0.9], [0.5, 0.9]]);
    s.meshes.push(lid);
    s.add_node(GlbNode {
        name: "lid".into(),
        mesh: Some(1),
        scale: Some([1.0, 2.0, 1.0]),
        translation: Some([0.0, 1.0, 0.0]),
        extras: movable.clone(),
        ..Default::default()
    });
    let scene = prm::load_scene(write(&s, dir.path()), &prm::LoadOptions::default()).unwrap();
    assert_eq!(scene.movables.len(), 1);
    let rig = |json: &str| prm::rig::Rig::parse(std::path::Path::new("r.json"), json, &scene.lights);
    let bind = |json: &str| {
        rig(json).unwrap().object_motion(std::path::Path::new("r.json"), &scene).unwrap_err().to_string()
    };
    let turn = r#"{"objects": [{"name": "lid", "keyframes": [{"time": 0, "rotation": [0.3826834, 0, 0, 0.9238795]}]}]}"#;
    assert!(bind(turn).contains("object 'lid'") && bind(turn).contains("not rigid"), "{}", bind(turn));
    let slide = r#"{"objects": [{"name": "lid", "keyframes": [{"time": 0, "translation": [0, 1, 0]}]}]}"#;
    assert!(rig(slide).unwrap().object_motion(std::path::Path::new("r.json"), &scene).is_ok());
    let unknown = r#"{"objects": [{"name": "hatch", "keyframes": [{"time": 0}]}]}"#;
    assert!(bind(unknown).contains("no such node"), "{}", bind(unknown));
    let unmarked = r#"{"objects": [{"name": "quad", "keyframes": [{"time": 0}]}]}"#;
    assert!(bind(unmarked).contains("not marked movable"), "{}", bind(unmarked));
    let not_unit = r#"{"objects": [{"name": "lid", "keyframes": [{"time": 0, "rotation": [0, 0, 0, 2]}]}]}"#;
    assert!(rig(not_unit).unwrap_err().to_string().contains("not a unit quaternion"));
    let back = r#"{"objects": [{"name": "lid", "keyframes": [{"time": 1}, {"time": 0}]}]}"#;
    assert!(rig(back).unwrap_err().to_string().contains("keyframe 1"));
}

/// The escaping share: none inside the closed doorway level, all of it above a lone floor.
#[test]
fn escape_is_the_open_share_of_the_hemisphere() {
    let scene = level();
    let texels = moving_texel_set(&scene, 32, 32);
    let params = VisibilityParams { res: 8, ..Default::default() };
    let vis = build_visibility(&scene, &texels, &params, Control::none()).unwrap();
    let worst = vis.escape.iter().cloned().fold(0.0f32, f32::max);
    assert!(worst < 0.02, "a texel of the closed level escapes {worst}");
    let floor = Scene::from_mesh(
        vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 0.0, 1.0), Vec3::Z],
        vec![
            glam::Vec2::new(0.05, 0.05),
            glam::Vec2::new(0.95, 0.05),
            glam::Vec2::new(0.95, 0.95),
            glam::Vec2::new(0.05, 0.95),
        ],
        &[0, 2, 1, 0, 3, 2],
    );
    let texels = TexelSet::build(&floor, 8, 8);
    let vis = build_visibility(&floor, &texels, &params, Control::none()).unwrap();
    assert!(vis.escape.iter().all(|&e| (e - 1.0).abs() < 1e-6), "{:?}", &vis.escape[..4]);
}
