//! The bundled scenes: current with their generator, loadable, and what the issue asks of them.

use std::path::PathBuf;

use glam::Vec3;
use prm::{load_scene, Bvh, LightKind, LoadOptions, Scene, TexelSet};

fn asset(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets").join(name)
}

fn load(name: &str) -> Scene {
    load_scene(asset(name), &LoadOptions { require_uv1: true, ..Default::default() }).unwrap()
}

#[test]
fn committed_assets_match_the_generator() {
    for (name, make) in prm_precompute::scenes::all() {
        let bytes = make().unwrap().to_glb();
        let on_disk = std::fs::read(asset(name)).unwrap();
        assert!(on_disk == bytes, "assets/{name} is stale: run `prm gen-assets`");
    }
}

/// Every ray from the texels of a closed level hits something (no holes), and at most
/// `hidden` of them reach a back face: only texels hidden under other geometry (floor under a
/// plinth or a carpet) may see the inside of a solid.
fn assert_closed(scene: &Scene, hidden: f64) {
    let bvh = Bvh::build(scene);
    let set = TexelSet::build(scene, 128, 128);
    let (mut k, mut rays, mut back) = (0u32, 0usize, 0usize);
    for t in set.texels.iter().step_by(3) {
        k = k.wrapping_mul(747796405).wrapping_add(2891336453);
        let a = (k >> 8) as f32 / (1u32 << 24) as f32;
        let b = ((k.wrapping_mul(277803737)) >> 8) as f32 / (1u32 << 24) as f32;
        let (e1, e2) = t.normal.any_orthonormal_pair();
        let r = a.sqrt();
        let phi = std::f32::consts::TAU * b;
        let d = (e1 * r * phi.cos() + e2 * r * phi.sin() + t.normal * (1.0 - a).sqrt()).normalize();
        let hit = bvh.trace_from_surface(t.position, t.normal, d).unwrap_or_else(|| {
            panic!("{}: ray escaped from texel ({}, {}) at {} along {d}", scene.source, t.i, t.j, t.position)
        });
        rays += 1;
        back += (scene.face_normal(hit.triangle as usize).dot(d) >= 0.0) as usize;
    }
    assert!(
        back as f64 <= hidden * rays as f64,
        "{}: {back} of {rays} rays reached a back face",
        scene.source
    );
}

#[test]
fn cornell_box_matches_the_published_box() {
    let s = load("cornell.glb");
    assert_eq!(s.triangles.len(), 30, "5 walls + 2 blocks of 5 faces, 2 triangles each");
    let (lo, hi) = s.bounds();
    assert!((lo - Vec3::ZERO).length() < 1e-6 && (hi - Vec3::new(0.556, 0.5488, 0.5592)).length() < 1e-6);
    assert_eq!(s.lights.len(), 1);
    assert_eq!(s.lights[0].kind, LightKind::Point);
    assert!(s.lights[0].position.y < 0.5488 && s.lights[0].position.y > 0.4);
    assert_eq!(s.cameras.len(), 1);
    // Red on the left (+x seen from the camera), green on the right.
    let red = s.materials.iter().position(|m| m.name == "red").unwrap() as u32;
    let red_x: f32 =
        s.triangles.iter().filter(|t| t.material == red).map(|t| s.positions[t.v[0] as usize].x).sum::<f32>();
    assert!(red_x > 0.5 * 2.0);
    // Room faces point into the box, block faces away from their block.
    let centre = Vec3::new(0.278, 0.274, 0.28);
    for t in 0..10 {
        let p = s.point(t, Vec3::splat(1.0 / 3.0));
        assert!(s.face_normal(t).dot(centre - p) > 0.0, "wall {} faces out", s.describe_triangle(t));
    }
}

#[test]
fn chamber_has_pillars_arches_and_two_lights() {
    let s = load("chamber.glb");
    assert!((3000..=5000).contains(&s.triangles.len()), "{} triangles", s.triangles.len());
    assert_eq!(s.lights.len(), 2);
    assert!(s.lights.iter().any(|l| matches!(l.kind, LightKind::Spot { .. })));
    assert!(prm::uv::find_overlaps(&s).is_empty());
    assert_eq!(s.report.uv_out_of_range, 0);
    assert_closed(&s, 0.015);
}

#[test]
fn two_rooms_are_sealed_except_for_the_door() {
    let s = load("two_rooms.glb");
    assert_eq!(s.lights.len(), 1);
    assert!(s.lights[0].position.x < 0.0, "the light is in room A");
    assert_closed(&s, 0.0);
    let bvh = Bvh::build(&s);
    // Through the door: visible. Through the 10 cm wall: blocked.
    let light = s.lights[0].position;
    assert!(bvh.visible_point(Vec3::new(1.0, 0.0, 0.0), Vec3::Y, Vec3::new(-1.0, 1.0, 0.0)));
    assert!(!bvh.visible_point(Vec3::new(2.0, 0.0, -1.5), Vec3::Y, light));
}

/// The torch rigs (`assets/<level>_torches.json`) put a torch where games do: every keyframe
/// is a place inside the level (rays from it meet only front faces; cornell's front is open), one is mid-room, one 2 cm
/// above the floor, one near three surfaces at once (a corner), one under the ceiling.
#[test]
fn torch_rigs_visit_the_places_games_put_lights() {
    // (level, corner distance: within this of three distinct planes, mid-room: at least this
    // far from everything)
    for (name, corner, mid) in
        [("cornell", 0.06f32, 0.1f32), ("chamber", 0.16, 2.0), ("two_rooms", 0.16, 1.0)]
    {
        let scene = load(&format!("{name}.glb"));
        let bvh = Bvh::build(&scene);
        let rig = prm::rig::Rig::load(&asset(&format!("{name}_torches.json")), &scene.lights).unwrap();
        let torch = rig.lights.iter().find(|l| l.base.name == "torch").expect("a light named torch");
        let keys: Vec<Vec3> = torch.keys.iter().map(|k| k.1).collect();
        assert!(keys.len() >= 6, "{name}: {} placements", keys.len());
        let (mut floor, mut ceiling, mut cornered, mut middle) = (false, false, false, false);
        let top = scene.bounds().1.y;
        for &p in &keys {
            for k in 0..64 {
                let d = prm::sampling::radical_inverse(k);
                let z = 1.0 - 2.0 * (k as f32 + 0.5) / 64.0;
                let phi = std::f32::consts::TAU * d;
                let r = (1.0 - z * z).sqrt();
                let dir = Vec3::new(r * phi.cos(), z, r * phi.sin());
                let Some(hit) = bvh.closest_hit(p, dir, f32::INFINITY) else { continue };
                let t = hit.triangle as usize;
                assert!(scene.facing_normal(t, dir).is_some(), "{name}: torch at {p} is inside a solid");
            }
            let near: Vec<(f32, Vec3)> = (0..scene.triangles.len())
                .map(|t| (scene.distance_to_triangle(t, p), scene.face_normal(t)))
                .collect();
            let nearest = near.iter().map(|x| x.0).fold(f32::INFINITY, f32::min);
            floor |= p.y <= 0.021 && nearest <= 0.021;
            ceiling |= top - p.y <= 0.11;
            middle |= nearest >= mid;
            let mut planes: Vec<Vec3> = Vec::new();
            for (d, n) in near {
                if d <= corner && planes.iter().all(|m| m.dot(n) < 0.9) {
                    planes.push(n);
                }
            }
            cornered |= planes.len() >= 3;
        }
        assert!(
            floor && ceiling && cornered && middle,
            "{name}: floor {floor} ceiling {ceiling} corner {cornered} mid {middle}"
        );
    }
}

/// The chamber's spot rig (`assets/chamber_spots.json`): one spot through eight places, each
/// inside the level with its axis meeting a surface from the front: mid-room over the floor
/// (3 m) and from under the ceiling (6.9 m), and within 26 cm of the surface it aims at in
/// five: down at the floor from 8 cm, along the floor from 3 cm, at a wall from 15 cm, into a
/// corner, at the ceiling from 10 cm.
#[test]
fn the_spot_rig_aims_at_surfaces_near_and_far() {
    let scene = load("chamber.glb");
    let bvh = Bvh::build(&scene);
    let rig = prm::rig::Rig::load(&asset("chamber_spots.json"), &scene.lights).unwrap();
    let spot = rig.lights.iter().find(|l| l.base.name == "spot").expect("a light named spot");
    assert!(matches!(spot.base.kind, prm::LightKind::Spot { .. }));
    let mut reach: Vec<f32> = spot
        .keys
        .iter()
        .map(|&(_, p, d, _)| {
            let d = d.normalize();
            let hit = bvh.closest_hit(p, d, f32::INFINITY).expect("the spot aims out of the level");
            assert!(
                scene.facing_normal(hit.triangle as usize, d).is_some(),
                "the spot at {p} is inside a solid"
            );
            hit.t
        })
        .collect();
    reach.sort_by(f32::total_cmp);
    assert_eq!(reach.len(), 8);
    assert!(reach[4] <= 0.27 && reach[6] >= 2.9, "axis lengths {reach:?}");
}

/// The sunroom's day (`assets/sunroom_sun.json`) keeps the sun in the sky south of the window:
/// at every keyframe a ray from the opening's middle back towards the sun leaves the level,
/// and one along the sunlight lands inside the room; from a low morning sun to a low evening
/// one, through noon.
#[test]
fn the_sunroom_day_sends_the_sun_through_its_window() {
    let scene = load("sunroom.glb");
    let bvh = Bvh::build(&scene);
    let rig = prm::rig::Rig::load(&asset("sunroom_sun.json"), &scene.lights).unwrap();
    let sun = rig.lights.iter().find(|l| l.base.name == "sun").expect("a light named sun");
    assert!(matches!(sun.base.kind, LightKind::Directional));
    let ([x0, x1], [y0, y1], depth) = prm_precompute::scenes::SUNROOM_WINDOW;
    let opening = Vec3::new(0.5 * (x0 + x1), 0.5 * (y0 + y1), -2.5 - 0.5 * depth);
    let mut lowest = f32::INFINITY;
    for k in &sun.keys {
        let d = k.2.normalize();
        lowest = lowest.min(-d.y);
        assert!(d.y < 0.0 && d.z > 0.0, "sun direction {d}: not from above the south");
        assert!(
            bvh.closest_hit(opening, -d, f32::INFINITY).is_none(),
            "sun direction {d}: the sky is blocked"
        );
        let hit = bvh.closest_hit(opening, d, f32::INFINITY).expect("the sunlight lands somewhere");
        let p = opening + d * hit.t;
        assert!(p.z > -2.5 - depth && p.y >= -1e-4, "sun direction {d} lands outside the room at {p}");
    }
    assert!(lowest < 0.25, "no low sun: the lowest is {} over the horizon", lowest.asin().to_degrees());
}

/// The chamber's flashlight rig (`assets/chamber_flashlight.json`): a narrow spot (8°-12°)
/// carried at hand height (1.2-1.6 m), out in the open, through eight aims: each axis meets a
/// surface from the front, from under 1.5 m (a wall, the floor at one's feet) to 6 m across the
/// nave, and two of them meet one of the pillars (marble), where its cells wrap round the
/// shaft (`docs/near-lights.md`, *A flashlight on a pillar*).
#[test]
fn the_flashlight_rig_is_carried_at_hand_height_and_aims_at_pillars_and_walls() {
    let scene = load("chamber.glb");
    let bvh = Bvh::build(&scene);
    let rig = prm::rig::Rig::load(&asset("chamber_flashlight.json"), &scene.lights).unwrap();
    let torch = rig.lights.iter().find(|l| l.base.name == "flashlight").expect("a light named flashlight");
    assert!(matches!(torch.base.kind, prm::LightKind::Spot { outer, .. } if outer < 0.25));
    let pillar = scene.materials.iter().position(|m| m.name == "pillar").expect("a pillar material") as u32;
    let (mut reach, mut on_pillars) = (Vec::new(), 0);
    for &(_, p, d, _) in &torch.keys {
        assert!((1.2..=1.6).contains(&p.y), "the flashlight at {p}: not at hand height");
        let d = d.normalize();
        let hit = bvh.closest_hit(p, d, f32::INFINITY).expect("the flashlight aims out of the level");
        assert!(
            scene.facing_normal(hit.triangle as usize, d).is_some(),
            "the flashlight at {p} is inside a solid"
        );
        on_pillars += (scene.triangles[hit.triangle as usize].material == pillar) as usize;
        reach.push(hit.t);
    }
    reach.sort_by(f32::total_cmp);
    assert_eq!(reach.len(), 8);
    assert!(reach[0] < 1.5 && reach[7] > 5.0, "axis lengths {reach:?}");
    assert!(on_pillars >= 2, "{on_pillars} aims meet a pillar");
}

/// two_rooms' flashlight rig (`assets/two_rooms_flashlight.json`; `docs/near-lights.md`, *The
/// same flashlight in two_rooms*): the chamber's narrow spot carried at 1.5 m through the two
/// rooms and their door (x = 0, 1 m wide, 2.1 m high). Each aim meets a surface from the front;
/// two send the beam through the door, one each way (the axis crosses the wall's plane inside
/// the opening and lands in the other room), and two land on the door's own faces (its jamb
/// and its lintel, within the wall's 10 cm).
#[test]
fn the_two_rooms_flashlight_shines_through_the_door_both_ways_and_onto_its_frame() {
    let scene = load("two_rooms.glb");
    let bvh = Bvh::build(&scene);
    let rig = prm::rig::Rig::load(&asset("two_rooms_flashlight.json"), &scene.lights).unwrap();
    let torch = rig.lights.iter().find(|l| l.base.name == "flashlight").expect("a light named flashlight");
    assert!(matches!(torch.base.kind, prm::LightKind::Spot { outer, .. } if outer < 0.25));
    let (mut through, mut on_frame) = ([0usize; 2], 0);
    for &(_, p, d, _) in &torch.keys {
        assert!((p.y - 1.5).abs() < 1e-4, "the flashlight at {p}: not at hand height");
        let d = d.normalize();
        let hit = bvh.closest_hit(p, d, f32::INFINITY).expect("the flashlight aims out of the level");
        assert!(
            scene.facing_normal(hit.triangle as usize, d).is_some(),
            "the flashlight at {p} is inside a solid"
        );
        let q = p + d * hit.t;
        if q.x.abs() <= 0.05 + 1e-3 {
            on_frame += 1;
            continue;
        }
        if p.x.signum() != q.x.signum() {
            // Where the axis crosses the wall's plane: inside the opening.
            let at = p + d * (-p.x / d.x);
            assert!(
                at.z.abs() < 0.5 && at.y < 2.1,
                "the beam from {p} crosses the wall at {at}, not the door"
            );
            through[(p.x > 0.0) as usize] += 1;
        }
    }
    assert!(through[0] >= 1 && through[1] >= 1, "through the door from A, from B: {through:?}");
    assert!(on_frame >= 2, "{on_frame} aims land on the door's faces");
}
