//! Scenes the runtime's tests build by hand: the integration tests (`mod common;`) and the
//! crate's own unit tests (`runtime/src/tests/`, by path) share them.
#![allow(dead_code)]

use glam::{Vec2, Vec3};
use prm::{Light, Scene};

pub fn v(x: f32, y: f32, z: f32) -> Vec3 {
    Vec3::new(x, y, z)
}

/// A point light named "p" of `i` W/sr in every channel.
pub fn point(p: Vec3, i: f32) -> Light {
    Light::point("p", p, Vec3::splat(i))
}

/// Quads (corners counter-clockwise seen from the lit side), each in its own UV cell of a row.
pub fn quads(qs: &[[Vec3; 4]]) -> Scene {
    quads_in_grid(qs, qs.len())
}

/// [`quads`] with the UV cells in rows of `columns`.
pub fn quads_in_grid(qs: &[[Vec3; 4]], columns: usize) -> Scene {
    let (mut pos, mut uv, mut idx) = (Vec::new(), Vec::new(), Vec::new());
    let grid = Vec2::new(columns as f32, qs.len().div_ceil(columns) as f32);
    for (k, q) in qs.iter().enumerate() {
        let base = pos.len() as u32;
        let cell = Vec2::new((k % columns) as f32, (k / columns) as f32);
        for (c, p) in q.iter().enumerate() {
            pos.push(*p);
            let corner =
                [Vec2::new(0.0, 0.0), Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0)][c];
            uv.push((cell + Vec2::splat(0.08) + corner * 0.84) / grid);
        }
        idx.extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    }
    Scene::from_mesh(pos, uv, &idx)
}

/// A box from the origin to `size`, closed on all six sides (UV cells 3 x 2), a 2 W/sr point
/// light inside: a room, where light bounces until the walls absorb it.
pub fn closed_box(size: Vec3) -> Scene {
    let mut s = quads_in_grid(&box_quads(Vec3::ZERO, size), 3);
    s.lights.push(point(v(0.6, 0.8, 0.6), 2.0));
    s
}

/// The six sides of the box from `origin` to `origin + size`, facing in (floor, ceiling, the
/// walls at z = 0, z = 1, x = 0, x = 1 of the unit box).
pub fn box_quads(origin: Vec3, size: Vec3) -> [[Vec3; 4]; 6] {
    let q = |c: [[f32; 3]; 4]| c.map(|p| origin + Vec3::from(p) * size);
    [
        q([[0., 0., 0.], [0., 0., 1.], [1., 0., 1.], [1., 0., 0.]]),
        q([[0., 1., 0.], [1., 1., 0.], [1., 1., 1.], [0., 1., 1.]]),
        q([[0., 0., 0.], [1., 0., 0.], [1., 1., 0.], [0., 1., 0.]]),
        q([[0., 0., 1.], [0., 1., 1.], [1., 1., 1.], [1., 0., 1.]]),
        q([[0., 0., 1.], [0., 0., 0.], [0., 1., 0.], [0., 1., 1.]]),
        q([[1., 0., 0.], [1., 0., 1.], [1., 1., 1.], [1., 1., 0.]]),
    ]
}

/// The faces `faces` of the box from `origin` to `origin + size`, turned out ([`box_quads`]'
/// face in): its sides are 2..6 and its top 1.
pub fn out(origin: Vec3, size: Vec3, faces: std::ops::Range<usize>) -> Vec<[Vec3; 4]> {
    box_quads(origin, size)[faces].iter().map(|q| [q[0], q[3], q[2], q[1]]).collect()
}

/// A closed 4 x 2 x 2 m room with a pillar in its middle (a 20 cm square shaft up to 1.6 m
/// under a 60 cm square abacus 10 cm thick) and a 2 W/sr lamp 3 cm over the floor 90 cm from
/// the shaft: the abacus's underside on the lamp's side sees the lamp's spot, on the far side
/// the shaft hides it, and its few entries lie on both sides.
pub fn pillar_room() -> Scene {
    let mut qs = box_quads(Vec3::ZERO, v(4.0, 2.0, 2.0)).to_vec();
    qs.extend(out(v(1.9, 0.0, 0.9), v(0.2, 1.6, 0.2), 2..6));
    qs.extend(out(v(1.7, 1.6, 0.7), v(0.6, 0.1, 0.6), 1..6));
    let under =
        |x0: f32, x1: f32, z0: f32, z1: f32| [v(x0, 1.6, z0), v(x1, 1.6, z0), v(x1, 1.6, z1), v(x0, 1.6, z1)];
    qs.extend([
        under(1.7, 1.9, 0.7, 1.3),
        under(2.1, 2.3, 0.7, 1.3),
        under(1.9, 2.1, 0.7, 0.9),
        under(1.9, 2.1, 1.1, 1.3),
    ]);
    let mut s = quads_in_grid(&qs, 5);
    s.lights.push(point(v(1.0, 0.03, 1.0), 2.0));
    s
}

/// A closed 4 x 2 x 2 m room with a pillar on a plinth (a 20 cm square shaft from the
/// plinth's top up to 1.6 m, on an 80 cm square plinth 30 cm high) and a narrow spot (8-12°,
/// 20 W/sr) 1.5 m in front of the shaft at 1.3 m, aimed at it a little low: its beam lands on
/// the shaft's upper half (and round it, on the far wall). The floor just before the plinth
/// sees the shaft only above its line over the plinth's edge (1.2 m up from 10 cm out), so the
/// shaft's cells are hidden from it in part: the chamber's flashlight across the nave
/// (`docs/near-lights.md`).
pub fn plinth_room() -> Scene {
    let mut qs = box_quads(Vec3::ZERO, v(4.0, 2.0, 2.0)).to_vec();
    qs.extend(out(v(1.9, 0.3, 0.9), v(0.2, 1.7, 0.2), 2..6));
    qs.extend(out(v(1.6, 0.0, 0.6), v(0.8, 0.3, 0.8), 1..6));
    let mut s = quads_in_grid(&qs, 5);
    let mut spot = point(v(0.4, 1.3, 1.0), 20.0);
    spot.kind = prm::LightKind::Spot { inner: 8f32.to_radians(), outer: 12f32.to_radians() };
    spot.direction = (v(1.9, 1.15, 1.0) - spot.position).normalize();
    s.lights.push(spot);
    s
}

/// A closed 4 x 2 x 2 m room lit by one spot (20-35°, 20 W/sr) 15 cm from each of the three
/// surfaces of its corner at the origin, aimed into it: the chamber's spot rig at its corner
/// (`assets/chamber_spots.json`, frame 5), where the floor a few mm from a wall sees the wall's
/// lowest cm, lit by the floor's hot spot beside it.
pub fn corner_spot_room() -> Scene {
    let mut s = quads_in_grid(&box_quads(Vec3::ZERO, v(4.0, 2.0, 2.0)), 5);
    let mut spot = point(v(0.15, 0.15, 0.15), 20.0);
    spot.kind = prm::LightKind::Spot { inner: 20f32.to_radians(), outer: 35f32.to_radians() };
    spot.direction = -Vec3::ONE.normalize();
    s.lights.push(spot);
    s
}

/// [`pillar_room`] lit by one narrow spot (10°-15°, 4 W/sr) 75 cm in front of its +z wall and
/// aimed at it, the pillar 15 cm behind the light: the light stands off the wall's lit patch
/// by more than the patch's cells are across, and sees round the pillar where the patch does
/// not.
pub fn pillar_room_spot_off_a_wall() -> Scene {
    let mut scene = pillar_room();
    let mut spot = point(v(2.0, 1.0, 1.25), 4.0);
    spot.kind = prm::LightKind::Spot { inner: 10f32.to_radians(), outer: 15f32.to_radians() };
    spot.direction = Vec3::Z;
    scene.lights = vec![spot];
    scene
}

/// Floor and two walls of the unit cube, open on three sides, a 2 W/sr point light inside.
pub fn open_box() -> Scene {
    let mut s = quads(&[
        [v(0., 0., 0.), v(0., 0., 1.), v(1., 0., 1.), v(1., 0., 0.)],
        [v(0., 0., 0.), v(1., 0., 0.), v(1., 1., 0.), v(0., 1., 0.)],
        [v(0., 0., 1.), v(0., 0., 0.), v(0., 1., 0.), v(0., 1., 1.)],
    ]);
    s.lights.push(point(v(0.6, 0.8, 0.6), 2.0));
    s
}
