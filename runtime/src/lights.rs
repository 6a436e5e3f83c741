//! Lights on the GPU: checking them, their shadow-map frusta, and the WGSL library
//! (`shaders/lights.wgsl`: incident light, cube-face choice, shadow-mapped visibility) that
//! the irradiance and shading shaders are built on.
//!
//! Shadow frusta (DESIGN.md §5 step 1), all reverse-Z (depth 1 at the light, 0 far away):
//! - point: a cube of six perspective faces (+X -X +Y -Y +Z -Z), each a little wider than 90°
//!   so the 3x3 PCF footprint at a face edge stays inside the face;
//! - spot: one perspective frustum just wider than the outer cone, or a cube when the cone is
//!   wider than 60° (a perspective frustum cannot hold a hemisphere);
//! - directional: orthographic boxes over the level's bounding box seen from the light, in a
//!   grid of n x n tiles (n from the level's size, [`sun_tiles`]) so that a level many rooms
//!   wide keeps the texel a room gets (one 1024² map over 16 sunlit rooms left the GPU's
//!   lightmap 13-21 % from the twin's). Each tile's map reaches [`SUN_TILE_MARGIN`] texels past
//!   its part of the grid, and a lookup picks its tile from where it falls in the first tile's
//!   map (`shaders/lights.wgsl` `sun_layer`).
//!
//! The near plane of perspective frusta is 1e-6 of the level's diagonal, so a light almost
//! touching a surface still sees it (reverse-Z keeps the depth precision).

use glam::camera::rh::proj::directx::{orthographic, perspective_infinite_reverse};
use glam::camera::rh::view::look_to_mat4;
use glam::{Mat4, Vec2, Vec3};
use prm::{Light, LightKind};

use crate::contract::CUBE_LAYERS;
use crate::layout::GpuLight;

/// The WGSL library of every shader that lights surfaces (after the prelude and bindings,
/// before the pass: [`crate::contract::Shader::source`]).
pub const LIBRARY: &str = include_str!("../../shaders/lights.wgsl");

/// The most of the level (its bounding sphere's diameter, in scene units: metres) one tile of a
/// directional light's map covers: the sunlit room's 8.4 m take 3 x 3 tiles, whose 1024²
/// texels are 3.9 mm. With one tile (8.3 mm texels; 10 m here before) its GPU lightmap was
/// 2.3-4.8 % darker than the twin's over the day, with 3 x 3 within 0.9 % (`docs/sunroom.md`, *A
/// sunlit room*). A level wider than [`SUN_TILES_MAX`] tiles of this keeps that many, wider.
pub const SUN_TILE_SPAN: f32 = 4.0;

/// Tiles per side of a directional light's map at most, by default
/// ([`crate::RuntimeParams::sun_tiles`]): 16 layers, 64 MB of depth at 1024².
pub const SUN_TILES_MAX: u32 = 4;

/// Texels each tile of a directional light's map reaches past its part of the grid on every
/// side: a lookup's 3 x 3 PCF of bilinear taps reaches 2 texels from the point that picked the
/// tile, so it never reads past the tile's map.
pub const SUN_TILE_MARGIN: u32 = 4;

/// Tiles per side of a directional light's map over a level of bounds `bounds`: enough that a
/// tile covers at most [`SUN_TILE_SPAN`] of the level's bounding-sphere diameter, 1 to `max`.
/// It does not depend on the light's direction, so a moving sun keeps its layers.
pub fn sun_tiles(bounds: Bounds, max: u32) -> u32 {
    let n = (2.0 * bounds.radius / SUN_TILE_SPAN).ceil();
    if n.is_finite() && n >= 1.0 {
        (n.min(u32::MAX as f32) as u32).clamp(1, max.max(1))
    } else {
        1
    }
}

/// Spot cones wider than this (half-angle, radians) get a cube of shadow maps.
pub const SPOT_CUBE_ABOVE: f32 = std::f32::consts::PI / 3.0;

/// A light the runtime refuses, with why.
#[derive(Debug, thiserror::Error)]
pub enum LightError {
    #[error("light '{name}' (#{index}): {what}")]
    Invalid { index: usize, name: String, what: String },
    #[error("{count} lights; the runtime's limit is {max} (prm::rig::MAX_LIGHTS)")]
    TooMany { count: usize, max: usize },
    #[error(
        "these lights need {needed} shadow-map layers (6 per point light or wide spot, a directional \
        light's tiles, 1 otherwise); the device allows {max}"
    )]
    TooManyLayers { needed: u32, max: u32 },
}

/// Checks every light for values the shaders cannot use.
pub fn validate(lights: &[Light]) -> Result<(), LightError> {
    if lights.len() > prm::rig::MAX_LIGHTS {
        return Err(LightError::TooMany { count: lights.len(), max: prm::rig::MAX_LIGHTS });
    }
    for (index, l) in lights.iter().enumerate() {
        let bad = |what: String| Err(LightError::Invalid { index, name: l.name.clone(), what });
        if !l.is_punctual() {
            return bad(
                "a sphere or polygon aperture or a photometric profile is for the bakers; the runtime's \
                shadow-mapped lights are punctual"
                    .into(),
            );
        }
        if l.is_positional() && !l.position.is_finite() {
            return bad(format!("position {} is not finite", l.position));
        }
        if !l.intensity.is_finite() || l.intensity.min_element() < 0.0 {
            return bad(format!("intensity {} must be finite and >= 0", l.intensity));
        }
        let unit = l.direction.is_finite() && (l.direction.length() - 1.0).abs() < 1e-3;
        if !matches!(l.kind, LightKind::Point) && !unit {
            return bad(format!("direction {} is not a unit vector", l.direction));
        }
        if let LightKind::Spot { inner, outer } = l.kind {
            if !(0.0 <= inner && inner <= outer && outer <= std::f32::consts::FRAC_PI_2) {
                return bad(format!(
                    "cone angles inner {inner} outer {outer} rad must satisfy 0 <= inner <= outer <= pi/2"
                ));
            }
        }
        if let Some(r) = l.range {
            if !(r.is_finite() && r >= 0.0) {
                return bad(format!("range {r} must be finite and >= 0"));
            }
        }
    }
    Ok(())
}

/// Shadow layers a light owns, a directional light's map being `sun_tiles` x `sun_tiles` tiles.
/// A spot with one frustum whose spots the far field sees (`close`: it lights some cell up
/// close, [`crate::cpu::UpClose`], and is among the first [`crate::cpu::CLOSE_SIGHTS`] that
/// do, [`crate::cpu::sighted`]) also owns a cube after it, at its eye: the spot of light it
/// makes lights the room, and the far field sees that spot as each texel sees the eye, in the
/// cube (`shaders/far.wgsl`).
pub fn layers(l: &Light, sun_tiles: u32, close: bool) -> u32 {
    match l.kind {
        LightKind::Point => CUBE_LAYERS,
        LightKind::Spot { outer, .. } if outer > SPOT_CUBE_ABOVE => CUBE_LAYERS,
        LightKind::Directional => sun_tiles * sun_tiles,
        LightKind::Spot { .. } if close => 1 + CUBE_LAYERS,
        LightKind::Spot { .. } => 1,
    }
}

/// Shadow texels a cube face reaches past its 90° on each side (so a lookup's PCF near a
/// face's edge stays on the face it picked).
pub const CUBE_PAD_TEXELS: f32 = 4.0;

/// The level's bounding box and the sphere around it (centre, radius), used to fit directional
/// frusta and near planes.
#[derive(Clone, Copy, Debug)]
pub struct Bounds {
    pub lo: Vec3,
    pub hi: Vec3,
    pub centre: Vec3,
    pub radius: f32,
}

impl Bounds {
    /// The bounds of the box `lo`..`hi` (a unit box at the origin when it is not finite).
    pub fn of_box(lo: Vec3, hi: Vec3) -> Bounds {
        if lo.is_finite() && hi.is_finite() && lo.cmple(hi).all() {
            Bounds { lo, hi, centre: (lo + hi) * 0.5, radius: ((hi - lo) * 0.5).length() }
        } else {
            Bounds {
                lo: Vec3::splat(-0.5),
                hi: Vec3::splat(0.5),
                centre: Vec3::ZERO,
                radius: 3f32.sqrt() * 0.5,
            }
        }
    }
}

/// View-projection matrices of a light's layers and the world size of one shadow texel
/// (per unit distance for perspective layers), for maps of `size` x `size` (a directional
/// light's in `sun_tiles` x `sun_tiles` tiles, row by row from the map's top left). A spot
/// that lights a cell up close (`close`) has its cube at its eye (`crate::cpu::sight_eye`),
/// where the far field sees its spots from; every other cube is at its light.
pub fn frusta(
    l: &Light,
    size: u32,
    bounds: Bounds,
    sun_tiles: u32,
    close: bool,
    eye: Vec3,
) -> (Vec<Mat4>, f32) {
    let pad = 1.0 + CUBE_PAD_TEXELS / size as f32;
    let near = (bounds.radius * 2e-6).max(f32::MIN_POSITIVE * 1e6);
    let cube = |pos: Vec3| {
        let half = pad.atan();
        let proj = perspective_infinite_reverse(2.0 * half, 1.0, near);
        let faces = [
            (Vec3::X, -Vec3::Y),
            (-Vec3::X, -Vec3::Y),
            (Vec3::Y, Vec3::Z),
            (-Vec3::Y, -Vec3::Z),
            (Vec3::Z, -Vec3::Y),
            (-Vec3::Z, -Vec3::Y),
        ];
        let mats = faces.iter().map(|&(d, up)| proj * look_to_mat4(pos, d, up)).collect();
        (mats, 2.0 * pad / size as f32)
    };
    match l.kind {
        LightKind::Point => cube(l.position),
        LightKind::Spot { outer, .. } if outer > SPOT_CUBE_ABOVE => cube(l.position),
        LightKind::Spot { outer, .. } => {
            let half = (outer.max(1e-3).tan() * pad).atan();
            let proj = perspective_infinite_reverse(2.0 * half, 1.0, near);
            let mut mats = vec![proj * look_to_mat4(l.position, l.direction, up_for(l.direction))];
            if close {
                mats.extend(cube(eye).0);
            }
            (mats, 2.0 * half.tan() / size as f32)
        }
        LightKind::Directional => sun_frusta(l.direction, size, bounds, sun_tiles),
    }
}

/// A directional light's tiles (see the module doc): the rectangle the level's box spans seen
/// from the light, in a grid of `n` x `n` tiles, each drawn [`SUN_TILE_MARGIN`] texels wider
/// on every side. Tile (i, j) is layer j n + i, i along the
/// map's u and j along its v (down the map). Depth covers the bounding sphere, as one map did.
fn sun_frusta(direction: Vec3, size: u32, bounds: Bounds, n: u32) -> (Vec<Mat4>, f32) {
    let n = n.max(1);
    let r = bounds.radius.max(1e-30) * 1.01;
    let view = look_to_mat4(bounds.centre - direction * r, direction, up_for(direction));
    let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
    for k in 0..8 {
        let pick = |bit: u32, a: f32, b: f32| if k & bit == 0 { a } else { b };
        let corner = Vec3::new(
            pick(1, bounds.lo.x, bounds.hi.x),
            pick(2, bounds.lo.y, bounds.hi.y),
            pick(4, bounds.lo.z, bounds.hi.z),
        );
        let p = view.transform_point3(corner).truncate();
        lo = lo.min(p);
        hi = hi.max(p);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        (lo, hi) = (Vec2::splat(-r), Vec2::splat(r));
    }
    // Each tile an n-th of the rectangle along each axis, so that every tile holds some of
    // the level (a low sun's rectangle is long and narrow). Texels along the two axes may then
    // differ; the larger is the light's texel (the offsets and reaches it sets are the larger).
    let side = ((hi - lo) / n as f32).max(Vec2::splat(r * 1e-6));
    let margin = SUN_TILE_MARGIN as f32;
    let step = side / (size as f32 - 2.0 * margin).max(1.0);
    let reach = size as f32 * step;
    let mut mats = Vec::with_capacity((n * n) as usize);
    for j in 0..n {
        for i in 0..n {
            let left = lo.x + i as f32 * side.x - margin * step.x;
            let top = lo.y + (n - j) as f32 * side.y + margin * step.y;
            mats.push(orthographic(left, left + reach.x, top - reach.y, top, 2.0 * r, 0.0) * view);
        }
    }
    let texel = step.max_element();
    (mats, texel)
}

/// The layer (counted from the light's first) of a directional light's `n` x `n` tiles that a
/// lookup at uv `uv` of its first tile's map reads, for maps of `size` texels: the CPU form of
/// `shaders/lights.wgsl` `sun_tile`.
#[cfg(test)]
pub fn sun_tile(uv: Vec2, size: u32, n: u32) -> u32 {
    let (size, m) = (size as f32, SUN_TILE_MARGIN as f32);
    let t =
        ((uv * size - m) / (size - 2.0 * m)).floor().clamp(Vec2::ZERO, Vec2::splat((n.max(1) - 1) as f32));
    t.y as u32 * n + t.x as u32
}

fn up_for(dir: Vec3) -> Vec3 {
    if dir.y.abs() > 0.99 {
        Vec3::Z
    } else {
        Vec3::Y
    }
}

/// GPU lights and their layer matrices for `lights` (already validated), each with whether it
/// lights a cell up close and its eye ([`frusta`]).
pub fn pack(
    lights: &[Light],
    size: u32,
    bounds: Bounds,
    sun_tiles: u32,
    close: &[bool],
    eyes: &[Vec3],
) -> (Vec<GpuLight>, Vec<Mat4>) {
    let mut gpu = Vec::with_capacity(lights.len());
    let mut mats = Vec::new();
    for (i, l) in lights.iter().enumerate() {
        let close = close.get(i).copied().unwrap_or(false);
        let eye = eyes.get(i).copied().unwrap_or(l.position);
        let (m, texel) = frusta(l, size, bounds, sun_tiles, close, eye);
        gpu.push(GpuLight::new(l, mats.len() as u32, m.len() as u32, texel));
        mats.extend(m);
    }
    (gpu, mats)
}

/// The same shadow frusta: what decides whether a light's maps must be re-rendered.
pub fn same_shadow(a: &Light, b: &Light) -> bool {
    a.kind == b.kind
        && a.range == b.range
        && (!a.is_positional() || a.position == b.position)
        && (matches!(a.kind, LightKind::Point) || a.direction == b.direction)
}

#[cfg(test)]
mod sun_tests {
    use super::*;
    use crate::tests::passes::sun;

    /// Every point of a level 40 x 6 x 30 m picks, from the first tile's map, a tile whose map
    /// holds it at least SUN_TILE_MARGIN texels in from every edge (so its 3 x 3 PCF stays in
    /// the tile) and within the depth range; every tile has the same texels, no larger than one
    /// map's over the bounding sphere would be a tile, and every tile holds some of the level.
    #[test]
    fn each_point_of_the_level_reads_a_tile_that_holds_its_lookup() {
        let bounds = Bounds::of_box(Vec3::new(-3.0, 0.0, -2.75), Vec3::new(37.0, 6.0, 27.0));
        let n = sun_tiles(bounds, SUN_TILES_MAX);
        assert_eq!(n, 4, "a 50 m level in tiles of at most {SUN_TILE_SPAN} m, at most 4 a side");
        assert_eq!(sun_tiles(bounds, 1), 1);
        // The sunlit room's box (8.4 m across): 3 x 3 tiles of at most 4 m.
        assert_eq!(sun_tiles(Bounds::of_box(Vec3::ZERO, Vec3::new(6.0, 3.0, 5.0)), SUN_TILES_MAX), 3);
        assert_eq!(sun_tiles(Bounds::of_box(Vec3::ZERO, Vec3::new(2.0, 2.0, 2.0)), SUN_TILES_MAX), 1);
        let size = 1024;
        let margin = SUN_TILE_MARGIN as f32 / size as f32;
        for dir in
            [Vec3::new(0.9192, -0.2079, 0.3345), Vec3::new(0.0, -0.788, 0.6157), Vec3::new(0.01, -1.0, 0.0)]
        {
            let l = sun(dir);
            assert_eq!(layers(&l, n, false), 16);
            let (mats, texel) = frusta(&l, size, bounds, n, false, l.position);
            assert_eq!(mats.len(), 16);
            // One map over the level's bounding sphere had texels of its diameter / size.
            assert!(texel * size as f32 <= 2.0 * bounds.radius / n as f32 * 1.01, "texel {texel}");
            let mut used = vec![false; 16];
            let steps = 24;
            for i in 0..=steps {
                for j in 0..=steps {
                    for k in 0..=4 {
                        let t = Vec3::new(i as f32, k as f32 * steps as f32 / 4.0, j as f32) / steps as f32;
                        let p = bounds.lo + (bounds.hi - bounds.lo) * t;
                        let uv = |m: Mat4| {
                            let c = m * p.extend(1.0);
                            (Vec2::new(c.x * 0.5 + 0.5, 0.5 - c.y * 0.5), c.z)
                        };
                        let tile = sun_tile(uv(mats[0]).0, size, n) as usize;
                        used[tile] = true;
                        let (at, depth) = uv(mats[tile]);
                        assert!(
                            at.cmpge(Vec2::splat(margin - 1e-4)).all()
                                && at.cmple(Vec2::splat(1.0 - margin + 1e-4)).all(),
                            "{p} picks tile {tile} at uv {at}"
                        );
                        assert!((0.0..=1.0).contains(&depth), "{p}: depth {depth}");
                    }
                }
            }
            // Every tile has the same texels, the larger of the two `texel`.
            let world =
                |m: Mat4, axis: Vec3| m.inverse().transform_vector3(axis).length() * 2.0 / size as f32;
            let first = (world(mats[0], Vec3::X), world(mats[0], Vec3::Y));
            assert!((first.0.max(first.1) - texel).abs() <= 1e-4 * texel, "{first:?} vs {texel}");
            for m in &mats {
                let t = (world(*m, Vec3::X), world(*m, Vec3::Y));
                assert!((t.0 - first.0).abs() <= 1e-4 * first.0 && (t.1 - first.1).abs() <= 1e-4 * first.1);
            }
            assert!(used.iter().all(|&u| u), "every tile holds some of the level: {used:?}");
        }
    }
}
