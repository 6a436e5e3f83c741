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
    let (mut pos, mut uv, mut idx) = (Vec::new(), Vec::new(), Vec::new());
    let n = qs.len() as f32;
    for (k, q) in qs.iter().enumerate() {
        let base = pos.len() as u32;
        for (c, p) in q.iter().enumerate() {
            pos.push(*p);
            let corner =
                [Vec2::new(0.0, 0.0), Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0)][c];
            uv.push((Vec2::new(k as f32, 0.0) + Vec2::splat(0.08) + corner * 0.84) / Vec2::new(n, 1.0));
        }
        idx.extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    }
    Scene::from_mesh(pos, uv, &idx)
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
