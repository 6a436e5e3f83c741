//! Scenes the precompute crate's tests build by hand.
#![allow(dead_code)]

use glam::{Vec2, Vec3};
use prm::Scene;

pub fn v(x: f32, y: f32, z: f32) -> Vec3 {
    Vec3::new(x, y, z)
}

/// Quads (a, b, c, d counter-clockwise from the front) as one scene of grey albedo `albedo`,
/// each quad its own UV chart on a 4 x 4 grid of cells.
pub fn quads(qs: &[[Vec3; 4]], albedo: f32) -> Scene {
    let (mut pos, mut uv, mut idx) = (Vec::new(), Vec::new(), Vec::new());
    for (k, q) in qs.iter().enumerate() {
        let cell = Vec2::new((k % 4) as f32, (k / 4) as f32);
        let base = pos.len() as u32;
        for (c, p) in q.iter().enumerate() {
            pos.push(*p);
            let corner =
                [Vec2::new(0.0, 0.0), Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0)][c];
            uv.push((cell + Vec2::splat(0.08) + corner * 0.84) / 4.0);
        }
        idx.extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    }
    let mut s = Scene::from_mesh(pos, uv, &idx);
    s.materials[0].albedo = Vec3::splat(albedo);
    s
}

/// The six inward faces of the unit box.
pub fn unit_box_faces() -> Vec<[Vec3; 4]> {
    vec![
        [v(0., 0., 0.), v(0., 0., 1.), v(1., 0., 1.), v(1., 0., 0.)],
        [v(0., 1., 0.), v(1., 1., 0.), v(1., 1., 1.), v(0., 1., 1.)],
        [v(0., 0., 0.), v(1., 0., 0.), v(1., 1., 0.), v(0., 1., 0.)],
        [v(1., 0., 1.), v(0., 0., 1.), v(0., 1., 1.), v(1., 1., 1.)],
        [v(0., 0., 1.), v(0., 0., 0.), v(0., 1., 0.), v(0., 1., 1.)],
        [v(1., 0., 0.), v(1., 0., 1.), v(1., 1., 1.), v(1., 1., 0.)],
    ]
}
