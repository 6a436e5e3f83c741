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
